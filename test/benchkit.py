"""Run ``scripts/benchmark.py`` as a user would and read what it wrote (shared by tests)."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path
from typing import Optional

REPO = Path(__file__).resolve().parents[1]
BENCHMARK = REPO / "scripts" / "benchmark.py"


def run_benchmark(*args: str, timeout_s: float = 600,
                  env: Optional[dict[str, str]] = None) -> subprocess.CompletedProcess[str]:
    """``benchmark.py *args`` in a subprocess (output captured, not checked)."""
    return subprocess.run([sys.executable, str(BENCHMARK), *args], capture_output=True,
                          text=True, timeout=timeout_s, env=env)


def read_rows(out: Path) -> list[dict[str, str]]:
    """The rows of ``out/results.csv``."""
    with open(out / "results.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def bench_rows(*args: str, out: Path, timeout_s: float = 600) -> list[dict[str, str]]:
    """``benchmark.py *args --out out``, which must exit 0; the rows it wrote."""
    proc = run_benchmark(*args, "--out", str(out), timeout_s=timeout_s)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return read_rows(out)
