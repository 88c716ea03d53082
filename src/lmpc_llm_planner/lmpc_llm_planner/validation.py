"""Parse and check a backend reply, then translate it into ``lmpc_msgs_py.Decision``.

Parsing refuses, each with its own error kind (RELIABILITY.md):
``empty``, ``too_long``, ``fenced`` (a Markdown code fence), ``prose`` (text around
the object), ``multiple_objects``, ``invalid_json`` (incl. truncated), ``non_finite``
(NaN / Infinity / 1e309), ``not_object``, ``missing_field``, ``unknown_field``,
``wrong_type``, ``unknown_agent`` (an id not offered in the prompt),
``out_of_range`` (an index outside the configured lists or the candidates actually
offered), ``no_lane`` (an ego candidate that follows no lane).

Translation turns the chosen candidates' indices into their control points; the
interval indices and weight levels stay choices of the decision space (the Decision
carries its hash), the MPC turns them into numbers (``lmpc_msgs_py.vocabulary``).
The safety floor then keeps close / low-TTC agents attended.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Literal, Optional, Sequence

import numpy as np
from lmpc_mpc.closeness import must_attend
from lmpc_mpc.reference import Candidate, bezier_points, closest_heading
from pydantic import ValidationError

from lmpc_msgs_py.messages import AgentPrediction, BezierTrajectory, Decision, WeightLevels
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.backends.base import DecisionRequest
from lmpc_llm_planner.scene import Scene, agent_candidates
from lmpc_llm_planner.schema import (
    ActionGuidance,
    EmergencyDecision,
    LlmDecision,
    ScenarioEncoding,
    WeightAdjustment,
    wire_model_for,
)

ParseErrorKind = Literal[
    "empty", "too_long", "fenced", "prose", "multiple_objects", "invalid_json", "non_finite",
    "not_object", "missing_field", "unknown_field", "wrong_type", "unknown_agent",
    "out_of_range", "no_lane",
]
DEFAULT_MAX_CHARS = 32000
MAX_ATTENTION = 200
"""``Decision.attention`` holds at most this many ids."""


@dataclass(frozen=True)
class ParseResult:
    """A validated wire object, or the error kind and a message fit for a re-ask."""

    wire: Optional[Any] = None
    """The validated model (type per mode / stage, see ``schema.wire_model_for``)."""
    error_kind: Optional[ParseErrorKind] = None
    message: str = ""

    @property
    def success(self) -> bool:
        return self.error_kind is None


class _Refused(Exception):
    def __init__(self, kind: ParseErrorKind, message: str) -> None:
        super().__init__(message)
        self.kind = kind
        self.message = message


def _no_constants(name: str) -> float:
    raise _Refused("non_finite", f"non-finite number {name} is not allowed")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _Refused("non_finite", f"number {text} overflows to infinity")
    return value


def _load_one_object(raw: str, *, max_chars: int) -> dict[str, Any]:
    if not isinstance(raw, str) or not raw.strip():
        raise _Refused("empty", "the reply is empty; answer with one JSON object")
    if len(raw) > max_chars:
        raise _Refused("too_long", f"the reply has {len(raw)} characters (limit {max_chars})")
    text = raw.strip()
    if "```" in text:
        raise _Refused("fenced", "no Markdown code fences: answer with the bare JSON object")
    if not text.startswith("{"):
        raise _Refused("prose", "text before the JSON object: answer with the object only")
    decoder = json.JSONDecoder(parse_constant=_no_constants, parse_float=_finite_float)
    try:
        obj, end = decoder.raw_decode(text)
    except json.JSONDecodeError as exc:
        raise _Refused("invalid_json", f"not valid JSON ({exc.msg} at char {exc.pos})") from None
    rest = text[end:].strip()
    if rest.startswith("{"):
        raise _Refused("multiple_objects", "more than one JSON object: answer with exactly one")
    if rest:
        raise _Refused("prose", "text after the JSON object: answer with the object only")
    if not isinstance(obj, dict):
        raise _Refused("not_object", f"expected a JSON object, got {type(obj).__name__}")
    return obj


def _schema_refusal(exc: ValidationError) -> _Refused:
    err = exc.errors(include_url=False)[0]
    loc = ".".join(str(p) for p in err["loc"]) or "<object>"
    kind = err["type"]
    more = exc.error_count() - 1
    tail = f" (+{more} more)" if more else ""
    if kind == "missing":
        return _Refused("missing_field", f"field '{loc}' is missing{tail}")
    if kind == "extra_forbidden":
        return _Refused("unknown_field", f"field '{loc}' is not part of the schema{tail}")
    if kind in ("less_than_equal", "greater_than_equal", "less_than", "greater_than"):
        return _Refused("out_of_range", f"field '{loc}': {err['msg']}{tail}")
    return _Refused("wrong_type", f"field '{loc}': {err['msg']}{tail}")


def _check_encoding(enc: ScenarioEncoding, scene: Scene) -> None:
    offered = set(scene.agent_ids)
    for agent_id in list(enc.attention) + list(enc.agent_trajectories):
        if agent_id not in offered:
            raise _Refused(
                "unknown_agent",
                f"agent id {agent_id!r} was not offered; use only ids from the prompt",
            )
    n_ego = len(scene.ego_candidates)
    if enc.ego_trajectory >= n_ego:
        raise _Refused(
            "out_of_range",
            f"ego_trajectory {enc.ego_trajectory} out of range 0..{n_ego - 1}",
        )
    if not scene.ego_candidates[enc.ego_trajectory].lane_ids:
        raise _Refused("no_lane", f"ego candidate {enc.ego_trajectory} follows no lane")
    for agent_id, idx in enc.agent_trajectories.items():
        view = scene.agent(agent_id)
        n = len(view.candidates) if view else 0
        if idx >= n:
            raise _Refused(
                "out_of_range", f"agent_trajectories[{agent_id!r}] {idx} out of range 0..{n - 1}"
            )


def _check_guidance(guide: ActionGuidance, request: DecisionRequest) -> None:
    n_a, n_s = len(request.accel_intervals_mps2), len(request.steer_intervals_rad)
    if guide.accel_interval >= n_a:
        raise _Refused(
            "out_of_range", f"accel_interval {guide.accel_interval} out of range 0..{n_a - 1}"
        )
    if guide.steer_interval >= n_s:
        raise _Refused(
            "out_of_range", f"steer_interval {guide.steer_interval} out of range 0..{n_s - 1}"
        )


def parse_decision(
    raw_text: str, *, request: DecisionRequest, max_chars: int = DEFAULT_MAX_CHARS
) -> ParseResult:
    """Parse ``raw_text`` as the reply to ``request``; never raises on the text.

    The expected model depends on the request's mode and stage
    (``schema.wire_model_for``); indices are checked against the lists and the
    candidates the request actually offered.
    """
    model = wire_model_for(mode=request.mode, stage=request.stage)
    try:
        obj = _load_one_object(raw_text, max_chars=max_chars)
        try:
            wire = model.model_validate(obj)
        except ValidationError as exc:
            raise _schema_refusal(exc) from None
        enc = getattr(wire, "scenario_encoding", None)
        if enc is not None:
            _check_encoding(enc, request.scene)
        guide = getattr(wire, "action_guidance", None)
        if guide is not None:
            _check_guidance(guide, request)
    except _Refused as ref:
        return ParseResult(error_kind=ref.kind, message=ref.message)
    except RecursionError:
        return ParseResult(error_kind="invalid_json", message="JSON nested too deeply")
    return ParseResult(wire=wire)


def merge_stages(answers: Sequence[Any]) -> LlmDecision | EmergencyDecision:
    """Join chained-stage answers into one decision (emergency: no scenario encoding)."""
    parts: dict[str, Any] = {}
    reasons = []
    for ans in answers:
        reasons.append(ans.reasoning.strip())
        for key in ("scenario_encoding", "action_guidance", "weight_adjustment"):
            if hasattr(ans, key):
                parts[key] = getattr(ans, key)
    reasoning = " ".join(r for r in reasons if r)[:8000]
    if "scenario_encoding" in parts:
        return LlmDecision(reasoning=reasoning, **parts)
    return EmergencyDecision(reasoning=reasoning, **parts)


@dataclass(frozen=True)
class DecisionMeta:
    """Bookkeeping fields of a translated decision."""

    decision_id: str
    seq: int
    source: str
    mode: Literal["normal", "emergency"]
    latency_s: float
    tokens_in: int
    tokens_out: int
    ttl_s: float


def to_trajectory(cand: Candidate, candidate_id: int) -> BezierTrajectory:
    """A candidate as the message's Bezier trajectory."""
    return BezierTrajectory(
        candidate_id=candidate_id,
        control_points=tuple((float(x), float(y)) for x, y in cand.control_points),
        label=cand.label[:120],
    )


