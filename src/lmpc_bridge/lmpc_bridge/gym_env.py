"""A Gymnasium environment over the benchmark's in-process episode (docs/RL.md).

``LmpcDrivingEnv(family=..., seeds=...)`` runs the same scenes, seeds, metrics and 10 Hz
step as ``benchmark.py``: one ``env.step`` is one ``Episode`` step, the agent in the
planner's place (it sees observation k and its decision can steer control k + 1, the
timing rule of docs/ARCHITECTURE.md). The MPC stays the controller; the action's
meaning is the composition root's (``lmpc_scripts.method_rl``: discrete for DQN,
continuous for PPO / SAC). The neutral action sends no decision: the episode is then the
``mpc`` method's to the last digit (``test/test_gym_env.py``).

Reward (the same for every algorithm): minus the per-step increments of the paper's
O.C. terms, a progress term and a collision penalty (``step_reward``; docs/RL.md).

Needs gymnasium (the ``rl`` extra); ``import lmpc_bridge`` does not import this module.
libsumo runs one simulation per process: one environment per process (vectorise with
``gymnasium.vector.AsyncVectorEnv``).
"""
from __future__ import annotations

import importlib
import math
import tempfile
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import gymnasium as gym
import numpy as np

from lmpc_bridge.metrics import W_ACC, W_DIST, W_TIME, step_ineff, step_pen_acc, step_pen_dist
from lmpc_bridge.rl_obs import DEFAULT_K_AGENTS, CLIP, RouteFrame, obs_size, \
    observation_vector

FAILURE_PENALTY = W_TIME * 200.0
"""A collision or leaving the route costs what the O.C.'s time term charges a timeout
(1.5 x 200 s = 300)."""
RESET_TRIES = 8
"""A scene SUMO cannot start (e.g. si/10086: the ego's insertion is blocked, a ``SimError``
the benchmark records as an ``error`` row) is skipped at reset: another of ``seeds`` is
drawn, up to this many times."""
ROUTE_SPEED_MPS = 13.89
"""The speed the progress term prices distance at (50 km/h, the oracle's cap)."""

_SIM: Any = None  # one SumoSim per process (libsumo)


def step_reward(step: Any, *, dist_before_m: float, dist_after_m: float, n_est: float,
                dt_s: float, outcome: str) -> float:
    """One step's reward (docs/RL.md): minus the step's share of the O.C.
    (``ineff + 15 pen_acc + 20 pen_dist`` of the step over the episode's estimated steps
    ``n_est``, plus ``1.5 dt`` of time), plus the progress ``1.5 (d_before - d_after) /
    ROUTE_SPEED_MPS``, minus ``FAILURE_PENALTY`` on a collision or off-route end."""
    pen = step_ineff(step) + W_ACC * step_pen_acc(step) + W_DIST * step_pen_dist(step)
    reward = -pen / max(n_est, 1.0) - W_TIME * dt_s
    reward += W_TIME * (dist_before_m - dist_after_m) / ROUTE_SPEED_MPS
    if outcome in ("collision", "off_route", "error"):
        reward -= FAILURE_PENALTY
    return float(reward)


def _composition_root(name: str) -> Any:
    """``lmpc_scripts.<name>``, imported by name: the bridge knows neither the planner nor
    the MPC, the composition root (scripts/) wires them."""
    return importlib.import_module(f"lmpc_scripts.{name}")


def _default_wiring(kind: str) -> tuple[Any, Callable[[], Any]]:
    planner = _composition_root("method_rl").ActionPlanner(kind)
    return planner, _composition_root("methods").make_controller


