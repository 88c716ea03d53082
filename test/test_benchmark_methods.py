"""The method registry (``scripts/methods.py``) and ``benchmark.py --list-methods``."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from graphkit import REPO

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_scripts import methods


def test_list_methods_prints_every_registered_method_on_one_line() -> None:
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"),
                          "--list-methods"], capture_output=True, text=True, check=True).stdout
    names = [line.split()[0] for line in out.splitlines()]
    assert names == list(methods.METHODS)
    assert {"mpc", "lmpc-rules", "lmpc-local", "lmpc-openai", "lmpc-replay"} <= set(names)
    assert all(len(line.split(maxsplit=1)) == 2 for line in out.splitlines())


def test_the_registry_names_an_unknown_method_and_a_replay_without_its_log() -> None:
    with pytest.raises(KeyError, match="unknown method 'lmpc-nope'"):
        methods.build(SceneSpec("lmpc-nope", "usi", 0))
    with pytest.raises(ValueError, match="--replay-from"):
        methods.build(SceneSpec("lmpc-replay", "usi", 0))


def test_a_misspelt_family_is_refused_before_any_scene_runs(
    tmp_path: Path, domain_id: int
) -> None:
    """benchmark.py and run_graph.py name the unknown family and the known ones, and
    neither runs anything (the benchmark wrote a results folder of error rows before)."""
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"),
                          "--families", "usi,usii", "--seeds", "0", "--out",
                          str(tmp_path / "bench")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unknown scenario family 'usii'; known:" in out.stderr
    assert "usi-multi" in out.stderr and not (tmp_path / "bench").exists()
    graph = subprocess.run([sys.executable, str(REPO / "scripts" / "run_graph.py"),
                            "--scenario", "usii", "--run-dir", str(tmp_path / "run"),
                            "--quiet", "--domain-id", str(domain_id)],
                           capture_output=True, text=True, timeout=60)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert graph.returncode == 3 and summary["outcome"] == "error"
    assert "unknown scenario family 'usii'" in summary["detail"]
    assert summary["nodes"] == {} and not list((tmp_path / "run").glob("*.log"))
    # a seed that is no number, or a negative one, is refused by the argument parser
    # ... and so is a planner config that cannot be read (the planner node died with it)
    for script, flag, value, said in (("benchmark.py", "--seeds", "0,x-3", "'x-3' in '0,x-3'"),
                                      ("benchmark.py", "--workers", "0",
                                       "--workers: 0 must be >= 1"),
                                      ("regret.py", "--workers", "-2",
                                       "--workers: -2 must be >= 1"),
                                      ("run_graph.py", "--max-time-s", "-5",
                                       "--max-time-s must be > 0, got -5.0"),
                                      ("run_graph.py", "--domain-id", "233",
                                       "--domain-id: 233 must be within 0-232"),
                                      ("run_graph.py", "--extra-subscribers", "-1",
                                       "--extra-subscribers: -1 must be >= 0"),
                                      ("run_graph.py", "--rt-priority", "100",
                                       "--rt-priority: 100 must be within 0-99"),
                                      ("run_graph.py", "--egos", "0", "--egos: 0 must be >= 1"),
                                      ("train_rl.py", "--envs", "0", "--envs: 0 must be >= 1"),
                                      ("run_graph.py", "--seed", "-1", "--seed: -1 must be >= 0"),
                                      ("run_graph.py", "--planner-config",
                                       str(tmp_path / "none.yaml"), "cannot read it")):
        bad = subprocess.run([sys.executable, str(REPO / "scripts" / script), flag, value],
                             capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and said in bad.stderr, (script, bad.stderr)
    # an MPC config that cannot be read, with no planner to compare it to: refused too
    # (the MPC node would have died with it), an error summary and no node log
    alone = subprocess.run([sys.executable, str(REPO / "scripts" / "run_graph.py"),
                            "--planner", "none", "--mpc-config", str(tmp_path / "none.yaml"),
                            "--run-dir", str(tmp_path / "alone"), "--quiet",
                            "--domain-id", str(domain_id)],
                           capture_output=True, text=True, timeout=60)
    summary = json.loads((tmp_path / "alone" / "summary.json").read_text())
    assert alone.returncode == 3 and summary["outcome"] == "error", alone.stderr
    assert "MPC config" in summary["detail"] and "cannot read it" in summary["detail"]
    assert summary["nodes"] == {} and not list((tmp_path / "alone").glob("*.log"))


def test_a_factory_named_module_function_is_imported_when_the_method_runs() -> None:
    entry = methods.Method("x", "a method by name", "lmpc_scripts.methods:build_mpc")
    wiring = entry.build(SceneSpec("x", "usi", 0))
    assert wiring.planner is None and hasattr(wiring.controller, "compute")
    assert set(wiring.finish(None)) == {"route_overrides", "stale_steps", "stale_agent_steps"}


@pytest.mark.parametrize("script,args", [
    ("benchmark.py", ["--families", "usi", "--seeds", "0", "--methods", "mpc"]),
    ("multi.py", []), ("regret.py", ["RUN_DIR"]), ("bench_loop.py", ["--runs", "1"]),
])
def test_an_out_that_is_a_file_is_refused_by_name(tmp_path: Path, script: str,
                                                  args: list[str]) -> None:
    """--out names a file: the script says so before it runs anything (benchmark.py,
    multi.py and bench_loop.py ended with a FileExistsError traceback from mkdir before)."""
    afile = tmp_path / "results.csv"
    afile.write_text("kept\n")
    out = subprocess.run([sys.executable, str(REPO / "scripts" / script),
                          *[str(tmp_path) if a == "RUN_DIR" else a for a in args],
                          "--out", str(afile)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    assert f"argument --out: '{afile}' is a file, not a folder" in out.stderr
    assert "Traceback" not in out.stderr and afile.read_text() == "kept\n"