KEEP_TRAJECTORY_OFF_M = 3.0
"""An emergency answer keeps the previous decision's ego trajectory while the ego is
within this distance of that curve ..."""
KEEP_DEVIATION_M = 1.5
"""... and that curve leaves the current route candidate by more than this (a lane
change or swerve under way); a previous decision that followed the route gives way to
the route candidate from the current pose."""


def translate(
    wire: LlmDecision | EmergencyDecision,
    *,
    scene: Scene,
    space: DecisionSpace,
    meta: DecisionMeta,
    previous: Optional[Decision] = None,
) -> Decision:
    """Turn a validated wire decision into a ``Decision`` of ``space`` (indices and
    levels, checked against the space, and its hash; the MPC turns them into numbers).

    An emergency answer has no scenario encoding (the paper's fast path skips that
    stage): the ego follows its route candidate, except that a deviation from the route
    chosen by ``previous`` (the last decision: a lane change, a swerve) that the ego is
    still on is kept (``_keeps_deviation``); a fallback passes no ``previous``. Every
    offered agent is attended with its closest-heading prediction (the baseline
    observation). Taking the route candidate mid-lane-change pulled the ego back towards
    the lane it left (eoa seed 3: it stopped across both lanes and was hit); keeping a
    route-following curve instead of the fresh route candidate made the ego take a
    right turn too wide (examples/city.yaml).
    """
    enc = getattr(wire, "scenario_encoding", None)
    kept: Optional[BezierTrajectory] = None
    if enc is None:
        ego_idx = scene.route_candidate_id
        if previous is not None and _keeps_deviation(previous.ego_trajectory, scene):
            kept = previous.ego_trajectory
        attention = list(scene.agent_ids)
        chosen: dict[str, int] = {}
    else:
        ego_idx = enc.ego_trajectory
        attention = list(dict.fromkeys(enc.attention))  # drop repeats, keep order
        chosen = dict(enc.agent_trajectories)
    predictions = []
    for agent_id in attention:
        view = scene.agent(agent_id)
        if view is None:
            continue
        idx = chosen.get(agent_id, view.closest_heading_id)
        predictions.append(
            AgentPrediction(agent_id=agent_id, trajectory=to_trajectory(view.candidates[idx], idx))
        )
    guide: ActionGuidance = wire.action_guidance
    space.bias_for(guide.accel_interval, guide.steer_interval)  # IndexError if out of range
    weights: WeightAdjustment = wire.weight_adjustment
    return Decision(
        stamp_s=scene.obs.stamp_s,
        seq=meta.seq,
        decision_id=meta.decision_id,
        source=meta.source,
        mode=meta.mode,
        latency_s=meta.latency_s,
        tokens_in=meta.tokens_in,
        tokens_out=meta.tokens_out,
        ttl_s=meta.ttl_s,
        ego_trajectory=kept if kept is not None else to_trajectory(
            scene.ego_candidates[ego_idx], ego_idx),
        agent_predictions=tuple(predictions),
        attention=tuple(attention),
        accel_interval=guide.accel_interval,
        steer_interval=guide.steer_interval,
        weights=WeightLevels(**weights.model_dump()),
        space_hash=space.space_hash,
        reasoning=wire.reasoning[:8000],
    )


