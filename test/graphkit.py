"""Helpers for graph tests: run the graph as a user would, one ROS domain per run."""
from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
RUN_GRAPH = REPO / "scripts" / "run_graph.py"
TOPICS = REPO / "scripts" / "topics.py"

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

_domains = itertools.count()


def next_domain_id() -> int:
    """A domain id of its own for each graph (parallel runs never cross-talk).

    Ids 1..100 are valid with Fast DDS' default port mapping; spread by pid so two
    pytest processes on one machine pick different ones. ``LMPC_TEST_DOMAINS=60-69``
    confines one pytest process to a range (people running tests side by side)."""
    span = os.environ.get("LMPC_TEST_DOMAINS")
    if span:
        low, high = (int(v) for v in span.split("-"))
        return low + next(_domains) % (high - low + 1)
    return 1 + (os.getpid() * 7 + next(_domains)) % 100


@dataclass
class GraphRun:
    returncode: int
    summary: dict[str, Any]
    episode: dict[str, Any]
    output: str


def run_graph(tmp_path: Path, domain_id: int, *extra: str, timeout_s: float = 300) -> GraphRun:
    """Run scripts/run_graph.py to the end of the episode; return its summary and record."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    run_dir = tmp_path / "run"
    summary_path = tmp_path / "summary.json"
    cmd = [sys.executable, str(RUN_GRAPH), "--run-dir", str(run_dir), "--summary-json",
           str(summary_path), "--domain-id", str(domain_id), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=tmp_path)
    output = proc.stdout + proc.stderr
    if not summary_path.exists():
        raise AssertionError(
            f"run_graph wrote no summary (exit {proc.returncode}):\n{output[-4000:]}")
    summary = json.loads(summary_path.read_text())
    episode_path = run_dir / "episode.json"
    episode = json.loads(episode_path.read_text()) if episode_path.exists() else {}
    return GraphRun(proc.returncode, summary, episode, output)


def graph_processes(domain_id: int) -> list[int]:
    """Pids of node processes (``python -m lmpc_*``) running on ``domain_id``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"-m" in cmdline and any(a.startswith(b"lmpc_") for a in cmdline) and \
                f"ROS_DOMAIN_ID={domain_id}".encode() in environ:
            pids.append(int(entry.name))
    return pids
