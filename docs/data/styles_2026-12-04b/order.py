"""Per family of a `benchmark.py --instruction-set styles-short` run: collisions + fails,
mean time conservative / normal / aggressive, mean accepted gap (junction gap, else
lane-change gap), and the scenes whose times break the order aggressive <= normal <=
conservative (aggressive < conservative; ties within 0.05 s count as no difference), as
`lmpc_bridge.evaluation.style.direction_share` counts them.

    python3 order.py RUN_DIR [FAMILY,...]
"""
import csv
import statistics as st
import sys
from collections import defaultdict

STYLES = ("conservative", "normal", "aggressive")


def main() -> None:
    fams = sys.argv[2].split(",") if len(sys.argv) > 2 else None
    rows = list(csv.DictReader(open(sys.argv[1] + "/styles.csv")))
    per: dict = defaultdict(dict)
    for r in rows:
        per[(r["family"], int(r["seed"]))][r["style"]] = r
    for fam in sorted({r["family"] for r in rows}):
        if fams and fam not in fams:
            continue
        bad, matter, follow, coll = [], 0, 0, 0
        times, gaps = defaultdict(list), defaultdict(list)
        for (fa, seed), by in sorted(per.items()):
            if fa != fam or len(by) < 3:
                continue
            c, n, a = (float(by[k]["time_s"]) for k in STYLES)
            for k in by:
                times[k].append(float(by[k]["time_s"]))
                coll += int(by[k]["collision"]) + int(by[k]["fail"])
                jg = by[k]["junction_gap_m"]
                g = float(jg if jg not in ("", "nan") else (by[k]["lc_gap_m"] or "nan"))
                if g == g:
                    gaps[k].append(g)
            if max(c, n, a) - min(c, n, a) <= 0.05:
                continue
            matter += 1
            ok = a <= n + .05 and n <= c + .05 and a < c
            follow += ok
            if not ok:
                bad.append(f"{seed}:{c}/{n}/{a}")
        mean_t = [round(st.fmean([x for x in times[k] if x == x]), 2) for k in STYLES]
        mean_g = [round(st.fmean(gaps[k]), 1) if gaps[k] else None for k in STYLES]
        print(fam, "coll+fail", coll, "time c/n/a", *mean_t, "gap c/n/a", *mean_g,
              f"order {follow}/{matter}", " ".join(bad))


if __name__ == "__main__":
    main()
