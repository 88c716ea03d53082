"""Table I: per family and method, counts of collisions and fails and means of the rest
(``aggregate``), and its Markdown (``table_md``)."""
from __future__ import annotations

import math
import statistics
from typing import Any, Iterable, Sequence

from lmpc_bridge.evaluation.rows import BASELINE


def finite(v: Any) -> bool:
    """A number that is not nan / inf (csv cells may be anything)."""
    return isinstance(v, (int, float)) and math.isfinite(v)


def mean_finite(values: Any) -> float:
    """Mean of the finite numbers of ``values``; nan if none."""
    vals = [float(v) for v in values if finite(v)]
    return statistics.fmean(vals) if vals else math.nan


def _mean(values: Any) -> float:
    return round(mean_finite(values), 3)


def aggregate(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family and method: counts of collisions and fails, means of the rest."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for family in sorted({r["family"] for r in rows}):
        out[family] = {}
        for method in sorted({r["method"] for r in rows if r["family"] == family},
                             key=lambda m: (m != BASELINE, m)):
            sel = [r for r in rows if r["family"] == family and r["method"] == method]
            out[family][method] = {
                "scenes": len(sel),
                "collisions": sum(r["collision"] for r in sel),
                "fails": sum(r["fail"] for r in sel),
                "off_route": sum(int(r.get("off_route", 0) or 0) for r in sel),
                # means over the scenes that produced metrics (error rows count as fails)
                **{k: _mean(r[k] for r in sel)
                   for k in ("ineff", "time_s", "pen_acc", "pen_dist", "overall_cost")},
                # how often the MPC found the decision in force stale (MpcController)
                "stale_scenes": sum(1 for r in sel if (r.get("stale_steps") or 0) > 0),
                "stale_steps": sum(int(r.get("stale_steps") or 0) for r in sel),
                "steps": sum(int(r.get("steps") or 0) for r in sel
                             if isinstance(r.get("steps"), int)),
            }
        base = out[family].get(BASELINE)
        for method, agg in out[family].items():
            if base and base["overall_cost"] > 0:
                agg["oc_change_vs_mpc"] = round(agg["overall_cost"] / base["overall_cost"] - 1, 4)
    return out


def wilson_interval(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a share of ``k`` in ``n`` (95 % for z = 1.96): how far
    a share over a few scenes may lie from the share over many; (nan, nan) for n = 0."""
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    scale = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / scale
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / scale
    return max(0.0, centre - half), min(1.0, centre + half)


def markdown(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table: the header, its rule and one line a row of cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines) + "\n"


def table_md(summary: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Table I: one row a family and method."""
    rows = []
    for family, methods in summary.items():
        for method, a in methods.items():
            change = a.get("oc_change_vs_mpc")
            rows.append([
                family.upper(), method, f"{a['collisions']}", f"{a['fails']}",
                f"{a.get('off_route', 0)}", f"{a['ineff']:.1f}", f"{a['time_s']:.1f}",
                f"{a['pen_acc']:.2f}", f"{a['pen_dist']:.2f}", f"{a['overall_cost']:.1f}",
                "" if change is None or method == BASELINE else f"{change:+.1%}"])
    return markdown(["Scenario", "Method", "Coll.", "Fail", "Off route", "Ineff", "Time",
                     "Acc", "Dist", "O.C.", "vs MPC"], rows)


ABLATION = (("mpc", False, False), ("lmpc-rules-enc", True, False),
            ("lmpc-rules-aw", False, True), ("lmpc-rules", True, True))
"""The paper's Table II rows: method, scenario encoding O^dy used, action bias & weights
used."""


def table2_md(summary: dict[str, dict[str, dict[str, Any]]]) -> str:
    """The paper's Table II (ablation) for the families whose summary holds an ablation
    method; the rows of ``ABLATION`` that ran. Empty when no ablation method ran."""
    rows = []
    for family, methods in summary.items():
        if not any(m in methods for m in ("lmpc-rules-enc", "lmpc-rules-aw")):
            continue
        for method, enc, aw in ABLATION:
            a = methods.get(method)
            if a is None:
                continue
            rows.append([
                family.upper(), "✓" if enc else "×", "✓" if aw else "×", method,
                f"{a['collisions']}", f"{a['fails']}", f"{a['ineff']:.1f}",
                f"{a['time_s']:.1f}", f"{a['pen_acc']:.2f}", f"{a['pen_dist']:.2f}",
                f"{a['overall_cost']:.1f}"])
    if not rows:
        return ""
    return markdown(["Scenario", "O^dy", "Â & W", "Method", "Coll.", "Fail", "Ineff", "Time",
                     "Acc", "Dist", "O.C."], rows)
