import csv, sys
KEYS = ["outcome","collision","fail","off_route","time_s","ineff","pen_acc","pen_dist","overall_cost","decisions","fallbacks","steps","stale_steps","stale_agent_steps"]
def load(p):
    return {(r["family"], r["seed"]): r for r in csv.DictReader(open(p))}
a, b = load(sys.argv[1]), load(sys.argv[2])
diff = 0
for k in sorted(set(a) | set(b), key=lambda k: (k[0], int(k[1]))):
    if k not in a or k not in b:
        print("missing", k, k in a, k in b); continue
    d = [c for c in KEYS if c in a[k] and c in b[k] and a[k][c] != b[k][c]]
    if d:
        diff += 1
        print(k, {c: (a[k][c], b[k][c]) for c in d if c in ("outcome","time_s","overall_cost","stale_steps","collision")} , "changed:", d)
print("rows", len(a), len(b), "differing", diff)
import collections
for name, rows in (("A", a), ("B", b)):
    fam = collections.defaultdict(list)
    for (f, s), r in rows.items(): fam[f].append(r)
    print(name, {f: (sum(int(r["collision"]) for r in rs), sum(int(r["fail"]) for r in rs), round(sum(float(r["overall_cost"]) for r in rs)/len(rs), 1)) for f, rs in sorted(fam.items())})
