"""Rule 10 of the rules backend: entering a roundabout, ring traffic has priority
(docs/lmpc_rules.md). On the straightened roundabout entry of
``lmpc_mpc.synthetic.roundabout_entry``: the ego from the south turns right onto the
ring lane R1_0, ring cars come along R0_0. No ROS, no SUMO."""
from __future__ import annotations

import math

import pytest
from lmpc_mpc import synthetic as syn
from rules_kit import accel_mid
from rules_kit import ask as ask_rules

NORTH = math.pi / 2.0
RING_START_X_M = -68.0  # R0_0 starts here (ring_m 60, junction box 8)


@pytest.fixture(scope="module")
def entry():
    return syn.roundabout_entry()


def ring_car(aid: str, *, x_m: float, v_mps: float = 8.0):
    return syn.agent(aid, x_m=x_m, y_m=-1.6, yaw_rad=0.0, v_mps=v_mps, lane_id="R0_0") \
        .model_copy(update={"lane_pos_m": x_m - RING_START_X_M})


def ask(map_, agents, planner_config, mpc_config, *, ego_y_m: float, v_mps: float):
    ego = syn.ego_state(x_m=1.6, y_m=ego_y_m, yaw_rad=NORTH, v_mps=v_mps, lane_id="S_in_0") \
        .model_copy(update={"lane_pos_m": ego_y_m + 100.0})
    w, _ = ask_rules(syn.observation(map_, ego, agents), planner_config, mpc_config)
    return accel_mid(w, mpc_config), w


def test_ring_car_close_to_the_entry_makes_the_ego_stop_at_the_yield_line(
        entry, planner_config, mpc_config):
    # the ego 12 m before the line at 4 m/s; a ring car 15 m before the merge at 8 m/s
    accel, w = ask(entry, [ring_car("circ", x_m=-8.0 - 15.0)], planner_config, mpc_config,
                   ego_y_m=-20.0, v_mps=4.0)
    assert accel < 0.0
    assert "circ" in w.scenario_encoding.attention
    assert "give way to circ" in w.reasoning


def test_a_far_ring_car_leaves_a_gap_and_the_ego_enters(entry, planner_config, mpc_config):
    # waiting at the line; the ring car 35 m before the junction at 8 m/s reaches the
    # merge point in ~6 s, the ego needs ~4 s to be on the ring
    accel, w = ask(entry, [ring_car("circ", x_m=-8.0 - 35.0)], planner_config, mpc_config,
                   ego_y_m=-11.0, v_mps=0.0)
    assert accel > 0.0
    assert "gap in the ring traffic" in w.reasoning


def test_a_ring_car_past_the_entry_is_no_conflict(entry, planner_config, mpc_config):
    car = syn.agent("gone", x_m=20.0, y_m=-1.6, yaw_rad=0.0, v_mps=8.0, lane_id="R1_0") \
        .model_copy(update={"lane_pos_m": 12.0})
    accel, w = ask(entry, [car], planner_config, mpc_config, ego_y_m=-11.0, v_mps=0.0)
    assert accel > 0.0
    assert "give way" not in w.reasoning


def test_the_approach_slows_down_for_the_entry(entry, planner_config, mpc_config):
    """No ring traffic in sight, 30 m before the line at 12 m/s: the ego slows (it must be
    able to stop for ring traffic that shows up), where far out it keeps its speed."""
    near, _ = ask(entry, [], planner_config, mpc_config, ego_y_m=-38.0, v_mps=12.0)
    far, _ = ask(entry, [], planner_config, mpc_config, ego_y_m=-95.0, v_mps=12.0)
    assert near < 0.0 <= far


def test_far_out_the_ego_does_not_speed_up_where_it_could_not_slow_down_after(
        entry, planner_config, mpc_config):
    """No ring traffic in sight at 8 m/s: 45 m before the line the way-is-clear rule would
    speed up towards the limit for the next 2.5 s, after which a comfortable slow-down for
    the entry no longer fits (rab 10049, training seed: 9.3 -> 12.5 m/s, then too close
    to stop for the ring car, committed, hit in the entry); it keeps its speed. 65 m out
    the speed-up still leaves room and it speeds up."""
    near, w = ask(entry, [], planner_config, mpc_config, ego_y_m=-55.0, v_mps=8.0)
    far, _ = ask(entry, [], planner_config, mpc_config, ego_y_m=-75.0, v_mps=8.0)
    assert near == 0.0 and "I keep my speed" in w.reasoning
    assert w.weight_adjustment.action == "high"  # else the MPC tracks the limit anyway
    assert far > 0.0


def test_the_held_speed_does_not_undo_a_conservative_slow_down(
        entry, planner_config, mpc_config):
    accel, w = ask_conservative(entry, ego_y_m=-55.0, v_mps=11.0,
                                planner_config=planner_config, mpc_config=mpc_config)
    assert accel < 0.0, w.reasoning


def ask_conservative(map_, *, ego_y_m, v_mps, planner_config, mpc_config):
    ego = syn.ego_state(x_m=1.6, y_m=ego_y_m, yaw_rad=NORTH, v_mps=v_mps, lane_id="S_in_0") \
        .model_copy(update={"lane_pos_m": ego_y_m + 100.0})
    w, _ = ask_rules(syn.observation(map_, ego, []), planner_config, mpc_config,
                     instruction="drive conservatively")
    return accel_mid(w, mpc_config), w


@pytest.mark.parametrize("instruction", ["drive conservatively", "drive aggressively"])
def test_before_a_roundabout_the_style_speed_is_not_held(
        entry, planner_config, mpc_config, instruction):
    """Far out (95 m) at 5 m/s the style still picks its interval, but not with the action
    weight "high" that holds it on an open road: before a roundabout the entry gap
    decides, and a held style speed met other gaps (rab training seeds 10000-10049)."""
    ego = syn.ego_state(x_m=1.6, y_m=-95.0, yaw_rad=NORTH, v_mps=5.0, lane_id="S_in_0") \
        .model_copy(update={"lane_pos_m": 5.0})
    w, _ = ask_rules(syn.observation(entry, ego, []), planner_config, mpc_config,
                     instruction=instruction)
    assert accel_mid(w, mpc_config) > 0.0, w.reasoning
    assert w.weight_adjustment.action == "normal", w.reasoning
