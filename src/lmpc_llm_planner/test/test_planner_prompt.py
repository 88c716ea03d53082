"""Prompt generator, token estimate, instruction sanitising, config loading, assembler."""
from __future__ import annotations

import math

import pytest

from lmpc_msgs_py.messages import AgentArray, SignalStates

from lmpc_llm_planner.assembler import ObservationAssembler
from lmpc_llm_planner.config import LOCAL_CONFIG_PATH, PlannerConfigError, load_planner_config
from lmpc_llm_planner.prompt import build_prompt, estimate_tokens, sanitize_instruction
from lmpc_llm_planner.scene import build_scene


@pytest.fixture
def scene(left_turn_map, obs_factory, oncoming_factory):
    obs = obs_factory(left_turn_map, agents=[oncoming_factory("car1", y_m=30.0, v_mps=10.0)])
    return build_scene(obs, lookahead_m=60.0, max_agents=20)


def test_prompt_content(scene, mpc_config):
    p = build_prompt(scene, space=mpc_config, instruction="drive conservatively")
    text = p.text
    assert "car1: car" in text and "oncoming" in text and "lane N_in_0" in text
    assert "turn left at the junction (your route)" in text
    assert "unsignalized" in text and "yield to oncoming traffic" in text
    assert '"drive conservatively"' in text
    accel_line = next(line for line in text.splitlines() if line.startswith("Accel"))
    for i, (lo, hi) in enumerate(mpc_config.accel_intervals_mps2):
        assert f"{i} {lo:g}..{hi:g}" in accel_line
    assert "Previous decision: none." in text
    assert p.tokens_estimate == math.ceil(len(text) / 3.0)


def test_emergency_prompt_is_short(scene, mpc_config):
    normal = build_prompt(scene, space=mpc_config)
    emergency = build_prompt(scene, space=mpc_config, mode="emergency")
    assert emergency.tokens_estimate < normal.tokens_estimate <= 1500
    assert emergency.tokens_estimate <= 600
    assert "scenario_encoding" not in emergency.text
    assert "junction" not in emergency.text  # no scene description, no candidates


def test_retry_prompt_carries_error(scene, mpc_config):
    p = build_prompt(scene, space=mpc_config, retry_error="fenced: no code fences")
    assert p.text.rstrip().endswith("Answer again.") and "fenced" in p.text


def test_estimate_and_sanitize():
    assert estimate_tokens("") == 0 and estimate_tokens("abcde") == 2
    assert estimate_tokens("abcde", chars_per_token=4.0) == 2
    assert estimate_tokens("abcdefg") == 3
    assert sanitize_instruction('a\x00b "c"\n\n d' + "x" * 5000).startswith("a b 'c' d")
    assert len(sanitize_instruction("y" * 5000)) == 2000


def test_config_default_and_refusal(tmp_path):
    cfg = load_planner_config()
    assert (cfg.period_s, cfg.ttl_s, cfg.deadline_s, cfg.max_retries) == (2.5, 5.0, 8.0, 1)
    bad = tmp_path / "p.yaml"
    bad.write_text("period_s: -1\n")
    with pytest.raises(PlannerConfigError, match="period_s"):
        load_planner_config(bad)
    bad.write_text("perod_s: 2\n")
    with pytest.raises(PlannerConfigError, match="perod_s"):
        load_planner_config(bad)
    with pytest.raises(PlannerConfigError, match="backend"):
        load_planner_config(None, overrides={"backend": "gpt-9"})
    local = load_planner_config(LOCAL_CONFIG_PATH)  # partial file: the rest are defaults
    assert (local.backend, local.fixed_latency_s) == ("local", 2.5)
    assert local.deadline_s > 8.0 and local.period_s == cfg.period_s


def test_assembler_matches_stamps(left_turn_map, obs_factory):
    asm = ObservationAssembler()
    obs = obs_factory(left_turn_map, stamp_s=1.0, seq=10)
    assert asm.complete(obs.ego) is None and asm.newest(obs.ego) is None  # no map yet
    asm.on_map(left_turn_map)
    asm.on_agents(AgentArray(stamp_s=0.9, seq=9))
    asm.on_signals(SignalStates(stamp_s=1.0, seq=10))
    assert asm.complete(obs.ego) is None
    best = asm.newest(obs.ego)
    assert best.agents.stamp_s == 0.9 and asm.incomplete_used == 1
    asm.on_agents(AgentArray(stamp_s=1.0, seq=10))
    full = asm.complete(obs.ego)
    assert full.agents.stamp_s == 1.0 and full.signals.stamp_s == 1.0


def test_an_agent_going_against_its_lane_is_offered_its_heading() -> None:
    """Issue 23 (si 20 at 2.5 s): a pedestrian walking a crossing against the lane's drawn
    direction was offered (and predicted along) the lane, i.e. walking backwards. It gets
    one straight candidate along its heading instead; one going the lane's way keeps the
    lane candidates."""
    from lmpc_mpc import synthetic as S

    from lmpc_llm_planner.scene import agent_candidates

    m = S.straight_road()
    wrong = S.agent("ped", x_m=100.0, y_m=1.6, yaw_rad=0.0, v_mps=1.2, lane_id="-E0_0",
                    length_m=0.5, width_m=0.5)  # walking east on the westbound lane
    obs = S.observation(m, S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0), [wrong])
    (only,) = agent_candidates(obs, wrong, lookahead_m=60.0)
    assert only.control_points[-1][0] > 100.0 and not only.lane_ids
    right = wrong.model_copy(update={"yaw_rad": math.pi})
    cands = agent_candidates(obs, right, lookahead_m=60.0)
    assert cands[0].lane_ids and cands[0].control_points[-1][0] < 100.0
