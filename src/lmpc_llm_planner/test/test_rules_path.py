"""Rules 4 and 5 of the ego's own path (backends/rules/path.py) called directly: brake for
an agent in the path, stop short of a standing one, otherwise go. On the two-lane straight
road (ego in ``E0_0`` at x = 50) and the junction of conftest.py."""
from __future__ import annotations

import math

from lmpc_mpc import synthetic as syn
from rules_kit import car, road_obs
from rules_units import accel_of, fresh_plan, inputs

from lmpc_llm_planner.backends.rules.intervals import brake_index, mildest_accel, neutral
from lmpc_llm_planner.backends.rules.path import (
    close_leader_in_path, go_rule, path_rule, path_threats,
)
from lmpc_llm_planner.backends.rules.scene_helpers import STANDOFF_M, queued_at_junction

NORTH = math.pi / 2.0


def test_a_standing_car_in_my_lane_is_a_stand_off_threat(road, planner_config, mpc_config):
    inp = inputs(road_obs(road, [car("stop", x_m=85.0, v_mps=0.0)]), planner_config,
                 mpc_config)
    threats, standoff = path_threats(inp, fresh_plan(inp), committed=False)
    assert [v.id for v in threats] == ["stop"]
    assert standoff["stop"] == threats[0].kin.gap_m - STANDOFF_M
    plan = fresh_plan(inp)
    path_rule(inp, plan, committed=False)
    assert plan.speed_set and accel_of(inp, plan) < 0.0 and plan.weights["safety"] == "high"
    assert "stop about 10 m behind where it stands" in plan.notes[-1]


def test_a_standing_car_in_the_other_lane_is_no_threat(road, planner_config, mpc_config):
    inp = inputs(road_obs(road, [car("stop", x_m=85.0, v_mps=0.0, left=True)]),
                 planner_config, mpc_config)
    assert path_threats(inp, fresh_plan(inp), committed=False) == ([], {})


def test_a_car_queued_at_the_junction_is_not_a_breakdown(left_turn_map, obs_factory,
                                                         planner_config, mpc_config):
    # standing 6 m before the stop line of a lane with three directions: it waits there,
    # and at a TTC over path_ttc_s the ego is not braking for it yet
    waiting = syn.agent("q", x_m=1.6, y_m=-14.25, yaw_rad=NORTH, v_mps=0.0, lane_id="S_in_0") \
        .model_copy(update={"lane_pos_m": 85.75})
    inp = inputs(obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=8.0, agents=[waiting]),
                 planner_config, mpc_config)
    view = inp.scene.agents[0]
    assert queued_at_junction(inp.scene, view)
    assert view.kin.ttc_s > planner_config.rules.path_ttc_s
    assert path_threats(inp, fresh_plan(inp), committed=False) == ([], {})


def test_committed_turn_brakes_only_for_a_shorter_ttc(road, planner_config, mpc_config):
    # closing at 8 m/s from 18.5 m: TTC ~2.3 s, under path_ttc_s (2.5), over
    # commit_ttc_s (1.5)
    inp = inputs(road_obs(road, [car("slow", x_m=73.0, v_mps=4.0)], v_mps=12.0),
                 planner_config, mpc_config)
    threats, _ = path_threats(inp, fresh_plan(inp), committed=False)
    assert [v.id for v in threats] == ["slow"]
    assert 1.5 < threats[0].kin.ttc_s < 2.5
    assert path_threats(inp, fresh_plan(inp), committed=True) == ([], {})


def test_path_rule_brakes_for_the_nearest_collision(road, planner_config, mpc_config):
    agents = [car("a", x_m=73.0, v_mps=4.0), car("b", x_m=100.0, v_mps=4.0)]
    inp = inputs(road_obs(road, agents, v_mps=12.0), planner_config, mpc_config)
    plan = fresh_plan(inp)
    path_rule(inp, plan, committed=False)
    assert list(plan.attention) == ["a"]
    assert plan.attention["a"].startswith("closing in,")
    # the braking interval covers the kinematic need v_close^2 / 2 (gap - 2)
    k = next(v for v in inp.scene.agents if v.id == "a").kin
    need = k.closing_speed_mps ** 2 / (2.0 * (k.gap_m - 2.0))
    assert plan.accel_index == brake_index(inp.accel, need, False)
    assert plan.weights["tracking"] == "normal"  # not an emergency


def test_nothing_in_the_path_changes_nothing(road, planner_config, mpc_config):
    inp = inputs(road_obs(road, [car("fast", x_m=90.0, v_mps=14.0)]), planner_config,
                 mpc_config)
    plan = fresh_plan(inp)
    path_rule(inp, plan, committed=False)
    assert plan == fresh_plan(inp)


def test_go_speeds_up_below_the_limit_and_keeps_the_speed_near_it(
        road, planner_config, mpc_config):
    slow = inputs(road_obs(road, v_mps=5.0), planner_config, mpc_config)
    plan = fresh_plan(slow)
    go_rule(slow, plan)
    assert plan.accel_index == mildest_accel(slow.accel) and "speed up" in plan.notes[0]
    fast = inputs(road_obs(road, v_mps=13.0), planner_config, mpc_config)
    plan = fresh_plan(fast)
    go_rule(fast, plan)
    assert plan.accel_index == neutral(fast.accel) and "keep my speed" in plan.notes[0]


def test_go_behind_a_standing_car_stays_creeps_or_stops_short(road, planner_config,
                                                              mpc_config):
    def go(x_m, v_mps):
        inp = inputs(road_obs(road, [car("stop", x_m=x_m, v_mps=0.0)], v_mps=v_mps),
                     planner_config, mpc_config)
        plan = fresh_plan(inp)
        go_rule(inp, plan)
        return inp, plan

    inp, plan = go(66.0, 0.0)  # 11.5 m gap, stopped: stay
    assert plan.accel_index == brake_index(inp.accel, 0.0, True)
    assert "stay where I am" in plan.notes[0]
    inp, plan = go(78.0, 0.0)  # 23.5 m gap, stopped: creep nearer
    assert plan.accel_index == mildest_accel(inp.accel) and "creep" in plan.notes[0]
    inp, plan = go(78.0, 6.0)  # moving: brake to stop ~10 m short
    assert accel_of(inp, plan) < 0.0 and "stop about 10 m short" in plan.notes[0]


def test_close_leader_in_path_ignores_faster_and_far_cars(road, planner_config, mpc_config):
    def leader(agent, v_mps=10.0):
        inp = inputs(road_obs(road, [agent], v_mps=v_mps), planner_config, mpc_config)
        return close_leader_in_path(inp, fresh_plan(inp))

    assert leader(car("c", x_m=70.0, v_mps=10.0)).id == "c"          # 15.5 m, same speed
    assert leader(car("c", x_m=70.0, v_mps=12.0)) is None            # faster: pulls away
    assert leader(car("c", x_m=90.0, v_mps=10.0)) is None            # beyond 2 s / 15 m
    assert leader(car("c", x_m=70.0, v_mps=10.0, left=True)) is None  # other lane
