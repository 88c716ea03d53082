"""Rule 11, situational text (backends/rules/situation.py and the make-room lane choice in
lane.py): pedestrians at the next junction, an emergency vehicle to make room for, a
closed lane where the road has one lane. Hand-made observations on the synthetic
four-way junction (``S_in_0``, stop line at y = -8) and the two-lane straight road."""
from __future__ import annotations

import pytest
from rules_kit import accel_mid, ask, car, chosen_label, road_obs

from lmpc_msgs_py.messages import LaneLink

from lmpc_llm_planner.backends.rules import parse_instruction
from lmpc_llm_planner.backends.rules.situation import (
    MAKE_ROOM_FRACTION, PEDESTRIAN_APPROACH_MPS, next_junction_m,
)
from lmpc_llm_planner.scene import build_scene

PEDESTRIANS = "pedestrians are crossing at the next junction"
AMBULANCE = "an ambulance is coming from behind, make room"


@pytest.mark.parametrize("text, make_room, pedestrians", [
    (AMBULANCE, True, False),
    ("fire truck behind us with its siren on", True, False),
    ("please pull over and let it pass", True, False),
    ("there is no ambulance", False, False),
    (PEDESTRIANS, False, True),
    ("kids walking to school near the junction", False, True),
    ("careful, a zebra crossing ahead", False, True),
    ("no pedestrians are crossing today", False, False),
    ("the right lane is closed ahead", False, False),
])
def test_situations_are_parsed(text, make_room, pedestrians):
    intent = parse_instruction(text)
    assert (intent.make_room, intent.pedestrians_ahead) == (make_room, pedestrians)


def test_next_junction_is_measured_along_the_route(straight_map, road, obs_factory):
    scene = build_scene(obs_factory(straight_map, ego_y_m=-40.0), lookahead_m=60.0,
                        max_agents=20)
    assert next_junction_m(scene) == pytest.approx(32.0, abs=0.01)  # stop line at y = -8
    far = build_scene(obs_factory(straight_map, ego_y_m=-90.0), lookahead_m=60.0,
                      max_agents=20)
    assert next_junction_m(far) is None  # 82 m: beyond the lookahead
    assert next_junction_m(build_scene(road_obs(road), lookahead_m=60.0, max_agents=20)) \
        is None  # no junction on the road


def test_pedestrians_slow_the_approach_to_the_junction(straight_map, obs_factory,
                                                       planner_config, mpc_config):
    obs = obs_factory(straight_map, ego_y_m=-40.0, ego_v_mps=10.0)
    plain, _ = ask(obs, planner_config, mpc_config)
    told, _ = ask(obs, planner_config, mpc_config, instruction=PEDESTRIANS)
    assert accel_mid(plain, mpc_config) >= 0.0
    assert accel_mid(told, mpc_config) < 0.0
    assert told.weight_adjustment.safety == "high"
    assert f"at {PEDESTRIAN_APPROACH_MPS:.0f} m/s at most" in told.reasoning


def test_pedestrians_change_nothing_without_a_junction_ahead(road, planner_config,
                                                             mpc_config):
    obs = road_obs(road, v_mps=10.0)
    plain, _ = ask(obs, planner_config, mpc_config)
    told, _ = ask(obs, planner_config, mpc_config, instruction=PEDESTRIANS)
    assert told.action_guidance == plain.action_guidance
    assert told.weight_adjustment == plain.weight_adjustment
    assert "changes nothing yet" in told.reasoning


def test_make_room_moves_to_the_kerb_lane(road, planner_config, mpc_config):
    left = road_obs(road, v_mps=12.0, left=True)
    plain, scene = ask(left, planner_config, mpc_config)
    told, scene = ask(left, planner_config, mpc_config, instruction=AMBULANCE)
    assert chosen_label(plain, scene) == "continue in lane"
    assert chosen_label(told, scene) == "change to the right lane"
    # on the kerb lane it stays there and keeps its speed (room given)
    right = road_obs(road, v_mps=12.0)
    kept, scene = ask(right, planner_config, mpc_config, instruction=AMBULANCE)
    assert chosen_label(kept, scene) == "continue in lane"
    assert accel_mid(kept, mpc_config) >= 0.0


