"""A mock LLM node replaces the planner: scripted decisions visibly steer the ego."""
from __future__ import annotations

from pathlib import Path

import pytest

from graphkit import REPO, run_graph

pytestmark = pytest.mark.graph

DATA = REPO / "test" / "data"
HOLD_UNTIL_S = 12.0  # from test/data/stop_then_go.yaml


def test_stop_holds_the_ego_before_the_junction_and_go_lets_it_pass(
    tmp_path: Path, domain_id: int
) -> None:
    held = run_graph(tmp_path / "stop", domain_id, "--planner", "mock", "--mock-script",
                     str(DATA / "stop_then_go.yaml"), "--scenario", "usi", "--seed", "1",
                     "--quiet")
    assert held.summary["outcome"] == "reached", held.output[-3000:]
    steps = held.episode["record"]["steps"]
    holding = [s for s in steps if 6.0 <= s["t_s"] < HOLD_UNTIL_S]
    assert holding, "no steps in the hold window"
    for s in holding:
        assert s["v_mps"] < 0.3, f"ego moving at t={s['t_s']}: {s['v_mps']:.2f} m/s"
        assert s["route_index"] == 0 and not s["lane_id"].startswith(":"), (
            f"ego not before the junction at t={s['t_s']}: lane {s['lane_id']}")
    assert {s["control_mode"] for s in holding} == {"decision"}
    assert held.summary["decisions"] >= 2

    free = run_graph(tmp_path / "go", domain_id, "--planner", "mock", "--mock-script",
                     str(DATA / "go.yaml"), "--scenario", "usi", "--seed", "1", "--quiet")
    assert free.summary["outcome"] == "reached", free.output[-3000:]
    first_moving_after_hold = min(
        s["t_s"] for s in steps if s["t_s"] >= HOLD_UNTIL_S and s["v_mps"] > 0.5)
    assert first_moving_after_hold < HOLD_UNTIL_S + 2.0, "the go decision did not release the ego"
    # Holding for 12 s costs time: the go-only run arrives clearly earlier.
    assert free.summary["sim_time_s"] < held.summary["sim_time_s"] - 5.0
