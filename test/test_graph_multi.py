"""Issue 18 with the real processes: two egos on ``narrow`` (development seed 101, where
two egos on their own planners collide in-process), one bridge, one MPC and one planner
process per ego, and in ``central`` mode a coordinator process (docs/MULTI.md)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from graphkit import RUN_GRAPH, Probe, graph_processes, run_graph, scripts_module

pytestmark = pytest.mark.graph

SEED = 101
EGOS = ("ego_1", "ego_2")


def _assert_both_through(summary: dict[str, Any]) -> None:
    egos = summary["egos"]
    assert set(egos) == set(EGOS), summary
    assert summary["outcome"] == "reached", summary["detail"]
    for eid in EGOS:
        assert egos[eid]["outcome"] == "reached", (eid, egos[eid])
    assert summary["ego_collisions"] == 0
    assert summary["deadlock"] is False
    assert summary["clear_s"] is not None


def _in_process(mode: str) -> Any:
    """The same scene in-process (scripts/multi.py's wiring, lmpc-rules)."""
    import tempfile

    multi = scripts_module("multi")
    from lmpc_bridge.multi_episode import run_multi_episode
    from lmpc_bridge.multi_sim import MultiSumoSim

    egos, coordination = multi.wire("lmpc-rules", list(EGOS), mode)
    sim = MultiSumoSim(work_dir=Path(tempfile.mkdtemp("-multi")))
    return run_multi_episode(sim, family="narrow", seed=SEED, egos=egos,
                             coordination=coordination)


@pytest.mark.parametrize("mode", ["distributed", "central"])
def test_narrow_both_egos_through_and_as_in_process(tmp_path: Path, domain_id: int,
                                                    mode: str) -> None:
    run = run_graph(tmp_path, domain_id, "--scenario", "narrow", "--seed", str(SEED),
                    "--planner", "rules", "--coordination", mode, "--quiet")
    assert not run.crosstalk, run.crosstalk
    s = run.summary
    _assert_both_through(s)
    assert s["n_egos"] == 2 and s["coordination"] == mode
    expected = {"bridge", *(f"{n}_{e}" for n in ("mpc", "planner") for e in EGOS)}
    assert set(s["nodes"]) == expected | ({"coordinator"} if mode == "central" else set())
    assert all(n["exit_code"] == 0 and n["tracebacks"] == 0 for n in s["nodes"].values()), \
        s["nodes"]
    stats = {eid: s["egos"][eid]["coordination"] for eid in EGOS}
    # somebody yielded: the hold point went into a planner's observation
    assert sum(st["hold_steps"] for st in stats.values()) > 0, stats
    assert all(st["statuses_received"] > 0 for st in stats.values()), stats
    # the command in force goes into each planner's prompt (and decision log) as text
    commands = [json.loads(line).get("command")
                for eid in EGOS
                for line in (Path(s["run_dir"]) / eid / "decisions.jsonl").read_text()
                .splitlines()]
    assert any(c and ("yield at" in c or "proceed at" in c) for c in commands), commands[:5]
    if mode == "central":
        assert s["coordinator"]["directives_issued"] > 0
        assert all(st["directives_followed"] > 0 for st in stats.values()), stats
        # the coordinator is not part of the sync barrier: a coordinator starved of CPU
        # for its directives' TTL (3 s sim, ~0.6 s wall here) would let them run out and
        # the fallback engage; it stays the exception (0 in 10 measured runs)
        assert all(st["silent_steps"] <= 10 for st in stats.values()), stats
    # the in-process episode of the same scene: the same outcome, about the same times
    # (distributed resolves on the same statuses: measured 0.1 s at most on seeds
    # 100-109; central's directives arrive a step or two later: up to 2.6 s)
    ref = _in_process(mode)
    assert ref.all_reached
    tol = 0.5 if mode == "distributed" else 5.0
    for e in ref.egos:
        got = s["egos"][e.ego_id]["reached_at_s"]
        assert abs(got - e.reached_at_s) <= tol, (e.ego_id, got, e.reached_at_s, stats)
    if mode == "distributed":  # steps resolved on the statuses of their own stamp
        # the peer's status is waited for 0.2 s of wall time (ASSEMBLY_WAIT_S), then the
        # planner decides without it (RELIABILITY); on a quiet machine that never
        # happens; under the full CI run of 2026-12-04 it did (the earlier CI runs
        # passed; reached times still within the tolerance above), so a few are allowed
        assert all(st["assembly_wait_expired"] <= 3 for st in stats.values()), stats
    # the summary line names the joint O.C. (a single ego's O.C. is not defined here)
    assert f"joint O.C.={s['joint_oc']}" in run.output and "O.C.=None" not in run.output
    if mode == "central":
        _assert_drawn_from_the_run_folder(Path(s["run_dir"]), s, tmp_path)


def _assert_drawn_from_the_run_folder(run_dir: Path, summary: dict[str, Any],
                                      tmp_path: Path) -> None:
    """``render.py multi RUN_DIR`` draws the graph's own run folder (every ego's record,
    its route from the rebuilt scene, the one-lane section shaded); ``render.py run`` on
    it says which command to use instead of "no 'record'"."""
    from lmpc_bridge import render

    render_py = scripts_module("render")
    data = render.load_multi_run(run_dir, shade=render_py.shaded_sections)
    assert data.ego_ids == EGOS and data.family == "narrow" and data.seed == SEED
    for eid in EGOS:
        assert data.outcomes[eid] == "reached"
        assert abs(data.records[eid].reached_at_s - summary["egos"][eid]["reached_at_s"]) < 1e-6
        assert len(data.routes[eid]) > 2
    assert data.routes["ego_1"] != data.routes["ego_2"] and data.shaded_lanes
    assert data.method == "lmpc-rules (graph)" and data.mode == "central"
    out = tmp_path / "strip.png"
    assert render_py.main(["multi", str(run_dir), "--out", str(out)]) == 0
    assert out.stat().st_size > 10_000
    done = subprocess.run([sys.executable, str(RUN_GRAPH.parent / "render.py"), "run",
                           str(run_dir)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and f"render.py multi {run_dir}" in done.stderr, done.stderr


def _start_graph(tmp_path: Path, domain_id: int, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(RUN_GRAPH), "--scenario", "narrow", "--seed", str(SEED),
         "--planner", "rules", "--quiet", "--run-dir", str(tmp_path / "run"),
         "--summary-json", str(tmp_path / "summary.json"), "--domain-id", str(domain_id),
         *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)


def _wait_log(path: Path, needle: str, proc: subprocess.Popen[str], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        if path.exists() and needle in path.read_text(errors="replace"):
            return
        time.sleep(0.05)
    raise AssertionError(f"{path.name} did not show {needle!r} within {timeout_s:.0f} s")


def _finish(proc: subprocess.Popen[str], tmp_path: Path) -> dict[str, Any]:
    try:
        out, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    path = tmp_path / "summary.json"
    assert path.exists(), out[-3000:]
    return json.loads(path.read_text())


def test_coordinator_killed_mid_run_egos_fall_back(tmp_path: Path, domain_id: int) -> None:
    proc = _start_graph(tmp_path, domain_id, "--coordination", "central")
    run_dir = tmp_path / "run"
    try:
        # a few rounds into the encounter (one ego is told to yield from the first round)
        _wait_log(run_dir / "coordinator.log", "round t=4.0s", proc, timeout_s=180)
        pids = [p for p in graph_processes(domain_id)
                if b"coordinator_node" in Path(f"/proc/{p}/cmdline").read_bytes()]
        assert len(pids) == 1, pids
        os.kill(pids[0], signal.SIGKILL)
        s = _finish(proc, tmp_path)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    _assert_both_through(s)
    assert "coordinator" in s["ended_early"]
    assert s["nodes"]["coordinator"]["exit_code"] == -signal.SIGKILL
    silent = {eid: s["egos"][eid]["coordination"]["silent_steps"] for eid in EGOS}
    assert sum(silent.values()) > 0, silent  # the fallback took over ...
    logs = "".join((run_dir / f"planner_{eid}.log").read_text() for eid in EGOS)
    assert "falling back to distributed" in logs  # ... and said so
    assert not graph_processes(domain_id)


def test_namespaced_topics_and_bad_directives_refused(tmp_path: Path, domain_id: int) -> None:
    pytest.importorskip("rclpy")
    from lmpc_msgs_py.codec import encode
    from lmpc_msgs_py.coordination import Directive, SpeedBand

    unknown = json.loads(encode(Directive(
        stamp_s=0.0, seq=1, directive_id="probe-1", ego_id="ego_2", conflict_id="narrow:x",
        priority=0, command="proceed", speed_band=SpeedBand(max_mps=10.0), deadline_s=3.0,
        source="rules")))
    unknown["ego_id"] = "ego_7"  # schema-valid, but not one of the graph's egos
    out_of_schema = dict(unknown, ego_id="ego_1", priority=-1)
    topics_seen: dict[str, list[str]] = {}
    nodes_seen: set[tuple[str, str]] = set()
    with Probe(domain_id) as probe:  # joins first: it sees every endpoint
        proc = _start_graph(tmp_path, domain_id, "--coordination", "central")
        try:
            probe.publish("/coordination/directive", json.dumps(unknown))
            probe.wait_subscribers("/coordination/directive", 2, timeout_s=120)
            # until the run ends: both kinds, again and again (a planner's reader may
            # match the probe's writer later than the probe sees it; volatile topic)
            sent = 0
            while proc.poll() is None:
                if sent < 40:
                    probe.publish("/coordination/directive",
                                  json.dumps(unknown if sent % 2 else out_of_schema))
                    sent += 1
                topics_seen.update(dict(probe.node.get_topic_names_and_types()))
                nodes_seen.update(probe.node.get_node_names_and_namespaces())
                time.sleep(0.25)
            s = _finish(proc, tmp_path)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    _assert_both_through(s)
    for eid in EGOS:
        for name in ("ego_state", "agents", "map", "decision", "control", "planner/status",
                     "episode", "coordination/hold"):
            assert topics_seen.get(f"/{eid}/lmpc/{name}") == ["std_msgs/msg/String"], \
                (eid, name, sorted(topics_seen))
        assert ("llm_planner", f"/{eid}") in nodes_seen
        assert ("mpc_controller", f"/{eid}") in nodes_seen
    for name in ("/coordination/status", "/coordination/directive", "/clock"):
        assert name in topics_seen
    assert "/lmpc/ego_state" not in topics_seen  # the single-ego names are not used
    for eid in EGOS:  # both kinds refused by each planner, counted, never followed
        st = s["egos"][eid]["coordination"]
        assert st["directives_refused"] >= 2, (eid, st)
    log = (tmp_path / "run" / "planner_ego_1.log").read_text()
    assert "unknown ego 'ego_7'" in log and "priority" in log


def test_a_hung_mpc_brakes_its_own_ego_only(tmp_path: Path, domain_id: int) -> None:
    """RELIABILITY.md per ego: ego_1's MPC stops answering for ~3 s wall (SIGSTOP); the
    bridge steps on after its control timeout with ego_1 braking, ego_2 on its controls."""
    proc = _start_graph(tmp_path, domain_id, "--coordination", "distributed")
    run_dir = tmp_path / "run"
    try:
        _wait_log(run_dir / "bridge.log", "progress t=5.0s", proc, timeout_s=180)
        pids = [p for p in graph_processes(domain_id)
                if b"ego_id:=ego_1" in Path(f"/proc/{p}/cmdline").read_bytes()
                and b"lmpc_mpc.mpc_node" in Path(f"/proc/{p}/cmdline").read_bytes()]
        assert len(pids) == 1, pids
        os.kill(pids[0], signal.SIGSTOP)
        time.sleep(3.0)
        os.kill(pids[0], signal.SIGCONT)
        s = _finish(proc, tmp_path)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    _assert_both_through(s)
    assert s["egos"]["ego_1"]["late_controls"] >= 2, s["egos"]["ego_1"]
    assert s["egos"]["ego_2"]["late_controls"] == 0, s["egos"]["ego_2"]
    assert "ego_1: no control for step" in (run_dir / "bridge.log").read_text()


def test_without_coordination_the_encounter_fails(tmp_path: Path, domain_id: int) -> None:
    """The control case: on the same scene two egos on their own planners (``none``) do
    not both get through (in-process with lmpc-rules they stop facing each other: a
    deadlock; the graph does the same), and the joint outcome and exit code say so."""
    run = run_graph(tmp_path, domain_id, "--scenario", "narrow", "--seed", str(SEED),
                    "--planner", "rules", "--coordination", "none", "--quiet")
    s = run.summary
    assert s["outcome"] in ("collision", "timeout"), s["detail"]
    assert run.returncode == {"collision": 1, "timeout": 2}[s["outcome"]]
    assert s["ego_collisions"] > 0 or s["deadlock"] is True, s
    assert "coordinator" not in s["nodes"]
    assert all(e["coordination"] is None for e in s["egos"].values())


def test_the_graph_and_the_benchmark_know_the_same_multi_ego_families() -> None:
    from lmpc_scripts import graph_multi, multi

    assert set(graph_multi.MULTI_FAMILIES) == set(multi.MULTI_FAMILIES)


def _section_together(run_dir: Path) -> int:
    """Steps at which the two egos were both in the one-lane section (``AB`` / ``BA``,
    one each way): what a coordinated pass never does."""
    records = json.loads((run_dir / "episode.json").read_text())["records"]
    lanes = {eid: {s["step"]: s["lane_id"] for s in records[eid]["steps"]} for eid in EGOS}
    return sum(1 for k, lane in lanes["ego_1"].items()
               if lane.startswith("AB") and lanes["ego_2"].get(k, "").startswith("BA"))


def test_llm_planners_and_llm_coordinator_then_both_replayed(
        tmp_path: Path, domain_id: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both egos' planners (``--planner openai``) and the coordinator (``openai``) ask a
    SIMULATED model (graphkit.FakeLlmServer: a planner answer is neutral, or braking while
    its prompt carries a ``yield`` command; a coordinator answer lets the committed or
    nearest car go first). Then the run again from its logs: every ego replays its own
    decision log, the coordinator its call log, and nothing asks the model."""
    from graphkit import FakeLlmServer

    with FakeLlmServer([]) as server:
        monkeypatch.setenv("LMPC_OPENAI_BASE_URL", server.base_url)
        monkeypatch.setenv("LMPC_OPENAI_MODEL", "fake")
        first = run_graph(tmp_path / "llm", domain_id, "--scenario", "narrow", "--seed",
                          str(SEED), "--planner", "openai", "--coordination", "central",
                          "--coordinator-backend", "openai", "--quiet")
        asked = len(server.calls)
        s = first.summary
        run_dir = Path(s["run_dir"])
        _assert_both_through(s)
        assert all(n["exit_code"] == 0 and n["tracebacks"] == 0 for n in s["nodes"].values())
        assert _section_together(run_dir) == 0
        # the coordinator asked the model every round it had a conflict, and logged it
        coord = s["coordinator"]
        assert coord["backend"] == "openai" and coord["llm_source"] == "llm:fake"
        calls = [json.loads(line) for line in
                 (run_dir / "coordinator.jsonl").read_text().splitlines()]
        assert len(calls) == coord["llm_calls"] > 0 and not coord["llm_errors"], coord
        assert coord["directives_issued"] > 0
        # each ego's planner: its own decision log, from the model, the command read
        commands: dict[str, list[str]] = {}
        for eid in EGOS:
            records = [json.loads(line) for line in
                       (run_dir / eid / "decisions.jsonl").read_text().splitlines()]
            assert records and all(r["source"] == "llm:fake" for r in records), eid
            commands[eid] = [r["command"] for r in records if r["command"]]
        assert any("yield at" in c for cs in commands.values() for c in cs), commands
        assert any("proceed at" in c for cs in commands.values() for c in cs), commands
        planner_prompts = [p for p in server.prompts if "Cars in a shared conflict" not in p]
        told = [p for p in planner_prompts if "Coordinator's command" in p]
        assert told and len(told) < len(planner_prompts)  # and without a command: no line
        assert sum("Cars in a shared conflict" in p for p in server.prompts) == len(calls)

        again = run_graph(tmp_path / "replay", domain_id, "--scenario", "narrow", "--seed",
                          str(SEED), "--planner", "replay", "--planner-replay", str(run_dir),
                          "--coordination", "central", "--coordinator-backend", "replay",
                          "--coordinator-replay", str(run_dir / "coordinator.jsonl"),
                          "--quiet")
        assert len(server.calls) == asked  # the replay asked nobody
    r = again.summary
    _assert_both_through(r)
    assert r["coordinator"]["backend"] == "replay" and r["coordinator"]["replay_misses"] == 0
    assert r["fallbacks"] == 0  # every decision found in its ego's log
    for eid in EGOS:
        a, b = s["egos"][eid], r["egos"][eid]
        assert b["outcome"] == a["outcome"], eid
        # measured equal to 0.1 s (2 runs); a directive a step later would shift it
        assert abs(b["reached_at_s"] - a["reached_at_s"]) <= 1.0, (eid, a, b)
        replayed = [json.loads(line) for line in
                    (Path(r["run_dir"]) / eid / "decisions.jsonl").read_text().splitlines()]
        assert all(d["source"] == "llm:fake" for d in replayed), eid
    assert not graph_processes(domain_id)


@pytest.mark.parametrize("extra, why", [
    (["--planner", "mock", "--mock-script", "x.yaml"], "--planner mock: a multi-ego graph"),
    (["--planner", "replay", "--coordination", "central"], "needs --planner-replay DIR"),
    (["--planner", "replay", "--planner-replay", "nowhere"], "the decision log of ego_1"),
    (["--planner-replay", "nowhere"], "--planner-replay needs --planner replay"),
    (["--coordination", "distributed", "--coordinator-backend", "openai"],
     "needs --coordination central"),
    (["--coordination", "central", "--coordinator-backend", "replay"],
     "needs --coordinator-replay LOG"),
    (["--coordination", "central", "--coordinator-replay", "c.jsonl"],
     "--coordinator-replay needs --coordinator-backend replay"),
    (["--coordination", "central", "--coordinator-config", "p.yaml"],
     "--coordinator-config needs --coordinator-backend openai or local"),
    (["--egos", "1", "--coordinator-backend", "openai"], "needs several egos"),
])
def test_unsupported_multi_ego_combinations_are_refused_in_one_line(
        tmp_path: Path, extra: list[str], why: str) -> None:
    run_graph_mod = scripts_module("run_graph")
    graph_multi = scripts_module("graph_multi")
    args = run_graph_mod.parse_args(["--scenario", "narrow", "--seed", str(SEED), *extra])
    error = graph_multi.check_args(args, tmp_path / "run" / "scene")
    assert error is not None and why in error and "\n" not in error, error


def test_a_refused_combination_starts_no_node(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(RUN_GRAPH), "--scenario", "narrow", "--seed", str(SEED),
         "--coordination", "distributed", "--coordinator-backend", "openai",
         "--run-dir", str(tmp_path / "run"), "--quiet"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 3
    assert "--coordinator-backend openai needs --coordination central" in proc.stdout
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["outcome"] == "error" and not s["nodes"]
