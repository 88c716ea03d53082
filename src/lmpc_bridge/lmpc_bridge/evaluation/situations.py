"""Situational text, measured: per-episode figures that show whether a situation the user
describes ("the right lane is closed ahead", "an ambulance is coming from behind, make
room", "pedestrians are crossing at the next junction") changed how the ego drove, and the
table of ``benchmark.py --instruction-set situations`` (per family and situation, against
the same scenes without an instruction).

Definitions (from :class:`lmpc_bridge.record.EpisodeRecord`):

- ``kerb_share``: of the steps on a normal (not junction) lane, the share on lane index 0
  (the kerb lane: rightmost, leftmost in left-hand traffic; a one-lane road's lane too,
  the record does not know how many lanes a road has); nan without such steps. A closed
  right lane should lower it, making room raise it;
- ``mean_speed_mps``: the ego's mean speed over the episode;
- ``approach_mps``: the mean ego speed over the ``APPROACH_M`` of road before each
  junction entry (a normal lane followed by an internal ``:`` lane), averaged over the
  entries; nan without one. Every entry counts, plain joins of two road pieces too
  (the record does not know which junctions have crossings): on roads with no real
  junction it should stay as it was.
"""
from __future__ import annotations

import math
import statistics
from typing import Any

from lmpc_bridge.evaluation.style import edge_lane
from lmpc_bridge.evaluation.table import finite, markdown, mean_finite
from lmpc_bridge.record import EpisodeRecord

APPROACH_M = 30.0
SITUATION_COLUMNS = ("kerb_share", "mean_speed_mps", "approach_mps")
SITUATIONS = ("none", "closure", "make-room", "pedestrians")
EXPECTED: dict[str, tuple[str, int]] = {
    # situation -> (the figure it should move, -1 lower / +1 higher than "none")
    "closure": ("kerb_share", -1),
    "make-room": ("kerb_share", +1),
    "pedestrians": ("approach_mps", -1),
}
"""What each situation should change, against the same scene without an instruction."""
MIN_CHANGE = {"kerb_share": 0.02, "approach_mps": 0.1, "mean_speed_mps": 0.1}
"""A scene counts as changed by a situation when its figure moves by more than this."""


def situation_metrics(record: EpisodeRecord) -> dict[str, Any]:
    """The situation figures of one episode (see the module doc); nan where undefined."""
    steps = record.steps
    where = [edge_lane(s.lane_id) for s in steps]
    normal = [w for w in where if w is not None]
    kerb = sum(1 for w in normal if w[1] == "0") / len(normal) if normal else math.nan
    # distance driven up to each step, for the approach windows
    dist = [0.0]
    for a, b in zip(steps, steps[1:]):
        dist.append(dist[-1] + math.hypot(b.x_m - a.x_m, b.y_m - a.y_m))
    approaches = []
    for k in range(1, len(steps)):
        entering = where[k - 1] is not None and (steps[k].lane_id or "").startswith(":")
        if entering:
            speeds = [steps[i].v_mps for i in range(k)
                      if dist[k] - dist[i] <= APPROACH_M]
            if speeds:
                approaches.append(statistics.fmean(speeds))
    speeds = [s.v_mps for s in steps]
    return {
        "kerb_share": round(kerb, 4) if math.isfinite(kerb) else math.nan,
        "mean_speed_mps": round(statistics.fmean(speeds), 3) if speeds else math.nan,
        "approach_mps": round(statistics.fmean(approaches), 3) if approaches else math.nan,
    }


def situation_summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family and situation (rows carry ``situation``): collisions, fails, means of
    time, O.C. and the figures, and for the situations of ``EXPECTED`` how many scenes
    the text changed (its figure moved by more than ``MIN_CHANGE`` against the same
    seed without an instruction) and how many of those moved the expected way."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for family in sorted({r["family"] for r in rows}):
        mine = [r for r in rows if r["family"] == family]
        base = {int(r["seed"]): r for r in mine if r.get("situation") == "none"}
        out[family] = {}
        for sit in SITUATIONS:
            sel = [r for r in mine if r.get("situation") == sit]
            if not sel:
                continue
            agg: dict[str, Any] = {
                "runs": len(sel), "collisions": sum(int(r["collision"]) for r in sel),
                "fails": sum(int(r["fail"]) for r in sel)}
            for k in ("time_s", "overall_cost", *SITUATION_COLUMNS):
                agg[k] = round(mean_finite(r.get(k) for r in sel), 3)
            changed = expected = 0
            if sit in EXPECTED:
                key, sign = EXPECTED[sit]
                for r in sel:
                    b = base.get(int(r["seed"]))
                    if b is None or not (finite(r.get(key)) and finite(b.get(key))):
                        continue
                    diff = float(r[key]) - float(b[key])
                    if abs(diff) > MIN_CHANGE[key]:
                        changed += 1
                        expected += int(diff * sign > 0)
            agg["changed"], agg["expected"] = changed, expected
            out[family][sit] = agg
    return out


def situation_table_md(summary: dict[str, dict[str, dict[str, Any]]]) -> str:
    """One row a family and situation; "Changed (expected)": scenes whose figure the text
    moved, and of those the ones moved the expected way (``EXPECTED``)."""

    def f(v: Any, fmt: str) -> str:
        return format(v, fmt) if finite(v) else "-"

    rows = []
    for family, sits in summary.items():
        for sit, a in sits.items():
            what = EXPECTED.get(sit)
            rows.append([
                family.upper(), sit, f"{a['runs']}", f"{a['collisions']}", f"{a['fails']}",
                f(a["time_s"], ".1f"), f(a["overall_cost"], ".1f"),
                f(a["kerb_share"], ".2f"), f(a["mean_speed_mps"], ".2f"),
                f(a["approach_mps"], ".2f"),
                f"{a['changed']} ({a['expected']}) in {what[0]}" if what else "-"])
    return markdown(["Scenario", "Situation", "Runs", "Coll.", "Fail", "Time", "O.C.",
                     "Kerb share", "Mean speed", "Approach speed", "Changed (expected)"],
                    rows)
