"""Record the MPC's problems and FATROP's solutions from in-process ``mpc`` episodes (the
ADP's training and held-out states; docs/RL.md, "ADP").

Every successful solve of the ``mpc`` method's FATROP solver is kept: the packed
parameter vector ``p`` (exactly what the NLP sees: x0, weights, per-stage reference and
obstacle half-planes), its obstacle-slot count, the initial guess the solver started
from (its warm start), the solution's controls, iterations and solve time. Slot counts
above ``--max-slots`` are padded down only if their extra slots are all off; problems
that really use more are dropped (counted).

    python scripts/adp_record.py --families si,usi,lane,rab,eoa --seeds 10000-10007 \\
        --out runs/adp/states-train.npz

Seeds must be >= 10000 (0-24 are the published test scenes, 100-124 development).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from lmpc_mpc.model import N_W, NOBS, NREF, NX
from lmpc_mpc.solver import MpcSolver

TRAIN_SEED_MIN = 10000


def parse_seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def pad_params(p: np.ndarray, n: int, n_slots: int, max_slots: int) -> Optional[np.ndarray]:
    """``p`` of ``n_slots`` slots laid out with ``max_slots`` (extra slots off: on = 0,
    rho-slot 1, as ``MpcSolver._params`` fills unused ones); None when a slot beyond
    ``max_slots`` is on."""
    head = p[:NX + N_W]
    stage = p[NX + N_W:].reshape(n + 1, NREF + NOBS * n_slots)
    obs = stage[:, NREF:].reshape(n + 1, n_slots, NOBS)
    if n_slots > max_slots:
        if np.any(obs[:, max_slots:, 5] > 0.0):
            return None
        obs = obs[:, :max_slots]
    elif n_slots < max_slots:
        pad = np.zeros((n + 1, max_slots - n_slots, NOBS))
        pad[..., 4] = 1.0
        obs = np.concatenate([obs, pad], axis=1)
    new = np.concatenate([stage[:, :NREF], obs.reshape(n + 1, -1)], axis=1)
    return np.concatenate([head, new.ravel()])


class Recorder:
    """Wraps ``MpcSolver.solve`` of this process: every successful solve is kept."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []
        self.tag: tuple[str, int] = ("", 0)
        self._orig = MpcSolver.solve

    def install(self) -> None:
        rec = self

        def solve(solver: MpcSolver, problem: Any) -> Any:
            try:
                p, x0, n_slots = solver._params(problem)
                w0 = solver._initial_guess(x0, n_slots)
            except Exception:  # noqa: BLE001 - the real solve reports bad input
                return rec._orig(solver, problem)
            res = rec._orig(solver, problem)
            if res.success and solver.solver_name == "fatrop":
                rec.rows.append({"family": rec.tag[0], "seed": rec.tag[1], "p": p,
                                 "n_slots": n_slots, "w0": w0, "u": res.controls.copy(),
                                 "iters": res.iterations, "t": res.solve_time_s,
                                 "cpu": res.solve_cpu_s})
            return res

        MpcSolver.solve = solve  # type: ignore[method-assign]

    def install_params(self, n: int, dt_s: float) -> None:
        """For the ``adp`` method (no NLP solve): keep every packed problem, with no MPC
        solution (u, w0 NaN): the states the network's own closed loop visits."""
        rec = self
        orig = MpcSolver._params

        def params(solver: MpcSolver, problem: Any) -> Any:
            out = orig(solver, problem)
            p, _, n_slots = out
            rec.rows.append({"family": rec.tag[0], "seed": rec.tag[1], "p": p,
                             "n_slots": n_slots, "w0": np.full((n + 1) * NX + n * 2, np.nan),
                             "u": np.full((n, 2), np.nan), "iters": 0, "t": np.nan,
                             "cpu": np.nan})
            return out

        MpcSolver._params = params  # type: ignore[method-assign]


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--families", default="si,usi,lane,rab,eoa")
    ap.add_argument("--seeds", type=parse_seeds, default=parse_seeds("10000-10007"))
    ap.add_argument("--max-slots", type=int, default=10)
    ap.add_argument("--method", choices=("mpc", "adp"), default="mpc",
                    help="adp: record the network's own closed loop (problems only)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    if min(args.seeds) < TRAIN_SEED_MIN:
        print(f"adp_record: seeds must be >= {TRAIN_SEED_MIN} (0-24 are the published test "
              f"scenes, 100-124 development), got {min(args.seeds)}", file=sys.stderr)
        return 2
    from lmpc_bridge.evaluation.scenes import RunSettings, run_scene
    from lmpc_scripts import methods

    rec = Recorder()
    if args.method == "mpc":
        rec.install()
    else:
        from lmpc_mpc.config import load_mpc_config

        cfg = load_mpc_config()
        rec.install_params(cfg.horizon, cfg.dt_s)
    work = tempfile.mkdtemp(prefix="adp-rec-")
    settings = RunSettings(work_dir=work)
    t0 = time.perf_counter()
    outcomes = []
    for fam in args.families.split(","):
        for seed in args.seeds:
            rec.tag = (fam, seed)
            before = len(rec.rows)
            row = run_scene(args.method, fam, seed, settings, methods.build, methods.prepare)
            outcomes.append(f"{fam}:{seed}:{row.get('outcome')}")
            print(f"{fam} {seed}: {row.get('outcome')}, {len(rec.rows) - before} solves, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
    from lmpc_mpc.config import load_mpc_config

    n = load_mpc_config().horizon
    ps, keep = [], []
    dropped = 0
    for r in rec.rows:
        q = pad_params(r["p"], n, r["n_slots"], args.max_slots)
        if q is None:
            dropped += 1
            continue
        ps.append(q)
        keep.append(r)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        args.out, p=np.array(ps), n_slots=np.array([r["n_slots"] for r in keep]),
        u=np.array([r["u"] for r in keep]),
        w0=np.array([r["w0"] for r in keep]),
        iters=np.array([r["iters"] for r in keep]), t=np.array([r["t"] for r in keep]),
        cpu=np.array([r["cpu"] for r in keep]),
        family=np.array([r["family"] for r in keep]), seed=np.array([r["seed"] for r in keep]),
        max_slots=np.array(args.max_slots), outcomes=np.array(outcomes),
        command=np.array(" ".join(sys.argv)))
    print(f"{len(keep)} states kept, {dropped} dropped (more than {args.max_slots} slots on) "
          f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
