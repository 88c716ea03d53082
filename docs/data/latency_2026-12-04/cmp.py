import csv, sys, collections
KEYS = ["outcome", "time_s", "ineff", "pen_acc", "pen_dist", "overall_cost"]
def load(ps):
    out = {}
    for p in ps.split(","):
        for r in csv.DictReader(open(p)):
            out[(r["family"], int(r["seed"]), r["method"])] = r
    return out
a, b = load(sys.argv[1]), load(sys.argv[2])
common = sorted(set(a) & set(b))
diff = 0
for k in common:
    d = [c for c in KEYS if a[k].get(c) != b[k].get(c)]
    if d:
        diff += 1
        print(k, a[k]["outcome"], a[k]["time_s"], a[k]["overall_cost"][:7], "->", b[k]["outcome"], b[k]["time_s"], b[k]["overall_cost"][:7])
print("common", len(common), "only A", len(set(a) - set(b)), "only B", len(set(b) - set(a)), "differing", diff)
for name, rows in (("A", {k: a[k] for k in common}), ("B", {k: b[k] for k in common})):
    fam = collections.defaultdict(list)
    for (f, s, m), r in rows.items(): fam[(m, f)].append(r)
    print(name, {f"{m}/{f}": (sum(r["outcome"] == "collision" for r in rs), sum(r["outcome"] not in ("reached", "collision") for r in rs), round(sum(float(r["overall_cost"]) for r in rs) / len(rs), 1)) for (m, f), rs in sorted(fam.items())})
