"""The planner core (no ROS): when to ask, what to ask, and what to do with the answer.

``PlannerCore.on_observation`` implements the in-process contract of
docs/ARCHITECTURE.md (``PlannerLike``). Per observation it runs the rule-based
emergency pre-evaluation (TTC); it requests a decision when ``period_s`` of sim
time has passed since the last request (the first at the first observation), sooner
when the last decision's backend asked to be asked again (``BackendReply.revisit_s``:
the rules near a roundabout's yield line), or at once on an emergency (at most every
``emergency_min_interval_s``). A request builds
the prompt, calls the backend under a wall deadline, validates and translates the
reply; on a timeout, transport error or invalid output it re-asks (carrying the
error) up to ``max_retries`` times, then emits a ``fallback`` decision (baseline
behaviour). The safety floor is applied to every decision. It never raises on
backend output.

Latency (DESIGN §2 sync mode: a decision takes effect at its observation's stamp plus its
latency): the wall time of all the decision's calls, or ``fixed_latency_s``, or, for a
backend with ``reports_latency = True``, the sum of the latencies its replies report (a
replayed log's recorded latency, exactly), or a simulated reasoner's
``reported_latency_s`` (rules: 0); an emergency decision reports ``emergency_latency_s``
instead when that is set (every backend, rules included).
"""
from __future__ import annotations

import copy
import hashlib
import json
import statistics
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

from lmpc_mpc.reference import ReferencePathError

from lmpc_msgs_py.messages import Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.backends.base import Backend, BackendReply, DecisionRequest, \
    PreviousDecision
from lmpc_llm_planner.config import PlannerConfig
from lmpc_llm_planner.lookahead import predict_observation
from lmpc_llm_planner.prompt import build_prompt, estimate_tokens, sanitize_instruction
from lmpc_llm_planner.scene import Scene, agent_kinematics, build_scene
from lmpc_llm_planner.schema import (
    STAGE_ORDER,
    ActionGuidance,
    EmergencyDecision,
    Stage,
    WeightAdjustment,
    decision_json_schema,
)
from lmpc_llm_planner.validation import (
    DecisionMeta,
    apply_safety_floor,
    merge_stages,
    parse_decision,
    translate,
)

Mode = Literal["normal", "emergency"]
TIME_EPS_S = 1e-6
"""Tolerance on sim-time comparisons (stamps are k * 0.1 s in floating point)."""


@dataclass(frozen=True)
class EmergencyCheck:
    """Result of the rule-based pre-evaluation of one observation."""

    tripped: bool
    agent_id: Optional[str] = None
    ttc_s: Optional[float] = None
    gap_m: Optional[float] = None


def emergency_check(obs: Observation, config: PlannerConfig) -> EmergencyCheck:
    """TTC pre-evaluation: an agent with TTC < ``emergency_ttc_s``, or closing in with a
    gap below ``emergency_min_gap_m``, trips it (the most urgent one is named)."""
    worst: Optional[EmergencyCheck] = None
    for k in agent_kinematics(obs):
        by_ttc = k.ttc_s is not None and k.ttc_s < config.emergency_ttc_s
        by_gap = k.closing_speed_mps > 0.1 and k.gap_m < config.emergency_min_gap_m
        if not (by_ttc or by_gap):
            continue
        cand = EmergencyCheck(True, k.agent.id, k.ttc_s, k.gap_m)
        key = (cand.ttc_s if cand.ttc_s is not None else 1e9, cand.gap_m, k.agent.id)
        if worst is None or key < (
            worst.ttc_s if worst.ttc_s is not None else 1e9, worst.gap_m, worst.agent_id
        ):
            worst = cand
    return worst or EmergencyCheck(False)


@dataclass(frozen=True)
class Attempt:
    """One backend call and what became of it (for the decision log)."""

    stage: Stage
    prompt_sha256: str
    tokens_in: int
    tokens_out: int
    latency_s: float
    raw_output: Optional[str]
    error_kind: Optional[str]
    error: str
    revisit_s: Optional[float] = None
    """The reply's ``BackendReply.revisit_s`` (replayed from the log)."""


