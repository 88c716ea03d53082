"""The ablation backend (``lmpc-rules-enc`` / ``lmpc-rules-aw``, the paper's Table II):
each keeps its half of the rules' answer and replaces the other with the baseline's."""
from __future__ import annotations

import dataclasses
import json

from rules_kit import car, road_obs

from lmpc_llm_planner.backends.ablation import AblatedBackend, baseline_encoding
from lmpc_llm_planner.backends.base import BackendReply
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision
from lmpc_msgs_py.vocabulary import neutral_index

NORMAL = {"tracking": "normal", "action": "normal", "smoothness": "normal", "safety": "normal"}


def _request(road, planner_config, space, mode="normal"):
    # a car standing close ahead, one beside in the other lane: the rules brake and
    # attend only who matters
    agents = [car("stop", x_m=72.0, v_mps=0.0), car("side", x_m=52.0, v_mps=12.0, left=True)]
    obs = road_obs(road, agents, v_mps=12.0)
    scene = build_scene(obs, lookahead_m=60.0, max_agents=20)
    return build_request(scene, config=planner_config, space=space, mode=mode)


def _answers(req, planner_config, keep):
    inner = RulesBackend(planner_config.rules)
    plain = json.loads(inner.complete(req).text)
    reply = AblatedBackend(inner, keep).complete(req)
    assert parse_decision(reply.text, request=req).success  # still a valid answer
    return plain, json.loads(reply.text)


def test_encoding_only_neutralises_bias_and_weights(road, planner_config, space):
    req = _request(road, planner_config, space)
    plain, ablated = _answers(req, planner_config, "encoding")
    neutral = {"accel_interval": neutral_index(req.accel_intervals_mps2),
               "steer_interval": neutral_index(req.steer_intervals_rad)}
    assert plain["action_guidance"] != neutral  # the rules had something to say here
    assert ablated["action_guidance"] == neutral
    assert ablated["weight_adjustment"] == NORMAL
    assert ablated["scenario_encoding"] == plain["scenario_encoding"]
    assert ablated["reasoning"].startswith("[ablation: only the scenario encoding kept]")


def test_action_only_takes_the_baseline_encoding(road, planner_config, space):
    req = _request(road, planner_config, space)
    plain, ablated = _answers(req, planner_config, "action")
    base = baseline_encoding(req.scene).model_dump()
    assert plain["scenario_encoding"] != base
    assert ablated["scenario_encoding"] == base
    assert set(base["attention"]) == {"stop", "side"}
    assert base["ego_trajectory"] == req.scene.route_candidate_id
    assert ablated["action_guidance"] == plain["action_guidance"]
    assert ablated["weight_adjustment"] == plain["weight_adjustment"]


def test_an_emergency_answer_keeps_or_loses_its_brake(road, planner_config, space):
    req = _request(road, planner_config, space, mode="emergency")
    plain, enc = _answers(req, planner_config, "encoding")
    assert "scenario_encoding" not in plain
    neutral = neutral_index(req.accel_intervals_mps2)
    assert plain["action_guidance"]["accel_interval"] < neutral  # it brakes
    assert enc["action_guidance"]["accel_interval"] == neutral
    plain, aw = _answers(req, planner_config, "action")
    assert aw == plain  # no encoding to replace: unchanged


class _Fixed:
    name = "fixed"

    def __init__(self, text):
        self.text = text

    def complete(self, request):
        return BackendReply(text=self.text, latency_s=0.0)


def test_a_reply_that_is_not_an_answer_passes_unchanged(road, planner_config, space):
    req = _request(road, planner_config, space)
    for text in ("not json", "[1, 2]", '{"reasoning": "x"}'):
        wrapped = AblatedBackend(_Fixed(text), "encoding")
        assert wrapped.complete(req).text == text and wrapped.rewritten == 0


class _Asks:
    """A backend whose answers ask to be asked again after 0.5 s (the rules near a ring)."""

    name = "rules"

    def __init__(self, planner_config):
        self.inner = RulesBackend(planner_config.rules)

    def complete(self, request):
        return dataclasses.replace(self.inner.complete(request), revisit_s=0.5)


def test_the_early_revisit_goes_with_the_action_half(road, planner_config, space):
    # the rules plan a roundabout approach on braking at the decision they ask for 0.5 s
    # later; an encoding-only answer cannot brake, so it is asked at the period
    req = _request(road, planner_config, space)
    inner = _Asks(planner_config)
    assert AblatedBackend(inner, "encoding").complete(req).revisit_s is None
    assert AblatedBackend(inner, "action").complete(req).revisit_s == 0.5
