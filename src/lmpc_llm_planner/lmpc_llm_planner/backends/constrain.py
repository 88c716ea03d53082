"""The decision schema narrowed to one request, for backends that constrain their output.

``schema.decision_json_schema`` is the same for every request: ids are any string,
indices any integer up to the configured maxima. A grammar (llama.cpp) or a
structured-output server (vLLM, llama.cpp server) built from it can still answer an
agent id that was not offered or an index past the offered candidates, which
validation then refuses. :func:`narrow_schema` closes those holes for one request:

- ``ego_trajectory``: an ``enum`` of the offered ego candidates that follow a lane;
- ``attention``: items from the offered agent ids (at most that many items);
- ``agent_trajectories``: optional properties, one per offered agent, each an
  ``enum`` of that agent's candidate indices (no other keys);
- ``accel_interval`` / ``steer_interval``: an ``enum`` of the configured indices;
- ``reasoning``: ``maxLength`` capped (a small model otherwise never closes it);
- (``baseline_first``) each ``enum`` lists the baseline choice first: the route
  candidate, the interval holding 0 (keep speed / straight), the ``normal`` weight
  level. Order means nothing to the schema, but a small grammar-constrained model tends
  to take the first option it is offered (SmolLM2-135M does, every time): with this
  order an undecided model drives the baseline instead of braking hard to the right.

Integer ranges are written as ``enum`` because every JSON-schema-to-grammar converter
supports it (``minimum`` / ``maximum`` are not everywhere). The answer is still
validated by ``validation.parse_decision``: narrowing only makes a valid answer likely.
"""
from __future__ import annotations

import copy
import json
import math
from typing import Any, Mapping, Optional

from lmpc_llm_planner.backends.base import DecisionRequest
from lmpc_llm_planner.prompt import answer_outline
from lmpc_llm_planner.schema import describe_schema

__all__ = ["SYSTEM_PROMPT", "compact_prompt", "describe_schema", "longest_answer_chars",
           "narrow_schema", "neutral_index", "output_token_budget"]

REASONING_FIELD = "reasoning"


def _int_enum(n: int, first: Optional[int] = None) -> dict[str, Any]:
    values = list(range(max(n, 0)))
    if first is not None and first in values:
        values.remove(first)
        values.insert(0, first)
    return {"type": "integer", "enum": values}


def neutral_index(intervals: tuple[tuple[float, float], ...]) -> Optional[int]:
    """The interval holding 0 (else the one whose midpoint is nearest to 0)."""
    if not intervals:
        return None
    for i, (lo, hi) in enumerate(intervals):
        if lo <= 0.0 <= hi:
            return i
    return min(range(len(intervals)), key=lambda i: abs(sum(intervals[i]) / 2.0))


def _find_def(schema: Mapping[str, Any], title: str) -> Optional[dict[str, Any]]:
    """The object schema titled ``title``: a ``$defs`` entry or the root itself."""
    if schema.get("title") == title:
        return schema  # type: ignore[return-value]
    for sub in (schema.get("$defs") or {}).values():
        if isinstance(sub, dict) and sub.get("title") == title:
            return sub
    return None


def _narrow_encoding(enc: dict[str, Any], request: DecisionRequest, *,
                     baseline_first: bool) -> None:
    props = enc.get("properties")
    if not isinstance(props, dict):
        return
    scene = request.scene
    ego_ok = [i for i, c in enumerate(scene.ego_candidates) if c.lane_ids]
    if baseline_first and scene.route_candidate_id in ego_ok:
        ego_ok.remove(scene.route_candidate_id)
        ego_ok.insert(0, scene.route_candidate_id)
    props["ego_trajectory"] = {"type": "integer", "enum": ego_ok or [scene.route_candidate_id]}
    ids = list(scene.agent_ids)
    if ids:
        props["attention"] = {
            "type": "array", "items": {"type": "string", "enum": ids}, "maxItems": len(ids),
        }
    else:
        # Nothing offered: the only valid attention list is the empty one.
        props["attention"] = {"type": "array", "items": {"type": "string"}, "maxItems": 0}
    props["agent_trajectories"] = {
        "type": "object",
        "properties": {
            v.id: _int_enum(len(v.candidates), v.closest_heading_id if baseline_first else None)
            for v in scene.agents
        },
        "additionalProperties": False,
    }


def _narrow_guidance(guide: dict[str, Any], request: DecisionRequest, *,
                     baseline_first: bool) -> None:
    props = guide.get("properties")
    if not isinstance(props, dict):
        return
    accel, steer = request.accel_intervals_mps2, request.steer_intervals_rad
    props["accel_interval"] = _int_enum(len(accel),
                                        neutral_index(accel) if baseline_first else None)
    props["steer_interval"] = _int_enum(len(steer),
                                        neutral_index(steer) if baseline_first else None)


def _normal_first(weights: dict[str, Any]) -> None:
    for prop in (weights.get("properties") or {}).values():
        levels = prop.get("enum") if isinstance(prop, dict) else None
        if isinstance(levels, list) and "normal" in levels:
            prop["enum"] = ["normal"] + [lv for lv in levels if lv != "normal"]


