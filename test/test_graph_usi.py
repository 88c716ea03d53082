"""Graph tests on real node processes: the unprotected left turn (usi) end to end.

Each run starts bridge, planner (or not) and MPC as separate processes through
scripts/run_graph.py in sync mode, on a ROS domain of its own.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from graphkit import run_graph

pytestmark = pytest.mark.graph


@pytest.mark.parametrize("planner", ["none", "rules"])
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_usi_reaches_target_without_collision(
    tmp_path: Path, domain_id: int, planner: str, seed: int
) -> None:
    run = run_graph(tmp_path, domain_id, "--scenario", "usi", "--seed", str(seed),
                    "--planner", planner, "--clock", "sync", "--quiet")
    s = run.summary
    assert s["outcome"] == "reached", f"{s['outcome']}: {s['detail']}\n{run.output[-3000:]}"
    assert run.returncode == 0
    assert s["collisions"] == 0
    assert s["late_controls"] == 0, "sync mode must never step without the control"
    assert all(n["tracebacks"] == 0 for n in s["nodes"].values()), s["nodes"]
    if planner == "rules":
        assert s["decisions"] >= 1 and s["fallbacks"] == 0
    else:
        assert s["decisions"] == 0
    for key in ("mpc_solve_ms", "control_latency_ms"):
        assert s[key]["median"] is not None and s[key]["p99"] >= s[key]["median"]
