"""Every junction entry and lane change of `lmpc-rules` on development scenes, once per
style (conservative / normal / aggressive = no instruction), with the gaps at that step
(issue 20: why the accepted-gap means of the style table are not ordered).

    .venv/bin/python trace.py junctions rab 100 125 junctions_rab.csv
    .venv/bin/python trace.py changes lane 100 125 changes_lane.csv

(with the checkout's `scripts/` importable as `lmpc_scripts`, e.g. a folder holding a
symlink `lmpc_scripts -> <checkout>/scripts` on PYTHONPATH). Run 2026-12-06 on main
bafda6e (si stops at 113, the scene SUMO cannot build: si has seeds 100-112).

junctions: seed, style, entry index, t, from lane, internal lane, ego speed, the smallest
gap to a moving crossing vehicle (the style table's `junction_gap_m` at that entry), the
smallest gap to such a vehicle that still comes towards the ego (the ego lies ahead of
it along its heading; nan: none comes), the episode's time.
changes: seed, style, t, from lane, to lane, ego speed, the smallest gap to a vehicle in
the target lane (the ego within 4.8 m on the target lane's side of it, in its own frame),
its id. A scene SUMO cannot build (si 113) ends the run with its error.
"""
import csv
import math
import sys

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.evaluation.style import CROSS_HEADING_RAD, MOVING_MPS, _angle, edge_lane
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods

STYLES = (("c", "drive conservatively"), ("n", None), ("a", "drive aggressively"))


def junctions(steps, time_s):
    k = 0
    for p, c in zip(steps, steps[1:]):
        if edge_lane(p.lane_id) is not None and c.lane_id and c.lane_id.startswith(":"):
            cr = [n for n in c.nearby if n.v_mps >= MOVING_MPS
                  and _angle(n.yaw_rad - c.yaw_rad) > CROSS_HEADING_RAD]
            coming = [n for n in cr if (c.x_m - n.x_m) * math.cos(n.yaw_rad)
                      + (c.y_m - n.y_m) * math.sin(n.yaw_rad) > 0]
            g = min((n.gap_m for n in cr), default=math.nan)
            lag = min((n.gap_m for n in coming), default=math.nan)
            yield [k, round(c.t_s, 1), p.lane_id, c.lane_id, round(c.v_mps, 1), round(g, 1),
                   round(lag, 1), time_s]
            k += 1


def changes(steps, time_s):
    for p, c in zip(steps, steps[1:]):
        a, b = edge_lane(p.lane_id), edge_lane(c.lane_id)
        if a and b and a[0] == b[0] and a[1] != b[1]:
            side = 1.0 if int(b[1]) > int(a[1]) else -1.0  # SUMO: index 0 is the right lane
            tgt = []
            for n in c.nearby:
                lat = -(c.x_m - n.x_m) * math.sin(n.yaw_rad) + (c.y_m - n.y_m) * math.cos(n.yaw_rad)
                if 0.0 < -side * lat <= 4.8:
                    tgt.append((round(n.gap_m, 1), n.id))
            best = min(tgt) if tgt else ("", "")
            yield [round(c.t_s, 1), p.lane_id, c.lane_id, round(c.v_mps, 1), *best]


def main() -> None:
    kind, fam, lo, hi, path = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
    sim = SumoSim(work_dir=f"/tmp/trace_{fam}_{lo}")
    out = csv.writer(open(path, "w"))
    for seed in range(lo, hi):
        for style, text in STYLES:
            w = methods.build(SceneSpec("lmpc-rules", fam, seed, instruction=text))
            res = run_episode(sim, family=fam, seed=seed, controller=w.controller,
                              planner=w.planner, max_time_s=200.0)
            for row in (junctions if kind == "junctions" else changes)(
                    res.record.steps, res.metrics.time_s):
                out.writerow([seed, style, *row])


if __name__ == "__main__":
    main()
