"""Helpers of the per-rule unit tests (test_rules_*.py): the rule inputs of a hand-made
observation as the rules backend builds them, and a fresh plan. Plain functions
(conftest.py puts this folder on ``sys.path``)."""
from __future__ import annotations

import dataclasses

from lmpc_llm_planner.backends.rules.backend import rule_inputs
from lmpc_llm_planner.backends.rules.intervals import mid, neutral
from lmpc_llm_planner.backends.rules.plan import Plan, RuleInputs
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene


def inputs(obs, planner_config, mpc_config, *, instruction=None, mode="normal",
           previous=None, expected_latency_s=None) -> RuleInputs:
    """The :class:`RuleInputs` of ``obs`` (scene analysed as the planner does)."""
    scene = build_scene(obs, lookahead_m=60.0, max_agents=20)
    req = build_request(scene, config=planner_config, space=mpc_config,
                        instruction=instruction, mode=mode, previous=previous,
                        expected_latency_s=expected_latency_s)
    return rule_inputs(planner_config.rules, req)


def fresh_plan(inp: RuleInputs) -> Plan:
    """The plan every request starts from (neutral intervals, normal weights)."""
    return Plan(accel_index=neutral(inp.accel), steer_index=neutral(inp.steer))


def changing_left_plan(inp: RuleInputs) -> Plan:
    """A fresh plan whose chosen candidate is "change to the left lane"."""
    return dataclasses.replace(
        fresh_plan(inp), ego_index=next(c.candidate_id for c in inp.scene.ego_candidates
                                        if c.label == "change to the left lane"))


def accel_of(inp: RuleInputs, plan: Plan) -> float:
    """The midpoint of the plan's acceleration interval (the bias), m/s^2."""
    return mid(inp.accel[plan.accel_index])
