"""The style's clear-way speed (backends/rules/path.py, ``go_rule``; issue 20) called
directly on the two-lane straight road (ego in ``E0_0`` at x = 50, limit 13.89 m/s):
aggressive speeds up briskly only where the way is clear by the rules' own gap checks and
never in an emergency decision; conservative slows down only where that blocks nobody."""
from __future__ import annotations

from rules_kit import car, road_obs
from rules_units import changing_left_plan, fresh_plan, inputs

from lmpc_llm_planner.backends.rules.intervals import accel_index, brake_index, mildest_accel
from lmpc_llm_planner.backends.rules.intervals import neutral
from lmpc_llm_planner.backends.rules.path import (
    AGGRESSIVE_ACCEL_MPS2, clear_for_brisk, close_follower, go_rule,
)


def _go(obs, planner_config, mpc_config, instruction, mode="normal"):
    inp = inputs(obs, planner_config, mpc_config, instruction=instruction, mode=mode)
    plan = fresh_plan(inp)
    go_rule(inp, plan)
    return inp, plan


def test_aggressive_speeds_up_briskly_on_a_clear_road(road, planner_config, mpc_config):
    inp, plan = _go(road_obs(road, v_mps=8.0), planner_config, mpc_config,
                    "drive aggressively")
    assert plan.accel_index == accel_index(inp.accel, AGGRESSIVE_ACCEL_MPS2)
    assert plan.accel_index != mildest_accel(inp.accel)
    # held to: at action weight "normal" the MPC would speed up at its own pace
    assert plan.weights["action"] == "high" and "in a hurry" in plan.notes[-1]
    inp, plan = _go(road_obs(road, v_mps=8.0), planner_config, mpc_config, None)
    assert plan.accel_index == mildest_accel(inp.accel)  # normal: the mildest interval


def test_aggressive_never_speeds_up_briskly_in_an_emergency(
        road, planner_config, mpc_config):
    # lane seeds 109/110/118: the brisk speed-up in the emergency checks ended in collisions
    inp, plan = _go(road_obs(road, v_mps=8.0), planner_config, mpc_config,
                    "drive aggressively", mode="emergency")
    assert plan.accel_index == mildest_accel(inp.accel)
    assert not any("in a hurry" in n for n in plan.notes)


def test_aggressive_speed_up_needs_the_headway_gap_ahead_and_beside(
        road, planner_config, mpc_config):
    def brisk(agents):
        inp, plan = _go(road_obs(road, agents, v_mps=10.0), planner_config, mpc_config,
                        "drive aggressively")
        assert clear_for_brisk(inp, plan) == (
            plan.accel_index == accel_index(inp.accel, AGGRESSIVE_ACCEL_MPS2))
        return clear_for_brisk(inp, plan)

    assert brisk([])
    assert brisk([car("far", x_m=150.0, v_mps=10.0)])  # ~95 m ahead
    # ~35 m ahead at 10 m/s: after 2.5 s at 2 m/s^2 (13.2 m/s) the headway rule wants
    # ~34 m plus the 4 m closed meanwhile
    assert not brisk([car("near", x_m=90.0, v_mps=10.0)])
    assert not brisk([car("side", x_m=60.0, v_mps=10.0, left=True)])  # the next lane


def test_conservative_slows_down_only_without_a_close_follower(road, planner_config,
                                                               mpc_config):
    inp, plan = _go(road_obs(road, v_mps=12.0), planner_config, mpc_config,
                    "drive conservatively")
    assert plan.accel_index == brake_index(inp.accel, 0.0, True)  # mildest braking
    assert "careful" in plan.notes[-1]
    # a car 5.5 m behind at 12 m/s: braking in front of it invites a rear-end collision,
    # so the speed is kept as without an instruction
    tail = road_obs(road, [car("tail", x_m=40.0, v_mps=12.0)], v_mps=12.0)
    inp, plan = _go(tail, planner_config, mpc_config, "drive conservatively")
    assert close_follower(inp) is not None and close_follower(inp).id == "tail"
    assert plan.accel_index == neutral(inp.accel)
    inp, plan = _go(road_obs(road, v_mps=12.0), planner_config, mpc_config,
                    "drive conservatively", mode="emergency")
    assert plan.accel_index == neutral(inp.accel)


