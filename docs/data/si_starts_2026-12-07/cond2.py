import lmpc_bridge.scenarios.si as si
from lmpc_bridge.scenarios.common import select_candidate
for seed in list(range(0, 25)) + list(range(100, 125)) + list(range(10000, 10300)):
    p = select_candidate("si", seed, sample=si._sample, check=si._check).params
    if p.bike is not None and p.bike[0] == 0 and p.leader_gap_m is None and (p.lanes == 1 or p.movement == "right"):
        rel = max(5.0 * p.bike[1], 12.0) - p.ego_dist_m
        gap = rel - 4.5 if rel > 0 else -rel - 1.8
        if gap < 15: print(seed, f"rel={rel:.1f} gap={gap:.1f} lanes={p.lanes} mv={p.movement}")
    if p.leader_gap_m is not None:
        d = p.ego_dist_m - p.leader_gap_m
        if d < p.ego_speed_mps ** 2 / 9 + 5: print(seed, f"leader d={d:.1f} brake={p.ego_speed_mps ** 2 / 9:.1f} mv={p.movement} lanes={p.lanes}")