def test_making_room_still_passes_a_standing_car(road, planner_config, mpc_config):
    # a car stands in the kerb lane ahead: the ego passes it through the inner lane
    obs = road_obs(road, [car("stopped", x_m=85.0, v_mps=0.0)], v_mps=8.0)
    told, scene = ask(obs, planner_config, mpc_config, instruction=AMBULANCE)
    assert chosen_label(told, scene) == "change to the left lane"


@pytest.mark.parametrize("leader_mps, label", [
    (2.0, "change to the left lane"),  # crawling: overtaken even while making room
    (9.0, "continue in lane"),  # slow, but no overtaking while making room
])
def test_making_room_overtakes_only_a_crawling_leader(road, planner_config, mpc_config,
                                                      leader_mps, label):
    obs = road_obs(road, [car("slow", x_m=95.0, v_mps=leader_mps)], v_mps=10.0)
    told, scene = ask(obs, planner_config, mpc_config, instruction=AMBULANCE)
    assert chosen_label(told, scene) == label
    plain, scene = ask(obs, planner_config, mpc_config)
    assert chosen_label(plain, scene) == "change to the left lane"  # overtakes either


def test_make_room_on_a_single_lane_slows_down(straight_map, obs_factory, planner_config,
                                               mpc_config):
    fast = obs_factory(straight_map, ego_y_m=-90.0, ego_v_mps=12.0)
    told, _ = ask(fast, planner_config, mpc_config, instruction=AMBULANCE)
    assert accel_mid(told, mpc_config) < 0.0
    assert "no lane to give" in told.reasoning
    slow = obs_factory(straight_map, ego_y_m=-90.0, ego_v_mps=MAKE_ROOM_FRACTION * 13.89 - 2)
    plain, _ = ask(slow, planner_config, mpc_config)
    told, _ = ask(slow, planner_config, mpc_config, instruction=AMBULANCE)
    assert told.action_guidance == plain.action_guidance  # already slow: only lowered


def test_a_closed_lane_on_a_single_lane_road_is_noted_and_changes_nothing(
        straight_map, obs_factory, planner_config, mpc_config):
    obs = obs_factory(straight_map, ego_y_m=-90.0, ego_v_mps=10.0)
    plain, _ = ask(obs, planner_config, mpc_config)
    told, _ = ask(obs, planner_config, mpc_config, instruction="the right lane is closed ahead")
    assert told.action_guidance == plain.action_guidance
    assert told.scenario_encoding == plain.scenario_encoding
    assert "my road has one lane here" in told.reasoning


def test_a_closed_lane_the_route_needs_is_kept(road, planner_config, mpc_config):
    # the route goes on (to N_0) only from the right lane E0_0, which the user says is
    # closed: leaving it would be undone by the route's lane change at the next decision
    right, left, back = road.lanes
    right = right.model_copy(update={"successors": (LaneLink(to_lane="N_0", direction="s"),)})
    on = right.model_copy(update={"id": "N_0", "edge_id": "N", "index": 0, "successors": (),
                                  "centerline": ((400.0, -4.8), (600.0, -4.8)),
                                  "length_m": 200.0})
    exit_right = road.model_copy(update={"lanes": (right, left, back, on),
                                         "ego_route": ("E0_0", "N_0")})
    told, scene = ask(road_obs(exit_right), planner_config, mpc_config,
                      instruction="the right lane is closed ahead")
    assert chosen_label(told, scene) == "continue in lane"
    assert "my route goes on only from it" in told.reasoning
    # on the plain road (the route ends on this edge) it leaves the closed lane
    plain, scene = ask(road_obs(road), planner_config, mpc_config,
                       instruction="the right lane is closed ahead")
    assert chosen_label(plain, scene) == "change to the left lane"
