"""README's late-decision table: lmpc-rules O.C. (collisions + fails) per family and
latency, si / usi from this folder, the other families from the runs they last changed in.
Run from the repository root: python3 docs/data/crossing_start_2026-12-07/lat.py"""
import csv
from statistics import mean
D = "docs/data/"
H = D + "crossing_start_2026-12-07/published/"
def load(paths, fams):
    rows = {}
    for p in paths:
        for r in csv.DictReader(open(p)):
            if r["method"] == "lmpc-rules" and r["family"] in fams:
                rows[(r["family"], r["seed"])] = r
    return rows
def src(L):
    if L == "0":
        return [D + "offroad_2026-12-06/results.csv", H + "t12/results.csv"]
    return [D + f"latency_2026-12-04/p{L}/results.csv", D + f"ring_revisit_2026-12-06/published/p{L}/results.csv", H + f"p{L}/results.csv"]
fams = ["si", "usi", "lane", "rab", "eoa"]
base = None
for L in ["0", "1.5", "2.5", "5"]:
    rows = load(src(L), fams)
    cells, oc = [], {}
    for f in fams:
        sel = [r for (ff, s), r in rows.items() if ff == f]
        assert len(sel) == 25, (L, f, len(sel))
        oc[f] = mean(float(r["overall_cost"]) for r in sel)
        c = sum(int(r["collision"]) for r in sel); fl = sum(int(r["fail"]) for r in sel)
        cells.append(f"{oc[f]:.1f} ({c}+{fl})")
    if base is None:
        base = oc; ch = ""
    else:
        ch = f"{100*mean(oc[f]/base[f]-1 for f in fams):+.1f} %"
    print(f"| {L} s | " + " | ".join(cells) + f" | {ch} |")
