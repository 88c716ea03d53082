"""The headway rule (backends/rules/headway.py) called directly: behind a moving leader in
the ego's lane on the straight road (ego in ``E0_0`` at x = 50, front at 52.25)."""
from __future__ import annotations

import dataclasses

import pytest
from rules_kit import car, road_obs
from rules_units import accel_of, changing_left_plan, fresh_plan, inputs

from lmpc_llm_planner.backends.rules.headway import (
    AGGRESSIVE_STANDOFF_M, CONSERVATIVE_HEADWAY_S, CONSERVATIVE_OPEN_ROAD_HEADWAY_S,
    HEADWAY_OPEN_FRACTION, HEADWAY_S, headway_rule, style_headway_s, wanted_gap_m,
)
from lmpc_llm_planner.backends.rules.scene_helpers import STANDOFF_M


@pytest.mark.parametrize("v, vl", [(5.0, 5.0), (12.0, 12.0), (20.0, 20.0), (12.0, 6.0)])
def test_wanted_gap_is_at_least_the_time_gap_and_grows_behind_a_slower_leader(v, vl):
    assert wanted_gap_m(v, vl) >= HEADWAY_S * v
    assert wanted_gap_m(v, vl - 2.0) > wanted_gap_m(v, vl) or \
        wanted_gap_m(v, vl - 2.0) == HEADWAY_S * v


def test_wanted_gap_covers_a_hard_braking_leader():
    # 20 m/s behind 20 m/s: 1 s reaction (20 m) + 40 m braking - 25 m leader's + 10 m
    assert wanted_gap_m(20.0, 20.0) == pytest.approx(45.0)


def _at_gap(road, planner_config, mpc_config, gap_m, *, v=12.0, vl=12.0, **kw):
    # the leader's rear at 52.25 + gap_m
    leader = car("lead", x_m=52.25 + gap_m + 2.25, v_mps=vl)
    inp = inputs(road_obs(road, [leader], v_mps=v), planner_config, mpc_config, **kw)
    plan = fresh_plan(inp)
    headway_rule(inp, plan)
    return inp, plan


def test_too_close_drops_back_a_little_short_holds_far_enough_nothing(
        road, planner_config, mpc_config):
    want = wanted_gap_m(12.0, 12.0)
    inp, plan = _at_gap(road, planner_config, mpc_config, 0.6 * want)
    assert plan.speed_set and accel_of(inp, plan) < 0.0 and plan.weights["action"] == "high"
    assert "drop back" in plan.notes[0] and "lead" in plan.attention
    inp, plan = _at_gap(road, planner_config, mpc_config,
                        0.5 * (1.0 + HEADWAY_OPEN_FRACTION) * want)
    assert plan.speed_set and accel_of(inp, plan) == 0.0 and "I follow lead" in plan.notes[0]
    inp, plan = _at_gap(road, planner_config, mpc_config, want + 2.0)
    assert plan == fresh_plan(inp)


def test_slow_ego_standing_leader_or_a_lane_change_are_left_alone(
        road, planner_config, mpc_config):
    inp, plan = _at_gap(road, planner_config, mpc_config, 5.0, v=3.0, vl=3.0)  # creeping
    assert plan == fresh_plan(inp)
    inp, plan = _at_gap(road, planner_config, mpc_config, 10.0, vl=0.0)  # standing
    assert plan == fresh_plan(inp)
    inp, _ = _at_gap(road, planner_config, mpc_config, 10.0)
    changing = dataclasses.replace(
        fresh_plan(inp), ego_index=next(c.candidate_id for c in inp.scene.ego_candidates
                                        if c.label == "change to the left lane"))
    headway_rule(inp, changing)
    assert not changing.speed_set and not changing.notes


def test_conservative_keeps_four_seconds_on_the_open_road_three_before_a_junction(
        road, straight_map, obs_factory, planner_config, mpc_config):
    """Issue 20: the conservative gap is 4 s where no junction is on the route within
    ``OPEN_ROAD_M`` (lane's long road), 3 s before one (a longer gap there changes which
    gap in the cross traffic the ego meets); other styles keep 2 s everywhere."""
    cons = "drive conservatively"
    open_road = inputs(road_obs(road, []), planner_config, mpc_config, instruction=cons)
    assert style_headway_s(open_road) == CONSERVATIVE_OPEN_ROAD_HEADWAY_S == 4.0
    near = inputs(obs_factory(straight_map), planner_config, mpc_config, instruction=cons)
    assert style_headway_s(near) == CONSERVATIVE_HEADWAY_S == 3.0
    for instruction in (None, "drive aggressively"):
        for obs in (road_obs(road, []), obs_factory(straight_map)):
            inp = inputs(obs, planner_config, mpc_config, instruction=instruction)
            assert style_headway_s(inp) == HEADWAY_S
    # at 12 m/s behind a 12 m/s leader 40 m ahead (3.3 s): on the open road the
    # conservative ego drops back, with no instruction it is left alone
    _, plan = _at_gap(road, planner_config, mpc_config, 40.0, instruction=cons)
    assert plan.speed_set and "drop back" in plan.notes[0]
    inp, plan = _at_gap(road, planner_config, mpc_config, 40.0)
    assert plan == fresh_plan(inp)


