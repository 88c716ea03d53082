#!/usr/bin/env python3
"""The latency and cadence table and plot (issues 16, 23) from benchmark runs at several
decision latencies and planning periods.

    benchmark.py --families si,usi,lane,rab,eoa --seeds 0-24 --methods lmpc-rules \\
        --decision-latency 2.5 --out runs/latency/2.5          # one folder per latency
    benchmark.py ... --planning-period 5 --out runs/latency/p5   # one folder per period
    latency_table.py runs/latency/0 runs/latency/1.5 runs/latency/2.5 runs/latency/5 \\
        runs/latency/p1 runs/latency/p5 --png docs/data/latency.png

Prints a markdown table (per family: collisions, fails, O.C., and how often the MPC's
stale-decision check fired, per latency and period) and draws the O.C. change and the
collisions against latency (at the packaged period) and against the period (at latency 0)
with matplotlib. Each folder's latency and period are read from its summary.json.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Optional, Sequence

METHOD = "lmpc-rules"


Setting = tuple[float, float]
"""(decision latency, planning period), s."""


def default_period_s() -> float:
    """The packaged planner config's period: a run without ``--planning-period``."""
    from lmpc_llm_planner.config import load_planner_config

    return load_planner_config().period_s


def load(folders: Sequence[Path], method: str = METHOD) -> dict[Setting, dict[str, Any]]:
    """(latency, period) -> family -> the method's aggregate row of that run (summary.json).
    A run without ``--planning-period`` ran at the packaged period. Raises ``ValueError``
    naming a folder without a latency or the method, or two folders of one setting."""
    out: dict[Setting, dict[str, Any]] = {}
    for folder in folders:
        summary = json.loads((folder / "summary.json").read_text())
        latency = summary.get("decision_latency_s")
        if latency is None and method == "lmpc-rules":
            # no --decision-latency: the backend's own, and the rules reasoner's is 0
            # (``RulesBackend.reported_latency_s``): e.g. the Table I run of ``make bench``
            latency = 0.0
        if latency is None:
            raise ValueError(f"{folder}: summary.json has no decision_latency_s (run the "
                             "benchmark with --decision-latency)")
        period = summary.get("planning_period_s")
        setting = (float(latency), float(period if period is not None else default_period_s()))
        if setting in out:
            raise ValueError(f"{folder}: a second run at latency {setting[0]:g} s, period "
                             f"{setting[1]:g} s")
        fams = {f: m[method] for f, m in summary["families"].items() if method in m}
        if not fams:
            raise ValueError(f"{folder}: no {method} rows")
        out[setting] = {"families": fams, "partial": summary.get("partial")}
    return dict(sorted(out.items()))


def table_md(runs: dict[Setting, dict[str, Any]]) -> str:
    """Per family and setting: scenes, collisions, fails, mean O.C. and its change
    against latency 0 at the packaged period (when run), scenes / steps the stale check
    fired."""
    families = sorted({f for r in runs.values() for f in r["families"]})
    ref = (0.0, default_period_s())
    lines = [f"| Scenario | Latency s | Period s | Scenes | Coll. | Fail | O.C. | vs "
             f"{ref[0]:g} s / {ref[1]:g} s | Check fired (scenes / steps) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for fam in families:
        base = runs.get(ref, {}).get("families", {}).get(fam)
        for (latency, period), run in runs.items():
            a = run["families"].get(fam)
            if a is None:
                continue
            change = ""
            if base is not None and (latency, period) != ref and base["overall_cost"] > 0:
                change = f"{a['overall_cost'] / base['overall_cost'] - 1:+.1%}"
            lines.append(
                f"| {fam.upper()} | {latency:g} | {period:g} | {a['scenes']} | "
                f"{a['collisions']} | {a['fails']} | {a['overall_cost']:.1f} | {change} | "
                f"{a.get('stale_scenes', '?')} / {a.get('stale_steps', '?')} |")
    return "\n".join(lines) + "\n"


def plot(runs: dict[Setting, dict[str, Any]], png: Path) -> None:
    """O.C. change (lines) and collisions + fails (bars) per family: against the decision latency
    at the packaged period (left) and against the planning period at latency 0 (right),
    where more than one such run exists."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = (0.0, default_period_s())
    axes = [("decision latency, s (emergencies: min(latency, 1.5 s))",
             {lat: run for (lat, per), run in runs.items() if per == ref[1]}),
            ("planning period, s (latency 0)",
             {per: run for (lat, per), run in runs.items() if lat == 0.0})]
    axes = [(label, series) for label, series in axes if len(series) > 1] or \
        [(axes[0][0], {lat: run for (lat, _), run in runs.items()})]
    families = sorted({f for r in runs.values() for f in r["families"]})
    fig, grid = plt.subplots(2, len(axes), figsize=(6 * len(axes), 6), squeeze=False)
    for col, (label, series) in enumerate(axes):
        ax_oc, ax_col = grid[0][col], grid[1][col]
        xs_all = sorted(series)
        width = 0.8 * (min(b - a for a, b in zip(xs_all, xs_all[1:]))
                       if len(xs_all) > 1 else 1.0) / max(1, len(families))
        for i, fam in enumerate(families):
            base = runs.get(ref, {}).get("families", {}).get(fam)
            xs = [x for x in xs_all if fam in series[x]["families"]]
            oc = [series[x]["families"][fam]["overall_cost"] for x in xs]
            if base is not None and base["overall_cost"] > 0:
                ax_oc.plot(xs, [100.0 * (v / base["overall_cost"] - 1) for v in oc], "o-",
                           label=fam.upper())
            bx = [x + (i - (len(families) - 1) / 2) * width for x in xs]
            coll = [series[x]["families"][fam]["collisions"] for x in xs]
            bars = ax_col.bar(bx, coll, width=width, label=fam.upper())
            ax_col.bar(bx, [series[x]["families"][fam]["fails"] for x in xs], width=width,
                       bottom=coll, color=bars.patches[0].get_facecolor(), alpha=0.45,
                       hatch="//")
        ax_oc.axhline(0.0, color="grey", lw=0.8)
        ax_oc.set_ylabel(f"O.C. change vs {ref[0]:g} s / {ref[1]:g} s, %")
        ax_oc.set_title(f"{METHOD}: what a slower decision costs" if col == 0
                        else f"{METHOD}: what a rarer decision costs")
        ax_oc.legend(ncol=len(families), fontsize=8)
        ax_col.set_ylabel("collisions (solid) + fails (hatched)")
        ax_col.set_ylim(bottom=0.0, top=max(1.0, ax_col.get_ylim()[1]))
        ax_col.set_xlabel(label)
        ax_col.set_xticks(xs_all)
        ax_col.yaxis.get_major_locator().set_params(integer=True)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="benchmark run folders")
    ap.add_argument("--png", type=Path, help="write the plot here")
    args = ap.parse_args(argv)
    try:
        runs = load(args.folders)
    except (OSError, ValueError, KeyError) as exc:
        print(f"latency_table: {exc}", file=sys.stderr)
        return 2
    for (latency, period), run in runs.items():
        if run["partial"]:
            print(f"note: the run at {latency:g} s latency, {period:g} s period is partial: "
                  f"{run['partial']}", file=sys.stderr)
    print(table_md(runs), end="")
    if args.png is not None:
        plot(runs, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
