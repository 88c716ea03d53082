"""``benchmark.py --executor ray`` gives the rows and decision logs of the local process
pool (every column but the timings), on a private local Ray that is gone when the run
ends; SIGTERM keeps the finished rows as with the pool. Skipped when Ray is not installed
(it is the optional ``ray`` extra)."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from graphkit import REPO, interrupt_after

pytest.importorskip("ray", reason="ray is not installed (the optional 'ray' extra: "
                                  "pip install -e '.[ray]')")

# one Ray at a time: these tests look for Ray processes they did not start
pytestmark = pytest.mark.xdist_group("ray")

TIMINGS = {"solve_ms_median", "solve_ms_p99", "compute_ms_median", "compute_ms_p99", "wall_s"}
RAY_PROCESSES = ("gcs_server", "raylet", "ray::", "default_worker.py", "dashboard",
                 "runtime_env", "log_monitor", "monitor.py")
# development seeds (never the published 0-24)
ARGS = ["--families", "usi", "--seeds", "100,101", "--methods", "mpc,lmpc-rules"]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("RAY_ADDRESS", None)  # a private local Ray, never someone's cluster
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def _ray_pids() -> set[int]:
    """Our user's processes that belong to a Ray instance."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if entry.stat().st_uid != os.getuid():
                continue
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if any(name in cmd for name in RAY_PROCESSES):
            found.add(int(entry.name))
    return found


def _assert_no_new_ray(before: set[int]) -> None:
    deadline = time.monotonic() + 20
    while (left := _ray_pids() - before) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, f"Ray processes outlived the run: {sorted(left)}"


def _rows(out: Path) -> list[dict[str, Any]]:
    with open(out / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    return sorted(({k: v for k, v in r.items() if k not in TIMINGS} for r in rows),
                  key=lambda r: (r["family"], int(r["seed"]), r["method"]))


def _log(path: Path) -> list[dict[str, Any]]:
    """A decision log without its wall-measured latencies."""
    records = []
    for line in path.read_text().splitlines():
        rec = json.loads(line)
        rec.pop("measured_latency_s", None)
        for attempt in rec.get("attempts", []):
            attempt.pop("latency_s", None)
        records.append(rec)
    return records


def _bench(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"), *ARGS,
                           "--out", str(out), *extra], capture_output=True, text=True,
                          timeout=400, env=_env())
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return proc


def test_ray_gives_the_rows_and_logs_of_the_pool(tmp_path: Path) -> None:
    before = _ray_pids()
    pool = _bench(tmp_path / "pool", "--workers", "1")
    ray = _bench(tmp_path / "ray", "--workers", "2", "--executor", "ray")
    _assert_no_new_ray(before)
    pool_rows, ray_rows = _rows(tmp_path / "pool"), _rows(tmp_path / "ray")
    assert len(pool_rows) == 4 and {r["outcome"] for r in pool_rows} != {"error"}
    assert ray_rows == pool_rows
    logs = sorted(p.name for p in (tmp_path / "pool" / "decisions").glob("*.jsonl"))
    assert logs == ["usi-100-lmpc-rules.jsonl", "usi-101-lmpc-rules.jsonl"]
    assert sorted(p.name for p in (tmp_path / "ray" / "decisions").glob("*.jsonl")) == logs
    for name in logs:
        pool_log = _log(tmp_path / "pool" / "decisions" / name)
        assert pool_log and _log(tmp_path / "ray" / "decisions" / name) == pool_log
    # the progress line and ETA as with the pool
    for proc in (pool, ray):
        progress = [line for line in proc.stdout.splitlines() if line.startswith("[")]
        assert [line.split("]")[0] for line in progress] == ["[1/4", "[2/4", "[3/4", "[4/4"]
        assert all(" ETA " in line for line in progress)
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["executor"] == "ray" and summary["partial"] is None


def test_sigterm_keeps_the_finished_rows_and_stops_ray(tmp_path: Path) -> None:
    before = _ray_pids()
    out = tmp_path / "bench"
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "100-103", "--methods", "lmpc-rules", "--workers", "1", "--executor",
         "ray", "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True, env=_env())
    text = interrupt_after(proc, "[1/4]")
    assert proc.returncode == 130, text[-2000:]
    finished = sum(line.startswith("[") and "/4]" in line for line in text.splitlines())
    assert 1 <= finished < 4, text[-2000:]
    with open(out / "results.csv") as fh:
        assert len(list(csv.DictReader(fh))) == finished
    summary = json.loads((out / "summary.json").read_text())
    assert summary["partial"] == {"scenes_done": finished, "scenes_planned": 4}
    _assert_no_new_ray(before)


def test_an_unreachable_cluster_is_a_one_line_error(tmp_path: Path) -> None:
    env = _env()
    env["RAY_ADDRESS"] = "127.0.0.1:1"  # nothing listens there
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"),
                           "--families", "usi", "--seeds", "100", "--methods", "mpc",
                           "--executor", "ray", "--out", str(tmp_path / "b")],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "benchmark: --executor ray: no Ray cluster at RAY_ADDRESS=127.0.0.1:1" \
        in proc.stderr
    assert "Traceback" not in proc.stderr