class LmpcDrivingEnv(gym.Env):
    """One family's scenes as a Gymnasium environment (see the module docstring).

    ``seeds``: the scene seeds an episode is drawn from (``reset(seed=s)`` draws with
    ``s``, so equal seeds give equal episodes; ``options={"scene_seed": n}`` picks one).
    ``action``: ``discrete`` (9 actions) or ``continuous`` (Box [-1, 1]^2).
    ``wiring(kind)``: (action planner, controller factory, called at each reset); the
    default is ``lmpc_scripts.method_rl.ActionPlanner`` and the benchmark's MPC
    (``methods.make_controller``: a fresh controller, no warm start carried over).
    ``train_cap``: for training only, end (``truncated``, outcome ``"cap"``) an episode
    still running after ``train_cap`` x its estimated steps (``n_est``, the steps to the
    target at ``ROUTE_SPEED_MPS``), so an exploring policy that stands costs a few hundred
    steps instead of the 200 s cap's 2 000; no penalty on that step (a truncation: the
    learner bootstraps from the last observation). ``None``: only ``max_time_s``."""

    metadata = {"render_modes": []}

    def __init__(self, family: str = "usi", seeds: Sequence[int] = (10000,), *,
                 action: str = "discrete", k_agents: int = DEFAULT_K_AGENTS,
                 max_time_s: float = 200.0, train_cap: Optional[float] = None,
                 work_dir: Optional[Path] = None,
                 wiring: Optional[Callable[[str], tuple[Any, Callable[[], Any]]]] = None
                 ) -> None:
        from lmpc_bridge.scenarios import families

        if family not in families():
            raise ValueError(f"unknown family {family!r}; choose from {', '.join(families())}")
        if not seeds:
            raise ValueError("seeds: give at least one scene seed")
        if action not in ("discrete", "continuous"):
            raise ValueError(f"action must be discrete or continuous, got {action!r}")
        if train_cap is not None and not train_cap > 0:
            raise ValueError(f"train_cap must be a positive multiple of the estimated steps, "
                             f"got {train_cap!r}")
        self.train_cap = train_cap
        self.family, self.seeds = family, tuple(int(s) for s in seeds)
        self.kind, self.k_agents, self.max_time_s = action, k_agents, max_time_s
        self.observation_space = gym.spaces.Box(-CLIP, CLIP, (obs_size(k_agents),), np.float32)
        self.action_space: gym.Space[Any] = (
            gym.spaces.Discrete(9) if action == "discrete"
            else gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self._work_dir = work_dir
        self._planner, self._make_controller = (wiring or _default_wiring)(action)
        self.episode: Any = None
        self.scene_seed: Optional[int] = None
        self._geometry = RouteFrame()
        self._obs: Any = None
        self._n_est = 1.0
        self._cap_steps: Optional[int] = None

    # -- gymnasium ----------------------------------------------------------------------------
    def reset(self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        global _SIM
        from lmpc_bridge.episode import Episode
        from lmpc_bridge.sim import SimError, SumoSim

        super().reset(seed=seed)
        pinned = bool(options and "scene_seed" in options)
        if _SIM is None:
            work = self._work_dir or Path(tempfile.mkdtemp(prefix="lmpc-gym-"))
            _SIM = SumoSim(work_dir=work)
        skipped: list[int] = []
        for attempt in range(RESET_TRIES):
            if pinned:
                scene_seed = int(options["scene_seed"])  # type: ignore[index]
            else:
                scene_seed = self.seeds[int(self.np_random.integers(len(self.seeds)))]
            self.scene_seed = scene_seed
            self.episode = Episode(_SIM, family=self.family, seed=scene_seed,
                                   controller=self._make_controller(), planner=None,
                                   max_time_s=self.max_time_s)
            try:
                self.episode.start()
                break
            except SimError as exc:
                # a scene SUMO cannot start: pinned, the caller's problem; else draw again
                if pinned or attempt == RESET_TRIES - 1:
                    self.episode = None
                    skip = f" (skipped before: {skipped})" if skipped else ""
                    raise SimError(f"{exc}{skip}") from None
                skipped.append(scene_seed)
        self._geometry = RouteFrame()
        self._obs = self.episode.begin_step()
        speed = ROUTE_SPEED_MPS
        self._n_est = self._obs.ego.dist_to_target_m / speed / _SIM.dt_s + 1.0
        self._cap_steps = (None if self.train_cap is None
                           else max(1, math.ceil(self.train_cap * self._n_est)))
        return self._vector(), {"scene_seed": scene_seed, "family": self.family,
                                "skipped_seeds": skipped}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        ep = self.episode
        if ep is None or ep.pending is None or self._capped():
            raise RuntimeError("step() before reset() or after the episode ended")
        self._planner.action = action
        decision = ep.ask(self._planner, self._obs)
        dist_before = self._obs.ego.dist_to_target_m
        ep.end_step(decision)
        sim = ep.sim
        outcome = sim.outcome
        running = outcome == "running"
        capped = self._capped()
        if running:
            self._obs = ep.begin_step()
            dist_after = self._obs.ego.dist_to_target_m
        else:
            dist_after = 0.0 if outcome == "reached" else dist_before
        last = sim.last_step()
        reward = step_reward(last, dist_before_m=dist_before, dist_after_m=dist_after,
                             n_est=self._n_est, dt_s=sim.dt_s, outcome=outcome)
        terminated = outcome in ("reached", "collision", "off_route", "error")
        truncated = outcome == "timeout" or capped
        info: dict[str, Any] = {"outcome": "cap" if capped else outcome,
                                "decision": decision is not None,
                                "scene_seed": self.scene_seed}
        if not running or capped:  # a capped episode's metrics are those so far
            result = ep.result()
            m = result.metrics
            info["metrics"] = {"time_s": m.time_s, "ineff": m.ineff, "pen_acc": m.pen_acc,
                               "pen_dist": m.pen_dist, "overall_cost": m.overall_cost,
                               "steps": m.steps}
        return self._vector(), reward, terminated, truncated, info

    def _capped(self) -> bool:
        """The episode still runs and has taken its ``train_cap`` share of steps."""
        sim = self.episode.sim
        return (self._cap_steps is not None and sim.outcome == "running"
                and sim.step_index >= self._cap_steps)

    def _vector(self) -> np.ndarray:
        return observation_vector(self._obs, self._geometry, self.k_agents)

    def close(self) -> None:
        if _SIM is not None:
            _SIM.close()
        super().close()


def neutral_action(env: LmpcDrivingEnv) -> Any:
    """The action that sends no decision (the MPC baseline)."""
    neutral = _composition_root("method_rl").NEUTRAL_DISCRETE
    return neutral if env.kind == "discrete" else np.zeros(2, dtype=np.float32)
