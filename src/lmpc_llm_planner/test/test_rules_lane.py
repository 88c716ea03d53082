"""Rule 8, lane choice (backends/rules/lane.py), its steps called directly on the two-lane
straight road of ``lmpc_mpc.synthetic.straight_road`` (``E0_0`` right at y = -4.8,
``E0_1`` left at y = -1.6, eastbound, 400 m; the ego at x = 50 unless told) and on a
variant whose route goes on only from the left lane."""
from __future__ import annotations

import pytest
from rules_kit import accel_mid, ask, car, road_obs
from rules_units import accel_of, fresh_plan, inputs

from lmpc_msgs_py.messages import LaneLink

from lmpc_llm_planner.backends.rules import parse_instruction
from lmpc_llm_planner.backends.rules.lane import (
    LeaderState, closed_lanes, continuing_lanes, gap_blocker, lane_rule, lane_state,
    lane_view, leader_state, overtake,
)


@pytest.fixture(scope="module")
def exit_left(road):
    """The road, but the route goes on (to ``N_0``) only from the left lane ``E0_1``."""
    right, left, back = road.lanes
    left = left.model_copy(update={"successors": (LaneLink(to_lane="N_0", direction="s"),)})
    on = left.model_copy(update={"id": "N_0", "edge_id": "N", "index": 0, "successors": (),
                                 "centerline": ((400.0, -1.6), (600.0, -1.6)),
                                 "length_m": 200.0})
    return road.model_copy(update={"lanes": (right, left, back, on),
                                   "ego_route": ("E0_0", "N_0")})


def label(inp, plan):
    return inp.scene.ego_candidates[plan.ego_index].label


def test_lane_view_of_the_road(road, planner_config, mpc_config):
    inp = inputs(road_obs(road), planner_config, mpc_config)
    lv = lane_view(inp.scene, inp.intent)
    assert lv is not None and lv.here.id == "E0_0"
    assert sorted(ln.id for ln in lv.siblings.values()) == ["E0_0", "E0_1"]
    assert set(lv.by_lane) == {"E0_0", "E0_1"}
    assert lv.need == 0 and lv.toward is None  # the route ends on this edge
    assert lv.dist_end_m == pytest.approx(400.0 - 52.25)


def test_lane_rule_does_not_apply_on_a_single_lane(left_turn_map, obs_factory,
                                                   planner_config, mpc_config):
    inp = inputs(obs_factory(left_turn_map), planner_config, mpc_config)
    assert lane_view(inp.scene, inp.intent) is None
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "none" and plan.ego_index is None


def test_closed_lanes_by_side_and_traffic_hand(road):
    siblings = {ln.index: ln for ln in road.lanes if ln.edge_id == "E0"}
    both = parse_instruction("right lane closed, left lane blocked")
    right = parse_instruction("the right lane is closed")
    assert closed_lanes(right, siblings, left_hand=False) == {"E0_0"}
    assert closed_lanes(right, siblings, left_hand=True) == {"E0_1"}  # outer = highest index
    assert closed_lanes(both, siblings, left_hand=False) == {"E0_0", "E0_1"}


def test_continuing_lanes_follow_the_route(exit_left, road, planner_config, mpc_config):
    inp = inputs(road_obs(exit_left), planner_config, mpc_config)
    lv = lane_view(inp.scene, inp.intent)
    assert [ln.id for ln in continuing_lanes(inp.scene, lv.here, lv.siblings)] == ["E0_1"]
    assert lv.need == 1 and lv.toward == 1
    plain = inputs(road_obs(road), planner_config, mpc_config)
    lv = lane_view(plain.scene, plain.intent)
    assert len(continuing_lanes(plain.scene, lv.here, lv.siblings)) == 2


def test_lane_state_is_the_nearest_leader_and_follower(road, planner_config, mpc_config):
    obs = road_obs(road, [car("far", x_m=120.0, v_mps=10.0), car("near", x_m=80.0, v_mps=10.0),
                          car("back", x_m=20.0, v_mps=10.0),
                          car("l", x_m=70.0, v_mps=10.0, left=True)])
    inp = inputs(obs, planner_config, mpc_config)
    lead, follow = lane_state(inp.scene, "E0_0")
    assert (lead.id, follow.id) == ("near", "back")
    lead, follow = lane_state(inp.scene, "E0_1")
    assert (lead.id, follow) == ("l", None)


@pytest.mark.parametrize("instruction, rule, chosen", [
    (None, "change", "change to the left lane"),                # normal: at once
    ("drive aggressively", "keep", "continue in lane"),         # aggressive: later
])
def test_route_lane_change_timing_by_style(exit_left, planner_config, mpc_config,
                                           instruction, rule, chosen):
    inp = inputs(road_obs(exit_left), planner_config, mpc_config, instruction=instruction)
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == rule
    assert label(inp, plan) == chosen


