"""``lmpc-oracle``: at each planning instant, the best of a bounded set of decisions,
found by rolling each one out in the simulation itself (docs/ORACLE.md).

The planner is the rules planner's core (same cadence, same emergency trigger, same
decision latency model, same scene and candidates, same safety floor and translation);
only what it decides differs. At each instant (``PlannerCore.due``) the oracle

1. lists the options (:func:`decision_options`, at most ``max_options``): always "no
   decision" (the MPC baseline) and the rules reasoner's own answer, then reference
   candidate x acceleration bias x steering bias x weight levels, with the agents'
   attention and predictions of the baseline or of the rules reasoner (``encoding``);
2. rolls each option out for ``lookahead_s`` of sim time in a forked copy of the
   process (``Episode.fork``, :func:`score_forked`: exact branching, docs/BRANCHING.md):
   the option handed to the same MPC at this step, then no further decision, the
   scene's own traffic around it;
3. scores each rollout (:func:`window_score`): the paper's per-step penalties summed over
   the window (priced as in the O.C.), the time used plus the distance still to go at
   the route's speed priced at the O.C.'s time weight; a collision or leaving the route
   scores +inf; ties go to the earlier option (no decision first);
4. applies the best option (no decision: returns nothing); the episode itself was never
   touched by the rollouts.

Deterministic: the rollouts are exact copies of the episode (docs/BRANCHING.md), the
options are listed in a fixed order. The planner needs the episode, so it runs only
in-process (``Episode.attach_episode``).
"""
from __future__ import annotations

import dataclasses
import math
import statistics
import time
from dataclasses import dataclass
from typing import Any, Callable, Literal, Optional, Sequence

from lmpc_bridge.evaluation.scenes import SceneSpec, Wiring
from lmpc_bridge.metrics import W_ACC, W_DIST, W_TIME, step_ineff, step_pen_acc, step_pen_dist
from lmpc_llm_planner.backends.ablation import baseline_encoding
from lmpc_llm_planner.planner import PlannerCore
from lmpc_llm_planner.scene import Scene
from lmpc_llm_planner.schema import (
    ActionGuidance,
    EmergencyDecision,
    LlmDecision,
    WeightAdjustment,
)
from lmpc_llm_planner.validation import DecisionMeta, apply_safety_floor, translate
from lmpc_msgs_py.messages import Decision

from lmpc_scripts import methods

Encoding = Literal["baseline", "rules"]
Scoring = Literal["window", "episode"]
Continuation = Literal["none", "rules"]


@dataclass(frozen=True)
class OracleConfig:
    """The oracle's search (docs/ORACLE.md)."""

    lookahead_s: float = 8.0
    """Sim time each option is rolled out for."""
    max_options: int = 32
    """At most this many options per instant (no decision and the rules' answer first)."""
    encoding: Encoding = "baseline"
    """Attention and agent predictions of the options: the baseline's (every offered
    agent, closest-heading prediction) or the rules reasoner's."""
    route_speed_cap_mps: float = 13.89
    """Upper bound of the route speed the progress term prices the distance to go at."""
    scoring: Scoring = "window"
    """``window``: the window's penalties over a common estimate of the episode's steps
    plus the progress term (:func:`window_score`); ``episode``: the episode's O.C. as
    it would end with nothing more after the window (:func:`episode_score`)."""
    continuation: Continuation = "none"
    """What follows an option in its rollout: ``none``, no further decision (the option
    until it expires, then the MPC baseline); ``rules``, the rules reasoner's decisions
    at the planner's cadence (a rollout policy: a manoeuvre that needs several decisions,
    such as going round a stopped car, is seen whole). The option ``none`` stays the MPC
    baseline over the whole window and ``rules`` becomes the rules planner's own run, so
    within its window the oracle is never worse than either ``mpc`` or ``lmpc-rules``."""

    def __post_init__(self) -> None:
        if not self.lookahead_s > 0.0:
            raise ValueError(f"lookahead_s must be > 0, got {self.lookahead_s}")
        if self.max_options < 1:
            raise ValueError(f"max_options must be >= 1, got {self.max_options}")
        if self.encoding not in ("baseline", "rules"):
            raise ValueError(f"encoding must be baseline or rules, got {self.encoding!r}")
        if self.scoring not in ("window", "episode"):
            raise ValueError(f"scoring must be window or episode, got {self.scoring!r}")
        if self.continuation not in ("none", "rules"):
            raise ValueError(f"continuation must be none or rules, got {self.continuation!r}")

    @classmethod
    def from_options(cls, options: Sequence[tuple[str, Any]]) -> "OracleConfig":
        """The config of a benchmark run's method options (``SceneSpec.method_options``:
        ``lookahead_s``, ``continuation``, ...); raises ``ValueError`` naming an unknown
        option or a bad value."""
        fields = [f.name for f in dataclasses.fields(cls)]
        kwargs: dict[str, Any] = {}
        for name, value in options:
            if name not in fields:
                raise ValueError(f"lmpc-oracle has no option {name!r}; options: "
                                 f"{', '.join(fields)}")
            kwargs[name] = value
        try:
            for name in ("lookahead_s", "route_speed_cap_mps"):
                if name in kwargs:
                    kwargs[name] = float(kwargs[name])
            if "max_options" in kwargs:
                kwargs["max_options"] = int(kwargs["max_options"])
        except (TypeError, ValueError) as exc:
            raise ValueError(f"lmpc-oracle option: {exc}") from None
        return cls(**kwargs)


