"""The emergency variant of the rules (backends/rules/emergency.py and the backend's rule
order): the same rules, safety high, no lane choice, and the strongest braking only for
a threat in the path under ``commit_ttc_s``."""
from __future__ import annotations

import dataclasses

from rules_kit import car, road_obs
from rules_units import inputs

from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.backends.rules.backend import run_rules, start_plan
from lmpc_llm_planner.backends.rules.emergency import brakes_hard, emergency_answer
from lmpc_llm_planner.backends.rules.intervals import strongest_brake
from lmpc_llm_planner.backends.rules.plan import Plan
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene


def _request(obs, planner_config, mpc_config, mode):
    scene = build_scene(obs, lookahead_m=60.0, max_agents=20)
    return build_request(scene, config=planner_config, space=mpc_config, mode=mode)


def test_brakes_hard_only_in_an_emergency_under_the_commit_ttc(road, planner_config,
                                                               mpc_config):
    # closing at 10 m/s from 8.5 m: TTC 0.85 s
    obs = road_obs(road, [car("slow", x_m=63.0, v_mps=2.0)], v_mps=12.0)
    urgent = inputs(obs, planner_config, mpc_config, mode="emergency")
    view = urgent.scene.agents[0]
    assert view.kin.ttc_s < planner_config.rules.commit_ttc_s
    assert brakes_hard(urgent, view)
    assert not brakes_hard(dataclasses.replace(urgent, emergency=False), view)
    later = dataclasses.replace(urgent, cfg=urgent.cfg.model_copy(
        update={"commit_ttc_s": view.kin.ttc_s - 0.1}))
    assert not brakes_hard(later, view)


def test_emergency_answer_brakes_at_the_strongest_interval_without_an_encoding(
        road, planner_config, mpc_config):
    obs = road_obs(road, [car("slow", x_m=63.0, v_mps=2.0)], v_mps=12.0)
    backend = RulesBackend(planner_config.rules)
    urgent = backend.decide(_request(obs, planner_config, mpc_config, "emergency"))
    normal = backend.decide(_request(obs, planner_config, mpc_config, "normal"))
    assert set(urgent) == {"reasoning", "action_guidance", "weight_adjustment"}
    assert urgent["reasoning"].startswith("Emergency check. slow is")
    assert urgent["action_guidance"]["accel_interval"] == \
        strongest_brake(mpc_config.accel_intervals_mps2)
    assert urgent["weight_adjustment"]["tracking"] == "low"
    assert urgent["weight_adjustment"]["safety"] == "high"
    assert "scenario_encoding" in normal
    assert normal["weight_adjustment"]["tracking"] == "normal"


def test_emergency_skips_the_lane_choice(road, planner_config, mpc_config):
    # a standing car far ahead and a free left lane: a normal request changes lanes
    obs = road_obs(road, [car("stop", x_m=120.0, v_mps=0.0)], v_mps=12.0)
    normal = inputs(obs, planner_config, mpc_config)
    plan = start_plan(normal)
    run_rules(normal, plan)
    assert plan.ego_index is not None
    urgent = inputs(obs, planner_config, mpc_config, mode="emergency")
    plan = start_plan(urgent)
    assert plan.weights["safety"] == "high"
    run_rules(urgent, plan)
    assert plan.ego_index is None


def test_emergency_answer_of_a_plan():
    p = Plan(accel_index=1, steer_index=2, notes=["a.", "b."])
    assert emergency_answer(p) == {
        "reasoning": "Emergency check. a. b.",
        "action_guidance": {"accel_interval": 1, "steer_interval": 2},
        "weight_adjustment": p.weights,
    }
