"""How often two styles make the same first junction entry / the same lane changes (from
trace.py's CSVs), and the mean gaps per style.

    python3 same.py
"""
import csv
import math
import statistics as st
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent


def junction_summary(fam: str) -> None:
    per: dict = defaultdict(dict)
    for s, sty, k, t, _a, _b, _v, g, lag, _T in csv.reader(open(HERE / f"junctions_{fam}.csv")):
        if k == "0":
            per[int(s)][sty] = (float(t), float(g), float(lag))
    both = lambda x, y: [s for s in per if x in per[s] and y in per[s]]  # noqa: E731
    same_cn = sum(abs(per[s]["c"][0] - per[s]["n"][0]) <= 0.15 for s in both("c", "n"))
    same_na = sum(abs(per[s]["n"][0] - per[s]["a"][0]) <= 0.15 for s in both("n", "a"))
    passed = sum(1 for s in per for v in per[s].values() if not math.isnan(v[1]) and math.isnan(v[2]))
    gaps = {k: [per[s][k][1] for s in per if k in per[s] and not math.isnan(per[s][k][1])] for k in "cna"}
    lags = {k: [per[s][k][2] for s in per if k in per[s] and not math.isnan(per[s][k][2])] for k in "cna"}
    print(f"{fam}: first entry at the same step (0.15 s): conservative = normal {same_cn} "
          f"of {len(both('c', 'n'))}, normal = aggressive {same_na} of {len(both('n', 'a'))}; "
          f"first entries whose smallest gap is to a car that has passed: {passed} of "
          f"{sum(len(v) for v in per.values())}")
    print("   first-entry gap c/n/a " + " / ".join(f"{st.fmean(gaps[k]):.1f} ({len(gaps[k])})" for k in "cna")
          + ";  lag c/n/a " + " / ".join(f"{st.fmean(lags[k]):.1f} ({len(lags[k])})" for k in "cna"))


def change_summary(fam: str) -> None:
    per: dict = defaultdict(lambda: defaultdict(list))
    for s, sty, t, _a, _b, _v, g, _i in csv.reader(open(HERE / f"changes_{fam}.csv")):
        per[int(s)][sty].append((round(float(t), 1), float(g) if g else math.nan))
    def same(s: int, x: str, y: str) -> bool:  # the same changes, each within 0.3 s
        a, b = per[s][x], per[s][y]
        return len(a) == len(b) and all(abs(p[0] - q[0]) <= 0.3 for p, q in zip(a, b))

    same_cn = sum(same(s, "c", "n") for s in per)
    same_na = sum(same(s, "n", "a") for s in per)
    tgt = {k: [min((g for _, g in per[s][k] if g == g), default=math.nan) for s in per] for k in "cna"}
    tgt = {k: [g for g in v if g == g] for k, v in tgt.items()}
    print(f"{fam}: the same lane changes (each within 0.3 s): conservative = normal {same_cn} of {len(per)}, "
          f"normal = aggressive {same_na} of {len(per)}")
    print("   smallest target-lane gap c/n/a " + " / ".join(
        f"{st.fmean(tgt[k]):.1f} ({len(tgt[k])})" for k in "cna"))


if __name__ == "__main__":
    for fam in ("rab", "si", "usi"):
        junction_summary(fam)
    for fam in ("lane", "eoa"):
        change_summary(fam)