@dataclass(frozen=True)
class Option:
    """One choice at an instant: ``wire`` is the decision (None: no decision)."""

    name: str
    wire: Optional[LlmDecision | EmergencyDecision]


_WEIGHTS = {  # weight-level variants tried on the route candidate (name -> levels)
    "cautious": ("normal", "normal", "normal", "high"),
    "bold": ("normal", "normal", "normal", "low"),
    "tight": ("high", "normal", "normal", "normal"),
    "smooth": ("normal", "normal", "high", "normal"),
}


def decision_options(scene: Scene, *, accel_intervals: Sequence[Any],
                     steer_intervals: Sequence[Any], neutral_accel: int, neutral_steer: int,
                     rules: Optional[LlmDecision | EmergencyDecision] = None,
                     encoding: Encoding = "baseline", max_options: int = 32) -> list[Option]:
    """The options of one instant, in priority order (the list is cut at ``max_options``):

    - ``none``: no decision (the MPC baseline; always first);
    - ``rules``: the rules reasoner's answer, when there is one (at an emergency instant
      its emergency answer: route or kept deviation, baseline attention);
    - the route candidate with every acceleration interval (neutral steering, normal
      weights);
    - the route candidate, neutral bias, with each weight variant of ``_WEIGHTS``;
    - every other offered candidate that does not leave the route: neutral, the mild
      speed-up and the mild braking interval (the options take the scene's own
      candidates at an emergency instant too: the oracle is not bound to the emergency
      prompt's form);
    - the route candidate with the mild left and right steering intervals.
    """
    def wire(name: str, cand: int, accel: int, steer: int,
             levels: tuple[str, str, str, str] = ("normal",) * 4) -> Option:
        if encoding == "rules" and isinstance(rules, LlmDecision):
            enc = rules.scenario_encoding.model_copy(update={"ego_trajectory": cand})
        else:
            enc = baseline_encoding(scene, cand)
        return Option(name, LlmDecision(
            reasoning=f"oracle option {name}", scenario_encoding=enc,
            action_guidance=ActionGuidance(accel_interval=accel, steer_interval=steer),
            weight_adjustment=WeightAdjustment(tracking=levels[0], action=levels[1],
                                               smoothness=levels[2], safety=levels[3])))

    route = scene.route_candidate_id
    out = [Option("none", None)]
    if rules is not None:
        out.append(Option("rules", rules))
    for a in range(len(accel_intervals)):
        out.append(wire(f"route/a{a}", route, a, neutral_steer))
    for name, levels in _WEIGHTS.items():
        out.append(wire(f"route/{name}", route, neutral_accel, neutral_steer, levels))
    mild = [a for a in (neutral_accel, neutral_accel + 1, neutral_accel - 1)
            if 0 <= a < len(accel_intervals)]
    for c in range(len(scene.ego_candidates)):
        if c == route or c in scene.leaving_ids:
            continue
        for a in mild:
            out.append(wire(f"cand{c}/a{a}", c, a, neutral_steer))
    for s in (neutral_steer - 1, neutral_steer + 1):
        if 0 <= s < len(steer_intervals):
            out.append(wire(f"route/s{s}", route, neutral_accel, s))
    return out[:max_options]


