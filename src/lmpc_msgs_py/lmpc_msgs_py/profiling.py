"""Where a node's time goes: per-stage wall-time samples, summarised as percentiles.

Every node of the graph keeps one :class:`StageTimes` (``LmpcNode.stage_times``); the
JSON plumbing records decode / encode / publish per topic, and each node times its own
stages (the bridge: SUMO step, observation, the wait for the control; the MPC: input
pairing, problem set-up, solve, mirrors). ``run_graph.py --profile`` prints them as one
table (docs/RESULTS.md, "Where the time goes"). Recording a sample costs ~0.3 us.
Memory stays bounded on a node that runs for days: the percentiles are over the last
:data:`WINDOW` samples of a stage, its count and total over all of them.
"""
from __future__ import annotations

import math
import statistics
import time
from collections import deque
from contextlib import contextmanager
from typing import Iterable, Iterator

WINDOW = 20_000
"""Samples per stage the percentiles are taken over (the most recent; ~33 min at 10 Hz)."""


def percentiles(values: Iterable[float]) -> dict[str, float]:
    """n, median, p99 (nearest rank), max and total of ``values`` (ms), rounded to us."""
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, math.ceil(0.99 * len(ordered)) - 1)]
    return {"n": len(ordered), "median": round(statistics.median(ordered), 3),
            "p99": round(p99, 3), "max": round(ordered[-1], 3),
            "total": round(sum(ordered), 3)}


class StageTimes:
    """Wall-time samples (ms) per named stage."""

    def __init__(self, window: int = WINDOW) -> None:
        self._window = window
        self._samples: dict[str, deque[float]] = {}
        self._count: dict[str, int] = {}
        self._total: dict[str, float] = {}

    def add(self, stage: str, ms: float) -> None:
        samples = self._samples.get(stage)
        if samples is None:
            samples = self._samples[stage] = deque(maxlen=self._window)
            self._count[stage], self._total[stage] = 0, 0.0
        samples.append(ms)
        self._count[stage] += 1
        self._total[stage] += ms

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the ``with`` block as one sample of ``name`` (also when it raises)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, (time.perf_counter() - t0) * 1e3)

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: n and total (ms) over every sample, median, p99 and max over the last
        ``window`` of them."""
        out = {}
        for name in sorted(self._samples):
            stats = percentiles(self._samples[name])
            stats.update(n=self._count[name], total=round(self._total[name], 3))
            out[name] = stats
        return out
