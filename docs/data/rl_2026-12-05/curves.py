"""Learning-curve figures of train_rl.py runs: per run the episodes, the mean return and
O.C. of each quarter of the episodes, the reached share of the last quarter, and whether
the curve has flattened: the least-squares slope of the return over the second half of
the episodes (per 1 000 steps, against total_steps) with its 95 % interval: "no trend" when
the interval contains 0 (with returns that vary from scene to scene this is weak evidence
of flattening; the quarter means show the rest), "rising" / "falling" otherwise.

    python curves.py RUN_DIR...          # each RUN_DIR holds curve.csv and provenance.json
"""
import csv
import json
import sys
from pathlib import Path

import numpy as np


def summary(run: Path) -> dict:
    rows = list(csv.DictReader(open(run / "curve.csv")))
    prov = json.load(open(run / "provenance.json"))
    ret = np.array([float(r["return"]) for r in rows])
    oc = np.array([float(r["overall_cost"]) for r in rows])
    x = np.array([float(r["total_steps"]) for r in rows]) / 1000.0
    reached = np.array([r["outcome"] == "reached" for r in rows])
    q = np.array_split(np.arange(len(rows)), 4)
    half = np.arange(len(rows) // 2, len(rows))
    slope, lo, hi = float("nan"), float("nan"), float("nan")
    if len(half) >= 4:
        A = np.vstack([x[half], np.ones(len(half))]).T
        coef, res, *_ = np.linalg.lstsq(A, ret[half], rcond=None)
        dof = len(half) - 2
        s2 = float(res[0]) / dof if len(res) else 0.0
        cov = s2 * np.linalg.inv(A.T @ A)
        se = float(np.sqrt(cov[0, 0]))
        slope, lo, hi = float(coef[0]), float(coef[0] - 1.96 * se), float(coef[0] + 1.96 * se)
    first, _, last = prov.get("eval_seeds", "0-(-1)").partition("-")
    n_eval = int(last) - int(first) + 1  # the held-out scenes, eval_seeds "a-b"
    trend = "-"
    if lo == lo:
        trend = "no trend" if lo <= 0 <= hi else "rising" if lo > 0 else "falling"
    return dict(run=f"{prov['algo']}-{prov['family']}", steps=prov["steps"], episodes=len(rows),
                train_wall_s=prov["train_wall_s"], steps_per_s=prov["steps_per_s"],
                q_return=[float(ret[i].mean()) for i in q if len(i)],
                q_oc=[float(np.nanmean(oc[i])) if np.isfinite(oc[i]).any() else float("nan")
                      for i in q if len(i)],
                last_q_reached=f"{int(reached[q[-1]].sum())}/{len(q[-1])}",
                slope=slope, lo=lo, hi=hi, trend=trend,
                held_out=tuple(f"{prov.get(f'eval_{who}_reached')}/{n_eval}, "
                               f"{prov.get(f'eval_{who}_oc')}" for who in ("policy", "mpc")))


def main() -> None:
    print("| run | steps | episodes | train wall | steps/s | return by quarter "
          "| O.C. by quarter "
          "| last quarter reached | 2nd-half slope / 1k steps (95 %) | curve | held-out policy "
          "| held-out mpc |")
    print("|---" * 12 + "|")
    for d in sys.argv[1:]:
        s = summary(Path(d))
        qr = " / ".join(f"{v:.0f}" for v in s["q_return"])
        qo = " / ".join(f"{v:.1f}" for v in s["q_oc"])
        print(f"| {s['run']} | {s['steps']} | {s['episodes']} | {s['train_wall_s']:.0f} s "
              f"| {s['steps_per_s']:.1f} | {qr} | {qo} | {s['last_q_reached']} "
              f"| {s['slope']:+.1f} [{s['lo']:+.1f}, {s['hi']:+.1f}] | {s['trend']} "
              f"| {s['held_out'][0]} | {s['held_out'][1]} |")


if __name__ == "__main__":
    main()