def options_in(scene: Scene, space: Any, rules: Optional[LlmDecision | EmergencyDecision],
               oracle: "OracleConfig") -> list[Option]:
    """:func:`decision_options` of ``scene`` in the decision space ``space``
    (``lmpc_msgs_py.vocabulary.DecisionSpace``) with the search of ``oracle``."""
    return decision_options(
        scene, accel_intervals=space.accel_intervals_mps2,
        steer_intervals=space.steer_intervals_rad, neutral_accel=space.neutral_accel_index,
        neutral_steer=space.neutral_steer_index, rules=rules, encoding=oracle.encoding,
        max_options=oracle.max_options)


def route_speed_mps(obs: Any, cap_mps: float) -> float:
    """The route's speed: the length-weighted mean speed limit of its lanes, at most
    ``cap_mps`` (the distance still to go is priced at it)."""
    lanes = {ln.id: ln for ln in obs.map.lanes}
    total = weighted = 0.0
    for lane_id in obs.map.ego_route:
        ln = lanes.get(lane_id)
        if ln is None:
            continue
        length = float(ln.length_m)
        total += length
        weighted += length * ln.speed_limit_mps
    speed = weighted / total if total > 0.0 else cap_mps
    return max(min(speed, cap_mps), 1.0)


def window_score(steps: Sequence[Any], *, outcome: str, start_s: float,
                 end_dist_m: float, route_speed: float, episode_steps: float) -> float:
    """The score of one rollout (lower is better; docs/ORACLE.md).

    ``steps``: the window's step records; ``outcome``: the episode's outcome at its end;
    ``end_dist_m``: the distance to the target then; ``episode_steps``: the estimated
    number of steps of the whole episode (the O.C. averages its penalties over them).
    """
    if outcome in ("collision", "off_route", "error"):
        return math.inf
    pen = sum(step_penalty(s) for s in steps) / max(episode_steps, 1.0)
    used = (steps[-1].t_s - start_s) if steps else 0.0
    to_go = 0.0 if outcome == "reached" else end_dist_m / route_speed
    return pen + W_TIME * (used + to_go)


@dataclass(frozen=True)
class Rollout:
    """What one rollout gave: the window's step records, the outcome at its end and
    the distance to the target then (0 once the episode ended)."""

    steps: tuple[Any, ...]
    outcome: str
    end_dist_m: float


def roll_out(episode: Any, snap: Any, decision: Optional[Decision], *,
             lookahead_s: float) -> Rollout:
    """Restore ``snap`` (taken while a planner is asked, ``Episode.begin_step`` done),
    hand ``decision`` (None: none) to the controller at that step, and run
    ``lookahead_s`` of sim time with no planner. The episode is left at the window's
    end (restore ``snap`` again to go on from it). Shared by the oracle and the regret of
    a recorded run (issue 16, item 3)."""
    episode.restore(snap, planner=False)
    episode.end_step(decision)
    episode.run(until_s=snap.time_s + lookahead_s, planner=None)
    sim = episode.sim
    end = sim.observe().ego.dist_to_target_m if sim.outcome == "running" else 0.0
    return Rollout(tuple(sim.record().steps[snap.step_index:]), sim.outcome, end)


def step_penalty(step: Any) -> float:
    """One step's share of the O.C.'s penalty terms, before averaging."""
    return step_ineff(step) + W_ACC * step_pen_acc(step) + W_DIST * step_pen_dist(step)


