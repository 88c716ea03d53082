#!/usr/bin/env python3
"""The latency table and plot (issue 23) from benchmark runs at several decision latencies.

    benchmark.py --families si,usi,lane,rab,eoa --seeds 0-24 --methods lmpc-rules \\
        --decision-latency 2.5 --out runs/latency/2.5          # one folder per latency
    latency_table.py runs/latency/0 runs/latency/1.5 runs/latency/2.5 runs/latency/5 \\
        --png docs/data/latency.png

Prints a markdown table (per family: collisions, fails, O.C., and how often the MPC's
stale-decision check fired, per latency) and draws O.C. and collisions against latency
(matplotlib). Each folder's latency is read from its summary.json.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Optional, Sequence

METHOD = "lmpc-rules"


def load(folders: Sequence[Path], method: str = METHOD) -> dict[float, dict[str, Any]]:
    """Latency -> family -> the method's aggregate row of that run (summary.json).
    Raises ``ValueError`` naming a folder without a latency or the method."""
    out: dict[float, dict[str, Any]] = {}
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
        fams = {f: m[method] for f, m in summary["families"].items() if method in m}
        if not fams:
            raise ValueError(f"{folder}: no {method} rows")
        out[float(latency)] = {"families": fams, "partial": summary.get("partial")}
    return dict(sorted(out.items()))


def table_md(runs: dict[float, dict[str, Any]]) -> str:
    """Per family and latency: scenes, collisions, fails, mean O.C. and its change
    against latency 0 (when run), scenes / steps the stale check fired."""
    families = sorted({f for r in runs.values() for f in r["families"]})
    lines = ["| Scenario | Latency s | Scenes | Coll. | Fail | O.C. | vs 0 s | Check fired "
             "(scenes / steps) |", "|---|---|---|---|---|---|---|---|"]
    for fam in families:
        base = runs.get(0.0, {}).get("families", {}).get(fam)
        for latency, run in runs.items():
            a = run["families"].get(fam)
            if a is None:
                continue
            change = ""
            if base is not None and latency != 0.0 and base["overall_cost"] > 0:
                change = f"{a['overall_cost'] / base['overall_cost'] - 1:+.1%}"
            lines.append(
                f"| {fam.upper()} | {latency:g} | {a['scenes']} | {a['collisions']} | "
                f"{a['fails']} | {a['overall_cost']:.1f} | {change} | "
                f"{a.get('stale_scenes', '?')} / {a.get('stale_steps', '?')} |")
    return "\n".join(lines) + "\n"


def plot(runs: dict[float, dict[str, Any]], png: Path) -> None:
    """O.C. (lines) and collisions (bars) per family against the decision latency."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families = sorted({f for r in runs.values() for f in r["families"]})
    lat = list(runs)
    fig, (ax_oc, ax_col) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    width = 0.8 * (min(b - a for a, b in zip(lat, lat[1:])) if len(lat) > 1 else 1.0)
    width /= max(1, len(families))
    for i, fam in enumerate(families):
        xs = [x for x in lat if fam in runs[x]["families"]]
        ax_oc.plot(xs, [runs[x]["families"][fam]["overall_cost"] for x in xs], "o-",
                   label=fam.upper())
        ax_col.bar([x + (i - (len(families) - 1) / 2) * width for x in xs],
                   [runs[x]["families"][fam]["collisions"] for x in xs], width=width,
                   label=fam.upper())
    ax_oc.set_ylabel("mean O.C. (lower is better)")
    ax_oc.set_title(f"{METHOD}: what a decision latency costs")
    ax_oc.legend(ncol=len(families), fontsize=8)
    ax_col.set_ylabel("collisions")
    ax_col.set_xlabel("decision latency, s (emergencies: min(latency, 1.5 s))")
    ax_col.set_xticks(lat)
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
    for latency, run in runs.items():
        if run["partial"]:
            print(f"note: the {latency:g} s run is partial: {run['partial']}", file=sys.stderr)
    print(table_md(runs), end="")
    if args.png is not None:
        plot(runs, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
