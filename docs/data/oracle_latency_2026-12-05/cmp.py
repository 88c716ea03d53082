"""Collisions + fails and mean O.C. per family of the oracle's rows at a decision latency
against mpc, lmpc-rules at 0 s and at that latency and the oracle at 0 s, on the seeds
every oracle-latency file covers (seeds 0-9; the other rows from the folders named
below, relative to this one). Each argument is LATENCY=FILE (a bare FILE is 2.5 s), or
perP=FILE for the oracle at planning period P (against the rules' ``per5`` / ``per1`` rows).

    python3 cmp.py 2.5=p2.5/results.csv 1.5=p1.5/results.csv per5=per5.0/results.csv
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
    runs = [a.split("=", 1) if "=" in a else ["2.5", a] for a in sys.argv[1:]]
    columns = {
        "mpc": load([t1], "mpc"),
        "rules 0": load([t1], "lmpc-rules"),
        **{f"rules {lat}": load([DATA / "latency_2026-12-04"
                                 / (lat if lat.startswith("per") else f"p{lat}")
                                 / "results.csv"], "lmpc-rules") for lat, _ in runs},
        "oracle 0": load(sorted((DATA / "oracle_c16_test_2026-12-04").glob("results_*.csv")),
                         "lmpc-oracle"),
        **{f"oracle {lat}": load([path], "lmpc-oracle") for lat, path in runs},
    }
    new = [columns[f"oracle {lat}"] for lat, _ in runs]
    for fam in sorted({k[0] for rows in new for k in rows}):
        keys = sorted(set.intersection(*({k for k in rows if k[0] == fam} for rows in new)))
        if not keys:
            continue
        print(fam, "seeds", [k[1] for k in keys])
        print("  " + " | ".join(f"{name} {cell(rows, keys)}" for name, rows in columns.items()))


if __name__ == "__main__":
    main()
