"""The benchmark's bar chart: mean overall cost (O.C.) per scenario family and method."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt

from lmpc_bridge.render.draw import save_figure
from lmpc_bridge.render.runs import RenderError

METHOD_COLOURS = {"mpc": "#8c8c8c", "lmpc-rules": "#1f5fd6"}
_EXTRA_COLOURS = ("#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf")


def plot_oc_bars(summary: dict[str, Any], out: Path, *, dpi: int = 150) -> Path:
    """Bar chart of the mean overall cost (O.C.) per scenario family and method.

    ``summary`` is a benchmark ``summary.json`` (``{"families": {family: {method:
    {"overall_cost", "collisions", "fails", ...}}}}``) or its ``families`` part.
    Each bar is labelled with its O.C., collisions (C) and fails (F); non-MPC bars
    also carry the relative O.C. change against ``mpc`` when the summary has it.
    """
    families = summary.get("families", summary)
    if not isinstance(families, dict) or not families:
        raise RenderError("summary has no families: expected {'families': {family: "
                          "{method: {'overall_cost': ...}}}}")
    names = list(families)
    methods: list[str] = []
    for fam in names:
        if not isinstance(families[fam], dict):
            raise RenderError(f"summary family {fam!r}: expected a dict of methods")
        for method in families[fam]:
            if method not in methods:
                methods.append(method)
    methods.sort(key=lambda m: (m != "mpc", m))
    width = min(0.8 / max(len(methods), 1), 0.3)  # one family: no slab-wide bars
    fig, ax = plt.subplots(figsize=(max(5.5, 0.8 * len(names) * max(len(methods), 1) + 2),
                                    4.2))
    top = 0.0
    for j, method in enumerate(methods):
        colour = METHOD_COLOURS.get(method, _EXTRA_COLOURS[j % len(_EXTRA_COLOURS)])
        xs, heights, labels = [], [], []
        for i, fam in enumerate(names):
            agg = families[fam].get(method)
            if not agg or agg.get("overall_cost") is None:
                continue
            oc = float(agg["overall_cost"])
            if not math.isfinite(oc):
                continue
            xs.append(i + (j - (len(methods) - 1) / 2) * width)
            heights.append(oc)
            label = f"{oc:.1f}\nC{agg.get('collisions', 0)} F{agg.get('fails', 0)}"
            change = agg.get("oc_change_vs_mpc")
            if method != "mpc" and change is not None:
                label += f"\n{float(change):+.0%}"
            labels.append(label)
        bars = ax.bar(xs, heights, width=width * 0.92, color=colour, label=method,
                      edgecolor="black", linewidth=0.5)
        ax.bar_label(bars, labels=labels, fontsize=7, padding=2)
        top = max([top, *heights])
    ax.set_xticks(range(len(names)))
    ax.set_xlim(-0.6, len(names) - 0.4)
    scenes = [next((a.get("scenes") for a in families[n].values() if a.get("scenes")), None)
              for n in names]
    ax.set_xticklabels([n.upper() + (f"\n({k} scenes)" if k else "")
                        for n, k in zip(names, scenes)])
    ax.set_ylabel("overall cost O.C. (lower is better)")
    ax.set_ylim(0, top * 1.35 if top > 0 else 1.0)
    ax.set_title("Mean overall cost per scenario family (C = collisions, F = fails)",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    return save_figure(fig, out, dpi=dpi)
