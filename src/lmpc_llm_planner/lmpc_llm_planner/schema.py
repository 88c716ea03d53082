"""The decision wire format: the one JSON object an LLM (or the rules backend) answers.

Fields come in the order of the paper's cognitive pathway, after a free-text
``reasoning`` (so a model reasons before it commits):

```
{"reasoning": str,
 "scenario_encoding": {"ego_trajectory": 0-2, "attention": [agent ids],
                       "agent_trajectories": {"<agent id>": 0-2}},
 "action_guidance": {"accel_interval": int, "steer_interval": int},
 "weight_adjustment": {"tracking": "low|normal|high", "action": .., "smoothness": ..,
                       "safety": ..}}
```

The emergency variant (paper: pre-evaluated emergencies skip scenario encoding)
has no ``scenario_encoding``. In ``chained`` mode each call answers one stage:
``{"reasoning": str, "<stage>": {...}}``.

The models are strict (no extra fields, no type coercion, no NaN); the semantic
checks against a request (agent ids, index ranges) live in ``validation.py``.
:func:`decision_json_schema` gives the JSON schema for structured-output / grammar
backends.
"""
from __future__ import annotations

import copy
import json
from functools import lru_cache
from typing import Annotated, Any, Literal, Mapping, Optional

from pydantic import BaseModel, ConfigDict, Field

from lmpc_msgs_py.messages import MAX_ID_CHARS, WeightLevel

Level = WeightLevel  # the level names of the decision space's weight pool (one definition)
AgentId = Annotated[str, Field(min_length=1, max_length=MAX_ID_CHARS)]  # as the messages
CandidateIndex = Annotated[int, Field(ge=0, le=2)]
IntervalIndex = Annotated[int, Field(ge=0, le=31)]
Stage = Literal["all", "scenario_encoding", "action_guidance", "weight_adjustment"]
STAGE_ORDER: tuple[Stage, ...] = ("scenario_encoding", "action_guidance", "weight_adjustment")
MAX_REASONING_CHARS = 8000


class _Wire(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class ScenarioEncoding(_Wire):
    """Stage 1: which ego candidate to track, whom to attend, what each attended agent does."""

    ego_trajectory: CandidateIndex
    attention: list[AgentId] = Field(max_length=200)
    agent_trajectories: dict[AgentId, CandidateIndex] = Field(max_length=200)


class ActionGuidance(_Wire):
    """Stage 2: indices into the configured accel / steer interval lists (bias = midpoints)."""

    accel_interval: IntervalIndex
    steer_interval: IntervalIndex


class WeightAdjustment(_Wire):
    """Stage 3: a pool level for each of the four weight groups."""

    tracking: Level
    action: Level
    smoothness: Level
    safety: Level


class LlmDecision(_Wire):
    """The full answer of a normal (single-call) request."""

    reasoning: str = Field(max_length=MAX_REASONING_CHARS)
    scenario_encoding: ScenarioEncoding
    action_guidance: ActionGuidance
    weight_adjustment: WeightAdjustment


class EmergencyDecision(_Wire):
    """The answer of an emergency request: no scenario encoding (baseline attention)."""

    reasoning: str = Field(max_length=MAX_REASONING_CHARS)
    action_guidance: ActionGuidance
    weight_adjustment: WeightAdjustment


class ScenarioEncodingAnswer(_Wire):
    """Chained mode, stage 1."""

    reasoning: str = Field(max_length=MAX_REASONING_CHARS)
    scenario_encoding: ScenarioEncoding


class ActionGuidanceAnswer(_Wire):
    """Chained mode, stage 2."""

    reasoning: str = Field(max_length=MAX_REASONING_CHARS)
    action_guidance: ActionGuidance


class WeightAdjustmentAnswer(_Wire):
    """Chained mode, stage 3."""

    reasoning: str = Field(max_length=MAX_REASONING_CHARS)
    weight_adjustment: WeightAdjustment


WireModel = type[_Wire]


def wire_model_for(*, mode: str, stage: Stage) -> WireModel:
    """The model a reply must match for a request of this mode and stage."""
    if stage == "scenario_encoding":
        return ScenarioEncodingAnswer
    if stage == "action_guidance":
        return ActionGuidanceAnswer
    if stage == "weight_adjustment":
        return WeightAdjustmentAnswer
    return EmergencyDecision if mode == "emergency" else LlmDecision


def decision_json_schema(*, mode: str = "normal", stage: Stage = "all") -> dict[str, Any]:
    """JSON schema of the expected reply (for structured-output and grammar backends).
    A fresh copy of a schema made once per model: pydantic takes ~2 ms to make one, and
    every decision needed two (its request and its prompt's outline)."""
    return copy.deepcopy(_wire_schema(wire_model_for(mode=mode, stage=stage)))


@lru_cache(maxsize=None)
def _wire_schema(model: WireModel) -> dict[str, Any]:
    return model.model_json_schema()


def describe_schema(schema: Mapping[str, Any], defs: Optional[Mapping[str, Any]] = None, *,
                    show_limits: bool = True) -> str:
    """A short JSON-like outline of ``schema`` (fields in order, choices spelled out).

    The prompt carries this instead of the JSON schema itself (a tenth of the tokens);
    structured-output backends send the schema, grammar backends enforce it.
    ``show_limits=False`` leaves out string length caps.
    """
    defs = defs if defs is not None else (schema.get("$defs") or {})
    ref = schema.get("$ref")
    if isinstance(ref, str):
        schema = defs.get(ref.split("/")[-1], {})
    if "enum" in schema:
        return "|".join(json.dumps(v) for v in schema["enum"]) or "(none)"
    kind = schema.get("type")
    if kind == "object":
        props = schema.get("properties") or {}
        required = set(schema.get("required") or ())
        parts = [
            f"{json.dumps(k)}{'' if k in required else '?'}: "
            + describe_schema(v, defs, show_limits=show_limits)
            for k, v in props.items()
        ]
        extra = schema.get("additionalProperties")
        if isinstance(extra, dict):
            parts.append(f"<id>: {describe_schema(extra, defs, show_limits=show_limits)}")
        return "{" + ", ".join(parts) + "}"
    if kind == "array":
        if schema.get("maxItems") == 0:
            return "[]"
        items = describe_schema(schema.get("items") or {}, defs, show_limits=show_limits)
        return "[" + items + ", ...]"
    if kind == "string":
        cap = schema.get("maxLength")
        return f"string (at most {cap} characters)" if cap and show_limits else "string"
    return str(kind or "value")