@dataclass
class PlannerCounters:
    """What happened so far; exposed on the node's status and diagnostics."""

    requests: int = 0
    decisions: int = 0
    fallbacks: int = 0
    emergencies: int = 0
    backend_calls: int = 0
    retries: int = 0
    floor_additions: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    """By error kind: timeout, transport, prose, fenced, unknown_agent, ..., scene, log."""

    def as_dict(self) -> dict[str, int]:
        out = {
            "requests": self.requests, "decisions": self.decisions, "fallbacks": self.fallbacks,
            "emergencies": self.emergencies, "backend_calls": self.backend_calls,
            "retries": self.retries, "floor_additions": self.floor_additions,
        }
        out.update({f"error:{k}": v for k, v in sorted(self.errors.items())})
        return out


@dataclass(frozen=True)
class PlannerSnapshot:
    """``PlannerCore.snapshot``: its own state and the decision log's length (bytes)."""

    state: dict
    log_bytes: Optional[int]


class _Timeout(Exception):
    pass


def _call_with_deadline(
    backend: Backend, request: DecisionRequest, deadline_s: float
) -> BackendReply:
    """Call the backend in a daemon thread; a reply later than the deadline is discarded.

    A hung call leaves its thread behind (daemon, so it never blocks exit) — the
    price of not trusting a backend to honour its own timeout.
    """
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box["reply"] = backend.complete(request)
        except Exception as exc:  # noqa: BLE001 - any backend fault is a transport error
            box["error"] = f"{type(exc).__name__}: {exc}"

    t0 = time.perf_counter()
    worker = threading.Thread(target=run, name="planner-backend", daemon=True)
    worker.start()
    worker.join(deadline_s)
    elapsed = time.perf_counter() - t0
    if worker.is_alive():
        return BackendReply(
            text=None, latency_s=elapsed, error_kind="timeout",
            error=f"no reply within the {deadline_s:.1f} s deadline",
        )
    if "error" in box:
        return BackendReply(text=None, latency_s=elapsed, error_kind="transport",
                            error=box["error"])
    reply = box.get("reply")
    if not isinstance(reply, BackendReply):
        return BackendReply(text=None, latency_s=elapsed, error_kind="transport",
                            error=f"backend returned {type(reply).__name__}, not BackendReply")
    if reply.ok and elapsed > deadline_s:
        return BackendReply(text=None, latency_s=elapsed, error_kind="timeout",
                            error=f"reply after {elapsed:.2f} s, deadline {deadline_s:.1f} s")
    return reply


def build_request(
    scene: Scene,
    *,
    config: PlannerConfig,
    space: DecisionSpace,
    mode: Mode = "normal",
    stage: Stage = "all",
    instruction: Optional[str] = None,
    previous: Optional[Decision] = None,
    retry_error: Optional[str] = None,
    prior_stages: Optional[dict[str, Any]] = None,
    command: Optional[str] = None,
    expected_latency_s: Optional[float] = None,
) -> DecisionRequest:
    """The request for one backend call: prompt text plus the structured inputs."""
    prompt = build_prompt(
        scene, space=space, mode=mode, stage=stage, instruction=instruction,
        previous=previous, retry_error=retry_error, prior_stages=prior_stages or None,
        chars_per_token=config.chars_per_token, command=command,
    )
    return DecisionRequest(
        prompt=prompt.text, mode=mode, scene=scene,
        accel_intervals_mps2=space.accel_intervals_mps2,
        steer_intervals_rad=space.steer_intervals_rad,
        json_schema=decision_json_schema(mode=mode, stage=stage), stage=stage,
        prior_stages=dict(prior_stages or {}), instruction=instruction,
        previous=None if previous is None else PreviousDecision.of(previous, space),
        retry_error=retry_error, tokens_estimate=prompt.tokens_estimate,
        deadline_s=config.deadline_s, expected_latency_s=expected_latency_s,
    )


