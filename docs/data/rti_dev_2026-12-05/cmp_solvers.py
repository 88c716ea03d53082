"""Two benchmark runs of the same scenes (e.g. FATROP vs SQP-RTI): per family and method
collisions + fails and mean O.C. of each, the scenes whose outcome differs, and the worker
time (sum of the scenes' wall).

    python3 cmp_solvers.py A/results.csv B/results.csv
"""
import csv
import statistics as st
import sys
from collections import defaultdict


def load(path):
    return {(r["family"], r["method"], int(r["seed"])): r for r in csv.DictReader(open(path))}


a, b = load(sys.argv[1]), load(sys.argv[2])
keys = sorted(set(a) & set(b))
groups = defaultdict(list)
for k in keys:
    groups[k[:2]].append(k)
tot = {"a": [0, 0, 0.0], "b": [0, 0, 0.0]}
for (fam, meth), ks in sorted(groups.items()):
    def cell(d, w):
        c = sum(int(d[k]["collision"]) for k in ks)
        f = sum(int(d[k]["fail"]) for k in ks)
        oc = st.fmean(float(d[k]["overall_cost"]) for k in ks)
        wall = sum(float(d[k]["wall_s"]) for k in ks)
        tot[w][0] += c
        tot[w][1] += f
        tot[w][2] += wall
        return f"{c}+{f}, {oc:.1f}, {wall:.0f} s"
    diff = [f"{k[2]}: {a[k]['outcome']}->{b[k]['outcome']}" for k in ks
            if a[k]["outcome"] != b[k]["outcome"]]
    print(f"{fam:5} {meth:11} n={len(ks):3} A {cell(a, 'a'):24} B {cell(b, 'b'):24} "
          + "; ".join(diff))
print("total collisions / fails / worker s: A", tot["a"], "B", tot["b"])
