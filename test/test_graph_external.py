"""Your own network: scene files through the benchmark and the real graph.

Networks unlike the templates (netgenerate --rand / --spider, a roundabout next to
a signalized junction, the same in left-hand traffic): the ego reaches its target
without collision under ``mpc`` and ``lmpc-rules`` (benchmark --scene, in-process
like the graph's logic); one real graph run with ``--scene``; a broken scene fails
with one clear error and leaves no node running.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchkit import bench_rows
from graphkit import REPO, graph_processes, run_graph

sys.path.insert(0, str(REPO / "src" / "lmpc_bridge" / "test"))
from test_bridge_external import (  # noqa: E402
    make_rab_tls_net,
    make_rand_net,
    make_spider_net,
    pick_route,
)
from test_bridge_limits import JOINED_FROM, JOINED_TO, longest_ids, make_joined_net  # noqa: E402

BUILDERS = {
    "rand": make_rand_net,
    "spider": make_spider_net,
    "rab_tls": make_rab_tls_net,
    "rab_tls_lh": lambda d: make_rab_tls_net(d, left_hand=True),
}


def _scene(tmp_path: Path, name: str) -> Path:
    net = BUILDERS[name](tmp_path)
    a, b = ("WT", "R2E") if name.startswith("rab") else pick_route(net)
    path = tmp_path / f"{name}.yaml"
    path.write_text(
        f"net: {net}\nseed: 1\nbackground: {{period_s: 3, end_s: 300, seed: 4}}\n"
        f"warmup_s: 20\nmax_time_s: 120\n"
        f"ego: {{start: {{edge: '{a}', pos_m: 15}}, speed_mps: 5, to_edge: '{b}'}}\n"
        f"target: {{pos_m: 30}}\n")
    return path


# The off-route check (issue 21) found lmpc-rules (and on spider the baseline too) leaving
# its route on the random and spider nets, at a junction turn sharper than 110 degrees
# (rand: 123 degrees right, spider: 126 degrees left; ~4.4 m radius, the car's kinematic
# limit). Cause and fix (docs/lmpc_bridge_external.md, "Leaving the route"): the Bezier
# reference cut the turn, the lead-in (for a car turned away from its path) fired mid-turn
# and replaced the rest of it by a 6 m arc, and a decision's curve rebased in the turn
# curled back; near such a turn the MPC now tracks the route's own centreline
# (lmpc_mpc.reference.sharp_turn_path) for every method. Kept for a net that fails anew.
_OPEN_OFF_ROUTE: set[str] = set()


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="off_route; issue 21 open"))
    if n in _OPEN_OFF_ROUTE else n for n in sorted(BUILDERS)])
def test_both_methods_reach_the_target(tmp_path: Path, name: str) -> None:
    scene = _scene(tmp_path, name)
    rows = bench_rows("--scene", str(scene), "--methods", "mpc,lmpc-rules", "--workers", "2",
                      out=tmp_path / "bench", timeout_s=400)
    assert sorted(r["method"] for r in rows) == ["lmpc-rules", "mpc"]
    for row in rows:
        assert row["outcome"] == "reached", row
        assert row["collision"] == "0"


def test_the_shipped_example_scene_reaches(tmp_path: Path) -> None:
    """examples/city.yaml, the scene the README's first example runs: both methods reach.
    Its right turn from edge 5 onto 28 (109.9 degrees, radius 4.75 m) was just under the
    110-degree sharp-turn threshold, and lmpc-rules ran wide onto the oncoming lanes of
    street 28 (off route) on every seed until the threshold became 100 degrees."""
    rows = bench_rows("--scene", str(REPO / "examples" / "city.yaml"), "--methods",
                      "mpc,lmpc-rules", "--workers", "2", out=tmp_path / "bench",
                      timeout_s=400)
    assert sorted(r["method"] for r in rows) == ["lmpc-rules", "mpc"]
    for row in rows:
        assert row["outcome"] == "reached" and row["collision"] == "0", row


def test_graph_runs_a_scene_file(tmp_path: Path, domain_id: int) -> None:
    scene = _scene(tmp_path, "rab_tls")
    run = run_graph(tmp_path, domain_id, "--scene", str(scene), "--planner", "rules",
                    "--quiet", timeout_s=400)
    assert run.returncode == 0, run.output[-3000:]
    assert run.summary["outcome"] == "reached" and run.summary["collisions"] == 0
    assert run.episode["scenario"] == "rab_tls" and run.summary["decisions"] > 0
    assert not graph_processes(domain_id)
    # the run folder draws from the scene file it names (render.py run RUN_DIR once
    # failed: "unknown scenario family 'rab_tls'")
    from lmpc_bridge import render

    assert run.episode["scene_file"] == str(scene.resolve())
    data = render.load_run(Path(run.summary["run_dir"]))
    assert data.map.lanes and len(data.record.steps) == run.episode["metrics"]["steps"]


def test_graph_bad_scene_fails_clearly(tmp_path: Path, domain_id: int) -> None:
    net = make_rab_tls_net(tmp_path)
    # Valid on paper, but the ego's start overlaps a parked car: only SUMO can see it,
    # so the bridge fails after the other nodes started.
    (tmp_path / "parked.rou.xml").write_text(
        '<routes><vType id="p" length="4.5"/><route id="rp" edges="WT TR0"/>'
        '<vehicle id="parked" type="p" route="rp" depart="0" departPos="30">'
        '<stop lane="WT_0" endPos="32" duration="1000"/></vehicle></routes>')
    scene = tmp_path / "overlap.yaml"
    scene.write_text(f"net: {net}\nroutes: [parked.rou.xml]\nwarmup_s: 20\n"
                     "ego: {start: {edge: WT, pos_m: 31}, to_edge: R2E}\n")
    run = run_graph(tmp_path / "a", domain_id, "--scene", str(scene), "--quiet",
                    timeout_s=120)
    assert run.returncode == 3
    assert "overlaps vehicle 'parked'" in run.summary["detail"]
    assert not graph_processes(domain_id)
    # A bad field never starts a node.
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"net: {net}\nego: {{start: {{edge: nowhere}}, to_edge: R2E}}\n")
    run = run_graph(tmp_path / "b", domain_id, "--scene", str(bad), "--quiet", timeout_s=60)
    assert run.returncode == 3 and "no edge 'nowhere'" in run.summary["detail"]
    assert run.summary["nodes"] == {}
    # Without --run-dir the run folder is named after the scene file (was "usi-0-...").
    cwd = tmp_path / "c"
    cwd.mkdir()
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "run_graph.py"), "--scene",
                           str(bad), "--quiet", "--domain-id", str(domain_id)],
                          cwd=cwd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 3
    assert [p.name.rsplit("-", 2)[0] for p in (cwd / "runs").iterdir()] == ["bad"]


def test_long_joined_ids_drive_through_benchmark_and_graph(
        tmp_path: Path, domain_id: int) -> None:
    """netconvert's twice-joined cluster (191-character internal lane ids; the issue's OSM
    import had 170+, over the old 128 bound) through every message of the real graph."""
    net = make_joined_net(tmp_path)
    assert longest_ids(net)[0] >= 170
    scene = tmp_path / "joined.yaml"
    scene.write_text(
        f"net: {net}\nseed: 1\nbackground: {{period_s: 4, end_s: 300, seed: 2}}\n"
        f"warmup_s: 20\nmax_time_s: 90\nego: {{start: {{edge: '{JOINED_FROM}', pos_m: 100}}, "
        f"speed_mps: 5, to_edge: '{JOINED_TO}'}}\ntarget: {{pos_m: 60}}\n")
    rows = bench_rows("--scene", str(scene), "--methods", "mpc,lmpc-rules", "--workers", "2",
                      out=tmp_path / "bench", timeout_s=400)
    assert {r["method"]: r["outcome"] for r in rows} == {"mpc": "reached",
                                                         "lmpc-rules": "reached"}, rows
    run = run_graph(tmp_path / "g", domain_id, "--scene", str(scene), "--planner", "rules",
                    "--quiet", timeout_s=400)
    assert run.returncode == 0, run.summary["detail"] + run.output[-3000:]
    assert run.summary["outcome"] == "reached" and run.summary["collisions"] == 0
    lanes = {s["lane_id"] for s in run.episode["record"]["steps"] if s["lane_id"]}
    assert max(len(lane) for lane in lanes) >= 170  # the ego drove on the long-id lanes
    assert not graph_processes(domain_id)


def test_late_demand_is_named_in_the_summary_and_the_benchmark(tmp_path: Path,
                                                               domain_id: int) -> None:
    """A recorded-style demand file departing from 7:00 (25200 s) on a scene without
    ``begin_s``: the episode would run on an empty network, and both tools say so."""
    net = make_joined_net(tmp_path)
    (tmp_path / "late.rou.xml").write_text(
        f'<routes><flow id="am" begin="25200" end="28800" period="5" from="eW_30648418100" '
        f'to="{JOINED_TO}"/></routes>')
    scene = tmp_path / "late.yaml"
    scene.write_text(f"net: {net}\nroutes: [late.rou.xml]\nwarmup_s: 10\nmax_time_s: 6\n"
                     f"ego: {{start: {{edge: '{JOINED_FROM}', pos_m: 100}}, speed_mps: 5, "
                     f"to_edge: '{JOINED_TO}'}}\n")
    run = run_graph(tmp_path / "g", domain_id, "--scene", str(scene), "--planner", "none",
                    "--quiet", timeout_s=300)
    (warning,) = run.summary["warnings"]
    assert "no background vehicle departs between t = 0 s and 16 s" in warning
    assert "set begin_s: 25200" in warning
    assert "warning: traffic: no background vehicle departs" in run.output
    (row,) = bench_rows("--scene", str(scene), "--methods", "mpc", "--workers", "1",
                        out=tmp_path / "bench", timeout_s=300)
    assert "traffic: no background vehicle departs" in row["detail"]
