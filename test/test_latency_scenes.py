"""Issue 23: the graph is safe at an LLM's latency. The four scenes that collided with the
rules reasoner's decisions arriving 2.5 s late (si 13, si 20, usi 14, usi 21) run
in-process through ``benchmark.py --decision-latency 2.5`` (emergencies 1.5 s); the
latencies are recorded in results.csv and summary.json, the MPC's stale-decision check
in the decision logs."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchkit import bench_rows, read_rows, run_benchmark
from graphkit import scripts_module

# the scenes named by the issue (all four reached after the MPC changes of 2026-12-03,
# docs/lmpc_mpc.md, "stale decisions, second round"; usi 21 is off route since the third)
SCENES = [("si", 13), ("si", 20), ("usi", 14), ("usi", 21)]


@pytest.fixture(scope="module")
def latency_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("latency")
    for family in ("si", "usi"):
        seeds = ",".join(str(s) for f, s in SCENES if f == family)
        bench_rows("--families", family, "--seeds", seeds, "--methods", "lmpc-rules",
                   "--workers", "1", "--decision-latency", "2.5", out=out / family,
                   timeout_s=900)
    return out


def _row(run: Path, family: str, seed: int) -> dict[str, str]:
    return next(r for r in read_rows(run / family) if int(r["seed"]) == seed)


_OPEN: set[tuple[str, int]] = set()
"""Scenes known not to reach at 2.5 s (strict xfail). usi 21 was one from the third round
of issue 23 (off route after a dodge in the junction, mechanism (2) of docs/RESULTS.md,
"Latency, third round") until the MPC's brake fallback stopped jumping the steer to 0
(commit b7c0906, 2026-12-03: the steer is ramped at the rate limit, as the bridge applied
it, so the MPC's record of its last control matches what was applied): bisected, usi 21
at 2.5 s is off route at 71f54fb and reaches at b7c0906 (40.5 s, O.C. 293.8)."""


@pytest.mark.slow
@pytest.mark.parametrize("family,seed", [
    pytest.param(f, s, marks=pytest.mark.xfail(strict=True, reason="off route after a dodge "
                                               "(mechanism 2), open (issue 23)"))
    if (f, s) in _OPEN else (f, s) for f, s in SCENES])
def test_scene_reaches_without_collision_at_2_5_s(
        latency_run: Path, family: str, seed: int) -> None:
    row = _row(latency_run, family, seed)
    assert (row["latency_s"], row["emergency_latency_s"]) == ("2.5", "1.5")
    assert row["outcome"] == "reached", row


@pytest.mark.slow
@pytest.mark.parametrize("family,seed", SCENES)
def test_scene_does_not_collide_at_2_5_s(latency_run: Path, family: str, seed: int) -> None:
    assert _row(latency_run, family, seed)["collision"] == "0"


@pytest.mark.slow
def test_latencies_and_the_stale_check_are_recorded(latency_run: Path) -> None:
    summary = json.loads((latency_run / "usi" / "summary.json").read_text())
    assert summary["decision_latency_s"] == 2.5 and summary["emergency_latency_s"] == 1.5
    # the check fired in these scenes and said so, per decision, in the decision logs
    assert sum(int(_row(latency_run, f, s)["stale_steps"]) for f, s in SCENES) > 0
    checks, records = [], []
    for family, seed in SCENES:
        log = latency_run / family / "decisions" / f"{family}-{seed:03d}-lmpc-rules.jsonl"
        recs = [json.loads(line) for line in log.read_text().splitlines()]
        records += recs
        checks += [r for r in recs if r.get("kind") == "mpc_stale_check"]
    assert checks and sum(r["go_refused_steps"] for r in checks) > 0
    decided = {r["decision_id"]: r for r in records if "decision" in r}
    assert all(c["decision_id"] in decided for c in checks)
    # every decision reports the latency it was given: 2.5 s normal, 1.5 s emergency
    assert {(r["mode"], r["latency_s"]) for r in decided.values()} <= {
        ("normal", 2.5), ("emergency", 1.5)}


def test_run_graph_passes_the_latencies_to_the_planner_node(tmp_path: Path) -> None:
    """``run_graph.py --decision-latency`` reaches the planner node's parameters (which map
    them through ``latency_overrides``), the emergency one defaulting to min(S, 1.5); a
    graph without a planner backend refuses the option, naming it."""
    run_graph = scripts_module("run_graph")

    args = run_graph.parse_args(["--decision-latency", "5"])
    params = run_graph.node_params(args, tmp_path)["planner"]
    assert params["decision_latency_s"] == 5.0 and "emergency_latency_s" not in params
    assert run_graph.effective_emergency_latency(args) == 1.5
    args = run_graph.parse_args(["--decision-latency", "2.5", "--emergency-latency", "1"])
    assert run_graph.node_params(args, tmp_path)["planner"]["emergency_latency_s"] == 1.0
    # --planning-period: the packaged config at that cadence, kept in the run folder
    args = run_graph.parse_args(["--planning-period", "1"])
    config = run_graph.node_params(args, tmp_path)["planner"]["config_file"]
    assert config == str(tmp_path / "planner_config.yaml")
    from lmpc_llm_planner.config import load_planner_config
    assert load_planner_config(config).period_s == 1.0
    for argv in (["--planner", "none", "--decision-latency", "1"],
                 ["--emergency-latency", "-1"], ["--planner", "mock", "--mock-script", "x",
                                                 "--planning-period", "1"],
                 ["--planning-period", "0"]):
        with pytest.raises(SystemExit) as exc:
            run_graph.parse_args(argv)
        assert exc.value.code == 2


def test_planning_period_spaces_the_normal_decisions(tmp_path: Path) -> None:
    """``benchmark.py --planning-period 5`` (issue 16 item 6): the rules' normal decisions
    come 5 s apart (emergencies in between as ever), the period is in summary.json and the
    config used is kept in the run folder; a bad period is refused before any scene."""
    out = tmp_path / "p5"
    bench_rows("--families", "usi", "--seeds", "100", "--methods", "lmpc-rules", "--workers",
               "1", "--planning-period", "5", out=out)
    assert json.loads((out / "summary.json").read_text())["planning_period_s"] == 5.0
    assert "period_s: 5.0" in (out / "planner_config.yaml").read_text()
    stamps = [json.loads(line)["stamp_s"] for line in
              (out / "decisions" / "usi-100-lmpc-rules.jsonl").read_text().splitlines()
              if json.loads(line).get("mode") == "normal"]
    assert len(stamps) >= 3, stamps
    assert min(b - a for a, b in zip(stamps, stamps[1:])) >= 5.0 - 1e-6, stamps
    bad = run_benchmark("--families", "usi", "--seeds", "100", "--methods", "lmpc-rules",
                        "--planning-period", "0", "--out", str(tmp_path / "bad"),
                        timeout_s=120)
    assert bad.returncode == 2 and "--planning-period must be within" \
        in bad.stderr, bad.stderr[-500:]