def test_aggressive_route_change_near_the_end_checks_the_gap(exit_left, planner_config,
                                                             mpc_config):
    # 78 m before the end (under 0.8 * 130 m, over the 60 m of a forced merge): the
    # change waits for a gap; a car beside in the left lane leaves none
    obs = road_obs(exit_left, [car("side", x_m=320.0, v_mps=12.0, left=True)], x_m=320.0)
    inp = inputs(obs, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait"
    assert label(inp, plan) == "continue in lane"
    assert "side" in plan.attention and "no safe gap" in plan.notes[-1]
    free = inputs(road_obs(exit_left, [], x_m=320.0), planner_config, mpc_config,
                  instruction="drive aggressively")
    plan = fresh_plan(free)
    assert lane_rule(free, plan) == "change" and "gap in the left lane is free" in plan.notes[-1]


def test_leader_state(road, planner_config, mpc_config):
    def state(agent):
        inp = inputs(road_obs(road, [agent]), planner_config, mpc_config)
        return leader_state(inp, lane_view(inp.scene, inp.intent))

    standing = state(car("s", x_m=110.0, v_mps=0.0))          # 60 m ahead, standing
    assert standing.blocked and standing.slow
    braking_near = state(car("b", x_m=90.0, v_mps=12.0, a_mps2=-6.0))
    assert braking_near.blocked and not braking_near.slow
    braking_far = state(car("b", x_m=125.0, v_mps=12.0, a_mps2=-6.0))  # beyond 60 m
    assert not braking_far.blocked
    cruising = state(car("c", x_m=90.0, v_mps=13.0))
    assert not cruising.blocked and not cruising.slow
    assert state(car("l", x_m=90.0, v_mps=0.0, left=True)) == LeaderState(None, False, False)


def test_overtake_needs_a_faster_neighbour_lane(road, planner_config, mpc_config):
    def want(agents, instruction="drive aggressively"):
        inp = inputs(road_obs(road, agents), planner_config, mpc_config,
                     instruction=instruction)
        lv = lane_view(inp.scene, inp.intent)
        return overtake(inp, lv, leader_state(inp, lv).lead)

    slow = car("slow", x_m=80.0, v_mps=6.0)
    got = want([slow])
    assert got is not None and got.index == 1 and "the left lane is faster" in got.why
    # the left lane's leader is barely faster (0.5 m/s < the 1 m/s an aggressive style needs)
    assert want([slow, car("l", x_m=90.0, v_mps=6.5, left=True)]) is None
    # normal style needs 2 m/s: 7.5 m/s is enough for aggressive only
    mid_speed = car("l", x_m=90.0, v_mps=7.5, left=True)
    assert want([slow, mid_speed]) is not None
    assert want([slow, mid_speed], instruction=None) is None


def test_gap_blocker_scales_with_the_style(road, planner_config, mpc_config):
    # a faster follower 25.5 m behind in the left lane: needed 6 + f * (0.8 * 14 + 3 * 2) m
    # = 23.2 m (normal), 31.8 m (conservative)
    follower = car("f", x_m=20.0, v_mps=14.0, left=True)

    def blocker(instruction):
        inp = inputs(road_obs(road, [follower]), planner_config, mpc_config,
                     instruction=instruction)
        lv = lane_view(inp.scene, inp.intent)
        plan = fresh_plan(inp)
        found = gap_blocker(inp, plan, [lv.siblings[1]], "left")
        assert plan.attention == {"f": "in the left lane behind"}
        return found

    assert blocker(None) is None
    got = blocker("drive conservatively")
    assert got is not None and got[0].id == "f" and got[1] == "behind"


def test_blocked_lane_without_a_gap_stops_short_of_the_standing_car(
        road, planner_config, mpc_config):
    obs = road_obs(road, [car("stop", x_m=90.0, v_mps=0.0),
                          car("side", x_m=52.0, v_mps=12.0, left=True)])
    inp = inputs(obs, planner_config, mpc_config)
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait"
    assert label(inp, plan) == "continue in lane"
    assert plan.speed_set and accel_of(inp, plan) < 0.0 and plan.weights["action"] == "high"
    assert "I stop about 10 m behind stop" in plan.notes[-1]
    # with the left lane free it changes round the standing car
    inp = inputs(road_obs(road, [car("stop", x_m=90.0, v_mps=0.0)]), planner_config,
                 mpc_config)
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "change" and label(inp, plan) == "change to the left lane"
    assert not plan.speed_set


def test_urgent_change_behind_a_faster_car_gets_ahead_else_lets_it_pass(
        exit_left, planner_config, mpc_config):
    # aggressive, 78 m before the end: a faster car close behind in the left lane
    behind = road_obs(exit_left, [car("f", x_m=305.0, v_mps=14.0, left=True)], x_m=320.0,
                      v_mps=8.0)
    inp = inputs(behind, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait" and accel_of(inp, plan) > 0.0
    # a slower car beside: ease off so it draws ahead
    beside = road_obs(exit_left, [car("s", x_m=322.0, v_mps=8.0, left=True)], x_m=320.0,
                      v_mps=8.0)
    inp = inputs(beside, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait" and accel_of(inp, plan) < 0.0


def test_aggressive_merges_at_once_into_a_much_slower_lane(exit_left, planner_config,
                                                           mpc_config):
    # 350 m before the end the aggressive style keeps its lane (late merge); with the
    # left lane's cars 6 m/s slower than the ego it merges at once instead (lane seeds
    # 110/118: squeezing in late among slower cars ended in collisions)
    slow = road_obs(exit_left, [car("l", x_m=80.0, v_mps=6.0, left=True)], stamp_s=5.0)
    inp = inputs(slow, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "change"
    assert label(inp, plan) == "change to the left lane"
    near = road_obs(exit_left, [car("l", x_m=80.0, v_mps=10.0, left=True)], stamp_s=5.0)
    inp = inputs(near, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "keep"


def test_aggressive_gaps_apply_only_after_the_first_second(road, planner_config, mpc_config):
    # eoa seed 104: a car inserted 1 m behind in the target lane 0.3 s into the episode;
    # here a car ~14 m behind in the left lane: inside the normal gap, outside the
    # aggressive one
    def rule(stamp_s, instruction="drive aggressively"):
        obs = road_obs(road, [car("slow", x_m=80.0, v_mps=6.0),
                              car("side", x_m=31.5, v_mps=12.0, left=True)], stamp_s=stamp_s)
        inp = inputs(obs, planner_config, mpc_config, instruction=instruction)
        plan = fresh_plan(inp)
        return lane_rule(inp, plan), label(inp, plan)

    assert rule(5.0) == ("change", "change to the left lane")
    assert rule(5.0, instruction=None)[1] == "continue in lane"
    assert rule(0.0) == ("wait", "continue in lane")


# lane seed 10055 (training), "drive aggressively": 78 m before the end of the edge the
# exit lane (here the left one) held a follower f beside / just behind the ego and its
# leader l too close ahead of f for the ego to fit in between
def _platoon(exit_left, *, x_f: float, stamp_s: float = 20.0, x_ego: float = 320.0):
    return road_obs(exit_left, [car("f", x_m=x_f, v_mps=10.0, left=True),
                                car("l", x_m=x_ego + 14.0, v_mps=10.0, left=True)],
                    x_m=x_ego, v_mps=8.0, stamp_s=stamp_s)


def test_urgent_change_drops_back_behind_a_follower_with_no_room_ahead_of_it(
        exit_left, planner_config, mpc_config):
    inp = inputs(_platoon(exit_left, x_f=314.0), planner_config, mpc_config,
                 instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait" and label(inp, plan) == "continue in lane"
    assert accel_of(inp, plan) < 0.0 and "no room in front of f, so I drop back" in plan.notes[-1]
    # with the leader far ahead there is room in front of f: get ahead of it
    free = road_obs(exit_left, [car("f", x_m=314.0, v_mps=10.0, left=True)], x_m=320.0,
                    v_mps=8.0, stamp_s=20.0)
    inp = inputs(free, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait" and accel_of(inp, plan) > 0.0


def test_the_late_forced_merge_waits_while_a_car_is_beside_in_the_target_lane(
        exit_left, planner_config, mpc_config):
    # 45 m before the end the aggressive merge goes along the route without the gap test,
    # but not into a car beside (or within the minimum gap) in the target lane
    beside = _platoon(exit_left, x_f=352.0, x_ego=352.0)
    inp = inputs(beside, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "wait" and label(inp, plan) == "continue in lane"
    clear = road_obs(exit_left, [car("f", x_m=320.0, v_mps=10.0, left=True)], x_m=352.0,
                     v_mps=8.0, stamp_s=20.0)
    inp = inputs(clear, planner_config, mpc_config, instruction="drive aggressively")
    plan = fresh_plan(inp)
    assert lane_rule(inp, plan) == "change"


def test_near_the_end_a_car_beside_in_the_route_lane_is_let_ahead_even_in_an_emergency(
        exit_left, planner_config, mpc_config):
    # the lane rule does not run in an emergency (nor within the lookahead of the edge's
    # end); the way-is-clear rule used to speed up beside the car (lane seed 119, dev)
    obs = road_obs(exit_left, [car("f", x_m=320.0, v_mps=8.0, left=True)], x_m=320.0,
                   v_mps=8.0, stamp_s=20.0)
    wire, _ = ask(obs, planner_config, mpc_config, "drive aggressively", mode="emergency")
    assert accel_mid(wire, mpc_config) < 0.0
    assert "f is beside me in the lane my route needs" in wire.reasoning
    plain, _ = ask(obs, planner_config, mpc_config, None, mode="emergency")
    assert accel_mid(plain, mpc_config) > 0.0  # no instruction: unchanged
    # far from the end (the late merge not due yet) the car beside changes nothing
    far = road_obs(exit_left, [car("f", x_m=150.0, v_mps=8.0, left=True)], x_m=150.0,
                   v_mps=8.0, stamp_s=20.0)
    wire, _ = ask(far, planner_config, mpc_config, "drive aggressively", mode="emergency")
    assert accel_mid(wire, mpc_config) > 0.0
