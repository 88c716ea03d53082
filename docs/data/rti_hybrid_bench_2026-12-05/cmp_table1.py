"""A make-bench run against the stored Table I rows (mpc, lmpc-rules: latency_2026-12-04/t1;
adp: learned_2026-12-04; dqn / ppo / sac: rl_2026-12-05): per method and family,
collisions + fails and mean O.C. of both, the scenes whose outcome differs, and how many
rows differ in any O.C. term.

    python3 cmp_table1.py NEW/results.csv [DOCS_DATA_DIR]
"""
import csv
import statistics as st
import sys
from collections import defaultdict
from pathlib import Path

data = Path(sys.argv[2] if len(sys.argv) > 2 else "docs/data")
stored = {}
for f, methods in [(data / "latency_2026-12-04/t1/results.csv", ("mpc", "lmpc-rules")),
                   (data / "learned_2026-12-04/results.csv", ("adp",)),
                   *[(f, ("dqn", "ppo", "sac"))
                     for f in sorted((data / "rl_2026-12-05").glob("results_*.csv"))]]:
    for r in csv.DictReader(open(f)):
        if r["method"] in methods:
            stored[(r["family"], r["method"], int(r["seed"]))] = r
new = {(r["family"], r["method"], int(r["seed"])): r for r in csv.DictReader(open(sys.argv[1]))}
keys = sorted(set(new) & set(stored))
groups = defaultdict(list)
for k in keys:
    groups[(k[1], k[0])].append(k)
terms = ("outcome", "time_s", "ineff", "pen_acc", "pen_dist", "overall_cost")
changed_rows = 0
tot = {"old": [0, 0], "new": [0, 0]}
for (meth, fam), ks in sorted(groups.items()):
    def cell(d, w):
        c = sum(int(d[k]["collision"]) for k in ks)
        f = sum(int(d[k]["fail"]) for k in ks)
        tot[w][0] += c
        tot[w][1] += f
        return f"{c}+{f}, {st.fmean(float(d[k]['overall_cost']) for k in ks):.1f}"
    diff = [f"{k[2]}: {stored[k]['outcome']}->{new[k]['outcome']}" for k in ks
            if stored[k]["outcome"] != new[k]["outcome"]]
    ch = sum(any(stored[k][t] != new[k][t] for t in terms) for k in ks)
    changed_rows += ch
    print(f"{meth:11} {fam:5} n={len(ks):3} stored {cell(stored, 'old'):14} new {cell(new, 'new'):14}"
          f" rows changed {ch:2}  " + "; ".join(diff))
print(f"{len(keys)} rows compared ({len(set(new) - set(stored))} new only); {changed_rows} "
      f"differ in an O.C. term; collisions+fails stored {tot['old']} new {tot['new']}")