def test_aggressive_follows_a_platoon_closer_but_still_stops_short(
        road, planner_config, mpc_config):
    """Issue 20: behind a 7 m/s leader normal and aggressive kept the same 19 m (the braking
    model's gap, with its 10 m to steer round); the aggressive margin is 5 m: still a stop
    short of a leader braking at 8 m/s^2 after the 1 s reaction."""
    normal = wanted_gap_m(7.0, 7.0)
    aggressive = wanted_gap_m(7.0, 7.0, standoff_m=AGGRESSIVE_STANDOFF_M)
    assert normal == pytest.approx(7.0 + 4.9 - 3.0625 + STANDOFF_M)
    # the 2 s time gap (14 m) binds before the braking model's 13.8 m
    assert aggressive == pytest.approx(max(HEADWAY_S * 7.0,
                                           normal - (STANDOFF_M - AGGRESSIVE_STANDOFF_M)))
    assert aggressive < normal - 4.0
    # stopping distance after the reaction minus the leader's: at least the margin is left
    stop_ego = 7.0 * 1.0 + 7.0 ** 2 / (2 * 5.0)
    assert aggressive - (stop_ego - 7.0 ** 2 / (2 * 8.0)) >= AGGRESSIVE_STANDOFF_M
    # 16 m behind: the normal ego drops back, the aggressive one is left alone (14 m wanted)
    inp, plan = _at_gap(road, planner_config, mpc_config, 16.0, v=7.0, vl=7.0)
    assert accel_of(inp, plan) < 0.0 and "drop back" in plan.notes[0]
    inp, plan = _at_gap(road, planner_config, mpc_config, 16.0, v=7.0, vl=7.0,
                        instruction="drive aggressively")
    assert plan == fresh_plan(inp)


def test_conservative_lane_change_keeps_its_headway_to_the_leader_it_merges_behind(
        road, planner_config, mpc_config):
    """Issue 20 (lane dev seeds: merging at once with its gentler braking, the conservative
    driver entered closer behind the new leader than normal did): changing lanes, the
    conservative style drops back from the leader of the lane it enters while that leader is
    nearer than the follower there; the leader of the lane it leaves does not count, and the
    other styles leave the speed to the MPC."""
    cons = "drive conservatively"
    here = car("here", x_m=52.25 + 8.0 + 2.25, v_mps=12.0)  # 8 m ahead in my lane

    def changing(gap_new_m: float, instruction, behind_m=None):
        new = car("new", x_m=52.25 + gap_new_m + 2.25, v_mps=12.0, left=True)
        others = [here, new]
        if behind_m is not None:  # a follower in the lane it enters, its front behind_m back
            others.append(car("back", x_m=47.75 - behind_m - 2.25, v_mps=12.0, left=True))
        inp = inputs(road_obs(road, others), planner_config, mpc_config,
                     instruction=instruction)
        plan = changing_left_plan(inp)
        headway_rule(inp, plan)
        return inp, plan

    inp, plan = changing(20.0, cons)  # 4 s at 12 m/s wants ~48 m
    assert plan.speed_set and accel_of(inp, plan) < 0.0
    assert plan.attention == {"new": "leader in the lane I change to"}
    assert "new drives 20 m ahead in the lane I change to" in plan.notes[0]
    far = wanted_gap_m(12.0, 12.0, CONSERVATIVE_OPEN_ROAD_HEADWAY_S) + 2.0
    inp, plan = changing(far, cons)
    assert not plan.speed_set and not plan.notes  # the 8 m leader it leaves: no matter
    for other in (None, "drive aggressively"):
        inp, plan = changing(20.0, other)
        assert not plan.speed_set and not plan.notes
    # a follower in that lane nearer than the leader: dropping back would only trade the
    # gap ahead for a smaller one behind; it keeps the middle of the gap
    inp, plan = changing(20.0, cons, behind_m=15.0)
    assert not plan.speed_set and not plan.notes
    inp, plan = changing(20.0, cons, behind_m=30.0)
    assert plan.speed_set and accel_of(inp, plan) < 0.0
