"""Train the ADP policy network: backpropagation through the MPC's model over its horizon
with the MPC's own cost, on states recorded from in-process ``mpc`` episodes
(``scripts/adp_record.py``, seeds >= 10000) plus perturbations (docs/RL.md, "ADP").

    python scripts/train_adp.py --data runs/adp/states-train.npz \\
        --heldout runs/adp/states-heldout.npz --steps 6000 --out runs/adp/train

The network maps the features of a packed MPC problem (``lmpc_mpc.adp.features``) to the
horizon's 30 controls (``adp.controls`` keeps them inside the MPC's hard bounds); the
loss is the mean over a batch of log(J + 0.1), J the NLP's objective of the roll-out
(``adp.objective`` of ``adp.rollout``), differentiated by JAX. Outputs in ``--out``:
``curve.csv``, ``provenance.json``, ``adp.npz`` (numpy weights, read by the ``adp``
method without JAX); ``--install`` copies the network to ``policies/adp.npz``.
Needs jax and optax (the ``rl`` extra); runs on one thread.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Optional, Sequence

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                      "intra_op_parallelism_threads=1")

import numpy as np  # noqa: E402

from lmpc_msgs_py.cli import folder_arg  # noqa: E402
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE  # noqa: E402
from lmpc_mpc import adp  # noqa: E402
from lmpc_mpc.model import NU, NX  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOSS_OFFSET = 0.1
"""The loss is log(J + this): the costs of the recorded states span 1e-7 to 1e3 (median
~0.2), so a plain mean would be all about the few worst states."""
TRAIN_SEED_MIN = 10000


def perturb(p: np.ndarray, rng: np.random.Generator, scale: float) -> np.ndarray:
    """Copies of ``p`` with the ego's state disturbed (position N(0, 0.5 m), yaw
    N(0, 0.05 rad), speed N(0, 1 m/s) clipped to [0, 20], previous controls N(0, 0.5 m/s^2)
    / N(0, 0.03 rad)) times ``scale``; reference and obstacles stay."""
    q = p.copy()
    n = len(q)
    sd = np.array([0.5, 0.5, 0.05, 1.0, 0.5, 0.03, 0.5, 0.03]) * scale
    q[:, :NX] += rng.normal(0.0, 1.0, (n, NX)) * sd
    q[:, 3] = np.clip(q[:, 3], 0.0, DEFAULT_VEHICLE.max_speed_mps)
    q[:, 4] = np.clip(q[:, 4], -DEFAULT_VEHICLE.max_decel_mps2, DEFAULT_VEHICLE.max_accel_mps2)
    q[:, 6] = np.clip(q[:, 6], -DEFAULT_VEHICLE.max_decel_mps2, DEFAULT_VEHICLE.max_accel_mps2)
    q[:, [5, 7]] = np.clip(q[:, [5, 7]], -DEFAULT_VEHICLE.max_steer_rad,
                           DEFAULT_VEHICLE.max_steer_rad)
    return q


def cap_per_episode(d: Any, cap: int, rng: np.random.Generator) -> np.ndarray:
    """Indices keeping at most ``cap`` random states of each (family, seed) episode (an
    eoa timeout alone records 2000 nearly equal standing states)."""
    keys = np.char.add(d["family"].astype(str), d["seed"].astype(str))
    out = []
    for k in np.unique(keys):
        idx = np.flatnonzero(keys == k)
        out.append(idx if len(idx) <= cap else rng.choice(idx, cap, replace=False))
    return np.sort(np.concatenate(out))


def gap_stats(j_adp: np.ndarray, j_mpc: np.ndarray) -> dict[str, float]:
    """The ADP's cost above the MPC's on the same states: absolute and relative."""
    diff = j_adp - j_mpc
    rel = diff / np.maximum(j_mpc, 1e-9)
    return {"n": int(len(diff)), "j_mpc_median": float(np.median(j_mpc)),
            "j_adp_median": float(np.median(j_adp)),
            "gap_median": float(np.median(diff)), "gap_p90": float(np.percentile(diff, 90)),
            "rel_gap_median": float(np.median(rel)),
            "rel_gap_p90": float(np.percentile(rel, 90)),
            "ratio_of_means": float(np.mean(j_adp) / np.mean(j_mpc)),
            "adp_below_mpc": float(np.mean(diff < 0.0))}


def mpc_costs(p: np.ndarray, u: np.ndarray, n: int, dt: float) -> np.ndarray:
    parts = adp.split_params(p, n)
    return adp.objective(np, parts, u, adp.rollout(np, parts.x0, u, DEFAULT_VEHICLE, dt),
                         DEFAULT_VEHICLE)


def git_commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], check=True,
                              capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="adp_record.py output")
    ap.add_argument("--heldout", type=Path, default=None,
                    help="adp_record.py output on other seeds: the cost gap to the MPC")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    ap.add_argument("--per-episode", type=int, default=400,
                    help="at most this many recorded states per episode")
    ap.add_argument("--perturbed", type=int, default=1,
                    help="perturbed copies per recorded state")
    ap.add_argument("--bc-steps", type=int, default=0,
                    help="first this many steps imitate the recorded MPC controls (a warm "
                    "start; the rest minimise the MPC's cost); 0: cost only")
    ap.add_argument("--extra", type=Path, nargs="*", default=[],
                    help="more adp_record.py files whose states join the cost's training "
                    "pool (e.g. the network's own closed loop: --method adp)")
    ap.add_argument("--init", type=Path, default=None,
                    help="start from this network (its layers and input scaling)")
    ap.add_argument("--seed", type=int, default=0, help="network init and perturbations")
    ap.add_argument("--eval-every", type=int, default=250)
    ap.add_argument("--out", type=folder_arg, default=Path("runs/adp/train"))
    ap.add_argument("--install", action="store_true", help="copy to policies/adp.npz")
    args = ap.parse_args(argv)
    try:
        import jax
        import jax.numpy as jnp
        import optax
    except ImportError:
        print("train_adp: needs jax and optax (pip install -e '.[rl]')", file=sys.stderr)
        return 2
    jax.config.update("jax_enable_x64", True)
    from lmpc_mpc.config import load_mpc_config

    cfg = load_mpc_config()
    n, dt, veh = cfg.horizon, cfg.dt_s, DEFAULT_VEHICLE
    rng = np.random.default_rng(args.seed)
    d = np.load(args.data)
    if int(d["seed"].min()) < TRAIN_SEED_MIN:
        print(f"train_adp: {args.data} holds seeds below {TRAIN_SEED_MIN}", file=sys.stderr)
        return 2
    idx = cap_per_episode(d, args.per_episode, rng)
    p0 = d["p"][idx]
    extra = []
    for path in args.extra:
        e = np.load(path)
        if int(e["seed"].min()) < TRAIN_SEED_MIN or int(e["max_slots"]) != int(d["max_slots"]):
            print(f"train_adp: {path}: seeds below {TRAIN_SEED_MIN} or another slot layout",
                  file=sys.stderr)
            return 2
        extra.append(e["p"][cap_per_episode(e, args.per_episode, rng)])
    p_all = np.concatenate([p0] + [perturb(p0, rng, 1.0) for _ in range(args.perturbed)]
                           + extra)
    feats = adp.features(adp.split_params(p_all, n), veh)
    init = adp.load_adp(args.init) if args.init is not None else None
    if init is not None:
        mean, std = init.mean, init.std
    else:
        mean = feats.mean(axis=0)
        std = feats.std(axis=0)
        std = np.where(std < 1e-6, 1.0, std)
    x_all = (feats - mean) / std
    print(f"{len(p0)} recorded states (of {len(d['p'])}), {len(p_all)} with perturbations, "
          f"{x_all.shape[1]} features", flush=True)
    held = None
    if args.heldout is not None:
        h = np.load(args.heldout)
        if int(h["seed"].min()) < TRAIN_SEED_MIN or set(h["seed"]) & set(d["seed"]):
            print("train_adp: held-out seeds must be >= 10000 and not training seeds",
                  file=sys.stderr)
            return 2
        hp = h["p"][cap_per_episode(h, args.per_episode, np.random.default_rng(1))]
        hu = h["u"][cap_per_episode(h, args.per_episode, np.random.default_rng(1))]
        held = (hp, mpc_costs(hp, hu, n, dt))

    sizes = [x_all.shape[1], *args.hidden, n * NU]
    key = jax.random.PRNGKey(args.seed)
    params = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        key, sub = jax.random.split(key)
        scale = 0.1 if b == n * NU else 1.0  # start near a = mid, steer rate 0
        bias = jnp.zeros(b)
        if b == n * NU:  # start at a = 0 (the tanh's midpoint is a braking mid-range)
            lo, hi = -veh.max_decel_mps2, veh.max_accel_mps2
            mid_a = (0.0 - 0.5 * (hi + lo)) / (0.5 * (hi - lo))
            bias = bias.at[0::2].set(float(np.arctanh(mid_a)))
        params.append((jax.random.normal(sub, (a, b)) * scale * np.sqrt(1.0 / a), bias))
    if init is not None:
        params = [(jnp.asarray(w), jnp.asarray(b)) for w, b in init.layers]
    opt = optax.adam(optax.cosine_decay_schedule(args.lr, args.steps, alpha=0.05))
    state = opt.init(params)

    def loss_fn(prm: Any, x: Any, p: Any) -> Any:
        parts = adp.split_params(p, n)
        z = adp.mlp(jnp, prm, x).reshape(x.shape[:-1] + (n, NU))
        us = adp.controls(jnp, z, parts.x0, veh, dt)
        xs = adp.rollout(jnp, parts.x0, us, veh, dt)
        j = adp.objective(jnp, parts, us, xs, veh)
        return jnp.mean(jnp.log(j + LOSS_OFFSET)), j

    u_rec = d["u"][idx]
    u_scale = jnp.asarray([1.0, 0.05])  # m/s2, rad: an error of either counts alike

    def bc_fn(prm: Any, x: Any, p: Any, u_mpc: Any) -> Any:
        parts = adp.split_params(p, n)
        z = adp.mlp(jnp, prm, x).reshape(x.shape[:-1] + (n, NU))
        us = adp.controls(jnp, z, parts.x0, veh, dt)
        return jnp.mean(((us - u_mpc) / u_scale) ** 2), jnp.zeros(x.shape[0])

    @jax.jit
    def bc_step(prm: Any, st: Any, x: Any, p: Any, u_mpc: Any) -> Any:
        (loss, j), grads = jax.value_and_grad(bc_fn, has_aux=True)(prm, x, p, u_mpc)
        upd, st = opt.update(grads, st, prm)
        return optax.apply_updates(prm, upd), st, loss, jnp.mean(j)

    @jax.jit
    def train_step(prm: Any, st: Any, x: Any, p: Any) -> Any:
        (loss, j), grads = jax.value_and_grad(loss_fn, has_aux=True)(prm, x, p)
        upd, st = opt.update(grads, st, prm)
        return optax.apply_updates(prm, upd), st, loss, jnp.mean(j)

    def to_policy(prm: Any, meta: dict[str, Any]) -> adp.AdpPolicy:
        layers = tuple((np.asarray(w, dtype=float), np.asarray(b, dtype=float))
                       for w, b in prm)
        return adp.AdpPolicy(layers, mean, std, meta)

    base_meta = {"kind": "adp", "horizon": n, "dt_s": dt, "feature_stride": adp.FEATURE_STRIDE,
                 "feature_slots": adp.FEATURE_SLOTS, "hidden": args.hidden}

    def evaluate(prm: Any) -> Optional[dict[str, float]]:
        if held is None:
            return None
        us, xs = to_policy(prm, base_meta).plan(held[0], veh)
        j = adp.objective(np, adp.split_params(held[0], n), us, xs, veh)
        return gap_stats(j, held[1])

    args.out.mkdir(parents=True, exist_ok=True)
    curve_path = args.out / "curve.csv"
    t0 = time.perf_counter()
    compile_s = None
    with curve_path.open("w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["step", "phase", "wall_s", "loss", "batch_mean_J", "heldout_rel_gap_median",
                     "heldout_rel_gap_p90", "heldout_gap_median"])
        run_loss, run_j = [], []
        for step in range(1, args.steps + 1):
            if step <= args.bc_steps:  # imitation warm start on the recorded states
                b = rng.integers(0, len(p0), args.batch)
                params, state, loss, mj = bc_step(params, state, jnp.asarray(x_all[b]),
                                                  jnp.asarray(p_all[b]), jnp.asarray(u_rec[b]))
            else:
                if step == args.bc_steps + 1:  # the cost's gradients are on another scale
                    state = opt.init(params)
                b = rng.integers(0, len(x_all), args.batch)
                params, state, loss, mj = train_step(params, state, jnp.asarray(x_all[b]),
                                                     jnp.asarray(p_all[b]))
            if compile_s is None:
                loss.block_until_ready()
                compile_s = time.perf_counter() - t0
            run_loss.append(float(loss))
            run_j.append(float(mj))
            if step % args.eval_every == 0 or step == args.steps:
                ev = evaluate(params) or {}
                wr.writerow([step, "bc" if step <= args.bc_steps else "cost",
                             round(time.perf_counter() - t0, 1),
                             round(float(np.mean(run_loss)), 5),
                             round(float(np.mean(run_j)), 5),
                             ev.get("rel_gap_median", ""), ev.get("rel_gap_p90", ""),
                             ev.get("gap_median", "")])
                fh.flush()
                print(f"step {step}: loss {np.mean(run_loss):.4f}, mean J {np.mean(run_j):.3f}"
                      + (f", held-out rel gap median {ev['rel_gap_median']:.3f} p90 "
                         f"{ev['rel_gap_p90']:.3f}" if ev else "")
                      + f", {time.perf_counter() - t0:.0f} s", flush=True)
                run_loss, run_j = [], []
    wall = time.perf_counter() - t0
    final = evaluate(params)
    meta = {**base_meta,
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
            "commit": git_commit(), "python": platform.python_version(),
            "jax": jax.__version__, "optax": optax.__version__, "numpy": np.__version__,
            "steps": args.steps, "bc_steps": args.bc_steps, "batch": args.batch,
            "lr": args.lr, "seed": args.seed,
            "loss": f"mean log(J + {LOSS_OFFSET})", "wall_s": round(wall, 1),
            "compile_s": round(compile_s or 0.0, 1),
            "init": None if init is None else {
                "file": str(args.init), "command": init.meta.get("command"),
                "steps": init.meta.get("steps")},
            "extra_data": [str(x) for x in args.extra],
            "extra_states": int(sum(len(x) for x in extra)),
            "train_states": int(len(p0)), "train_states_with_perturbed": int(len(p_all)),
            "train_data": str(args.data), "train_seeds": sorted(int(s) for s in set(d["seed"])),
            "train_families": sorted(str(f) for f in set(d["family"])),
            "record_command": str(d["command"]),
            "heldout": None if held is None else {
                "data": str(args.heldout), "seeds": sorted(int(s) for s in set(h["seed"])),
                **(final or {})}}
    pol = to_policy(params, meta)
    pol.save(args.out / "adp.npz")
    (args.out / "provenance.json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"trained in {wall:.0f} s -> {args.out / 'adp.npz'}")
    if final:
        print("held-out:", json.dumps(final))
    if args.install:
        dst = REPO / "policies" / "adp.npz"
        dst.parent.mkdir(exist_ok=True)
        shutil.copy(args.out / "adp.npz", dst)
        print(f"installed {dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
