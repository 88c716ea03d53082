"""The scene questions several rules share (backends/rules/scene_helpers.py) and the
backend's default attention (rules 1-2), on the straight road (ego in ``E0_0`` at
x = 50) and the junction of conftest.py."""
from __future__ import annotations

import math

import numpy as np
import pytest
from lmpc_mpc import synthetic as syn
from rules_kit import car, road_obs
from rules_units import fresh_plan, inputs

from lmpc_llm_planner.backends.rules.backend import attend_defaults, start_plan
from lmpc_llm_planner.backends.rules.scene_helpers import (
    distance_to_path, lane_leader, other_lane, queued_at_junction, queued_behind,
)

NORTH = math.pi / 2.0


def _view(inp, aid):
    return next(v for v in inp.scene.agents if v.id == aid)


def test_lane_leader_is_the_nearest_car_ahead_in_my_lane(road, planner_config, mpc_config):
    obs = road_obs(road, [car("far", x_m=110.0, v_mps=10.0), car("near", x_m=80.0, v_mps=10.0),
                          car("left", x_m=60.0, v_mps=10.0, left=True),
                          car("back", x_m=30.0, v_mps=10.0)])
    inp = inputs(obs, planner_config, mpc_config)
    assert lane_leader(inp.scene).id == "near"
    assert other_lane(inp.scene, _view(inp, "left"))
    assert not other_lane(inp.scene, _view(inp, "near"))


def test_queued_behind_needs_both_nearly_stopped(road, planner_config, mpc_config):
    behind = car("b", x_m=40.0, v_mps=0.5)  # 5.5 m behind my rear
    inp = inputs(road_obs(road, [behind], v_mps=0.0), planner_config, mpc_config)
    assert queued_behind(inp.scene).id == "b"
    moving = inputs(road_obs(road, [behind], v_mps=5.0), planner_config, mpc_config)
    assert queued_behind(moving.scene) is None
    far = inputs(road_obs(road, [car("b", x_m=25.0, v_mps=0.0)], v_mps=0.0),
                 planner_config, mpc_config)  # 20.5 m behind
    assert queued_behind(far.scene) is None


@pytest.mark.parametrize("y_m, queued", [(-14.25, True), (-60.0, False)])
def test_queued_at_junction_only_near_the_lane_end(left_turn_map, obs_factory,
                                                   planner_config, mpc_config, y_m, queued):
    standing = syn.agent("q", x_m=1.6, y_m=y_m, yaw_rad=NORTH, v_mps=0.0, lane_id="S_in_0") \
        .model_copy(update={"lane_pos_m": y_m + 100.0})
    inp = inputs(obs_factory(left_turn_map, ego_y_m=-80.0, agents=[standing]),
                 planner_config, mpc_config)
    assert queued_at_junction(inp.scene, _view(inp, "q")) is queued


def test_queued_at_junction_not_on_a_plain_road(road, planner_config, mpc_config):
    inp = inputs(road_obs(road, [car("s", x_m=380.0, v_mps=0.0)], x_m=340.0), planner_config,
                 mpc_config)
    assert not queued_at_junction(inp.scene, _view(inp, "s"))  # no light, no choice


def test_distance_to_path_is_to_the_nearest_segment():
    path = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    assert distance_to_path(path, 5.0, 3.0) == pytest.approx(3.0)
    assert distance_to_path(path, 13.0, 5.0) == pytest.approx(3.0)
    assert distance_to_path(path, -3.0, -4.0) == pytest.approx(5.0)  # past the first point


def test_default_attention_is_the_leader_and_nearby_agents(road, planner_config, mpc_config):
    obs = road_obs(road, [car("lead", x_m=100.0, v_mps=10.0),
                          car("side", x_m=60.0, v_mps=10.0, left=True),
                          car("far", x_m=150.0, v_mps=10.0, left=True)])
    inp = inputs(obs, planner_config, mpc_config)
    plan = fresh_plan(inp)
    attend_defaults(inp, plan)
    assert list(plan.attention) == ["lead", "side"]
    assert plan.attention["lead"] == "leader in my lane"
    assert plan.attention["side"].startswith("within ")


def test_start_plan_reads_style_and_refusals(road, planner_config, mpc_config):
    inp = inputs(road_obs(road), planner_config, mpc_config,
                 instruction="drive carefully and ignore the speed limit")
    assert inp.safe_gap_s == pytest.approx(planner_config.rules.safe_gap_s
                                           * planner_config.rules.conservative_gap_factor)
    plan = start_plan(inp)
    assert plan.weights["safety"] == "high"
    assert "careful driving" in plan.notes[0]
    assert "'ignore the speed limit'" in plan.notes[1]
