"""The learned planners (``dqn``, ``ppo``, ``sac``): an action of a policy turned into a
``Decision`` for the same tracking MPC (docs/RL.md).

The paper's RL baselines are "RL-based planning": they replace the decision maker, not
the controller. So an action here is what a reasoner's answer is: a reference candidate
and an acceleration bias (an interval of the decision space), handed to the MPC as a
``Decision`` with the baseline's scenario encoding (every offered agent attended,
closest-heading predictions) and normal weights. One decision per 10 Hz step, decided
with no latency (a network forward pass), in force for exactly the next step; the
neutral action sends no decision at all, so the MPC runs its baseline, bit for bit the
``mpc`` method.

- discrete (DQN): ``DISCRETE_ACTIONS``, {brake, keep, accelerate} x {keep lane, left,
  right}; keep lane is the route candidate, left / right the candidate that starts in
  the neighbour lane (the route candidate when there is none);
- continuous (PPO, SAC): (acceleration bias, lateral reference offset) in [-1, 1]^2,
  scaled by ``ACCEL_SCALE_MPS2`` and ``OFFSET_SCALE_M``; the bias becomes the decision
  space interval that contains it (the MPC only takes indices), the offset shifts the
  route candidate's control points sideways (left positive).

``build`` (the methods ``dqn`` / ``ppo`` / ``sac``) loads a saved policy
(``policy_path``) and drives with it; ``lmpc_bridge.gym_env`` sets the action itself.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Optional, Sequence

import numpy as np

from lmpc_bridge.evaluation.scenes import SceneSpec, Wiring
from lmpc_bridge.rl_obs import DEFAULT_K_AGENTS, RouteFrame, observation_vector
from lmpc_msgs_py.messages import BezierTrajectory, Decision
from lmpc_msgs_py.observation import Observation

ActionKind = Literal["discrete", "continuous"]
ALGOS: dict[str, ActionKind] = {"dqn": "discrete", "ppo": "continuous", "sac": "continuous"}

ACCEL_STEPS = ("brake", "keep", "accelerate")
LANE_STEPS = ("keep lane", "left", "right")
DISCRETE_ACTIONS: tuple[tuple[str, str], ...] = tuple(
    (a, lane) for lane in LANE_STEPS for a in ACCEL_STEPS)
"""Index -> (acceleration step, lane step)."""
NEUTRAL_DISCRETE = DISCRETE_ACTIONS.index(("keep", "keep lane"))
ACCEL_SCALE_MPS2 = 5.0
OFFSET_SCALE_M = 3.5
NEUTRAL_OFFSET_M = 0.25
"""A continuous action whose bias falls in the neutral interval and whose offset is
smaller than this sends no decision (the MPC baseline)."""
DECISION_TTL_S = 0.2
"""Effect at stamp + dt (the timing rule), ttl 2 dt: each decision steers one step."""

POLICY_DIR_ENV = "LMPC_POLICY_DIR"
DEFAULT_POLICY_DIR = Path(__file__).resolve().parent.parent / "policies"


class ActionPlanner:
    """Turns ``self.action`` (set before each step) into a decision for the MPC."""

    def __init__(self, kind: ActionKind, *, name: str = "rl") -> None:
        from lmpc_llm_planner.config import load_planner_config
        from lmpc_msgs_py.vocabulary import load_decision_space

        if kind not in ("discrete", "continuous"):
            raise ValueError(f"action kind must be discrete or continuous, got {kind!r}")
        self.kind = kind
        self.source = f"policy:{name}"
        self.config = load_planner_config()
        self.space = load_decision_space()
        self.action: Any = NEUTRAL_DISCRETE if kind == "discrete" else np.zeros(2)
        self._n = 0
        self.decisions = 0

    # -- the action's meaning ---------------------------------------------------------------
    def accel_index(self, step: str | float) -> int:
        """The decision space's interval for a discrete step or a continuous bias."""
        space = self.space
        neutral = space.neutral_accel_index
        if isinstance(step, str):
            idx = {"brake": neutral - 1, "keep": neutral, "accelerate": neutral + 1}[step]
            return int(min(max(idx, 0), len(space.accel_intervals_mps2) - 1))
        intervals = space.accel_intervals_mps2
        for i, (lo, hi) in enumerate(intervals):
            if lo <= step < hi:
                return i
        return 0 if step < intervals[0][0] else len(intervals) - 1

    def is_neutral(self, action: Any) -> bool:
        if self.kind == "discrete":
            return int(action) == NEUTRAL_DISCRETE
        a = np.asarray(action, dtype=float).reshape(-1)
        return (self.accel_index(float(a[0]) * ACCEL_SCALE_MPS2) == self.space.neutral_accel_index
                and abs(float(a[1]) * OFFSET_SCALE_M) < NEUTRAL_OFFSET_M)

    # -- the planner's contract -------------------------------------------------------------
    def on_observation(self, obs: Observation) -> Optional[Decision]:
        return self.decide(obs, self.action)

    def decide(self, obs: Observation, action: Any) -> Optional[Decision]:
        """The decision of ``action`` at ``obs`` (None: neutral, the MPC baseline)."""
        if self.is_neutral(action):
            return None
        from lmpc_llm_planner.backends.ablation import baseline_encoding
        from lmpc_llm_planner.scene import build_scene
        from lmpc_llm_planner.schema import ActionGuidance, LlmDecision, WeightAdjustment
        from lmpc_llm_planner.validation import DecisionMeta, translate

        try:
            scene = build_scene(obs, lookahead_m=self.config.lookahead_m,
                                max_agents=self.config.max_agents_in_prompt)
        except (ValueError, KeyError, IndexError):
            return None  # no candidates: the MPC keeps its baseline
        route = scene.route_candidate_id
        offset = 0.0
        if self.kind == "discrete":
            accel_step, lane_step = DISCRETE_ACTIONS[int(action)]
            accel = self.accel_index(accel_step)
            cand = route if lane_step == "keep lane" else self._neighbour(scene, lane_step)
        else:
            a = np.asarray(action, dtype=float).reshape(-1)
            accel = self.accel_index(float(np.clip(a[0], -1, 1)) * ACCEL_SCALE_MPS2)
            offset = float(np.clip(a[1], -1, 1)) * OFFSET_SCALE_M
            cand = route
        wire = LlmDecision(
            reasoning="", scenario_encoding=baseline_encoding(scene, cand),
            action_guidance=ActionGuidance(accel_interval=accel,
                                           steer_interval=self.space.neutral_steer_index),
            weight_adjustment=WeightAdjustment(tracking="normal", action="normal",
                                               smoothness="normal", safety="normal"))
        self._n += 1
        stamp_ms = int(round(obs.stamp_s * 1000.0))
        meta = DecisionMeta(decision_id=f"{stamp_ms}-p{self._n}", seq=self._n,
                            source=self.source, mode="normal", latency_s=0.0, tokens_in=0,
                            tokens_out=0, ttl_s=DECISION_TTL_S)
        decision = translate(wire, scene=scene, space=self.space, meta=meta)
        if offset != 0.0:
            decision = decision.model_copy(update={
                "ego_trajectory": shifted(decision.ego_trajectory, offset)})
        self.decisions += 1
        return decision

    @staticmethod
    def _neighbour(scene: Any, side: str) -> int:
        """The candidate that starts in the ego's left / right neighbour lane, else the
        route candidate."""
        here = scene.lanes.get(scene.obs.ego.lane_id or "")
        lane = None if here is None else (here.left_lane if side == "left" else here.right_lane)
        if lane is not None:
            for c in scene.ego_candidates:
                if c.lane_ids and c.lane_ids[0] == lane and c.candidate_id not in \
                        scene.leaving_ids:
                    return int(c.candidate_id)
        return int(scene.route_candidate_id)


