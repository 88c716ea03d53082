"""Rule 10, entering a roundabout (backends/rules/roundabout.py), called directly on the
straightened entry of ``lmpc_mpc.synthetic.roundabout_entry`` (ego northbound on S_in_0,
yield line at y = -8, turning right onto R1_0; ring cars along R0_0, which ends at
x = -8 and joins R1_0 through the 16 m junction lane :J_1_0)."""
from __future__ import annotations

import dataclasses
import math

import pytest
from lmpc_mpc import synthetic as syn
from rules_units import accel_of, fresh_plan, inputs

from lmpc_llm_planner.backends.rules.roundabout import (
    RING_LOOKBACK_M, ring_conflicts, ring_distance_m, roundabout_rule,
)
from lmpc_llm_planner.route import next_maneuver

RING_START_X_M = -68.0


@pytest.fixture(scope="module")
def entry():
    return syn.roundabout_entry()


def ring_car(aid, *, x_m, v_mps=8.0):
    return syn.agent(aid, x_m=x_m, y_m=-1.6, yaw_rad=0.0, v_mps=v_mps, lane_id="R0_0") \
        .model_copy(update={"lane_pos_m": x_m - RING_START_X_M})


def _inputs(map_, agents, planner_config, mpc_config, *, ego_y_m, v_mps, **kw):
    ego = syn.ego_state(x_m=1.6, y_m=ego_y_m, yaw_rad=math.pi / 2.0, v_mps=v_mps,
                        lane_id="S_in_0").model_copy(update={"lane_pos_m": ego_y_m + 100.0})
    return inputs(syn.observation(map_, ego, agents), planner_config, mpc_config, **kw)


def test_ring_distance_follows_the_ring_links(entry):
    lanes = {ln.id: ln for ln in entry.lanes}
    r0 = lanes["R0_0"]
    # 60 m ring lane: from 30 m in, 30 m to its end plus the 16 m junction lane
    assert ring_distance_m(lanes, r0, 30.0, "R1_0", 100.0) == pytest.approx(46.0)
    assert ring_distance_m(lanes, r0, 10.0, "R1_0", 100.0) == pytest.approx(66.0)
    assert ring_distance_m(lanes, r0, 10.0, "R1_0", RING_LOOKBACK_M) is None  # too far
    assert ring_distance_m(lanes, lanes["R1_0"], 5.0, "R1_0", 100.0) is None  # past it


def test_not_a_roundabout_entry_is_none(left_turn_map, obs_factory, planner_config,
                                        mpc_config):
    inp = inputs(obs_factory(left_turn_map), planner_config, mpc_config)
    plan = fresh_plan(inp)
    assert roundabout_rule(inp, plan) == "none"
    assert plan == fresh_plan(inp)


def test_ring_conflicts_count_only_upstream_ring_traffic(entry, planner_config, mpc_config):
    gone = syn.agent("gone", x_m=20.0, y_m=-1.6, yaw_rad=0.0, v_mps=8.0, lane_id="R1_0") \
        .model_copy(update={"lane_pos_m": 12.0})
    inp = _inputs(entry, [ring_car("a", x_m=-28.0), ring_car("b", x_m=-48.0), gone],
                  planner_config, mpc_config, ego_y_m=-11.0, v_mps=0.0)
    man = next_maneuver(inp.scene.obs, inp.scene.lanes, max_distance_m=70.0)
    ring = inp.scene.lanes["R1_0"]
    got = {c.view.id: c for c in ring_conflicts(inp, man, ring)}
    assert set(got) == {"a", "b"}
    # 20 m farther along the ring at 8 m/s: 2.5 s later at the merge point
    assert got["b"].t_agent_s - got["a"].t_agent_s == pytest.approx(2.5)
    assert got["a"].t_clear_s == got["b"].t_clear_s > 0.0


def test_close_ring_car_yields_far_one_enters(entry, planner_config, mpc_config):
    close = _inputs(entry, [ring_car("circ", x_m=-23.0)], planner_config, mpc_config,
                    ego_y_m=-20.0, v_mps=4.0)
    plan = fresh_plan(close)
    assert roundabout_rule(close, plan) == "yield"
    assert accel_of(close, plan) < 0.0 and plan.weights["safety"] == "high"
    assert "give way to circ" in plan.notes[-1]
    far = _inputs(entry, [ring_car("circ", x_m=-43.0)], planner_config, mpc_config,
                  ego_y_m=-11.0, v_mps=0.0)
    plan = fresh_plan(far)
    assert roundabout_rule(far, plan) == "go"
    assert accel_of(far, plan) > 0.0  # at the line with ring traffic coming: briskly
    assert plan.attention == {"circ": "on the roundabout, has priority at my entry"}


