"""Table I with every row, the paper's O.C. change vs MPC beside ours (the layout of
../learned_2026-12-04/all_rows.py), from several results.csv files, each optionally
restricted to some methods: PATH[:method,method...].

    python table1.py ../latency_2026-12-04/t1/results.csv results_dqn.csv results_sac.csv \
        ../learned_2026-12-04/results.csv:ppo,adp
"""
import csv
import sys

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


def pct(x: float) -> str:
    return f"{x:+.1%}".replace("%", " %").replace("-", "−")


def main() -> None:
    rows = []
    for arg in sys.argv[1:]:
        path, _, only = arg.partition(":")
        keep = set(only.split(",")) if only else set(ORDER)
        for r in csv.DictReader(open(path)):
            if r["method"] not in keep or r["method"] not in ORDER:
                continue
            for k in ("collision", "fail", "off_route", "stale_steps", "steps"):
                r[k] = int(r[k] or 0)
            for k in ("ineff", "time_s", "pen_acc", "pen_dist", "overall_cost"):
                r[k] = float(r[k])
            rows.append(r)
    agg = aggregate(rows)
    print("| Scenario | Method | Coll. | Fail | Ineff | Time | Acc | Dist | O.C. | vs MPC "
          "| paper: vs MPC |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for fam in ["si", "usi", "lane", "rab", "eoa"]:
        for m in ORDER:
            if m not in agg.get(fam, {}):
                continue
            a = agg[fam][m]
            ours = "" if m == "mpc" else pct(a["oc_change_vs_mpc"])
            pap = "" if m == "mpc" else pct(PAPER[fam][IDX[m]] / PAPER[fam][0] - 1)
            print(f"| {fam.upper()} | {m} | {a['collisions']} | {a['fails']} | {a['ineff']:.1f} "
                  f"| {a['time_s']:.1f} | {a['pen_acc']:.2f} | {a['pen_dist']:.2f} "
                  f"| {a['overall_cost']:.1f} | {ours} | {pap} |")


if __name__ == "__main__":
    main()
