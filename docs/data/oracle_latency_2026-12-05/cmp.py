"""Collisions + fails and mean O.C. per family of the oracle's rows at 2.5 s latency
against mpc, lmpc-rules at 0 / 2.5 s and the oracle at 0 s, on the seeds the new rows
cover (seeds 0-9; the other rows from the folders named below, relative to this one).

    python3 cmp.py p2.5/results.csv
"""
import csv
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parent.parent


def load(paths, method):
    rows = {}
    for p in paths:
        for r in csv.DictReader(open(p)):
            if r["method"] == method and int(r["seed"]) < 10:
                rows[(r["family"], int(r["seed"]))] = r
    return rows


def cell(rows, keys):
    rs = [rows[k] for k in keys if k in rows]
    coll = sum(int(r["collision"] or 0) for r in rs)
    fail = sum(int(r["fail"] or 0) for r in rs)
    oc = sum(float(r["overall_cost"]) for r in rs) / len(rs)
    return f"{coll}+{fail} {oc:.1f} ({len(rs)})"


def main() -> None:
    t1 = DATA / "latency_2026-12-04" / "t1" / "results.csv"
    columns = {
        "mpc": load([t1], "mpc"),
        "rules 0": load([t1], "lmpc-rules"),
        "rules 2.5": load([DATA / "latency_2026-12-04" / "p2.5" / "results.csv"], "lmpc-rules"),
        "oracle 0": load(sorted((DATA / "oracle_c16_test_2026-12-04").glob("results_*.csv")),
                         "lmpc-oracle"),
        "oracle 2.5": load([sys.argv[1]], "lmpc-oracle"),
    }
    new = columns["oracle 2.5"]
    for fam in sorted({k[0] for k in new}):
        keys = sorted(k for k in new if k[0] == fam)
        print(fam, "seeds", [k[1] for k in keys])
        print("  " + " | ".join(f"{name} {cell(rows, keys)}" for name, rows in columns.items()))


if __name__ == "__main__":
    main()
