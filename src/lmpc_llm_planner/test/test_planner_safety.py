"""Safety floor and emergency fast path (issue 5 items 4 and 5), through PlannerCore.

(a) whatever the backend answers, agents with a time to collision below
``safety_floor_ttc_s`` or closer than ``safety_floor_dist_m`` end up attended — also
agents the prompt did not offer, also on fallback decisions;
(b) an emergency observation between two normal requests triggers an immediate request
with the short emergency prompt (no scenario-encoding stage), not the 2.5 s cadence.
"""
from __future__ import annotations

import json
import math

from lmpc_mpc import synthetic as syn

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.config import PlannerConfig
from lmpc_llm_planner.planner import PlannerCore

SOUTH, NORTH = -math.pi / 2.0, math.pi / 2.0


def cfg_with(base: PlannerConfig, **kw) -> PlannerConfig:
    return PlannerConfig.model_validate({**base.model_dump(), **kw})


class Blind:
    """A weak model: valid JSON that attends nobody and keeps its speed; records requests."""

    name = "llm:blind"

    def __init__(self, *, fail: bool = False) -> None:
        self.fail = fail
        self.requests: list[DecisionRequest] = []

    def complete(self, request: DecisionRequest) -> BackendReply:
        self.requests.append(request)
        if self.fail:
            return BackendReply(text=None, latency_s=0.0, error_kind="transport", error="down")
        body = {"reasoning": "All clear."}
        if request.mode == "normal":
            body["scenario_encoding"] = {"ego_trajectory": request.scene.route_candidate_id,
                                         "attention": [], "agent_trajectories": {}}
        body["action_guidance"] = {"accel_interval": 3, "steer_interval": 2}
        body["weight_adjustment"] = {"tracking": "normal", "action": "normal",
                                     "smoothness": "normal", "safety": "low"}
        if request.stage != "all":  # chained: only the stage asked for
            body = {"reasoning": body["reasoning"], request.stage: body[request.stage]}
        return BackendReply(text=json.dumps(body), latency_s=0.0)


def scene_agents():
    """``near``: 8 m ahead in the ego's lane, same speed (close, no TTC); ``fast``: 35 m
    ahead, coming head-on in the ego's lane (TTC ~1.9 s, far beyond 12 m); ``calm``: far
    away on the oncoming lane (neither)."""
    return [
        syn.agent("near", x_m=1.6, y_m=-32.0, yaw_rad=NORTH, v_mps=8.0, lane_id="S_in_0"),
        syn.agent("fast", x_m=1.6, y_m=-5.0, yaw_rad=SOUTH, v_mps=10.0, lane_id=None),
        syn.agent("calm", x_m=-1.6, y_m=70.0, yaw_rad=SOUTH, v_mps=2.0, lane_id="N_in_0"),
    ]


def test_blind_answer_still_attends_close_and_urgent_agents(left_turn_map, obs_factory,
                                                            planner_config, mpc_config,
                                                            tmp_path):
    log = tmp_path / "decisions.jsonl"
    cfg = cfg_with(planner_config, emergency_ttc_s=0.5, emergency_min_gap_m=0.0)
    core = PlannerCore(cfg, Blind(), mpc_config, log_path=log)
    obs = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=8.0, agents=scene_agents())
    d = core.on_observation(obs)
    assert d.mode == "normal" and d.source == "llm:blind"
    assert set(d.attention) == {"near", "fast"}  # added by the floor, calm is not
    assert {p.agent_id for p in d.agent_predictions} == {"near", "fast"}
    assert core.counters.floor_additions == 2
    rec = json.loads(log.read_text().splitlines()[-1])
    assert sorted(rec["floor_added"]) == ["fast", "near"]


def test_floor_covers_agents_the_prompt_did_not_offer(left_turn_map, obs_factory,
                                                      planner_config, mpc_config):
    # Only the nearest agent is offered; the urgent one further away is not in the prompt.
    cfg = cfg_with(planner_config, max_agents_in_prompt=1, emergency_ttc_s=0.5,
                   emergency_min_gap_m=0.0)
    backend = Blind()
    core = PlannerCore(cfg, backend, mpc_config)
    d = core.on_observation(obs_factory(left_turn_map, agents=scene_agents()))
    assert backend.requests[0].agent_ids == ("near",)
    assert "fast" not in backend.requests[0].prompt
    assert set(d.attention) == {"near", "fast"}


def test_floor_applies_to_fallback_decisions(left_turn_map, obs_factory, planner_config,
                                             mpc_config):
    cfg = cfg_with(planner_config, max_agents_in_prompt=1, emergency_ttc_s=0.5,
                   emergency_min_gap_m=0.0)
    core = PlannerCore(cfg, Blind(fail=True), mpc_config)
    d = core.on_observation(obs_factory(left_turn_map, agents=scene_agents()))
    assert d.source == "fallback"
    assert set(d.attention) == {"near", "fast"}  # offered one + the floor's one


def test_emergency_asks_at_once_with_the_short_prompt(left_turn_map, obs_factory,
                                                      planner_config, mpc_config):
    backend = Blind()
    core = PlannerCore(planner_config, backend, mpc_config)
    quiet = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=8.0, stamp_s=0.0, seq=0)
    assert core.on_observation(quiet).mode == "normal"
    for k in (1, 2):  # nothing due before the 2.5 s cadence
        assert core.on_observation(obs_factory(left_turn_map, stamp_s=0.1 * k, seq=k)) is None
    wrongway = syn.agent("wrongway", x_m=1.6, y_m=-22.0, yaw_rad=SOUTH, v_mps=10.0,
                         lane_id="S_in_0")  # 18 m ahead, closing at 18 m/s
    d = core.on_observation(obs_factory(left_turn_map, stamp_s=0.3, seq=3,
                                        agents=[wrongway]))
    assert d is not None and d.mode == "emergency" and math.isclose(d.stamp_s, 0.3)
    normal_req, emergency_req = backend.requests
    assert emergency_req.mode == "emergency" and emergency_req.stage == "all"
    assert "scenario_encoding" not in emergency_req.json_schema["properties"]
    assert "scenario_encoding" not in emergency_req.prompt
    assert emergency_req.prompt.startswith("EMERGENCY")
    assert len(emergency_req.prompt) < 0.8 * len(normal_req.prompt)
    assert "wrongway" in emergency_req.prompt and "TTC" in emergency_req.prompt
    # the emergency answer attends nobody; the translation and the floor attend the threat
    assert "wrongway" in d.attention
    assert core.counters.emergencies == 1


def test_chained_emergency_skips_scenario_encoding(left_turn_map, obs_factory,
                                                   planner_config, mpc_config):
    backend = Blind()
    core = PlannerCore(cfg_with(planner_config, stages="chained"), backend, mpc_config)
    wrongway = syn.agent("wrongway", x_m=1.6, y_m=-22.0, yaw_rad=SOUTH, v_mps=10.0,
                         lane_id="S_in_0")
    d = core.on_observation(obs_factory(left_turn_map, agents=[wrongway]))
    assert d.mode == "emergency"
    assert [r.stage for r in backend.requests] == ["action_guidance", "weight_adjustment"]
    assert all(r.mode == "emergency" for r in backend.requests)