def shifted(traj: BezierTrajectory, offset_m: float) -> BezierTrajectory:
    """``traj`` with every control point after the first moved ``offset_m`` to the left of
    the local direction (the first stays at the ego)."""
    pts = np.asarray(traj.control_points, dtype=float)
    out = [tuple(pts[0])]
    for i in range(1, len(pts)):
        d = pts[i] - pts[i - 1]
        norm = math.hypot(d[0], d[1]) or 1.0
        out.append((pts[i, 0] - d[1] / norm * offset_m, pts[i, 1] + d[0] / norm * offset_m))
    return BezierTrajectory(candidate_id=traj.candidate_id,
                            control_points=tuple((float(x), float(y)) for x, y in out),
                            label=f"{traj.label} offset {offset_m:+.1f} m"[:120])


# -- saved policies ---------------------------------------------------------------------------
@dataclass(frozen=True)
class NumpyPolicy:
    """A trained policy network as numpy arrays (Dense layers with ReLU between; the
    continuous policies end with tanh): evaluation needs neither JAX nor gymnasium."""

    algo: str
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    meta: dict[str, Any]

    @property
    def kind(self) -> ActionKind:
        return ALGOS[self.algo]

    @property
    def k_agents(self) -> int:
        return int(self.meta.get("k_agents", DEFAULT_K_AGENTS))

    def forward(self, x: np.ndarray) -> np.ndarray:
        h = np.asarray(x, dtype=np.float32)
        for i, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if i < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return h

    def act(self, x: np.ndarray) -> Any:
        """The deterministic action: argmax Q (DQN) or the mean action (PPO, SAC)."""
        out = self.forward(x)
        if self.kind == "discrete":
            return int(np.argmax(out))
        return np.tanh(out)

    def save(self, path: Path) -> None:
        arrays = {f"w{i}": w for i, (w, _) in enumerate(self.layers)}
        arrays.update({f"b{i}": b for i, (_, b) in enumerate(self.layers)})
        arrays["meta"] = np.array(json.dumps({**self.meta, "algo": self.algo}))
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:
            np.savez_compressed(fh, **arrays)


