"""Per family of one or two `benchmark.py --instruction-set styles-short` runs: collisions +
fails, mean time and mean accepted gap (junction gap, else lane-change gap, as
docs/data/styles_2026-12-04b/order.py takes it) per style, and the per-scene order of
time and of that gap (aggressive <= normal <= conservative, not all equal; ties within
0.05 s / 0.05 m count as equal) among the scenes where the styles differ.

    python3 gaps.py RUN_DIR [RUN_DIR_AGGRESSIVE]

With a second run, its aggressive rows replace the first run's (the first run's
conservative and normal rows stay): "before" and "after" of an aggressive-only change.
"""
import csv
import statistics as st
import sys
from collections import defaultdict

STYLES = ("conservative", "normal", "aggressive")


def rows_of(path):
    return list(csv.DictReader(open(path + "/styles.csv")))


def gap_of(r):
    jg = r["junction_gap_m"]
    return float(jg if jg not in ("", "nan") else (r["lc_gap_m"] or "nan"))


def ordered(c, n, a, tol):
    if max(c, n, a) - min(c, n, a) <= tol:
        return None  # the style does not matter here
    return a <= n + tol and n <= c + tol and a < c


def main() -> None:
    rows = rows_of(sys.argv[1])
    if len(sys.argv) > 2:
        rows = [r for r in rows if r["style"] != "aggressive"] + [
            r for r in rows_of(sys.argv[2]) if r["style"] == "aggressive"]
    per = defaultdict(dict)
    for r in rows:
        per[(r["family"], int(r["seed"]))][r["style"]] = r
    for fam in sorted({r["family"] for r in rows}):
        bad = defaultdict(int)
        times, gaps = defaultdict(list), defaultdict(list)
        t_ok = t_n = g_ok = g_n = 0
        for (fa, _seed), by in sorted(per.items()):
            if fa != fam or len(by) < 3:
                continue
            for k in STYLES:
                bad[k] += int(by[k]["collision"]) + int(by[k]["fail"])
                times[k].append(float(by[k]["time_s"]))
                if gap_of(by[k]) == gap_of(by[k]):
                    gaps[k].append(gap_of(by[k]))
            o = ordered(*(float(by[k]["time_s"]) for k in STYLES), 0.05)
            if o is not None:
                t_n += 1
                t_ok += o
            g = [gap_of(by[k]) for k in STYLES]
            if all(x == x for x in g):
                o = ordered(*g, 0.05)
                if o is not None:
                    g_n += 1
                    g_ok += o
        mt = "/".join(f"{st.fmean([t for t in times[k] if t == t]):.1f}" for k in STYLES)
        mg = "/".join(f"{st.fmean(gaps[k]):.1f}" if gaps[k] else "-" for k in STYLES)
        cf = "/".join(str(bad[k]) for k in STYLES)
        print(f"{fam:5s} coll+fail c/n/a {cf}  time {mt} s  gap {mg} m  "
              f"time order {t_ok}/{t_n}  gap order {g_ok}/{g_n}")


if __name__ == "__main__":
    main()
