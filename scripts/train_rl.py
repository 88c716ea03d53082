#!/usr/bin/env python3
"""Train a learned planner (DQN, PPO or SAC; skrl on JAX) on one family's training scenes.

    python scripts/train_rl.py --algo dqn --family usi --steps 5000 --seed 10000

Scenes: seeds ``--seed`` .. ``--seed + --scenes - 1``, all >= 10000 (the training range;
the published scenes 0-24 and the development seeds 100-124 are refused). ``--envs``
environments (``lmpc_bridge.gym_env.LmpcDrivingEnv``, one worker process each: libsumo
runs one simulation per process) step in parallel (``gymnasium.vector.AsyncVectorEnv``).
``--steps``: environment steps in all (one step = 0.1 s of one scene).

Writes into ``--out`` (default ``runs/rl/<algo>-<family>-s<seed>``): ``curve.csv`` (one
row per finished episode: the total steps then, return, length, outcome, O.C.),
``curve.png``, ``policy.npz`` (the policy network as numpy arrays, with its provenance:
command, library versions, commit, steps, wall time) and ``provenance.json``.
``--install`` also copies the policy to ``policies/<algo>-<family>.npz``, where the
benchmark's ``dqn`` / ``ppo`` / ``sac`` methods look for it (docs/RL.md).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import platform
import shutil
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any, Optional

import numpy as np
from lmpc_msgs_py.cli import int_arg, folder_arg

REPO = Path(__file__).resolve().parent.parent
MIN_TRAIN_SEED = 10000
HIDDEN = (64, 64)
DQN_REWARD_SCALE = 0.01
"""DQN learns from the reward times this (skrl's ``rewards_shaper``): a step costs ~1-2 and a
failure 300, so unscaled Q-values run to the hundreds; scaled they are O(1), what the
learning rate and the MSE loss suit. A positive factor leaves the greedy action unchanged;
the curve and the held-out returns are in the unscaled reward."""
TRAIN_CAP = 0.0
"""``--train-cap``'s default: off (only the 200 s cap). With a cap c a training episode
ends (truncated) after c times its estimated steps (``LmpcDrivingEnv(train_cap=...)``) and
the learner bootstraps from its last observation (``_stored_next``); c = 2 was measured
on 14 of the 15 pairs (docs/RL.md, "A training cap, tried"): 1.3-5.5x the episodes, but
most si, usi and eoa episodes ended at the cap, and the held-out checks came out worse in
10 of 14 pairs (47 of 70 held-out scenes reached, 60 without the cap), so it is not the
default."""
CURVE_FIELDS = ("episode", "total_steps", "wall_s", "return", "length", "outcome",
                "overall_cost", "scene_seed")


def parse_args(argv: Optional[list[str]] = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--algo", required=True, choices=("dqn", "ppo", "sac"))
    p.add_argument("--family", required=True)
    p.add_argument("--steps", type=int_arg(1), required=True, help="environment steps in all")
    p.add_argument("--seed", type=int, required=True,
                   help=f"RNG seed and first scene seed (>= {MIN_TRAIN_SEED})")
    p.add_argument("--scenes", type=int_arg(1), default=200, help="scene seeds seed..seed+N-1")
    p.add_argument("--envs", type=int_arg(1), default=2,
                   help="parallel environments (processes)")
    p.add_argument("--train-cap", type=float, default=TRAIN_CAP,
                   help="end a training episode still running after this many times its "
                        "estimated steps (truncated, outcome 'cap'; 0, the default: only the "
                        "200 s cap; docs/RL.md)")
    p.add_argument("--out", type=folder_arg, default=None)
    p.add_argument("--eval-scenes", type=int_arg(0), default=10,
                   help="after training, drive this many further training scenes (the "
                        "seeds after the training ones) with the greedy policy and with "
                        "the neutral action (the mpc method); 0: none")
    p.add_argument("--install", action="store_true",
                   help="copy the policy to policies/<algo>-<family>.npz")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p.parse_args(argv)


def check_args(args: argparse.Namespace) -> Optional[str]:
    """One line saying what is wrong with the arguments, or None."""
    from lmpc_bridge.scenarios import unknown_families

    if args.seed < MIN_TRAIN_SEED:
        return (f"--seed {args.seed}: training uses seeds >= {MIN_TRAIN_SEED} only (0-24 are "
                "the published test scenes, 100-124 the development seeds)")
    unknown = unknown_families([args.family])
    if unknown:
        return f"--family: {unknown}"
    if not args.train_cap >= 0:
        return f"--train-cap must be >= 0 (0: only the 200 s cap), got {args.train_cap}"
    return None


# -- the networks (flax; exported as numpy by policy_layers) ------------------------------------
def make_models(algo: str, obs_space: Any, act_space: Any, device: Any) -> dict[str, Any]:
    import flax.linen as nn
    import jax.numpy as jnp
    from skrl.models.jax import DeterministicMixin, GaussianMixin, Model

    class Mlp(nn.Module):  # type: ignore[misc]
        out: int

        @nn.compact
        def __call__(self, x: Any) -> Any:
            for width in HIDDEN:
                x = nn.relu(nn.Dense(width)(x))
            return nn.Dense(self.out)(x)

    class QNet(DeterministicMixin, Model):  # type: ignore[misc]
        def __init__(self, **kwargs: Any) -> None:
            Model.__init__(self, **kwargs)
            DeterministicMixin.__init__(self)

        @nn.compact
        def __call__(self, inputs: Any, role: str) -> Any:
            return Mlp(int(self.action_space.n), name="mlp")(inputs["observations"]), {}

    class Actor(GaussianMixin, Model):  # type: ignore[misc]
        def __init__(self, **kwargs: Any) -> None:
            Model.__init__(self, **kwargs)
            GaussianMixin.__init__(self, clip_actions=True, clip_log_std=True,
                                   min_log_std=-5.0, max_log_std=1.0)

        @nn.compact
        def __call__(self, inputs: Any, role: str) -> Any:
            mean = nn.tanh(Mlp(self.num_actions, name="mlp")(inputs["observations"]))
            log_std = self.param("log_std", lambda _: jnp.full(self.num_actions, -0.5))
            return mean, {"log_std": log_std}

    class Value(DeterministicMixin, Model):  # type: ignore[misc]
        def __init__(self, **kwargs: Any) -> None:
            Model.__init__(self, **kwargs)
            DeterministicMixin.__init__(self)

        @nn.compact
        def __call__(self, inputs: Any, role: str) -> Any:
            return Mlp(1, name="mlp")(inputs["observations"]), {}

    class Critic(DeterministicMixin, Model):  # type: ignore[misc]
        def __init__(self, **kwargs: Any) -> None:
            Model.__init__(self, **kwargs)
            DeterministicMixin.__init__(self)

        @nn.compact
        def __call__(self, inputs: Any, role: str) -> Any:
            x = jnp.concatenate([inputs["observations"], inputs["taken_actions"]], axis=-1)
            return Mlp(1, name="mlp")(x), {}

    kw = dict(observation_space=obs_space, action_space=act_space, device=device)
    if algo == "dqn":
        models = {"q_network": QNet(**kw), "target_q_network": QNet(**kw)}
    elif algo == "ppo":
        models = {"policy": Actor(**kw), "value": Value(**kw)}
    else:
        models = {"policy": Actor(**kw), "critic_1": Critic(**kw), "critic_2": Critic(**kw),
                  "target_critic_1": Critic(**kw), "target_critic_2": Critic(**kw)}
    for role, model in models.items():
        model.init_state_dict(role=role)
    return models


def make_agent(algo: str, models: dict[str, Any], env: Any, steps_per_env: int) -> Any:
    from skrl.memories.jax import RandomMemory

    n, dev = env.num_envs, env.device
    common = dict(models=models, observation_space=env.observation_space,
                  action_space=env.action_space, device=dev)
    if algo == "dqn":
        from skrl.agents.jax.dqn import DQN, DQN_CFG

        explore = max(1, steps_per_env // 2)
        cfg = DQN_CFG(batch_size=64, discount_factor=0.99, learning_rate=1e-3,
                      learning_starts=min(500, steps_per_env // 4),
                      rewards_shaper=lambda r, _t, _total: r * DQN_REWARD_SCALE,
                      exploration_scheduler=lambda t, _total: max(0.05, 1.0 - 0.95 * t / explore))
        memory = RandomMemory(memory_size=max(1, min(steps_per_env, 100_000)), num_envs=n,
                              device=dev)
        agent = DQN(memory=memory, cfg=cfg, **common)
    elif algo == "ppo":
        from skrl.agents.jax.ppo import PPO, PPO_CFG

        # skrl jit-compiles its GAE as a loop unrolled over the rollouts: 256 took 2 min
        # 10 s to compile on this machine (once per run), so at most 64
        rollouts = max(8, min(64, steps_per_env // 4))
        cfg = PPO_CFG(rollouts=rollouts, learning_epochs=4, mini_batches=4, discount_factor=0.99,
                      gae_lambda=0.95, learning_rate=3e-4, entropy_loss_scale=0.0,
                      value_loss_scale=0.5, time_limit_bootstrap=True)
        agent = PPO(memory=RandomMemory(memory_size=rollouts, num_envs=n, device=dev), cfg=cfg,
                    **common)
    else:
        from skrl.agents.jax.sac import SAC, SAC_CFG

        cfg = SAC_CFG(batch_size=64, discount_factor=0.99, learning_rate=1e-3,
                      learning_starts=min(500, steps_per_env // 4), learn_entropy=True)
        memory = RandomMemory(memory_size=max(1, min(steps_per_env, 100_000)), num_envs=n,
                              device=dev)
        agent = SAC(memory=memory, cfg=cfg, **common)
    agent.cfg.experiment.write_interval = 0  # no TensorBoard files: the CSV is the record
    agent.cfg.experiment.checkpoint_interval = 0
    return agent


def policy_layers(algo: str, agent: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """The acting network's Dense layers (kernel, bias) in order, as numpy."""
    import jax

    model = agent.q_network if algo == "dqn" else agent.policy
    params = jax.device_get(model.state_dict.params)
    mlp = params["params"]["mlp"]
    names = sorted(mlp, key=lambda k: int(k.rsplit("_", 1)[1]))
    return [(np.asarray(mlp[k]["kernel"], np.float32), np.asarray(mlp[k]["bias"], np.float32))
            for k in names]


# -- the learning curve -------------------------------------------------------------------------
def _episode_ends(info: dict[str, Any], done: np.ndarray) -> list[tuple[int, dict[str, Any]]]:
    """(env index, that env's last info) of the environments that ended this step (the
    vector env resets them in the same step: their info is under ``final_info``)."""
    final = info.get("final_info", info)

    def pick(d: dict[str, Any], i: int) -> dict[str, Any]:
        # a vector env's info: per key an array over the envs (nested dicts: a dict of
        # them) and a mask "_key" of the envs that set it
        one: dict[str, Any] = {}
        for key, val in d.items():
            if key.startswith("_"):
                continue
            mask = d.get(f"_{key}")
            if mask is not None and not mask[i]:
                continue
            one[key] = pick(val, i) if isinstance(val, dict) else val[i]
        return one

    return [(int(i), pick(final, int(i))) for i in np.nonzero(done)[0]]


def write_png(csv_path: Path, png_path: Path, title: str,
              reference: Optional[dict[str, float]] = None) -> None:
    """The curve: each episode's return, its running mean, and ``reference`` lines (the
    held-out scenes' mean return of the policy and of the mpc method)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(csv_path.open()))
    fig, ax = plt.subplots(figsize=(7, 4))
    if rows:
        x = np.array([float(r["total_steps"]) for r in rows])
        y = np.array([float(r["return"]) for r in rows])
        ax.plot(x, y, ".", alpha=0.35, label="episode return")
        k = max(1, min(20, len(y) // 5))
        if len(y) >= k:
            smooth = np.convolve(y, np.ones(k) / k, mode="valid")
            ax.plot(x[k - 1:], smooth, "-", label=f"mean of {k}")
    else:
        ax.text(0.5, 0.5, "no episode finished", ha="center", transform=ax.transAxes)
    for (label, value), style in zip((reference or {}).items(), ("--", ":")):
        ax.axhline(value, linestyle=style, color="k", label=f"{label}: {value:.1f}")
    if rows or reference:
        ax.legend(fontsize=8)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("return")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(png_path, dpi=90)
    plt.close(fig)


# -- held-out check -------------------------------------------------------------------------------
EVAL_FIELDS = ("scene_seed", "driver", "return", "outcome", "overall_cost", "time_s")


def evaluate(policy: Any, family: str, seeds: tuple[int, ...], path: Path
             ) -> dict[str, Any]:
    """Drive ``seeds`` with the greedy ``policy`` and with the neutral action (the ``mpc``
    method) in this process; one row each into ``path``; the means."""
    from lmpc_bridge.gym_env import LmpcDrivingEnv, neutral_action

    env = LmpcDrivingEnv(family, seeds=seeds, action=policy.kind, k_agents=policy.k_agents)
    rows = []
    try:
        for seed in seeds:
            for driver in ("policy", "mpc"):
                obs, _ = env.reset(options={"scene_seed": seed})
                total, info = 0.0, {}
                while True:
                    act = policy.act(obs) if driver == "policy" else neutral_action(env)
                    obs, reward, terminated, truncated, info = env.step(act)
                    total += reward
                    if terminated or truncated:
                        break
                m = info["metrics"]
                rows.append({"scene_seed": seed, "driver": driver, "return": round(total, 4),
                             "outcome": info["outcome"],
                             "overall_cost": round(m["overall_cost"], 4),
                             "time_s": round(m["time_s"], 2)})
    finally:
        env.close()
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=EVAL_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    out: dict[str, Any] = {"eval_seeds": f"{seeds[0]}-{seeds[-1]}"}
    for driver in ("policy", "mpc"):
        mine = [r for r in rows if r["driver"] == driver]
        out[f"eval_{driver}_return"] = round(float(np.mean([r["return"] for r in mine])), 2)
        out[f"eval_{driver}_oc"] = round(float(np.mean([r["overall_cost"] for r in mine])), 2)
        out[f"eval_{driver}_reached"] = sum(r["outcome"] == "reached" for r in mine)
    return out


# -- the run --------------------------------------------------------------------------------------
def _git_commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("skrl", "jax", "jaxlib", "flax", "gymnasium", "numpy", "casadi", "eclipse-sumo"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "absent"
    return out


def _make_env(family: str, seeds: tuple[int, ...], action: str,
              train_cap: Optional[float] = None) -> Any:
    def make() -> Any:
        from lmpc_bridge.gym_env import LmpcDrivingEnv

        return LmpcDrivingEnv(family, seeds=seeds, action=action, train_cap=train_cap)
    return make


def _stored_next(next_obs: Any, info: dict[str, Any], done: np.ndarray) -> Any:
    """The next observations to store with this step's transitions: the vector env resets a
    finished environment in the same step and returns the new episode's first
    observation; the finished episode's last one is ``info["final_obs"]``. A truncated
    episode (the training cap, the 200 s cap) bootstraps from it (skrl's DQN and SAC
    targets stop only at ``terminated``; PPO with ``time_limit_bootstrap``)."""
    final = info.get("final_obs")
    if final is None or not done.any():
        return next_obs
    stored = np.array(next_obs, dtype=np.float32, copy=True)
    for i in np.nonzero(done)[0]:
        stored[i] = np.asarray(final[i], dtype=np.float32).reshape(-1)
    return stored


def train(args: argparse.Namespace) -> dict[str, Any]:
    import gymnasium as gym
    import tqdm
    from skrl.envs.wrappers.jax import wrap_env
    from skrl.utils import set_seed

    from lmpc_scripts.method_rl import ALGOS, NumpyPolicy

    out = args.out or REPO / "runs" / "rl" / f"{args.algo}-{args.family}-s{args.seed}"
    out.mkdir(parents=True, exist_ok=True)
    seeds = tuple(range(args.seed, args.seed + args.scenes))
    kind = ALGOS[args.algo]
    set_seed(args.seed)
    t0 = time.perf_counter()
    cap = args.train_cap or None
    venv = gym.vector.AsyncVectorEnv([_make_env(args.family, seeds, kind, cap)] * args.envs,
                                     autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
                                     context="spawn")
    env = wrap_env(venv, wrapper="gymnasium")
    env._seed = args.seed  # the wrapper's first reset seeds the vector env (env i: seed + i)
    iterations = max(1, math.ceil(args.steps / env.num_envs))
    models = make_models(args.algo, env.observation_space, env.action_space, env.device)
    agent = make_agent(args.algo, models, env, iterations)
    agent.init()
    agent.enable_training_mode(True)
    curve_path = out / "curve.csv"
    returns = np.zeros(env.num_envs)
    lengths = np.zeros(env.num_envs, dtype=int)
    episodes: list[dict[str, Any]] = []
    setup_s = time.perf_counter() - t0
    env_s = 0.0  # wall time waiting for the environments (the rest: the agent, skrl)
    t1 = time.perf_counter()
    with curve_path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=CURVE_FIELDS)
        writer.writeheader()
        obs, _ = env.reset()
        bar = tqdm.tqdm(total=iterations * env.num_envs, unit="step", disable=args.no_progress,
                        file=sys.stderr)
        try:
            for t in range(iterations):
                agent.pre_interaction(timestep=t, timesteps=iterations)
                actions, _ = agent.act(obs, None, timestep=t, timesteps=iterations)
                t_env = time.perf_counter()
                next_obs, rewards, terminated, truncated, info = env.step(actions)
                env_s += time.perf_counter() - t_env
                done = (np.asarray(terminated).reshape(-1)
                        | np.asarray(truncated).reshape(-1)).astype(bool)
                agent.record_transition(
                    observations=obs, states=None, actions=actions, rewards=rewards,
                    next_observations=_stored_next(next_obs, info, done),
                    next_states=None, terminated=terminated, truncated=truncated, infos=info,
                    timestep=t, timesteps=iterations)
                agent.post_interaction(timestep=t, timesteps=iterations)
                obs = next_obs
                r = np.asarray(rewards).reshape(-1)
                returns += r
                lengths += 1
                for i, last in _episode_ends(info, done):
                    metrics = last.get("metrics") or {}
                    row = {"episode": len(episodes) + 1,
                           "total_steps": (t + 1) * env.num_envs,
                           "wall_s": round(time.perf_counter() - t1, 2),
                           "return": round(float(returns[i]), 4), "length": int(lengths[i]),
                           "outcome": last.get("outcome", ""),
                           # a capped episode has no O.C. (its metrics are those so far)
                           "overall_cost": (math.nan if last.get("outcome") == "cap" else
                                            round(float(metrics.get("overall_cost", math.nan)),
                                                  4)),
                           "scene_seed": last.get("scene_seed", "")}
                    writer.writerow(row)
                    fh.flush()
                    episodes.append(row)
                    returns[i], lengths[i] = 0.0, 0
                bar.update(env.num_envs)
                if episodes:
                    recent = episodes[-20:]
                    bar.set_postfix(episodes=len(episodes),
                                    ret=f"{np.mean([e['return'] for e in recent]):.1f}")
        finally:
            bar.close()
            venv.close()
    wall = time.perf_counter() - t1
    steps = iterations * env.num_envs
    prov = {
        "algo": args.algo, "family": args.family, "seed": args.seed,
        "scene_seeds": f"{seeds[0]}-{seeds[-1]}", "steps": steps, "envs": args.envs,
        "train_cap": cap,
        "episodes": len(episodes), "train_wall_s": round(wall, 1),
        "setup_wall_s": round(setup_s, 1), "steps_per_s": round(steps / wall, 1),
        "env_wall_s": round(env_s, 1), "agent_wall_s": round(wall - env_s, 1),
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
        "commit": _git_commit(), "versions": _versions(), "hidden": list(HIDDEN),
        "k_agents": None, "action": kind,
        "reward_scale": DQN_REWARD_SCALE if args.algo == "dqn" else 1.0,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    from lmpc_bridge.rl_obs import DEFAULT_K_AGENTS

    prov["k_agents"] = DEFAULT_K_AGENTS
    policy = NumpyPolicy(algo=args.algo, layers=tuple(policy_layers(args.algo, agent)),
                         meta=prov)
    if args.eval_scenes:
        held_out = tuple(range(seeds[-1] + 1, seeds[-1] + 1 + args.eval_scenes))
        t2 = time.perf_counter()
        prov.update(evaluate(policy, args.family, held_out, out / "eval.csv"))
        prov["eval_wall_s"] = round(time.perf_counter() - t2, 1)
        policy = NumpyPolicy(algo=args.algo, layers=policy.layers, meta=prov)
    write_png(curve_path, out / "curve.png",
              f"{args.algo.upper()} on {args.family}: {steps} steps, {args.envs} envs",
              {f"held-out mean, {d}": prov[f"eval_{d}_return"] for d in ("policy", "mpc")
               if f"eval_{d}_return" in prov})
    policy.save(out / "policy.npz")
    (out / "provenance.json").write_text(json.dumps(prov, indent=2) + "\n")
    if args.install:
        dest = REPO / "policies" / f"{args.algo}-{args.family}.npz"
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(out / "policy.npz", dest)
        prov["installed"] = str(dest.relative_to(REPO))
    prov["out"] = str(out)
    return prov


def main(argv: Optional[list[str]] = None) -> int:
    args = parse_args(argv)
    problem = check_args(args)
    if problem is not None:
        print(f"train_rl: {problem}", file=sys.stderr)
        return 2
    try:
        import gymnasium  # noqa: F401
        import skrl  # noqa: F401
    except ImportError as exc:
        print(f"train_rl: {exc.name} is not installed: pip install -e '.[rl]'", file=sys.stderr)
        return 2
    prov = train(args)
    print(f"{prov['algo']} {prov['family']}: {prov['steps']} steps in {prov['train_wall_s']} s "
          f"({prov['steps_per_s']} steps/s, {prov['envs']} envs; {prov['env_wall_s']} s in "
          f"the envs), {prov['episodes']} episodes; "
          f"policy {prov['out']}/policy.npz")
    if "eval_policy_oc" in prov:
        n = args.eval_scenes
        print(f"held-out scenes {prov['eval_seeds']}: policy reached {prov['eval_policy_reached']}"
              f"/{n}, mean O.C. {prov['eval_policy_oc']}, return {prov['eval_policy_return']}; "
              f"mpc reached {prov['eval_mpc_reached']}/{n}, mean O.C. {prov['eval_mpc_oc']}, "
              f"return {prov['eval_mpc_return']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
