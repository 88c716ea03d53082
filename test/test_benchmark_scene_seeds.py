"""benchmark.py with a scene file (issue 21): ``--seeds`` makes one scene per seed (SUMO
seed and background-traffic seed), and a run whose every row is an error exits non-zero."""
from __future__ import annotations

import sys
from pathlib import Path

from benchkit import bench_rows, read_rows, run_benchmark
from graphkit import REPO

sys.path.insert(0, str(REPO / "src" / "lmpc_bridge" / "test"))
from test_bridge_external import make_rab_tls_net  # noqa: E402


def test_scene_with_seeds_runs_one_scene_per_seed(tmp_path: Path) -> None:
    net = make_rab_tls_net(tmp_path)
    scene = tmp_path / "short.yaml"
    scene.write_text(f"net: {net}\nseed: 1\nbackground: {{period_s: 3, end_s: 200, seed: 4}}\n"
                     "warmup_s: 20\nmax_time_s: 8\n"
                     "ego: {start: {edge: WT, pos_m: 15}, speed_mps: 5, to_edge: R2E}\n")
    rows = bench_rows("--scene", str(scene), "--seeds", "0-1", "--methods", "mpc", "--workers",
                      "2", out=tmp_path / "bench")
    assert sorted((r["family"], r["seed"]) for r in rows) == [("short", "0"), ("short", "1")]
    assert all(r["outcome"] in ("reached", "timeout", "collision") for r in rows), rows
    # without --seeds: the file's own seed, one scene
    rows = bench_rows("--scene", str(scene), "--methods", "mpc", "--workers", "1",
                      out=tmp_path / "own")
    assert [(r["family"], r["seed"]) for r in rows] == [("short", "1")]


def test_a_benchmark_whose_every_row_is_an_error_exits_non_zero(tmp_path: Path) -> None:
    net = make_rab_tls_net(tmp_path)
    # valid on paper; SUMO sees the ego's start overlap a parked car: an error row
    (tmp_path / "parked.rou.xml").write_text(
        '<routes><vType id="p" length="4.5"/><route id="rp" edges="WT TR0"/>'
        '<vehicle id="parked" type="p" route="rp" depart="0" departPos="30">'
        '<stop lane="WT_0" endPos="32" duration="1000"/></vehicle></routes>')
    scene = tmp_path / "overlap.yaml"
    scene.write_text(f"net: {net}\nroutes: [parked.rou.xml]\nwarmup_s: 20\n"
                     "ego: {start: {edge: WT, pos_m: 31}, to_edge: R2E}\n")
    out = tmp_path / "bench"
    proc = run_benchmark("--scene", str(scene), "--seeds", "0-1", "--methods", "mpc",
                         "--workers", "2", "--out", str(out))
    rows = read_rows(out)
    assert [r["outcome"] for r in rows] == ["error", "error"]
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "every one of the 2 scene(s) ended in an error" in proc.stderr
    assert "overlaps vehicle 'parked'" in proc.stderr
