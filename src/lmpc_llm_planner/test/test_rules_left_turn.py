"""Rule 3, gap acceptance of a left turn (backends/rules/left_turn.py), called directly on
the hand-made junction of conftest.py (ego northbound on S_in_0 turning left, stop line at
y = -8; oncoming cars southbound on N_in_0). No ROS, no SUMO."""
from __future__ import annotations

import dataclasses

import pytest
from lmpc_mpc import synthetic as syn
from rules_kit import road_obs
from rules_units import accel_of, fresh_plan, inputs

from lmpc_llm_planner.backends.rules import travel_time_s
from lmpc_llm_planner.backends.rules.intervals import mid
from lmpc_llm_planner.backends.rules.junction import go_accel_mps2
from lmpc_llm_planner.backends.rules.left_turn import (
    crossing_conflict, left_turn_rule, oncoming_conflict, steer_for_path,
)
from lmpc_llm_planner.route import next_maneuver


def _inputs(obs, planner_config, mpc_config, **kw):
    return inputs(obs, planner_config, mpc_config, **kw)


def _conflict(inp, aid):
    """The oncoming conflict of agent ``aid`` as the rule computes it."""
    man = next_maneuver(inp.scene.obs, inp.scene.lanes,
                        max_distance_m=inp.cfg.junction_attention_m)
    view = next(v for v in inp.scene.agents if v.id == aid)
    return oncoming_conflict(inp, view, man, ("l", "L"), go_accel_mps2(inp))


def test_no_left_turn_ahead_is_none(straight_map, road, obs_factory, planner_config,
                                    mpc_config):
    for obs in (obs_factory(straight_map), road_obs(road)):
        inp = _inputs(obs, planner_config, mpc_config)
        plan = fresh_plan(inp)
        assert left_turn_rule(inp, plan) == "none"
        assert plan == fresh_plan(inp)  # nothing chosen


def test_clear_junction_goes(left_turn_map, obs_factory, planner_config, mpc_config):
    inp = _inputs(obs_factory(left_turn_map, ego_y_m=-12.0, ego_v_mps=3.0),
                  planner_config, mpc_config)
    plan = fresh_plan(inp)
    assert left_turn_rule(inp, plan) == "go"
    assert plan.speed_set and accel_of(inp, plan) > 0.0  # within the go zone: briskly
    assert "no oncoming traffic conflicts" in plan.notes[0]


