"""Post-encroachment time to vehicles the ego went in front of on its junction path, from the records
of dump_records.py: python pet.py usi."""
import glob, math, pickle, statistics, sys
import numpy as np
sys.path.insert(0, "/work/main/src/lmpc_bridge")
from lmpc_bridge.evaluation.style import _angle

NEAR_M = 1.5; BACK_S = 2.0; CROSS = math.radians(30)

def pets(rec):
    """PET (s) to each vehicle that came from another direction and reached a point of the
    ego's path after the ego (the ego went in front of it)."""
    st = rec.steps
    T = np.array([s.t_s for s in st]); X = np.array([[s.x_m, s.y_m] for s in st]); Y = np.array([s.yaw_rad for s in st])
    onj = np.array([bool(s.lane_id and s.lane_id.startswith(":")) for s in st])
    tracks = {}
    for s in st:
        for n in s.nearby:
            tracks.setdefault(n.id, []).append((s.t_s, n.x_m, n.y_m, n.yaw_rad))
    out = {}
    idx_j = np.nonzero(onj)[0]
    if len(idx_j) == 0: return out
    EJ = X[idx_j]
    for vid, tr in tracks.items():
        tr = np.array(tr)
        d = np.linalg.norm(tr[:, None, 1:3] - EJ[None, :, :], axis=2)  # other steps x ego junction steps
        i, j = np.nonzero(d < NEAR_M)
        best = None
        for a, b in zip(i, j):
            k = idx_j[b]; to, te = tr[a, 0], T[k]
            if to <= te: continue      # it was there first
            # directions they came from
            ko = np.searchsorted(tr[:, 0], to - BACK_S); ke = np.searchsorted(T, te - BACK_S)
            if _angle(tr[ko, 3] - Y[ke]) <= CROSS: continue
            p = to - te
            best = p if best is None else min(best, p)
        if best is not None: out[vid] = best
    return out

fam = sys.argv[1]
per = {}
for path in sorted(glob.glob(f"/tmp/recs/{fam}_*.pkl")):
    _, seed, s = path[:-4].split("/")[-1].split("_")
    rec, t = pickle.load(open(path, "rb"))
    p = pets(rec)
    per.setdefault(int(seed), {})[s] = min(p.values()) if p else math.nan
for s in "cna":
    v = [d[s] for d in per.values() if s in d and not math.isnan(d[s])]
    print(fam, s, f"mean {statistics.fmean(v):.2f} median {statistics.median(v):.2f} n {len(v)}")
diff = fol = 0
for seed, d in sorted(per.items()):
    if not all(s in d and not math.isnan(d[s]) for s in "cna"): continue
    c, n, a = d["c"], d["n"], d["a"]
    if max(c, n, a) - min(c, n, a) < 0.1: continue
    diff += 1; ok = (a <= n + 0.1 and n <= c + 0.1 and a < c); fol += ok
    print(seed, round(c,2), round(n,2), round(a,2), "ok" if ok else "")
print("per scene follow", fol, "of", diff)