def episode_score(steps: Sequence[Any], *, outcome: str, start_s: float, end_dist_m: float,
                  route_speed: float, before_penalty: float, before_steps: int,
                  dt_s: float) -> float:
    """The episode's O.C. if it went on from the window's end to the target at the route
    speed with no further penalty (lower is better): the penalties of the steps before
    the window (``before_penalty`` over ``before_steps``) and in it, averaged over the
    estimated number of steps, plus the time weight times the estimated time."""
    if outcome in ("collision", "off_route", "error"):
        return math.inf
    used = (steps[-1].t_s - start_s) if steps else 0.0
    to_go = 0.0 if outcome == "reached" else end_dist_m / route_speed
    total_s = start_s + used + to_go
    n = max(total_s / dt_s, float(before_steps + len(steps)), 1.0)
    return (before_penalty + sum(step_penalty(s) for s in steps)) / n + W_TIME * total_s


def oracle_meta(core: PlannerCore, scene: Scene, mode: Any, dt_s: float, *,
                commit: bool) -> DecisionMeta:
    """The bookkeeping of an oracle decision at this instant: the planner's next id (not
    taken unless ``commit``: every rollout's decision gets the id the applied one will
    get), source ``oracle``, the planner's latency model, in force until the next
    instant's decision takes effect (``period_s + max(latency, dt)``)."""
    n = core._n
    meta = core._next_meta(scene, source="oracle", mode=mode,
                           latency_s=getattr(core.backend, "reported_latency_s", 0.0),
                           tokens_in=0, tokens_out=0)
    if not commit:
        core._n = n
    return dataclasses.replace(meta, ttl_s=core.config.period_s + max(meta.latency_s, dt_s))


def option_decision(core: PlannerCore, scene: Scene, wire: LlmDecision | EmergencyDecision,
                    meta: DecisionMeta, previous: Optional[Decision]) -> Decision:
    """``wire`` as ``core`` would hand it over: translated with ``meta`` (after
    ``previous``) and the safety floor applied. Shared by the oracle and regret.py."""
    cfg = core.config
    decision = translate(wire, scene=scene, space=core.space, meta=meta, previous=previous)
    return apply_safety_floor(
        decision, scene=scene, ttc_s=cfg.safety_floor_ttc_s, dist_m=cfg.safety_floor_dist_m,
        lookahead_m=cfg.lookahead_m, reach_s=cfg.safety_floor_reach_s).decision


@dataclass(frozen=True)
class Pricing:
    """What the score of every rollout from one snapshot shares (:func:`score_rollout`)."""

    speed: float
    """The route speed the distance to go is priced at."""
    episode_steps: float
    """Estimated steps of the whole episode (``window`` scoring)."""
    before_penalty: float
    """Penalties of the steps before the snapshot (``episode`` scoring)."""
    before_steps: int
    dt_s: float

    @classmethod
    def at(cls, episode: Any, snap: Any, obs: Any, config: OracleConfig) -> "Pricing":
        """``snap``: anything with the ``step_index`` of the branch point (a snapshot,
        or the episode's ``sim`` itself for a forked branch)."""
        speed = route_speed_mps(obs, config.route_speed_cap_mps)
        dt = episode.sim.dt_s
        before = episode.sim.record().steps[:snap.step_index]
        return cls(speed=speed,
                   episode_steps=(obs.stamp_s + obs.ego.dist_to_target_m / speed) / dt + 1.0,
                   before_penalty=sum(step_penalty(s) for s in before),
                   before_steps=len(before), dt_s=dt)


def score_rollout(episode: Any, snap: Any, decision: Optional[Decision], config: OracleConfig,
                  pricing: Pricing) -> float:
    """Roll ``decision`` out from ``snap`` (:func:`roll_out`) and score it with the
    config's scoring (lower is better; +inf: collision, off route, error)."""
    r = roll_out(episode, snap, decision, lookahead_s=config.lookahead_s)
    return _score(r, snap.time_s, config, pricing)


