"""Issue 23: on lane seed 104 at 5 s decision latency SUMO inserted the truck ``v11``
(pending since t = 0) onto the ego's body half-way through a lane change: a collision no
driver could avoid. The bridge now holds such an insertion back until the spot is clear
(``lmpc_bridge.insertion``); the scene runs in-process through ``benchmark.py``."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_lane_104_at_5_s_holds_the_truck_back(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "lane",
         "--seeds", "104", "--methods", "lmpc-rules", "--workers", "1",
         "--decision-latency", "5", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    with open(tmp_path / "results.csv", newline="") as fh:
        row = next(csv.DictReader(fh))
    assert row["latency_s"] == "5.0"
    # before: outcome collision at 8.2 s, "ego box overlaps 'v11'"
    assert row["collision"] == "0" and "v11" not in row["detail"], row
    assert int(row["held_insertions"]) >= 1, row
