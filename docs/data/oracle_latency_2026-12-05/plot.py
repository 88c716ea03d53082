"""The latency and cadence plot of the oracle (issue 16 item 6), seeds 0-9: per family the
mean O.C. change against `mpc` on the same seeds, of `lmpc-oracle` (solid) and
`lmpc-rules` (dashed), against the decision latency (at the packaged 2.5 s period) and
against the planning period (at latency 0). A family's point is left out where a file
lacks some of its ten seeds (an unfinished run); the printed table says so.

    python3 plot.py latency_cadence_oracle.png
"""
import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).resolve().parent
LAT = HERE.parent / "latency_2026-12-04"
FAMILIES = ("si", "usi", "lane", "rab", "eoa")
SEEDS = range(10)
# (axis, x) -> file of each method; latency 0 at the 2.5 s period is both axes' point
ORACLE = {("latency", 0.0): sorted((HERE.parent / "oracle_c16_test_2026-12-04")
                                    .glob("results_*.csv")),
          ("latency", 1.5): [HERE / "p1.5/results.csv"],
          ("latency", 2.5): [HERE / "p2.5/results.csv"],
          ("period", 1.0): [HERE / "per1.0/results.csv"],
          ("period", 5.0): [HERE / "per5.0/results.csv"]}
RULES = {("latency", 0.0): [LAT / "t1/results.csv"],
         ("latency", 1.5): [LAT / "p1.5/results.csv"],
         ("latency", 2.5): [LAT / "p2.5/results.csv"],
         ("period", 1.0): [LAT / "per1/results.csv"],
         ("period", 5.0): [LAT / "per5/results.csv"]}


def mean_oc(paths: list, method: str, family: str) -> float | None:
    oc = {}
    for p in paths:
        for r in csv.DictReader(open(p)):
            if r["method"] == method and r["family"] == family and int(r["seed"]) in SEEDS:
                oc[int(r["seed"])] = float(r["overall_cost"])
    return sum(oc.values()) / len(oc) if len(oc) == len(SEEDS) else None


def curves(files: dict, method: str, family: str, base: float) -> dict:
    out: dict = {"latency": [], "period": []}
    for (axis, x), paths in files.items():
        m = mean_oc(paths, method, family)
        if m is not None:
            out[axis].append((x, 100.0 * (m / base - 1.0)))
    zero = [y for x, y in out["latency"] if x == 0.0]
    out["period"] += [(2.5, y) for y in zero]  # latency 0 runs at the 2.5 s period
    return {k: sorted(v) for k, v in out.items()}


def main() -> None:
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    print("| family | method | " + " | ".join(f"{a} {x:g} s" for a, x in ORACLE) + " |")
    print("|---|---|" + "---|" * len(ORACLE))
    for i, fam in enumerate(FAMILIES):
        base = mean_oc([LAT / "t1/results.csv"], "mpc", fam)
        color = f"C{i}"
        for method, files, style in (("lmpc-oracle", ORACLE, "-o"),
                                     ("lmpc-rules", RULES, "--x")):
            c = curves(files, method, fam, base)
            cells = [mean_oc(p, method, fam) for p in files.values()]
            print(f"| {fam} | {method} | " + " | ".join(
                f"{100 * (m / base - 1):+.1f} %" if m is not None else "incomplete"
                for m in cells) + " |")
            for ax, axis in zip(axes, ("latency", "period")):
                if c[axis]:
                    xs, ys = zip(*c[axis])
                    ax.plot(xs, ys, style, color=color,
                            label=f"{fam} {method.split('-')[1]}" if axis == "latency" else None)
    axes[0].set_xlabel("decision latency, s of sim (period 2.5 s)")
    axes[1].set_xlabel("planning period, s of sim (latency 0)")
    axes[0].set_ylabel("O.C. change vs mpc, % (seeds 0-9)")
    for ax in axes:
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.grid(alpha=0.3)
    fig.legend(loc="center right", fontsize=7)
    fig.tight_layout(rect=(0, 0, 0.86, 1))
    fig.savefig(sys.argv[1] if len(sys.argv) > 1 else "latency_cadence_oracle.png", dpi=110)


if __name__ == "__main__":
    main()