def test_conservative_holds_its_speed_on_a_free_road(road, planner_config, mpc_config):
    # below 65 % of the limit: the mildest speed-up, held to by the action weight (at
    # "normal" the MPC tracks the limit on its own: si 120 went 9.7 -> 13.3 m/s)
    inp, plan = _go(road_obs(road, v_mps=5.0), planner_config, mpc_config,
                    "drive conservatively")
    assert plan.accel_index == mildest_accel(inp.accel)
    assert plan.weights["action"] == "high" and "gently" in plan.notes[-1]
    # 65-75 %: hold the speed
    inp, plan = _go(road_obs(road, v_mps=9.7), planner_config, mpc_config,
                    "drive conservatively")
    assert plan.accel_index == neutral(inp.accel) and plan.weights["action"] == "high"
    # without an instruction the MPC keeps its own pull towards the limit
    inp, plan = _go(road_obs(road, v_mps=5.0), planner_config, mpc_config, None)
    assert plan.accel_index == mildest_accel(inp.accel)
    assert plan.weights["action"] == "normal"


def test_conservative_does_not_hold_its_speed_while_changing_lanes(
        road, planner_config, mpc_config):
    """Issue 20 (lane dev 112, training 10006 / 10016 / 10029): a held band speed (action
    weight "high") kept the conservative driver from the slowing the MPC did for the normal
    one during the route's first lane change; it entered the slower lane faster and closer
    behind its leader. Changing lanes it now eases off towards a slower leader of either
    lane (held) and otherwise does not speed up, leaving the MPC its own slowing."""
    cons = "drive conservatively"

    def changing(agents, instruction=cons, v_mps=10.0):
        inp = inputs(road_obs(road, agents, v_mps=v_mps), planner_config, mpc_config,
                     instruction=instruction)
        plan = changing_left_plan(inp)
        go_rule(inp, plan)
        return inp, plan

    # in the band (65-75 % of the 13.89 m/s limit), off a change: held
    inp, plan = _go(road_obs(road, v_mps=10.0), planner_config, mpc_config, cons)
    assert plan.accel_index == neutral(inp.accel) and plan.weights["action"] == "high"
    # the same changing lanes on a clear road: no speed-up, not held
    inp, plan = changing([])
    assert plan.accel_index == neutral(inp.accel) and plan.weights["action"] != "high"
    assert "do not speed up while I change lanes" in plan.notes[-1]
    # below the band: no gentle speed-up while changing; above it the held mild braking
    inp, plan = changing([], v_mps=6.0)
    assert plan.accel_index == neutral(inp.accel)
    inp, plan = changing([], v_mps=11.0)
    assert plan.accel_index == brake_index(inp.accel, 0.0, True)
    assert plan.weights["action"] == "high"
    # a slower leader in the lane it enters (40 m ahead, 8 m/s): ease off, held
    inp, plan = changing([car("new", x_m=52.25 + 40.0 + 2.25, v_mps=8.0, left=True)])
    assert plan.accel_index == brake_index(inp.accel, 0.0, True)
    assert plan.weights["action"] == "high" and "ease off towards the 8.0 m/s of new" \
        in plan.notes[-1]
    # ... or in the lane it leaves; out of range or not slower: nothing to ease off for
    inp, plan = changing([car("old", x_m=52.25 + 40.0 + 2.25, v_mps=8.0)])
    assert plan.accel_index == brake_index(inp.accel, 0.0, True)
    for far in (car("new", x_m=52.25 + 70.0 + 2.25, v_mps=8.0, left=True),
                car("new", x_m=52.25 + 40.0 + 2.25, v_mps=9.8, left=True)):
        inp, plan = changing([far])
        assert plan.accel_index == neutral(inp.accel)
    # the normal driver changing lanes speeds up as before
    inp, plan = changing([], instruction=None, v_mps=8.0)
    assert plan.accel_index == mildest_accel(inp.accel)