def test_too_close_to_stop_commits(entry, planner_config, mpc_config):
    # 2 m before the line at 8 m/s: stopping would need 16 m/s^2
    inp = _inputs(entry, [ring_car("circ", x_m=-20.0)], planner_config, mpc_config,
                  ego_y_m=-12.5, v_mps=8.0)
    plan = fresh_plan(inp)
    assert roundabout_rule(inp, plan) == "commit"
    assert accel_of(inp, plan) > 0.0


def test_hysteresis_after_a_go(entry, planner_config, mpc_config):
    inp = _inputs(entry, [ring_car("circ", x_m=-40.0)], planner_config, mpc_config,
                  ego_y_m=-11.0, v_mps=0.0)
    man = next_maneuver(inp.scene.obs, inp.scene.lanes, max_distance_m=70.0)
    gap = ring_conflicts(inp, man, inp.scene.lanes["R1_0"])[0].gap_s
    tight = dataclasses.replace(inp, safe_gap_s=gap + 0.25)
    assert roundabout_rule(tight, fresh_plan(tight)) == "yield"
    went = dataclasses.replace(tight, previous_go=True)
    assert roundabout_rule(went, fresh_plan(went)) == "go"


def test_far_out_the_stop_waits_for_the_next_decision(entry, planner_config, mpc_config):
    # 67 m out at 12 m/s with ring traffic at the entry: keep the speed for now
    agents = [ring_car("circ", x_m=-15.0)]
    normal = _inputs(entry, agents, planner_config, mpc_config, ego_y_m=-75.0, v_mps=12.0)
    plan = fresh_plan(normal)
    assert roundabout_rule(normal, plan) == "yield"
    assert accel_of(normal, plan) == 0.0 and "for now" in plan.notes[-1]
    urgent = _inputs(entry, agents, planner_config, mpc_config, ego_y_m=-75.0, v_mps=12.0,
                     mode="emergency")
    plan = fresh_plan(urgent)
    assert roundabout_rule(urgent, plan) == "yield"
    assert accel_of(urgent, plan) < 0.0


def test_a_decision_in_force_soon_asks_again_soon_and_keeps_its_speed_longer(
        entry, planner_config, mpc_config):
    # 36 m before the yield line at 10 m/s, nobody on the ring. Decided again 2.5 s
    # later, the ego must start slowing to the turn speed now; a decision in force at
    # once (the rules alone: expected latency 0) asks to be asked again after 0.5 s
    # (ring_revisit_s) and keeps its speed until then
    def ask(**kw):
        inp = _inputs(entry, [], planner_config, mpc_config, ego_y_m=-46.0, v_mps=10.0, **kw)
        plan = fresh_plan(inp)
        assert roundabout_rule(inp, plan) == "go"
        return plan.revisit_s, accel_of(inp, plan), plan.notes

    revisit, accel, notes = ask(expected_latency_s=0.0)
    assert revisit == planner_config.rules.ring_revisit_s == 0.5
    assert accel >= 0.0 and not any("slow down" in n for n in notes)
    # a decision that acts later than the revisit, one whose latency is not known yet
    # (an LLM's first) and an emergency answer approach as before
    for kw in ({"expected_latency_s": 1.5}, {"expected_latency_s": None},
               {"expected_latency_s": 0.0, "mode": "emergency"}):
        revisit, accel, notes = ask(**kw)
        assert revisit is None and accel < 0.0, kw
        assert "I slow down to 5 m/s for the turn." in notes, (kw, notes)


def test_a_decision_in_force_soon_enters_ahead_of_a_ring_car_it_can_beat(
        entry, planner_config, mpc_config):
    # 36 m out at 10 m/s, a ring car far enough upstream that the gap is safe: go now
    # (accelerate) instead of approaching slowly, which would close the gap
    agents = [ring_car("circ", x_m=-50.0, v_mps=6.0)]
    soon = _inputs(entry, agents, planner_config, mpc_config, ego_y_m=-46.0, v_mps=10.0,
                   expected_latency_s=0.0)
    plan = fresh_plan(soon)
    assert roundabout_rule(soon, plan) == "go"
    assert accel_of(soon, plan) > 0.0 and plan.revisit_s == 0.5
    assert "gap in the ring traffic" in plan.notes[0]
    late = _inputs(entry, agents, planner_config, mpc_config, ego_y_m=-46.0, v_mps=10.0,
                   expected_latency_s=None)
    plan = fresh_plan(late)
    assert roundabout_rule(late, plan) == "go"
    assert accel_of(late, plan) < 0.0 and plan.revisit_s is None
