"""Control time and cost of the ADP network next to FATROP's solve, on the same recorded
MPC problems, measured in the same run (docs/RL.md, "ADP").

For each state of an ``adp_record.py`` file (held-out seeds) it times, interleaved,
FATROP's solve of the recorded problem from the recorded warm start (the compiled
``nlpsol`` call only) and the network's forward pass (features, MLP, bounded controls,
roll-out: what ``AdpSolver.solve`` adds to the parameter packing both share), and
prices both plans with the MPC's objective.

    python scripts/bench_adp.py --states runs/adp/states-heldout.npz --policy policies/adp.npz
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE
from lmpc_mpc import adp
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.model import N_W, NOBS, NREF, NX
from lmpc_mpc.solver import MpcSolver


def unpad(p: np.ndarray, n: int, n_slots: int) -> np.ndarray:
    """A padded vector back to ``n_slots`` slots (its extra slots are off)."""
    s = adp.n_slots_of(len(p), n)
    if n_slots >= s:
        return p
    stage = p[NX + N_W:].reshape(n + 1, NREF + NOBS * s)[:, :NREF + NOBS * n_slots]
    return np.concatenate([p[:NX + N_W], stage.ravel()])


def pct(a: np.ndarray) -> str:
    return (f"median {np.median(a) * 1e3:.3f} ms, p99 {np.percentile(a, 99) * 1e3:.3f} ms, "
            f"max {np.max(a) * 1e3:.3f} ms")


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--states", type=Path, required=True)
    ap.add_argument("--policy", type=Path, default=Path(__file__).resolve().parents[1]
                    / "policies" / "adp.npz")
    ap.add_argument("--max-states", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args(argv)
    try:
        pol = adp.load_adp(args.policy)
    except (FileNotFoundError, ValueError) as exc:
        print(f"bench_adp: {exc}", file=sys.stderr)
        return 2
    d = np.load(args.states)
    if int(d["seed"].min()) < 10000:
        print("bench_adp: states from seeds below 10000 (test / development scenes)",
              file=sys.stderr)
        return 2
    cfg = load_mpc_config()
    solver = MpcSolver(cfg, solver="fatrop")
    n, veh = cfg.horizon, DEFAULT_VEHICLE
    rng = np.random.default_rng(args.seed)
    idx = np.arange(len(d["p"]))
    if len(idx) > args.max_states:
        idx = np.sort(rng.choice(idx, args.max_states, replace=False))
    max_slots = int(d["max_slots"])
    t_fat, c_fat, t_adp, c_adp, j_fat, j_adp, j_rec, du = [], [], [], [], [], [], [], []
    fails = 0
    pol.plan(d["p"][idx[0]], veh)  # first call outside the figures
    for i in idx:
        p_pad = d["p"][i]
        ns = solver.slots_for(min(int(d["n_slots"][i]), max_slots))
        p = unpad(p_pad, n, ns)
        comp = solver.compiled(ns)
        t0, c0 = time.perf_counter(), time.process_time()
        sol = comp.solver(x0=d["w0"][i], p=p, lbx=comp.lbx, ubx=comp.ubx, lbg=comp.lbg,
                          ubg=comp.ubg)
        t1, c1 = time.perf_counter(), time.process_time()
        us_a, xs_a = pol.plan(p, veh)
        t2, c2 = time.perf_counter(), time.process_time()
        if not comp.solver.stats().get("success", False):
            fails += 1
            continue
        t_fat.append(t1 - t0)
        c_fat.append(c1 - c0)
        t_adp.append(t2 - t1)
        c_adp.append(c2 - c1)
        w = np.asarray(sol["x"]).ravel()
        st = np.concatenate([w, np.zeros(2)]).reshape(n + 1, NX + 2)
        us_f = st[:n, NX:]
        parts = adp.split_params(p, n)
        j_fat.append(float(adp.objective(np, parts, us_f, adp.rollout(
            np, parts.x0, us_f, veh, cfg.dt_s), veh)))
        j_rec.append(float(adp.objective(np, parts, d["u"][i], adp.rollout(
            np, parts.x0, d["u"][i], veh, cfg.dt_s), veh)))
        j_adp.append(float(adp.objective(np, parts, us_a, xs_a, veh)))
        du.append(np.abs(us_a[0] - us_f[0]))
    t_fat, t_adp, c_fat, c_adp = map(np.asarray, (t_fat, t_adp, c_fat, c_adp))
    j_fat, j_adp, du = np.asarray(j_fat), np.asarray(j_adp), np.asarray(du)
    gap = j_adp - j_fat
    rel = gap / np.maximum(j_fat, 1e-9)
    out = {
        "states": int(len(t_fat)), "fatrop_failed": fails,
        "seeds": sorted(int(s) for s in set(d["seed"])), "policy": str(args.policy),
        "fatrop_wall_ms": {"median": np.median(t_fat) * 1e3,
                           "p99": np.percentile(t_fat, 99) * 1e3},
        "adp_wall_ms": {"median": np.median(t_adp) * 1e3, "p99": np.percentile(t_adp, 99) * 1e3},
        "fatrop_cpu_ms_median": np.median(c_fat) * 1e3,
        "adp_cpu_ms_median": np.median(c_adp) * 1e3,
        "fatrop_cpu_ms_p99": np.percentile(c_fat, 99) * 1e3,
        "adp_cpu_ms_p99": np.percentile(c_adp, 99) * 1e3,
        "ratio_cpu_median": np.median(c_fat) / np.median(c_adp),
        "ratio_median": np.median(t_fat) / np.median(t_adp),
        "ratio_p99": np.percentile(t_fat, 99) / np.percentile(t_adp, 99),
        "cost_mpc_median": np.median(j_fat), "cost_adp_median": np.median(j_adp),
        "gap_median": np.median(gap), "gap_p90": np.percentile(gap, 90),
        "rel_gap_median": np.median(rel), "rel_gap_p90": np.percentile(rel, 90),
        "adp_below_mpc": float(np.mean(gap < 0)),
        "recorded_vs_resolved_cost_max_abs": float(np.max(np.abs(np.asarray(j_rec) - j_fat))),
        "u0_abs_diff_accel_mps2": {"median": np.median(du[:, 0]),
                                   "p90": np.percentile(du[:, 0], 90)},
        "u0_abs_diff_steer_rad": {"median": np.median(du[:, 1]),
                                  "p90": np.percentile(du[:, 1], 90)},
    }
    out = json.loads(json.dumps(out, default=float))
    print(f"{len(t_fat)} held-out states (seeds {out['seeds'][0]}-{out['seeds'][-1]}), "
          f"{fails} FATROP failures left out")
    print("wall times (a loaded machine inflates them; process CPU time inflates less):")
    print(f"FATROP solve (warm) : {pct(t_fat)}; cpu {pct(c_fat)}")
    print(f"ADP forward pass    : {pct(t_adp)}; cpu {pct(c_adp)}")
    print(f"ratio FATROP / ADP  : median {out['ratio_median']:.1f}x, p99 {out['ratio_p99']:.1f}x; "
          f"cpu median {out['ratio_cpu_median']:.1f}x")
    print(f"MPC cost J          : median {np.median(j_fat):.4f}; ADP median "
          f"{np.median(j_adp):.4f}")
    print(f"ADP - MPC cost      : median {np.median(gap):.4f}, p90 {np.percentile(gap, 90):.4f}; "
          f"relative median {np.median(rel):.2f}, p90 {np.percentile(rel, 90):.2f}")
    print(f"|u0 ADP - u0 MPC|   : accel median {np.median(du[:, 0]):.3f} p90 "
          f"{np.percentile(du[:, 0], 90):.3f} m/s2, steer median {np.median(du[:, 1]):.4f} "
          f"p90 {np.percentile(du[:, 1], 90):.4f} rad")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
