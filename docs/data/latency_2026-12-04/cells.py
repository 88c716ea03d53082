import csv, sys, collections
# cells: collisions+fails (mean O.C.) per family, lmpc-rules rows, si 113 left out
for p in sys.argv[1:]:
    fam = collections.defaultdict(list)
    for r in csv.DictReader(open(p + "/results.csv")):
        if r["method"] != "lmpc-rules" or (r["family"], r["seed"]) == ("si", "113"):
            continue
        fam[r["family"]].append(r)
    cells = []
    tc = tf = 0
    for f in ["si", "usi", "lane", "rab", "eoa"]:
        rs = fam[f]
        c = sum(r["outcome"] == "collision" for r in rs); fl = sum(r["outcome"] not in ("reached", "collision") for r in rs)
        tc += c; tf += fl
        cells.append(f"{c}+{fl} ({sum(float(r['overall_cost']) for r in rs)/len(rs):.1f})")
    print(f"| {p} | " + " | ".join(cells) + f" | {tc}+{tf} |")