def narrow_schema(
    request: DecisionRequest, *, max_reasoning_chars: int, baseline_first: bool = True
) -> dict[str, Any]:
    """``request.json_schema`` narrowed to what ``request`` offers (see the module doc).

    Never raises on an unexpected schema shape: the parts it does not recognise are
    left as they are (the answer is validated anyway).
    """
    schema: dict[str, Any] = copy.deepcopy(dict(request.json_schema))
    root_props = schema.get("properties")
    if isinstance(root_props, dict) and isinstance(root_props.get(REASONING_FIELD), dict):
        reasoning = root_props[REASONING_FIELD]
        reasoning["maxLength"] = min(
            int(reasoning.get("maxLength", max_reasoning_chars)), max_reasoning_chars
        )
    enc = _find_def(schema, "ScenarioEncoding")
    if enc is not None:
        _narrow_encoding(enc, request, baseline_first=baseline_first)
    guide = _find_def(schema, "ActionGuidance")
    if guide is not None:
        _narrow_guidance(guide, request, baseline_first=baseline_first)
    weights = _find_def(schema, "WeightAdjustment")
    if weights is not None and baseline_first:
        _normal_first(weights)
    return schema


def compact_prompt(request: DecisionRequest, schema: Mapping[str, Any]) -> str:
    """``request.prompt`` with its generic answer outline (``prompt.answer_outline``)
    replaced by the outline of ``schema``, the schema narrowed to this request (offered
    choices spelled out, baseline first); unchanged when the outline is not found.

    A grammar-constrained model copies what it reads: the narrowed outline shows it the
    values the grammar will accept. (Before the prompt carried only an outline, this
    replaced ~600 tokens of embedded JSON schema; that text is still recognised.)
    """
    generic = answer_outline(mode=request.mode, stage=request.stage)
    full = json.dumps(dict(request.json_schema), separators=(",", ":"))
    for old in (generic, full):
        if old in request.prompt:
            return request.prompt.replace(
                old, describe_schema(schema) + " (fields marked ? are optional)", 1)
    return request.prompt


SYSTEM_PROMPT = (
    "You are the high-level decision maker of an autonomous car; a model-predictive "
    "controller drives it from your decision. Read the scene in the user message and "
    "answer with exactly one JSON object matching the JSON schema given there: fields in "
    "the given order, \"reasoning\" first and short, no Markdown, no code fences, no text "
    "before or after the object. Use only the agent ids and the indices the message offers."
)
"""System message of the chat backends: the role and the output format."""


UNBOUNDED_ITEMS = 8
"""Items assumed for an array or free-key object without a bound (the narrowed decision
schema bounds all of them: this matters only for an un-narrowed schema)."""
UNBOUNDED_STRING_CHARS = 200
ESCAPE_FACTOR = 1.1
"""A string's JSON text is longer than its characters by its escapes (quotes, newlines)."""


def longest_answer_chars(schema: Mapping[str, Any],
                         defs: Optional[Mapping[str, Any]] = None) -> int:
    """Characters of the longest JSON text ``schema`` allows (every optional field present,
    arrays full, strings at ``maxLength``, ``", "`` / ``": "`` separators): the output a
    structured-output server may produce, to size ``max_tokens`` from.

    An upper bound for the decision schemas; a part it does not know counts 12 characters.
    """
    defs = defs if defs is not None else (schema.get("$defs") or {})
    ref = schema.get("$ref")
    if isinstance(ref, str):
        return longest_answer_chars(defs.get(ref.split("/")[-1], {}), defs)
    options = schema.get("anyOf") or schema.get("oneOf")
    if isinstance(options, list) and options:
        return max(longest_answer_chars(o, defs) for o in options if isinstance(o, dict))
    if "enum" in schema:
        return max((len(json.dumps(v)) for v in schema["enum"]), default=4)
    kind = schema.get("type")
    if kind == "object":
        props = schema.get("properties") or {}
        parts = [len(json.dumps(k)) + 2 + longest_answer_chars(v, defs)
                 for k, v in props.items() if isinstance(v, dict)]
        extra = schema.get("additionalProperties")
        if isinstance(extra, dict):
            parts += [24 + longest_answer_chars(extra, defs)] * UNBOUNDED_ITEMS
        return 2 + sum(parts) + 2 * max(len(parts) - 1, 0)
    if kind == "array":
        n = schema.get("maxItems")
        n = UNBOUNDED_ITEMS if not isinstance(n, int) else n
        item = longest_answer_chars(schema.get("items") or {}, defs)
        return 2 + n * item + 2 * max(n - 1, 0)
    if kind == "string":
        cap = schema.get("maxLength")
        cap = UNBOUNDED_STRING_CHARS if not isinstance(cap, int) else cap
        return 2 + math.ceil(cap * ESCAPE_FACTOR)
    if kind == "boolean":
        return 5
    if kind == "null":
        return 4
    return 12  # integer / number / unknown


def output_token_budget(schema: Mapping[str, Any], *, chars_per_token: float,
                        slack_tokens: int) -> int:
    """``max_tokens`` for an answer of ``schema``: its longest JSON text at
    ``chars_per_token`` (pick a low ratio: JSON punctuation and ids tokenise poorly) plus
    ``slack_tokens`` (whitespace, the end token)."""
    if chars_per_token <= 0.0:
        raise ValueError(f"chars_per_token must be > 0, got {chars_per_token}")
    return math.ceil(longest_answer_chars(schema) / chars_per_token) + slack_tokens