def _keeps_deviation(traj: BezierTrajectory, scene: Scene) -> bool:
    """The ego is within ``KEEP_TRAJECTORY_OFF_M`` of the curve, not past its end, and
    the curve's rest leaves the route candidate by more than ``KEEP_DEVIATION_M``."""
    pts = bezier_points(traj.control_points, 100)
    ego = scene.obs.ego
    d = np.hypot(pts[:, 0] - ego.x_m, pts[:, 1] - ego.y_m)
    i = int(np.argmin(d))
    if d[i] > KEEP_TRAJECTORY_OFF_M or i >= len(pts) - 1 or not scene.ego_candidates:
        return False
    route = scene.ego_candidates[scene.route_candidate_id].sample(200)
    rest = pts[i:]
    off = np.min(np.hypot(rest[:, None, 0] - route[None, :, 0],
                          rest[:, None, 1] - route[None, :, 1]), axis=1)
    if not np.max(off) > KEEP_DEVIATION_M:
        return False
    # A curve that runs along a candidate leaving the route (``Scene.leaving_ids``) is no
    # manoeuvre worth keeping: it is an older route candidate that, seen from nearer the
    # junction, turns out to be the wrong lane's junction choice (issue 21: kept by two
    # emergency answers, it took the ego straight on past its turn, off its route).
    return _nearest_candidate(rest, scene) not in scene.leaving_ids


