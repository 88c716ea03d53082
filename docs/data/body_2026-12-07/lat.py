"""README's late-decision table after the body check (2026-12-07, seventh stop): lmpc-rules
O.C. (collisions + fails) per family and latency, every family re-run on main 0f7a9b6
(t1/ for 0 s, p1.5/ p2.5/ p5/). Run from the repository root:
python3 docs/data/body_2026-12-07/lat.py [DIR/] (another folder with the same layout, e.g.
docs/data/yawwrap_2026-12-07/, the eighth stop's rows)"""
import csv
import sys
from statistics import mean
H = sys.argv[1] if len(sys.argv) > 1 else "docs/data/body_2026-12-07/"
fams = ["si", "usi", "lane", "rab", "eoa"]
base = None
for L in ["0", "1.5", "2.5", "5"]:
    path = H + ("t1" if L == "0" else f"p{L}") + "/results.csv"
    rows = [r for r in csv.DictReader(open(path)) if r["method"] == "lmpc-rules"]
    cells, oc = [], {}
    for f in fams:
        sel = [r for r in rows if r["family"] == f]
        assert len(sel) == 25, (L, f, len(sel))
        oc[f] = mean(float(r["overall_cost"]) for r in sel)
        c = sum(int(r["collision"]) for r in sel)
        fl = sum(int(r["fail"]) for r in sel)
        cells.append(f"{oc[f]:.1f} ({c}+{fl})")
    if base is None:
        base, change = oc, ""
    else:
        change = f"{100 * (mean(oc[f] / base[f] for f in fams) - 1):+.1f} %"
    print(f"| {L} s | " + " | ".join(cells) + f" | {change} |")
