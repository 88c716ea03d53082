"""Table I with every row: mpc + lmpc-rules (t1) and dqn, ppo, sac, adp; the paper's O.C.
change vs MPC beside ours."""
import csv, sys
from lmpc_bridge.evaluation.table import aggregate

PAPER = {  # the paper's Table I O.C.: MPC, DQN, PPO, SAC, ADP, Ours
    "si": (160.2, 173.6, 168.6, 172.8, 179.6, 96.1),
    "usi": (235.6, 262.7, 251.2, 261.9, 255.1, 145.7),
    "lane": (18.9, 17.7, 17.7, 17.6, 16.5, 13.0),
    "rab": (112.7, 115.5, 125.8, 121.9, 113.6, 110.3),
    "eoa": (150.7, 157.2, 145.1, 140.3, 141.7, 128.7),
}
IDX = {"dqn": 1, "ppo": 2, "sac": 3, "adp": 4, "lmpc-rules": 5}
ORDER = ["mpc", "dqn", "ppo", "sac", "adp", "lmpc-rules"]
rows = []
for p in sys.argv[1:]:
    for r in csv.DictReader(open(p)):
        if r["method"] not in ORDER:
            continue
        for k in ("collision", "fail", "off_route", "stale_steps", "steps"):
            r[k] = int(r[k] or 0)
        for k in ("ineff", "time_s", "pen_acc", "pen_dist", "overall_cost"):
            r[k] = float(r[k])
        rows.append(r)
agg = aggregate(rows)
print("| Scenario | Method | Coll. | Fail | Ineff | Time | Acc | Dist | O.C. | vs MPC | paper: vs MPC |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for fam in ["si", "usi", "lane", "rab", "eoa"]:
    for m in ORDER:
        a = agg[fam][m]
        ch = a.get("oc_change_vs_mpc")
        ours = "" if m == "mpc" else f"{ch:+.1%}".replace("%", " %").replace("-", "−")
        pap = "" if m == "mpc" else f"{PAPER[fam][IDX[m]] / PAPER[fam][0] - 1:+.1%}".replace("%", " %").replace("-", "−")
        print(f"| {fam.upper()} | {m} | {a['collisions']} | {a['fails']} | {a['ineff']:.1f} | {a['time_s']:.1f} | {a['pen_acc']:.2f} | {a['pen_dist']:.2f} | {a['overall_cost']:.1f} | {ours} | {pap} |")