def score_forked(episode: Any, decision: Optional[Decision], config: OracleConfig,
                 pricing: Pricing, then: Optional[Callable[[], Any]] = None) -> float:
    """:func:`score_rollout` in a forked copy of the process (``Episode.fork``), from
    the step the episode is in (``begin_step`` done, a planner being asked): no snapshot
    and no restore, so the episode here goes on exactly as if the rollout had not been
    made (regret.py; docs/BRANCHING.md). ``then``: called in the copy, gives the planner
    that decides in the rest of the window (None: none)."""
    start_s, start_step = episode.time_s, episode.sim.step_index

    def branch(ep: Any) -> float:
        ep.end_step(decision)
        ep.run(until_s=start_s + config.lookahead_s, planner=None if then is None else then())
        sim = ep.sim
        end = sim.observe().ego.dist_to_target_m if sim.outcome == "running" else 0.0
        r = Rollout(tuple(sim.record().steps[start_step:]), sim.outcome, end)
        return _score(r, start_s, config, pricing)

    return episode.fork(branch)


def _score(r: Rollout, start_s: float, config: OracleConfig, pricing: Pricing) -> float:
    if config.scoring == "episode":
        return episode_score(r.steps, outcome=r.outcome, start_s=start_s,
                             end_dist_m=r.end_dist_m, route_speed=pricing.speed,
                             before_penalty=pricing.before_penalty,
                             before_steps=pricing.before_steps, dt_s=pricing.dt_s)
    return window_score(r.steps, outcome=r.outcome, start_s=start_s,
                        end_dist_m=r.end_dist_m, route_speed=pricing.speed,
                        episode_steps=pricing.episode_steps)


class OraclePlanner(PlannerCore):
    """The planner core whose decisions are the best rolled-out option (module doc)."""

    _SHARED = PlannerCore._SHARED + ("_episode", "oracle")

    def __init__(self, *args: Any, oracle: OracleConfig = OracleConfig(), **kwargs: Any
                 ) -> None:
        super().__init__(*args, **kwargs)
        self.oracle = oracle
        self._episode: Any = None
        self.wall_s: list[float] = []
        """Wall time of each decision (its rollouts included)."""
        self.chosen: list[str] = []
        """The option chosen at each instant."""
        self._as_rules = False
        """Set only in a rollout's forked copy: decide as the rules planner does."""

    def attach_episode(self, episode: Any) -> None:
        """The episode this planner branches (``lmpc_bridge.episode.Episode.start``)."""
        self._episode = episode

    # -- one instant ------------------------------------------------------------------------
    def _decide(self, scene: Scene, mode: Any) -> Optional[Decision]:  # type: ignore[override]
        if self._as_rules:  # a rollout's continuation (OracleConfig.continuation)
            return super()._decide(scene, mode)
        if self._episode is None:
            raise RuntimeError("lmpc-oracle needs the episode (Episode.attach_episode): it "
                               "runs in-process only")
        t0 = time.perf_counter()
        attempts: list[Any] = []
        rules = self._ask(scene, mode, "all", {}, attempts)  # an emergency answer too
        options = options_in(scene, self.space, rules, self.oracle)
        ep = self._episode
        # each rollout in a forked copy of the process: the episode here is never
        # restored (a restore is exact only up to SUMO's bookkeeping outside its state
        # file, docs/BRANCHING.md)
        pricing = Pricing.at(ep, ep.sim, scene.obs, self.oracle)
        obs = scene.obs
        scores = []
        for opt in options:
            decision = None if opt.wire is None else self._decision(scene, mode, opt.wire)
            scores.append(score_forked(ep, decision, self.oracle, pricing,
                                       then=self._continuation(decision)))
        best = min(range(len(options)), key=lambda i: (scores[i], i))
        choice = options[best]
        decision = None if choice.wire is None else self._decision(
            scene, mode, choice.wire, commit=True)
        wall = time.perf_counter() - t0
        self.wall_s.append(wall)
        self.chosen.append(choice.name)
        record: dict[str, Any] = {
            "kind": "oracle", "stamp_s": obs.stamp_s, "mode": mode, "chosen": choice.name,
            "wall_s": round(wall, 4),
            "scores": {o.name: (None if math.isinf(s) else round(s, 6))
                       for o, s in zip(options, scores)},
        }
        if decision is not None:
            self.counters.decisions += 1
            self.last_decision = decision
            self._recent_latency[mode].append(decision.latency_s)
            record.update(decision_id=decision.decision_id, source=decision.source,
                          latency_s=decision.latency_s,
                          decision=decision.model_dump(mode="json", by_alias=True))
        self._log(record)
        return decision

    def _continuation(self, decision: Optional[Decision]) -> Optional[Callable[[], Any]]:
        """What decides after ``decision`` in its rollout (``OracleConfig.continuation``):
        with ``rules``, this planner in the forked copy, the option taken as its last
        decision, deciding as the rules planner from the next instant on and writing no
        log; nothing after ``none`` (the baseline stays the baseline)."""
        if self.oracle.continuation == "none" or decision is None:
            return None

        def rules_from_here() -> "OraclePlanner":
            self._as_rules = True
            continue_as_rules(self, decision)
            return self

        return rules_from_here

    def _decision(self, scene: Scene, mode: Any, wire: LlmDecision | EmergencyDecision, *,
                  commit: bool = False) -> Decision:
        """``wire`` as the planner would hand it over (translated, safety floor applied),
        in force from its latency on until the next instant's decision takes effect."""
        meta = oracle_meta(self, scene, mode, self._episode.sim.dt_s, commit=commit)
        return option_decision(self, scene, wire, meta, self.last_decision)

    def wall_summary(self) -> dict[str, float]:
        """Median / p95 / count of the decisions' wall times."""
        w = sorted(self.wall_s)
        if not w:
            return {"oracle_decisions": 0}
        return {"oracle_decisions": len(w), "oracle_wall_s_median": round(statistics.median(w), 3),
                "oracle_wall_s_p95": round(w[min(len(w) - 1, int(0.95 * len(w)))], 3)}


