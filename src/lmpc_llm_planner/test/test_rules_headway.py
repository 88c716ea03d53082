"""The headway rule (backends/rules/headway.py) called directly: behind a moving leader in
the ego's lane on the straight road (ego in ``E0_0`` at x = 50, front at 52.25)."""
from __future__ import annotations

import dataclasses

import pytest
from rules_kit import car, road_obs
from rules_units import accel_of, fresh_plan, inputs

from lmpc_llm_planner.backends.rules.headway import (
    HEADWAY_OPEN_FRACTION, HEADWAY_S, headway_rule, wanted_gap_m,
)


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
