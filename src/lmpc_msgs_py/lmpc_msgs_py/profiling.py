"""Where a node's time goes: per-stage wall-time samples, summarised as percentiles.

Every node of the graph keeps one :class:`StageTimes` (``LmpcNode.stage_times``); the
JSON plumbing records decode / encode / publish per topic, and each node times its own
stages (the bridge: SUMO step, observation, the wait for the control; the MPC: input
pairing, problem set-up, solve, mirrors). ``run_graph.py --profile`` prints them as one
table (docs/RESULTS.md, "Where the time goes"). Recording a sample costs ~0.3 us.
"""
from __future__ import annotations

import math
import statistics
import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator


def percentiles(values: list[float]) -> dict[str, float]:
    """n, median, p99 (nearest rank), max and total of ``values`` (ms), rounded to us."""
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, math.ceil(0.99 * len(ordered)) - 1)]
    return {"n": len(ordered), "median": round(statistics.median(ordered), 3),
            "p99": round(p99, 3), "max": round(ordered[-1], 3),
            "total": round(sum(ordered), 3)}


class StageTimes:
    """Wall-time samples (ms) per named stage."""

    def __init__(self) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)

    def add(self, stage: str, ms: float) -> None:
        self._samples[stage].append(ms)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the ``with`` block as one sample of ``name`` (also when it raises)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._samples[name].append((time.perf_counter() - t0) * 1e3)

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: n, median, p99, max, total (ms); stages with no sample are left out."""
        return {name: percentiles(values) for name, values in sorted(self._samples.items())
                if values}
