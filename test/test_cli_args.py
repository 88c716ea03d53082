"""Output paths on the command line are checked when the arguments are read, so a long run
does not end in a traceback without its output (``lmpc_msgs_py.cli``)."""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from lmpc_msgs_py.cli import file_arg, folder_arg

from graphkit import REPO


def test_folder_and_file_arguments_name_what_is_in_the_way(tmp_path: Path) -> None:
    afile = tmp_path / "notes.txt"
    afile.write_text("kept\n")
    assert folder_arg(str(tmp_path / "new" / "deeper")) == tmp_path / "new" / "deeper"
    assert folder_arg(str(tmp_path)) == tmp_path
    with pytest.raises(argparse.ArgumentTypeError, match="is a file, not a folder"):
        folder_arg(str(afile))
    assert file_arg(str(tmp_path / "new" / "x.png")) == tmp_path / "new" / "x.png"
    assert file_arg(str(afile)) == afile  # overwritten later, as asked
    with pytest.raises(argparse.ArgumentTypeError, match="is a folder, not a file"):
        file_arg(str(tmp_path))
    with pytest.raises(argparse.ArgumentTypeError,
                       match=f"lies under the file '{afile}'"):
        file_arg(str(afile / "sub" / "x.png"))
    assert afile.read_text() == "kept\n"


def test_render_refuses_a_picture_under_a_file_before_it_runs(tmp_path: Path) -> None:
    afile = tmp_path / "notes.txt"
    afile.write_text("kept\n")
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "render.py"), "run",
                          "--family", "usi", "--seed", "0", "--gif", str(afile / "g.gif")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"argument --gif: '{afile / 'g.gif'}' lies under the file '{afile}'" in out.stderr


def test_run_graph_refuses_a_run_dir_or_summary_it_could_not_write(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lmpc_scripts import run_graph

    afile = tmp_path / "notes.txt"
    afile.write_text("kept\n")
    for flag, value, said in (("--run-dir", afile, "is a file, not a folder"),
                              ("--summary-json", afile / "s.json", "lies under the file")):
        with pytest.raises(SystemExit) as exc:
            run_graph.parse_args([flag, str(value)])
        assert exc.value.code == 2
        assert f"argument {flag}: '{value}' {said}" in capsys.readouterr().err


@pytest.mark.parametrize("script", ["run_graph.py", "benchmark.py"])
def test_an_instruction_the_planner_would_refuse_is_refused_by_the_script(script: str) -> None:
    """2 001 characters: the planner node drops such a message (run_graph waited 60 s for
    its receipt and ended with "did not report 'instruction received'"), and in process
    the prompt cut it (the benchmark ran the scenes with a different text)."""
    out = subprocess.run([sys.executable, str(REPO / "scripts" / script), "--instruction",
                          "x" * 2001], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "--instruction: 2001 characters exceeds 2000" in out.stderr


def test_run_graph_replays_one_ego_from_a_run_folder(tmp_path: Path) -> None:
    """``--planner replay --planner-replay DIR`` with one ego replays DIR/decisions.jsonl
    (the planner config written to the run folder names it); without a log the run is
    refused before any node starts, in one line."""
    import yaml

    from lmpc_scripts import graph_multi, run_graph

    old = tmp_path / "old"
    old.mkdir()
    (old / "decisions.jsonl").write_text("")
    run_dir = tmp_path / "run"
    run_dir.mkdir()

    def check(*extra: str) -> tuple[argparse.Namespace, str | None]:
        args = run_graph.parse_args(["--scenario", "usi", "--seed", "0", *extra])
        return args, graph_multi.check_args(args, run_dir / "scene")

    for extra, why in (((), "--planner replay needs --planner-replay DIR (a finished run "
                            "folder with DIR/decisions.jsonl)"),
                       (("--planner-replay", str(tmp_path / "nowhere")),
                        "decisions.jsonl does not exist (the decision log of the ego)"),
                       (("--planner-replay", str(run_dir)), "another run folder")):
        error = check("--planner", "replay", *extra)[1]
        assert error is not None and why in error and "\n" not in error, error
    args, error = check("--planner", "replay", "--planner-replay", str(old))
    assert error is None and args.egos == 1
    config = run_graph.node_params(args, run_dir)["planner"]["config_file"]
    replay = yaml.safe_load(Path(str(config)).read_text())["replay"]
    assert replay["log_path"] == str((old / "decisions.jsonl").resolve())
