"""Validation of backend replies: every bad-output kind is refused with its own kind."""
from __future__ import annotations

import json

import pytest

from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision


@pytest.fixture
def request_(left_turn_map, obs_factory, oncoming_factory, planner_config, mpc_config):
    obs = obs_factory(left_turn_map, agents=[oncoming_factory("car1", y_m=30.0, v_mps=10.0)])
    scene = build_scene(obs, lookahead_m=60.0, max_agents=20)
    return build_request(scene, config=planner_config, space=mpc_config)


def good(request_) -> dict:
    return json.loads(RulesBackend().complete(request_).text)


def kind(text: str, request_) -> str | None:
    return parse_decision(text, request=request_).error_kind


def test_rules_reply_is_valid(request_):
    res = parse_decision(json.dumps(good(request_)), request=request_)
    assert res.success, res.message
    assert res.wire.scenario_encoding.attention == ["car1"]


@pytest.mark.parametrize(
    "make, expected",
    [
        (lambda t: "", "empty"),
        (lambda t: "   \n", "empty"),
        (lambda t: "Sure! Here is my decision: " + t, "prose"),
        (lambda t: t + "\nI hope this helps.", "prose"),
        (lambda t: "```json\n" + t + "\n```", "fenced"),
        (lambda t: t + "\n" + t, "multiple_objects"),
        (lambda t: t[: len(t) // 2], "invalid_json"),
        (lambda t: "[" + t + "]", "prose"),
        (lambda t: "x" * 40000, "too_long"),
    ],
)
def test_text_level_refusals(request_, make, expected):
    assert kind(make(json.dumps(good(request_))), request_) == expected


def _mutate(obj: dict, path: str, value) -> dict:
    node = obj
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[k]
    if value is KeyError:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return obj


@pytest.mark.parametrize(
    "path, value, expected",
    [
        ("weight_adjustment.safety", KeyError, "missing_field"),
        ("action_guidance", KeyError, "missing_field"),
        ("reasoning", KeyError, "missing_field"),
        ("scenario_encoding.attention", ["car1", "ghost7"], "unknown_agent"),
        ("scenario_encoding.agent_trajectories", {"ghost7": 0}, "unknown_agent"),
        ("action_guidance.accel_interval", 6, "out_of_range"),  # 6 intervals: 0..5
        ("action_guidance.steer_interval", 5, "out_of_range"),  # 5 intervals: 0..4
        ("action_guidance.accel_interval", 99, "out_of_range"),
        ("action_guidance.accel_interval", -1, "out_of_range"),
        ("scenario_encoding.ego_trajectory", 3, "out_of_range"),
        ("scenario_encoding.agent_trajectories", {"car1": 2}, "out_of_range"),  # car1 has 2
        ("action_guidance.accel_interval", "2", "wrong_type"),
        ("action_guidance.accel_interval", 2.0, "wrong_type"),
        ("action_guidance.accel_interval", True, "wrong_type"),
        ("weight_adjustment.safety", "extreme", "wrong_type"),
        ("action_guidance.brake_now", 1, "unknown_field"),
    ],
)
def test_field_level_refusals(request_, path, value, expected):
    obj = _mutate(good(request_), path, value)
    res = parse_decision(json.dumps(obj), request=request_)
    assert res.error_kind == expected, res.message
    assert res.message  # the re-ask carries an actionable message


@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e309"])
def test_non_finite_numbers_refused(request_, number):
    text = json.dumps(good(request_))
    text = text.replace('"accel_interval":', f'"accel_interval":{number},"x":')
    assert kind(text, request_) == "non_finite"


def test_ego_index_checked_against_offered_candidates(request_):
    # The junction offers three ego candidates; a scene with fewer refuses index 2.
    n = len(request_.scene.ego_candidates)
    obj = good(request_)
    obj["scenario_encoding"]["ego_trajectory"] = n - 1
    assert parse_decision(json.dumps(obj), request=request_).success
    from dataclasses import replace

    short = replace(request_, scene=replace(request_.scene,
                                            ego_candidates=request_.scene.ego_candidates[:1]))
    assert parse_decision(json.dumps(obj), request=short).error_kind == "out_of_range"


def test_emergency_reply_has_no_scenario_encoding(request_):
    from dataclasses import replace

    emergency = replace(request_, mode="emergency")
    full = good(request_)
    assert parse_decision(json.dumps(full), request=emergency).error_kind == "unknown_field"
    del full["scenario_encoding"]
    assert parse_decision(json.dumps(full), request=emergency).success