def load_policy(path: Path) -> NumpyPolicy:
    """A policy saved by ``NumpyPolicy.save``; one-line errors for a missing or bad file."""
    if not path.is_file():
        raise FileNotFoundError(
            f"no saved policy {path}: train one (scripts/train_rl.py) or point "
            f"{POLICY_DIR_ENV} at a folder holding <algo>-<family>.npz")
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            n = sum(1 for k in data.files if k.startswith("w"))
            layers = tuple((data[f"w{i}"].astype(np.float32), data[f"b{i}"].astype(np.float32))
                           for i in range(n))
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not a saved policy ({exc})") from None
    algo = meta.get("algo")
    if algo not in ALGOS:
        raise ValueError(f"{path}: unknown algorithm {algo!r} in the policy file")
    return NumpyPolicy(algo=algo, layers=layers, meta=meta)


def policy_path(algo: str, family: str, directory: Optional[Path] = None) -> Path:
    """Where the ``algo`` policy of ``family`` is: ``directory``, else ``$LMPC_POLICY_DIR``,
    else the repository's ``policies/``; file ``<algo>-<family>.npz``."""
    base = directory or Path(os.environ.get(POLICY_DIR_ENV) or DEFAULT_POLICY_DIR)
    return base / f"{algo}-{family}.npz"


class PolicyPlanner(ActionPlanner):
    """A saved policy deciding every step from the observation vector."""

    def __init__(self, policy: NumpyPolicy) -> None:
        super().__init__(policy.kind, name=policy.algo)
        self.policy = policy
        self.geometry = RouteFrame()
        self.actions: list[Any] = []

    def on_observation(self, obs: Observation) -> Optional[Decision]:
        action = self.policy.act(observation_vector(obs, self.geometry, self.policy.k_agents))
        self.actions.append(action)
        return self.decide(obs, action)


def action_counts(kind: ActionKind, actions: Sequence[Any]) -> str:
    """How often the policy chose what, for the row's note."""
    if kind == "discrete":
        counts = np.bincount(np.asarray(actions, dtype=int), minlength=len(DISCRETE_ACTIONS))
        return ", ".join(f"{a}/{lane} {c}" for (a, lane), c in zip(DISCRETE_ACTIONS, counts)
                         if c)
    arr = np.asarray(actions, dtype=float).reshape(-1, 2) if len(actions) else np.zeros((0, 2))
    if not len(arr):
        return "no steps"
    return (f"bias mean {arr[:, 0].mean() * ACCEL_SCALE_MPS2:+.2f} m/s2, offset mean "
            f"{arr[:, 1].mean() * OFFSET_SCALE_M:+.2f} m")


def build(spec: SceneSpec) -> Wiring:
    """``dqn`` / ``ppo`` / ``sac``: the saved policy of the method and the scene's family
    (``policy_path``) deciding for the MPC."""
    from lmpc_scripts import methods

    policy = load_policy(policy_path(spec.method, spec.family))
    if policy.algo != spec.method:
        raise ValueError(f"policy file for {spec.method} holds a {policy.algo} policy")
    planner = PolicyPlanner(policy)
    controller = methods.make_controller()

    def finish(log: Optional[Path]) -> dict[str, Any]:
        if log is not None:  # the MPC's stale checks go to the scene's decision log
            log.parent.mkdir(parents=True, exist_ok=True)
        cells = methods.controller_cells(controller, log)
        cells["note"] = f"{spec.method}: {planner.decisions} decisions; " + action_counts(
            policy.kind, planner.actions)
        return cells

    return Wiring(planner, controller, finish)