def _nearest_candidate(pts: np.ndarray, scene: Scene) -> int:
    """The offered ego candidate nearest to the (M, 2) curve ``pts`` (mean distance of
    the curve's points to the candidate's samples)."""
    best, best_d = scene.route_candidate_id, math.inf
    for c in scene.ego_candidates:
        s = c.sample(200)
        d = float(np.mean(np.min(np.hypot(pts[:, None, 0] - s[None, :, 0],
                                          pts[:, None, 1] - s[None, :, 1]), axis=1)))
        if d < best_d:
            best, best_d = c.candidate_id, d
    return best


@dataclass(frozen=True)
class FloorResult:
    decision: Decision
    added: tuple[str, ...]
    """Agents the floor added to the attention mask."""


def apply_safety_floor(
    decision: Decision, *, scene: Scene, ttc_s: float, dist_m: float, lookahead_m: float,
    reach_s: float = 0.0,
) -> FloorResult:
    """Keep every agent attended that ``lmpc_mpc.closeness.must_attend`` names: closer
    than ``dist_m`` plus what it and the ego drive in ``reach_s``, or closing in within
    ``ttc_s`` (range-rate TTC, no collision-course test).

    Added agents get their closest-heading prediction. This is the guard that holds
    whatever the backend says (an LLM may drop a car that matters).
    """
    attended = set(decision.attention)
    added_ids: list[str] = []
    preds = list(decision.agent_predictions)
    for kin in scene.all_kinematics:
        if kin.agent.id in attended:
            continue
        if len(attended) >= MAX_ATTENTION:
            break  # the message holds at most 200; nearest first, so the closest are in
        if not must_attend(kin, ego_v_mps=scene.obs.ego.v_mps, agent_v_mps=kin.agent.v_mps,
                           ttc_s=ttc_s, dist_m=dist_m, reach_s=reach_s):
            continue
        view = scene.agent(kin.agent.id)
        cands = view.candidates if view else agent_candidates(
            scene.obs, kin.agent, lookahead_m=lookahead_m
        )
        best = closest_heading(list(cands), kin.agent.yaw_rad)
        preds.append(
            AgentPrediction(
                agent_id=kin.agent.id, trajectory=to_trajectory(best, best.candidate_id)
            )
        )
        added_ids.append(kin.agent.id)
        attended.add(kin.agent.id)
    if not added_ids:
        return FloorResult(decision=decision, added=())
    new = decision.model_copy(
        update={
            "attention": decision.attention + tuple(added_ids),
            "agent_predictions": tuple(preds),
        }
    )
    # model_copy skips validation: re-validate so the floor can never emit a bad message.
    return FloorResult(decision=Decision.model_validate(new.model_dump()), added=tuple(added_ids))