class PlannerCore:
    """Decisions from observations; see the module docstring."""

    def __init__(
        self,
        config: PlannerConfig,
        backend: Backend,
        space: DecisionSpace,
        *,
        log_path: Optional[str | Path] = None,
    ) -> None:
        self.config = config
        self.backend = backend
        self.space = space
        """The decision space the planner offers and its Decisions name (by hash)."""
        self.counters = PlannerCounters()
        self.instruction: Optional[str] = None
        self.command: Optional[str] = None
        self.last_decision: Optional[Decision] = None
        self.last_emergency: EmergencyCheck = EmergencyCheck(False)
        self._t_last_request: Optional[float] = None
        self._t_last_emergency: Optional[float] = None
        self._revisit_s: Optional[float] = None
        self._n = 0
        self._ahead_s = 0.0
        self._recent_latency: dict[str, deque[float]] = {
            "normal": deque(maxlen=5), "emergency": deque(maxlen=5)}
        path = log_path if log_path is not None else config.decision_log
        self._log_path = Path(path) if path else None

    # -- branching ------------------------------------------------------------------------
    _SHARED = ("config", "backend", "space", "_log_path")

    def snapshot(self) -> "PlannerSnapshot":
        """The planner's state (cadence and emergency timers, counters, the last decision,
        recent latencies) and how long its decision log is; the backend is shared (a
        stateless reasoner such as rules; a model's state is not copied). ``restore``
        continues exactly from it (episode branching, ``lmpc_bridge.episode``)."""
        own = {k: v for k, v in self.__dict__.items() if k not in self._SHARED}
        size = None
        if self._log_path is not None and self._log_path.is_file():
            size = self._log_path.stat().st_size
        return PlannerSnapshot(copy.deepcopy(own), size)

    def restore(self, snap: "PlannerSnapshot") -> None:
        """Go back to a ``snapshot``; the decision log is cut back to its length then."""
        self.__dict__.update(copy.deepcopy(snap.state))
        if self._log_path is not None and self._log_path.is_file():
            with self._log_path.open("r+b") as fh:
                fh.truncate(snap.log_bytes or 0)

    # -- inputs ---------------------------------------------------------------------------
    def on_command(self, text: Optional[str]) -> None:
        """The coordinator's command in force for this ego, in words (None: none); an LLM
        backend reads it in its prompt (issue 18), the rules backend acts on the
        coordination's hold obstacle and speed band instead."""
        self.command = text or None

    def on_instruction(self, text: str) -> None:
        """Store the user's instruction (untrusted text: it only goes into the prompt)."""
        cleaned = sanitize_instruction(text)
        self.instruction = cleaned or None

    def due(self, obs: Observation) -> Optional[Mode]:
        """Which request (if any) this observation triggers; updates the emergency state."""
        t = obs.stamp_s
        if self._t_last_request is not None and t + TIME_EPS_S < self._t_last_request:
            # Time went backwards: a new episode (or a restarted bridge). Start afresh.
            self._t_last_request = None
            self._t_last_emergency = None
            self._revisit_s = None
        check = emergency_check(obs, self.config)
        self.last_emergency = check
        if check.tripped and (
            self._t_last_emergency is None
            or t - self._t_last_emergency >= self.config.emergency_min_interval_s - TIME_EPS_S
        ):
            return "emergency"
        period = self.config.period_s
        if self._revisit_s is not None:
            period = min(period, self._revisit_s)  # the backend asked to be asked sooner
        if self._t_last_request is None or t - self._t_last_request >= period - TIME_EPS_S:
            return "normal"
        return None

    def on_observation(self, obs: Observation) -> Optional[Decision]:
        """A new decision when one is due (see :meth:`due`), else None. Never raises on
        backend output."""
        mode = self.due(obs)
        if mode is None:
            return None
        t = obs.stamp_s
        self._t_last_request = t
        if mode == "emergency":
            self._t_last_emergency = t
            self.counters.emergencies += 1
        self.counters.requests += 1
        try:
            ahead = self._ahead_s = self.expected_latency_s(mode)
            seen = obs if ahead <= 0.0 else predict_observation(
                obs, ahead, lookahead_m=self.config.lookahead_m)
            scene = build_scene(
                seen, candidates_from=obs, lookahead_m=self.config.lookahead_m,
                max_agents=self.config.max_agents_in_prompt,
            )
        except (ReferencePathError, ValueError, KeyError, IndexError) as exc:
            # No candidates means no decision can be expressed; the MPC keeps its
            # current decision or baseline. Counted and reported, never raised.
            self.counters.errors["scene"] += 1
            self._log({"stamp_s": t, "mode": mode, "error_kind": "scene", "error": str(exc)})
            return None
        return self._decide(scene, mode)

    def expected_latency_s(self, mode: Mode) -> float:
        """How far ahead a decision requested now is decided for (``decide_for_effect_time``):
        ``latency_estimate_s`` (0 while unknown), at most ``ttl_s``; 0 when off."""
        cfg = self.config
        if not cfg.decide_for_effect_time:
            return 0.0
        estimate = self.latency_estimate_s(mode)
        return min(max(estimate or 0.0, 0.0), cfg.ttl_s)

    def latency_estimate_s(self, mode: Mode) -> Optional[float]:
        """The latency a decision requested now will have: the declared one
        (``emergency_latency_s``, ``fixed_latency_s``, a simulated backend's), else the
        median latency of the last decisions of this mode; None before the first decision
        of a backend that declares none (an LLM whose latency is not known yet)."""
        cfg = self.config
        declared = cfg.emergency_latency_s if mode == "emergency" else None
        if declared is None:
            declared = cfg.fixed_latency_s
        if declared is None and not getattr(self.backend, "reports_latency", False):
            declared = getattr(self.backend, "reported_latency_s", None)
        if declared is None:
            recent = self._recent_latency[mode]
            declared = float(statistics.median(recent)) if recent else None
        return declared

    # -- one request ----------------------------------------------------------------------
    def _next_meta(self, scene: Scene, *, source: str, mode: Mode, latency_s: float,
                   tokens_in: int, tokens_out: int) -> DecisionMeta:
        self._n += 1
        stamp_ms = int(round(scene.obs.stamp_s * 1000.0))
        reported = self.config.fixed_latency_s
        if mode == "emergency" and self.config.emergency_latency_s is not None:
            reported = self.config.emergency_latency_s  # the paper's short emergency path
        if reported is None and source == self.backend.name:
            # a simulated reasoner (rules) declares its latency: its wall time depends
            # on the machine's load and would make runs unrepeatable
            reported = getattr(self.backend, "reported_latency_s", None)
        return DecisionMeta(
            decision_id=f"{stamp_ms}-{self._n}",
            seq=self._n,
            source=source,
            mode=mode,
            latency_s=min(reported if reported is not None else latency_s, 600.0),
            tokens_in=tokens_in,
            tokens_out=tokens_out,
            ttl_s=self.config.ttl_s,
        )

    def _ask(self, scene: Scene, mode: Mode, stage: Stage, prior: dict[str, Any],
             attempts: list[Attempt]) -> Any:
        """Ask for one stage (or all) with re-asks; the validated wire object or None."""
        retry_error: Optional[str] = None
        for attempt in range(self.config.max_retries + 1):
            if attempt:
                self.counters.retries += 1
            request = build_request(
                scene, config=self.config, space=self.space, mode=mode, stage=stage,
                instruction=self.instruction, previous=self.last_decision,
                retry_error=retry_error, prior_stages=prior, command=self.command,
                expected_latency_s=self.latency_estimate_s(mode),
            )
            self.counters.backend_calls += 1
            reply = _call_with_deadline(self.backend, request, self.config.deadline_s)
            tokens_in = reply.tokens_in or request.tokens_estimate
            tokens_out = reply.tokens_out or estimate_tokens(
                reply.text or "", chars_per_token=self.config.chars_per_token
            )
            sha = hashlib.sha256(request.prompt.encode("utf-8")).hexdigest()
            kind: Optional[str]
            if not reply.ok:
                kind, msg = reply.error_kind or "transport", reply.error or "no text"
                wire = None
            else:
                parsed = parse_decision(
                    reply.text or "", request=request, max_chars=self.config.max_output_chars
                )
                kind, msg, wire = parsed.error_kind, parsed.message, parsed.wire
                if kind is not None and reply.truncated:
                    msg = (f"the answer was cut off at the output limit ({reply.tokens_out or '?'}"
                           " tokens); answer again in the compact form, with a reasoning of one "
                           f"short sentence ({msg})")
            attempts.append(Attempt(stage, sha, tokens_in, tokens_out, reply.latency_s,
                                    reply.text, kind, msg, reply.revisit_s))
            if wire is not None:
                return wire
            self.counters.errors[kind or "unknown"] += 1
            retry_error = f"{kind}: {msg}"
        return None

    def _decide(self, scene: Scene, mode: Mode) -> Decision:
        attempts: list[Attempt] = []
        t0 = time.perf_counter()
        wire: Any = None
        if self.config.stages == "single":
            wire = self._ask(scene, mode, "all", {}, attempts)
        else:
            answers: list[Any] = []
            prior: dict[str, Any] = {}
            stages = STAGE_ORDER[1:] if mode == "emergency" else STAGE_ORDER
            for stage in stages:
                ans = self._ask(scene, mode, stage, prior, attempts)
                if ans is None:
                    answers = []
                    break
                answers.append(ans)
                prior[stage] = getattr(ans, stage).model_dump()
            if answers:
                wire = merge_stages(answers)
        latency_s = time.perf_counter() - t0
        if getattr(self.backend, "reports_latency", False):
            # A backend that knows the latency better than this wall clock (replay with
            # ``latency: report``, a simulated LLM) reports it per call; their sum is the
            # decision's latency, so a replayed decision takes effect at the recorded time.
            latency_s = sum(a.latency_s for a in attempts)
        tokens_in = sum(a.tokens_in for a in attempts)
        tokens_out = sum(a.tokens_out for a in attempts)
        if wire is None:
            decision = self._fallback(scene, mode, latency_s, tokens_in, tokens_out, attempts)
        else:
            meta = self._next_meta(scene, source=self.backend.name, mode=mode,
                                   latency_s=latency_s, tokens_in=tokens_in,
                                   tokens_out=tokens_out)
            decision = translate(wire, scene=scene, space=self.space, meta=meta,
                                 previous=self.last_decision)
        floor = apply_safety_floor(
            decision, scene=scene, ttc_s=self.config.safety_floor_ttc_s,
            dist_m=self.config.safety_floor_dist_m, lookahead_m=self.config.lookahead_m,
            reach_s=self.config.safety_floor_reach_s,
        )
        decision = floor.decision
        self.counters.floor_additions += len(floor.added)
        self.counters.decisions += 1
        self.last_decision = decision
        asked = [a.revisit_s for a in attempts if a.error_kind is None and a.revisit_s]
        self._revisit_s = min(asked) if wire is not None and asked else None
        self._recent_latency[mode].append(decision.latency_s)
        self._log({
            "decision_id": decision.decision_id,
            "stamp_s": decision.stamp_s,
            "mode": mode,
            "source": decision.source,
            "latency_s": decision.latency_s,
            "measured_latency_s": latency_s,
            "decided_for_s": self._ahead_s,
            "tokens_in": tokens_in,
            "tokens_out": tokens_out,
            "floor_added": list(floor.added),
            # the user's text in force for this decision (sanitized; None: no instruction):
            # one given mid-episode shows from the first decision after it
            "instruction": self.instruction,
            # the coordinator's command in force (multi-ego runs; None: none)
            "command": self.command,
            "attempts": [a.__dict__ for a in attempts],
            "error_kind": None if wire is not None else (
                attempts[-1].error_kind if attempts else "none"
            ),
            "decision": decision.model_dump(mode="json", by_alias=True),
        })
        return decision

    def _fallback(self, scene: Scene, mode: Mode, latency_s: float, tokens_in: int,
                  tokens_out: int, attempts: list[Attempt]) -> Decision:
        """Baseline behaviour: route candidate, every offered agent attended with its
        closest-heading prediction, neutral bias, normal weights."""
        self.counters.fallbacks += 1
        reason = attempts[-1].error_kind if attempts else "no attempt"
        wire = EmergencyDecision(
            reasoning=f"Fallback (baseline behaviour) after {len(attempts)} failed call(s); "
                      f"last error: {reason}.",
            action_guidance=ActionGuidance(
                accel_interval=self.space.neutral_accel_index,
                steer_interval=self.space.neutral_steer_index,
            ),
            weight_adjustment=WeightAdjustment(
                tracking="normal", action="normal", smoothness="normal", safety="normal"
            ),
        )
        meta = self._next_meta(scene, source="fallback", mode=mode, latency_s=latency_s,
                               tokens_in=tokens_in, tokens_out=tokens_out)
        return translate(wire, scene=scene, space=self.space, meta=meta)

    # -- decision log ---------------------------------------------------------------------
    def _log(self, record: dict[str, Any]) -> None:
        if self._log_path is None:
            return
        try:
            self._log_path.parent.mkdir(parents=True, exist_ok=True)
            with self._log_path.open("a", encoding="utf-8") as fh:
                fh.write(json.dumps(record, separators=(",", ":"), default=str) + "\n")
        except OSError:
            # A full disk must not stop the car: count it, keep deciding.
            self.counters.errors["log"] += 1