def continue_as_rules(core: PlannerCore, decision: Decision) -> None:
    """Make ``core``, in a rollout's forked copy, the rules planner that decides after
    ``decision`` (``OracleConfig.continuation == "rules"``; the oracle and regret.py):
    the rules backend (whatever the recorded method's), ``decision`` its last one and
    its id taken, no log written. The caller switches off its own per-instant work."""
    from lmpc_llm_planner.backends.rules import RulesBackend

    if core.backend.name != "rules":
        core.backend = RulesBackend(core.config.rules)
    core._log_path = None
    core._n = max(core._n, decision.seq)  # the option's id was taken in this copy
    core.last_decision = decision


def build(spec: SceneSpec, oracle: Optional[OracleConfig] = None) -> Wiring:
    """``lmpc-oracle``: the oracle planner on the rules planner's settings, and the MPC.
    ``oracle``: the search (default: ``spec.method_options``, e.g. from ``benchmark.py
    --oracle-lookahead-s``, over the defaults)."""
    if oracle is None:
        oracle = OracleConfig.from_options(spec.method_options)
    base = methods.make_planner("lmpc-rules", None, latency=spec.latency,
                                planner_config=spec.planner_config, backend=spec.backend)
    planner = OraclePlanner(base.config, base.backend, base.space,
                            log_path=spec.log_path, oracle=oracle)
    if spec.instruction:
        planner.on_instruction(spec.instruction)
    controller = methods.make_controller()

    def finish(log: Any) -> dict[str, Any]:
        cells = methods.controller_cells(controller, log)
        w = planner.wall_summary()
        if w["oracle_decisions"]:
            counts: dict[str, int] = {}
            for name in planner.chosen:
                counts[name] = counts.get(name, 0) + 1
            cells["note"] = (
                f"oracle ({oracle.lookahead_s:g} s window, continuation {oracle.continuation}"
                f"): {w['oracle_decisions']} instants, wall per instant median "
                f"{w['oracle_wall_s_median']} s, p95 {w['oracle_wall_s_p95']} s; chosen "
                + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
        return cells

    return Wiring(planner, controller, finish)
