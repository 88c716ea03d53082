"""Graph tests on real node processes: text-modulated driving (paper Fig. 5 / Fig. 7).

``run_graph.py --instruction TEXT`` publishes the user's text on ``/lmpc/instruction``
before the episode starts; the rules planner reads it. Each run is cut short with
``--max-time-s`` (the behaviour compared happens early), so the outcome is a timeout
and what is compared comes from the bridge's per-step episode record: which lane the
ego is on at each step and how far from the target it is there.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import pytest

from graphkit import GraphRun, run_graph

pytestmark = pytest.mark.graph


def _run(tmp_path: Path, domain_id: int, scenario: str, seed: int, max_time_s: float,
         instruction: Optional[str]) -> GraphRun:
    extra = ["--instruction", instruction] if instruction else []
    run = run_graph(tmp_path, domain_id, "--scenario", scenario, "--seed", str(seed),
                    "--planner", "rules", "--clock", "sync", "--quiet",
                    "--max-time-s", str(max_time_s), *extra)
    s = run.summary
    assert s["outcome"] in ("timeout", "reached"), f"{s['outcome']}: {s['detail']}\n" \
        + run.output[-3000:]
    assert s["collisions"] == 0
    assert s["instruction"] == instruction
    assert all(n["tracebacks"] == 0 for n in s["nodes"].values()), s["nodes"]
    if instruction:
        planner_log = (Path(s["run_dir"]) / "planner.log").read_text()
        assert "instruction received" in planner_log
    return run


def _steps(run: GraphRun) -> list[dict[str, Any]]:
    steps = run.episode["record"]["steps"]
    assert steps, "the episode record has no steps"
    return steps


def _first_off_lane(steps: list[dict[str, Any]], lane_id: str) -> tuple[float, float]:
    """(time, distance to target) of the first step not on ``lane_id``; the last step's
    when the ego never left it (it left, if at all, later and nearer the target)."""
    for st in steps:
        if st["lane_id"] is not None and st["lane_id"] != lane_id:
            return st["t_s"], st["dist_to_target_m"]
    return steps[-1]["t_s"], steps[-1]["dist_to_target_m"]


def _first_on_lane(steps: list[dict[str, Any]], lane_id: str) -> float:
    """Time of the first step on ``lane_id`` (inf when never)."""
    return next((st["t_s"] for st in steps if st["lane_id"] == lane_id), float("inf"))


def test_closed_lane_instruction_leaves_the_lane_earlier(tmp_path: Path, domain_id: int
                                                         ) -> None:
    """construction seed 0: the ego starts in the lane closed ~200 m ahead. Told so, it
    changes lanes at once; without the text it does so only when it sees the work zone."""
    plain = _run(tmp_path / "plain", domain_id, "construction", 0, 12.0, None)
    told = _run(tmp_path / "told", domain_id, "construction", 0, 12.0,
                "The right lane is closed ahead.")
    lane0 = _steps(plain)[0]["lane_id"]
    assert lane0 == _steps(told)[0]["lane_id"] and lane0.endswith("_0")
    t_plain, d_plain = _first_off_lane(_steps(plain), lane0)
    t_told, d_told = _first_off_lane(_steps(told), lane0)
    # where along the road the ego leaves the closed lane: much farther from the target
    assert d_told > d_plain + 50.0, (t_told, d_told, t_plain, d_plain)
    assert t_told < t_plain


def test_conservative_follows_aggressive_keeps_the_fast_lane(tmp_path: Path, domain_id: int
                                                             ) -> None:
    """lane seed 101: the ego starts in the fast left lane, its exit lane (slower traffic)
    to the right. Conservative: into the exit lane at once, behind the slow traffic;
    aggressive: stays in the fast lane and merges late (outside this window)."""
    cons = _run(tmp_path / "cons", domain_id, "lane", 101, 12.0, "drive conservatively")
    aggr = _run(tmp_path / "aggr", domain_id, "lane", 101, 12.0, "drive aggressively")
    start_lane = _steps(cons)[0]["lane_id"]
    exit_lane = start_lane.rsplit("_", 1)[0] + "_0"
    assert start_lane != exit_lane
    t_cons = _first_on_lane(_steps(cons), exit_lane)
    t_aggr = _first_on_lane(_steps(aggr), exit_lane)
    assert t_cons < 8.0
    assert t_aggr > t_cons + 4.0
