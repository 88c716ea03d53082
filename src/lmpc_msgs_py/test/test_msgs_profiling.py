"""Stage times (``lmpc_msgs_py.profiling``): percentiles per stage, bounded memory."""
from __future__ import annotations

import pytest

from lmpc_msgs_py.profiling import StageTimes, percentiles


def test_percentiles_are_nearest_rank_in_ms() -> None:
    stats = percentiles([float(v) for v in range(1, 101)])
    assert stats == {"n": 100, "median": 50.5, "p99": 99.0, "max": 100.0, "total": 5050.0}


def test_a_stage_keeps_its_count_and_total_but_only_a_window_of_samples() -> None:
    times = StageTimes(window=10)
    for v in range(100):
        times.add("solve", float(v))
    with pytest.raises(RuntimeError):
        with times.stage("setup"):
            raise RuntimeError("timed even when it raises")
    summary = times.summary()
    assert list(summary) == ["setup", "solve"]
    assert summary["solve"]["n"] == 100 and summary["solve"]["total"] == 4950.0
    assert summary["solve"]["max"] == 99.0 and summary["solve"]["median"] == 94.5  # 90..99
    assert len(times._samples["solve"]) == 10
    assert summary["setup"]["n"] == 1 and summary["setup"]["max"] >= 0.0