def test_close_oncoming_car_yields_with_a_stop_before_the_line(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    inp = _inputs(obs_factory(left_turn_map, ego_y_m=-30.0, ego_v_mps=8.0,
                              agents=[oncoming_factory("car1", y_m=25.0, v_mps=10.0)]),
                  planner_config, mpc_config)
    plan = fresh_plan(inp)
    assert left_turn_rule(inp, plan) == "yield"
    assert accel_of(inp, plan) < 0.0
    assert plan.weights["action"] == plan.weights["safety"] == "high"
    assert plan.attention == {"car1": "oncoming, conflicts with my turn"}
    assert "stop before the stop line" in plan.notes[-1]


def test_far_from_the_line_the_stop_waits_but_not_in_an_emergency(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    obs = obs_factory(left_turn_map, ego_y_m=-70.0, ego_v_mps=10.0,
                      agents=[oncoming_factory("car1", y_m=5.0, v_mps=10.0)])
    normal = _inputs(obs, planner_config, mpc_config)
    urgent = _inputs(obs, planner_config, mpc_config, mode="emergency")
    p_n, p_e = fresh_plan(normal), fresh_plan(urgent)
    assert left_turn_rule(normal, p_n) == left_turn_rule(urgent, p_e) == "yield"
    assert accel_of(normal, p_n) == 0.0 and "keep my speed for now" in p_n.notes[-1]
    assert accel_of(urgent, p_e) < 0.0


def test_inside_the_junction_with_an_oncoming_car_commits(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    # the ego's front is over the stop line at 6 m/s: it cannot stop before the oncoming
    # lane comfortably, so it clears the junction instead of stopping in it
    inp = _inputs(obs_factory(left_turn_map, ego_y_m=-7.0, ego_v_mps=6.0,
                              agents=[oncoming_factory("car1", y_m=30.0, v_mps=10.0)]),
                  planner_config, mpc_config)
    plan = fresh_plan(inp)
    assert left_turn_rule(inp, plan) == "commit"
    assert accel_of(inp, plan) > 0.0 and plan.weights["safety"] == "high"


def test_hysteresis_after_a_go_accepts_a_slightly_smaller_gap(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    inp = _inputs(obs_factory(left_turn_map, ego_y_m=-20.0, ego_v_mps=5.0,
                              agents=[oncoming_factory("car1", y_m=45.0, v_mps=10.0)]),
                  planner_config, mpc_config)
    gap = _conflict(inp, "car1").gap_s
    # a required gap a quarter second above this one: refused, unless the last
    # decision went (the hysteresis takes go_hysteresis_s = 0.5 s off)
    tight = dataclasses.replace(inp, safe_gap_s=gap + 0.25)
    assert left_turn_rule(tight, fresh_plan(tight)) == "yield"
    went = dataclasses.replace(tight, previous_go=True)
    assert left_turn_rule(went, fresh_plan(went)) == "go"


def test_oncoming_conflict_timing(left_turn_map, obs_factory, oncoming_factory,
                                  planner_config, mpc_config):
    def conflict(agent):
        inp = _inputs(obs_factory(left_turn_map, ego_y_m=-20.0, ego_v_mps=4.0,
                                  agents=[agent]), planner_config, mpc_config)
        return _conflict(inp, agent.id)

    near = conflict(oncoming_factory("c", y_m=20.0, v_mps=10.0))
    far = conflict(oncoming_factory("c", y_m=40.0, v_mps=10.0))
    assert near is not None and far is not None
    assert far.t_agent_s == pytest.approx(near.t_agent_s + 2.0, abs=1e-6)  # 20 m at 10 m/s
    assert far.t_clear_s == pytest.approx(near.t_clear_s)  # the ego's time is its own
    assert 0.0 < near.zone_start_m < near.ego_s_m
    # waiting short of the crossing, or already past it: no conflict
    assert conflict(oncoming_factory("c", y_m=20.0, v_mps=0.0)) is None
    past = syn.agent("c", x_m=-1.6, y_m=-25.0, yaw_rad=-1.5708, v_mps=10.0,
                     lane_id="S_out_0")
    assert conflict(past) is None


def test_steer_for_path_follows_the_turn(left_turn_map, straight_map, obs_factory,
                                         planner_config, mpc_config):
    def steer_mid(map_):
        inp = _inputs(obs_factory(map_, ego_y_m=-12.0), planner_config, mpc_config)
        man = next_maneuver(inp.scene.obs, inp.scene.lanes, max_distance_m=70.0)
        return mid(inp.steer[steer_for_path(man, inp.steer)])

    assert steer_mid(left_turn_map) > 0.0  # left = counter-clockwise
    assert steer_mid(straight_map) == 0.0


def test_travel_time_accelerates_up_to_the_cap():
    assert travel_time_s(25.0, v0_mps=0.0, accel_mps2=2.0, vmax_mps=10.0) == pytest.approx(5.0)
    assert travel_time_s(45.0, v0_mps=0.0, accel_mps2=2.0, vmax_mps=10.0) == pytest.approx(7.0)
    assert travel_time_s(30.0, v0_mps=15.0, accel_mps2=2.0, vmax_mps=10.0) == pytest.approx(2.0)
    assert travel_time_s(0.0, v0_mps=0.0, accel_mps2=2.0, vmax_mps=10.0) == 0.0


def test_a_car_standing_short_of_the_crossing_waits_for_an_ego_in_the_junction(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    """Both stand: the ego inside the junction (past the stop line, before the oncoming
    lane), an oncoming car 1 m short of the crossing. The car waits for the ego (traffic
    in the junction goes first), so it is no conflict and the ego turns. Taken as
    arriving "in 0 s", the two waited for each other until the timeout (si 110). From
    behind the stop line the ego still waits for such a car."""
    car = oncoming_factory("car1", y_m=3.4, v_mps=0.0)
    inside = _inputs(obs_factory(left_turn_map, ego_y_m=-5.0, ego_v_mps=0.0, agents=[car],
                                 lane_id=":J_1_0"), planner_config, mpc_config)
    assert next_maneuver(inside.scene.obs, inside.scene.lanes,
                         max_distance_m=inside.cfg.junction_attention_m).inside_junction
    assert _conflict(inside, "car1") is None
    plan = fresh_plan(inside)
    assert left_turn_rule(inside, plan) == "go"
    assert accel_of(inside, plan) > 0.0
    behind = _inputs(obs_factory(left_turn_map, ego_y_m=-12.0, ego_v_mps=0.0, agents=[car]),
                     planner_config, mpc_config)
    c = _conflict(behind, "car1")
    assert c is not None and c.t_agent_s == 0.0
    assert left_turn_rule(behind, fresh_plan(behind)) == "yield"


def _normal_and_careful(left_turn_map, obs_factory, car, cfgs, *, ego_y_m, ego_v_mps):
    """The rule inputs of the ego at (``ego_y_m``, ``ego_v_mps``) with the oncoming
    ``car``, without an instruction and with a conservative one."""
    obs = obs_factory(left_turn_map, ego_y_m=ego_y_m, ego_v_mps=ego_v_mps, agents=[car])
    return (_inputs(obs, *cfgs),
            _inputs(obs, *cfgs, instruction="drive conservatively"))


def test_the_conservative_style_turns_gently_and_so_needs_a_larger_gap(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    normal, careful = _normal_and_careful(
        left_turn_map, obs_factory, oncoming_factory("car1", y_m=60.0, v_mps=7.0),
        (planner_config, mpc_config), ego_y_m=-12.0, ego_v_mps=3.0)
    # a gentler go (the mildest accelerating interval) clears the crossing later
    assert go_accel_mps2(careful) < go_accel_mps2(normal)
    assert _conflict(careful, "car1").t_clear_s > _conflict(normal, "car1").t_clear_s
    p_n, p_c = fresh_plan(normal), fresh_plan(careful)
    assert left_turn_rule(normal, p_n) == left_turn_rule(careful, p_c) == "go"
    assert 0.0 < accel_of(careful, p_c) < accel_of(normal, p_n)
    # the same gap, required at the same margin: the gentle go takes it later
    tight = dataclasses.replace(careful, safe_gap_s=_conflict(normal, "car1").gap_s - 0.1)
    assert left_turn_rule(dataclasses.replace(normal, safe_gap_s=tight.safe_gap_s),
                          fresh_plan(normal)) == "go"
    assert left_turn_rule(tight, fresh_plan(tight)) == "yield"


def test_a_committed_conservative_ego_still_clears_briskly(
        left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    normal, careful = _normal_and_careful(
        left_turn_map, obs_factory, oncoming_factory("car1", y_m=30.0, v_mps=10.0),
        (planner_config, mpc_config), ego_y_m=-7.0, ego_v_mps=6.0)
    p_n, p_c = fresh_plan(normal), fresh_plan(careful)
    assert left_turn_rule(careful, p_c) == left_turn_rule(normal, p_n) == "commit"
    assert accel_of(careful, p_c) == accel_of(normal, p_n) > 0.0


def test_aggressive_takes_a_gap_normal_refuses(left_turn_map, obs_factory, oncoming_factory,
                                               planner_config, mpc_config):
    """Issue 20: the aggressive style's turn gap is ``safe_gap_s`` x
    ``aggressive_gap_factor`` (1.5 -> 1.125 s): an oncoming car whose gap beyond the
    ego's clear time lies between the two is yielded to with no instruction and taken
    when aggressive (same clear time: both go with the go interval)."""
    rules = planner_config.rules
    lo, hi = rules.safe_gap_s * rules.aggressive_gap_factor, rules.safe_gap_s
    found = 0
    for tenths in range(60, 100):  # slower and slower oncoming cars 55 m up the road
        agents = [oncoming_factory("car1", y_m=55.0, v_mps=tenths / 10.0)]
        obs = obs_factory(left_turn_map, ego_y_m=-20.0, ego_v_mps=5.0, agents=agents)
        normal = _inputs(obs, planner_config, mpc_config)
        aggressive = _inputs(obs, planner_config, mpc_config, instruction="drive aggressively")
        assert aggressive.safe_gap_s == pytest.approx(lo)
        gap = _conflict(normal, "car1").gap_s
        assert _conflict(aggressive, "car1").gap_s == pytest.approx(gap)
        if lo + 0.05 < gap < hi - 0.05:
            found += 1
            assert left_turn_rule(normal, fresh_plan(normal)) == "yield"
            assert left_turn_rule(aggressive, fresh_plan(aggressive)) == "go"
    assert found >= 2  # the positions swept do cover the band between the two gaps


def test_a_crossing_car_starting_into_the_junction_is_yielded_to(
        left_turn_map, obs_factory, planner_config, mpc_config):
    """usi training seed 10005: a car of the crossing road moved off its line with the
    ego (SUMO does not see an ego placed by ``moveToXY`` coming until it is on the
    internal lane) and the two met in the junction. A crossing car *starting into the
    junction* (slow, accelerating, near the crossing) is now a conflict of the turn; one
    standing at its line, or braking towards it, is not (it waits: counting every
    moving crossing car put Table I's usi 19 off route)."""
    def crossing_car(v_mps, a_mps2):
        # eastbound from the west arm, its front ~7 m before the ego's turn path
        car = syn.agent("cross0", x_m=-10.0, y_m=-1.6, yaw_rad=0.0, v_mps=v_mps)
        return car.model_copy(update={"a_mps2": a_mps2})

    def decide(car):
        inp = _inputs(obs_factory(left_turn_map, ego_y_m=-10.0, ego_v_mps=0.5, agents=[car]),
                      planner_config, mpc_config)
        man = next_maneuver(inp.scene.obs, inp.scene.lanes,
                            max_distance_m=inp.cfg.junction_attention_m)
        view = inp.scene.agents[0]
        plan = fresh_plan(inp)
        verdict = left_turn_rule(inp, plan)
        return crossing_conflict(inp, view, man, go_accel_mps2(inp)), verdict, plan, inp

    conflict, verdict, plan, inp = decide(crossing_car(2.0, 3.0))
    assert conflict is not None and conflict.what == "crossing"
    assert verdict == "yield" and accel_of(inp, plan) <= 0.0
    assert plan.attention == {"cross0": "crossing, conflicts with my turn"}
    assert "must yield to crossing cross0" in plan.notes[-1]
    for v_mps, a_mps2 in ((0.0, 0.0), (4.0, -2.0), (10.0, 0.0)):
        # standing at its line, braking to it, or a through car far from starting
        conflict, verdict, plan, _ = decide(crossing_car(v_mps, a_mps2))
        assert conflict is None and verdict == "go", (v_mps, a_mps2)
        assert plan.attention == {}
