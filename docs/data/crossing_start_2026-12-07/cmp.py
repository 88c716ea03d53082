"""Compare two results.csv (usage: cmp.py OLD NEW [families] [methods]): rows per (family, seed, method) whose outcome/time/O.C. differ."""
import csv, sys
from collections import defaultdict
def load(p):
    return {(r["family"], r["seed"], r["method"]): r for r in csv.DictReader(open(p))}
a, b = load(sys.argv[1]), load(sys.argv[2])
fams = set(sys.argv[3].split(",")) if len(sys.argv) > 3 else None
meth = set(sys.argv[4].split(",")) if len(sys.argv) > 4 else None
agg = defaultdict(lambda: [0, 0.0, 0.0, 0, 0])
for k in sorted(b, key=lambda k: (k[0], k[2], int(k[1]))):
    if k not in a or (fams and k[0] not in fams) or (meth and k[2] not in meth):
        continue
    ra, rb = a[k], b[k]
    oa, ob = float(ra["overall_cost"]), float(rb["overall_cost"])
    g = agg[(k[0], k[2])]; g[0] += 1; g[1] += oa; g[2] += ob
    if ra["outcome"] != rb["outcome"] or abs(oa - ob) > 1e-3:
        g[3] += 1
        print(f"{k[0]} {k[1]:>3} {k[2]:<16} {ra['outcome']:>9} -> {rb['outcome']:<9} t {float(ra['time_s']):6.1f} -> {float(rb['time_s']):6.1f}  OC {oa:7.1f} -> {ob:7.1f} ({ob-oa:+.1f})")
for (f, m), g in sorted(agg.items()):
    print(f"== {f} {m}: {g[3]}/{g[0]} changed, mean OC {g[1]/g[0]:.1f} -> {g[2]/g[0]:.1f}")
