"""Situational text, measured (issue 20 item 3): the situation figures of an episode record,
the summary that counts, per family, the scenes a situation changed and how many the
expected way (``lmpc_bridge.evaluation.situations``), and one development scene per
situation where the rules reasoner, told it, drives the expected way."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.evaluation.situations import (
    EXPECTED,
    MIN_CHANGE,
    situation_metrics,
    situation_summary,
)
from lmpc_bridge.evaluation.style import INSTRUCTION_SETS
from lmpc_bridge.record import EpisodeRecord, StepRecord
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_llm_planner.backends.rules.instruction import parse_instruction
from lmpc_scripts import methods


def _record(lanes: list[str], speeds: list[float]) -> EpisodeRecord:
    steps = tuple(StepRecord(step=k, t_s=0.1 * k, x_m=10.0 * k, y_m=0.0, yaw_rad=0.0, v_mps=v,
                             a_mps2=0.0, steer_rad=0.0, lane_id=lane)
                  for k, (lane, v) in enumerate(zip(lanes, speeds)))
    return EpisodeRecord(family="x", seed=0, dt_s=0.1, max_time_s=10.0,
                         target_center=(0.0, 0.0), target_radius_m=1.0, steps=steps)


def test_the_situation_figures_of_a_record() -> None:
    # a single-lane edge "a", a junction, then the two-lane edge "b" (lane 1, then lane 0)
    lanes = ["a_0"] * 5 + [":j_0"] + ["b_1"] * 3 + ["b_0"] * 1
    speeds = [10.0, 10.0, 8.0, 6.0, 4.0, 4.0, 5.0, 5.0, 5.0, 5.0]
    m = situation_metrics(_record(lanes, speeds))
    assert m["kerb_share"] == pytest.approx(6 / 9, abs=1e-4)  # 9 steps off the junction
    assert m["mean_speed_mps"] == pytest.approx(sum(speeds) / len(speeds))
    # 10 m a step: the 30 m before the junction entry (step 5) are steps 2-4
    assert m["approach_mps"] == pytest.approx((8.0 + 6.0 + 4.0) / 3)
    inside = situation_metrics(_record([":j_0"] * 4, [3.0] * 4))
    assert math.isnan(inside["kerb_share"]) and math.isnan(inside["approach_mps"])


def test_the_summary_counts_changed_scenes_and_their_direction() -> None:
    def row(seed: int, sit: str, kerb: float, approach: float) -> dict:
        return {"family": "lane", "seed": seed, "situation": sit, "collision": 0, "fail": 0,
                "time_s": 10.0, "overall_cost": 1.0, "kerb_share": kerb,
                "mean_speed_mps": 5.0, "approach_mps": approach}
    rows = [row(1, "none", 0.5, 6.0), row(2, "none", 0.5, 6.0),
            row(1, "closure", 0.1, 6.0), row(2, "closure", 0.6, 6.0),  # one each way
            row(1, "pedestrians", 0.5, 6.05), row(2, "pedestrians", 0.5, 4.0)]
    s = situation_summary(rows)["lane"]
    assert (s["closure"]["changed"], s["closure"]["expected"]) == (2, 1)
    assert (s["pedestrians"]["changed"], s["pedestrians"]["expected"]) == (1, 1)  # 0.05: noise
    assert s["closure"]["kerb_share"] == pytest.approx(0.35)


def test_the_situation_set_parses_as_its_label_says() -> None:
    for label, text in INSTRUCTION_SETS["situations"]:
        intent = parse_instruction(text)
        assert (label == "closure") == (intent.closed_sides == frozenset({"right"}))
        assert (label == "make-room") == intent.make_room
        assert (label == "pedestrians") == intent.pedestrians_ahead
        assert intent.style == "normal"  # a situation is not a style


@pytest.mark.parametrize("family, seed, label", [
    ("eoa", 102, "make-room"),  # kerb share 0.01 -> 0.87 (2026-12-03)
    ("si", 101, "pedestrians"),  # approach speed 11.4 -> 0.5 m/s
    ("construction", 100, "closure"),  # leaves the closed right lane before the work zone
])
def test_each_situation_changes_its_scene_the_expected_way(family: str, seed: int,
                                                           label: str, tmp_path: Path) -> None:
    """One development scene per situation, run without and with its text: the figure the
    situation should move (``EXPECTED``) moves that way, no collision, and the decision
    log's reasoning says what the text made the rules do."""
    text = dict(INSTRUCTION_SETS["situations"])[label]
    key, sign = EXPECTED[label]
    sim = SumoSim(work_dir=tmp_path / "scenes")
    figures = {}
    for instruction in (None, text):
        wiring = methods.build(SceneSpec("lmpc-rules", family, seed, instruction=instruction))
        res = run_episode(sim, family=family, seed=seed, controller=wiring.controller,
                          planner=wiring.planner, max_time_s=120.0)
        assert res.outcome == "reached", (family, seed, instruction, res.outcome, res.detail)
        figures[instruction] = situation_metrics(res.record)[key]
    assert (figures[text] - figures[None]) * sign > MIN_CHANGE[key], figures
