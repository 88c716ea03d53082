"""Accepted lag at junction entries (FAMILY jn) / time gaps at lane changes (FAMILY lc) from the
records of dump_records.py: python time_gaps.py rab jn [x: per seed]."""
import glob, math, pickle, statistics, sys
sys.path.insert(0, "/work/main/src/lmpc_bridge")
from lmpc_bridge.evaluation.style import CROSS_HEADING_RAD, MOVING_MPS, _angle, edge_lane

def lc_time(steps):
    out = []
    for p, c in zip(steps, steps[1:]):
        a, b = edge_lane(p.lane_id), edge_lane(c.lane_id)
        if a and b and a[0] == b[0] and a[1] != b[1]:
            side = 1.0 if int(b[1]) > int(a[1]) else -1.0
            best = math.inf
            for n in c.nearby:
                if _angle(n.yaw_rad - c.yaw_rad) > CROSS_HEADING_RAD: continue
                dx, dy = n.x_m - c.x_m, n.y_m - c.y_m
                lon = dx * math.cos(c.yaw_rad) + dy * math.sin(c.yaw_rad)
                lat = -dx * math.sin(c.yaw_rad) + dy * math.cos(c.yaw_rad)
                if abs(lat) > 2.4: continue  # in the target lane (the ego is in it now)
                if lon > 0: t = n.gap_m / max(c.v_mps, 1.0)   # ego behind the new leader
                else: t = n.gap_m / max(n.v_mps, 1.0)         # new follower behind the ego
                best = min(best, t)
            out.append(best)
    return out

def jn_time(steps):
    out = []
    for p, c in zip(steps, steps[1:]):
        if edge_lane(p.lane_id) is not None and c.lane_id and c.lane_id.startswith(":"):
            cr = [n for n in c.nearby if n.v_mps >= MOVING_MPS and _angle(n.yaw_rad - c.yaw_rad) > CROSS_HEADING_RAD]
            coming = [n for n in cr if (c.x_m - n.x_m) * math.cos(n.yaw_rad) + (c.y_m - n.y_m) * math.sin(n.yaw_rad) > 0]
            out.append(min((n.gap_m / n.v_mps for n in coming), default=math.inf))
    return out

fam = sys.argv[1]; kind = sys.argv[2]
f = lc_time if kind == "lc" else jn_time
per = {}
for path in glob.glob(f"/tmp/recs/{fam}_*.pkl"):
    _, seed, st = path[:-4].split("/")[-1].split("_")
    rec, t = pickle.load(open(path, "rb"))
    v = f(rec.steps)
    per.setdefault(int(seed), {})[st] = (min(v) if v else math.nan, (v[0] if v else math.nan), t)
for which, idx in (("min over episode", 0), ("first", 1)):
    for cap in (math.inf, 10.0):
        vals = {s: [] for s in "cna"}
        for seed, d in per.items():
            for s in "cna":
                if s in d and not math.isnan(d[s][idx]): vals[s].append(min(d[s][idx], cap))
        def m(x): 
            y = [v for v in x if math.isfinite(v)]
            return f"{statistics.fmean(y):.2f} (n {len(y)}) med {statistics.median(x) if x else math.nan:.2f}"
        print(fam, kind, which, "cap", cap, {s: m(vals[s]) for s in "cna"})
# per-scene order
diff = fol = 0
for seed, d in per.items():
    if not all(s in d for s in "cna"): continue
    c, n, a = (min(d[s][0], 10.0) for s in "cna")
    if any(math.isnan(x) for x in (c, n, a)): continue
    if max(c, n, a) - min(c, n, a) < 0.05: continue
    diff += 1; fol += (a <= n + 0.05 and n <= c + 0.05 and a < c)
print("per scene follow", fol, "of", diff)
if len(sys.argv) > 3:
    for seed, d in sorted(per.items()):
        print(seed, {s: tuple(round(x, 2) for x in d[s]) for s in "cna" if s in d})
