"""An interrupted benchmark keeps what it finished: results.csv grows with every
finished scene, and SIGTERM (or Ctrl-C) writes results.csv, summary.json and table.md
of the finished scenes, marked partial, stops the workers and exits 130; ``--resume``
then runs only the scenes the interrupted run lacks (and keeps the rows of scenes outside
its selection)."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from graphkit import REPO, interrupt_after


def test_sigterm_writes_the_finished_scenes_and_stops_the_workers(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "0-3", "--methods", "mpc", "--workers", "1", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)

    def one_row_written() -> None:  # before the whole run ends
        with open(out / "results.csv") as fh:
            assert len(list(csv.DictReader(fh))) == 1

    text = interrupt_after(proc, "[1/4]", one_row_written)
    assert proc.returncode == 130, text[-2000:]
    assert "interrupted after" in text
    finished = sum(line.startswith("[") and "/4]" in line for line in text.splitlines())
    with open(out / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == finished >= 1
    assert all(r["family"] == "usi" and r["method"] == "mpc" for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["partial"] == {"scenes_done": finished, "scenes_planned": 4}
    assert summary["families"]["usi"]["mpc"]["scenes"] == finished
    assert (out / "table.md").read_text().startswith(f"PARTIAL: interrupted after {finished} of 4")
    # no worker left running in the benchmark's process group
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        raise AssertionError("a benchmark worker outlived the interrupted run")
    # --resume keeps the finished rows and runs only the rest
    again = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "0-3", "--methods", "mpc", "--workers", "1", "--out", str(out),
         "--resume"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"{finished} scene(s) kept" in again.stdout
    ran = [line for line in again.stdout.splitlines() if line.startswith("[")]
    assert len(ran) == 4 - finished and all(f"/{4 - finished}]" in line for line in ran)
    with open(out / "results.csv") as fh:
        resumed = list(csv.DictReader(fh))
    assert sorted(int(r["seed"]) for r in resumed) == [0, 1, 2, 3]
    assert [r for r in resumed if r["seed"] in {x["seed"] for x in rows}] == rows
    summary = json.loads((out / "summary.json").read_text())
    assert summary["partial"] is None and summary["resumed_rows"] == finished
    assert summary["families"]["usi"]["mpc"]["scenes"] == 4
    # a resume with another selection runs it and keeps the rows outside it
    more = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "4", "--methods", "mpc", "--workers", "1", "--out", str(out),
         "--resume"], capture_output=True, text=True, timeout=300)
    assert more.returncode == 0, more.stderr[-2000:]
    assert "4 row(s) of scenes outside this selection kept" in more.stdout
    with open(out / "results.csv") as fh:
        assert sorted(int(r["seed"]) for r in csv.DictReader(fh)) == [0, 1, 2, 3, 4]
    assert json.loads((out / "summary.json").read_text())[
        "families"]["usi"]["mpc"]["scenes"] == 5


def test_resume_names_a_malformed_results_file(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    out.mkdir()
    (out / "results.csv").write_text("family,seed\nusi,zero\n")
    proc = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "0", "--methods", "mpc", "--out", str(out), "--resume"],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "--resume: cannot read" in proc.stderr and "line 2" in proc.stderr
