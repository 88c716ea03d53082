"""Issue 23: on lane seed 104 at 5 s decision latency SUMO inserted the truck ``v11``
(pending since t = 0) onto the ego's body half-way through a lane change: a collision no
driver could avoid. The bridge now holds such an insertion back until the spot is clear
(``lmpc_bridge.insertion``); the scene runs in-process through ``benchmark.py``."""
from __future__ import annotations

from pathlib import Path

from benchkit import bench_rows


def test_lane_104_at_5_s_holds_the_truck_back(tmp_path: Path) -> None:
    (row,) = bench_rows("--families", "lane", "--seeds", "104", "--methods", "lmpc-rules",
                        "--workers", "1", "--decision-latency", "5", out=tmp_path,
                        timeout_s=900)
    assert row["latency_s"] == "5.0"
    # before: outcome collision at 8.2 s, "ego box overlaps 'v11'"
    assert row["collision"] == "0" and "v11" not in row["detail"], row
    assert int(row["held_insertions"]) >= 1, row
