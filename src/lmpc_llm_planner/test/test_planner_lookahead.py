"""Deciding for the take-effect time (``lmpc_llm_planner.lookahead``, issue 23): the
observation predicted forward by the decision's expected latency."""
from __future__ import annotations

import math

import pytest
from lmpc_mpc.synthetic import agent, ego_state, observation, straight_road

from lmpc_llm_planner.lookahead import predict_link, predict_observation, travel_m
from lmpc_msgs_py.messages import LinkSignal, SignalStates


def _link(state: str, dist_m: float, switch_s: float | None = None) -> LinkSignal:
    return LinkSignal(tls_id="J", link_index=0, from_lane="E0_0", to_lane="X_0", state=state,
                      distance_m=dist_m, time_to_switch_s=switch_s)


def test_travel_stops_at_rest_and_never_reverses() -> None:
    assert travel_m(10.0, 0.0, 2.5) == pytest.approx((25.0, 10.0))
    assert travel_m(10.0, 2.0, 1.0) == pytest.approx((11.0, 12.0))
    # 10 m/s braking at 5 m/s^2 stops after 2 s and 10 m, then stays
    assert travel_m(10.0, -5.0, 2.5) == pytest.approx((10.0, 0.0))


def test_zero_lookahead_is_the_observation_itself() -> None:
    obs = observation(straight_road(), ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=10.0,
                                                 lane_id="E0_0"))
    assert predict_observation(obs, 0.0, lookahead_m=60.0) is obs


def test_ego_and_agents_move_on_along_their_lanes_stamps_stay() -> None:
    ego = ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=10.0, lane_id="E0_0", stamp_s=3.0)
    lead = agent("lead", x_m=40.0, y_m=-4.8, yaw_rad=0.0, v_mps=8.0, lane_id="E0_0")
    onc = agent("onc", x_m=150.0, y_m=1.6, yaw_rad=math.pi, v_mps=12.0, lane_id="-E0_0")
    parked = agent("parked", x_m=200.0, y_m=-1.6, yaw_rad=0.0, lane_id="E0_1")
    obs = observation(straight_road(), ego, [lead, onc, parked])
    ahead = predict_observation(obs, 2.5, lookahead_m=60.0)
    assert ahead.stamp_s == 3.0 and ahead.agents.stamp_s == obs.agents.stamp_s
    assert (ahead.ego.x_m, ahead.ego.y_m) == pytest.approx((35.0, -4.8), abs=0.05)
    assert ahead.ego.lane_id == "E0_0" and ahead.ego.v_mps == pytest.approx(10.0)
    assert ahead.ego.dist_to_target_m == pytest.approx(100.0 - 25.0)
    moved = {a.id: a for a in ahead.agents.agents}
    assert (moved["lead"].x_m, moved["lead"].y_m) == pytest.approx((60.0, -4.8), abs=0.05)
    assert (moved["onc"].x_m, moved["onc"].y_m) == pytest.approx((120.0, 1.6), abs=0.05)
    assert moved["onc"].lane_id == "-E0_0"
    assert moved["parked"] == parked  # a standing agent stays put


def test_an_ego_in_the_next_lane_stays_in_it() -> None:
    # the route is E0_0; the ego drives in E0_1 (a lane change still to make)
    ego = ego_state(x_m=10.0, y_m=-1.6, yaw_rad=0.0, v_mps=10.0, lane_id="E0_1")
    ahead = predict_observation(observation(straight_road(), ego), 2.0, lookahead_m=60.0)
    assert ahead.ego.y_m == pytest.approx(-1.6, abs=0.05)
    assert ahead.ego.lane_id == "E0_1"


def test_the_predicted_ego_stops_before_a_red_light_and_behind_a_leader() -> None:
    ego = ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=12.0, lane_id="E0_0")
    red = SignalStates(stamp_s=0.0, seq=0, links=(_link("r", 20.0),))
    ahead = predict_observation(observation(straight_road(), ego, signals=red), 2.5,
                                lookahead_m=60.0)
    # box centre stops half a length + 1 m before the line; speed 0 there
    assert ahead.ego.x_m == pytest.approx(10.0 + 20.0 - 2.25 - 1.0, abs=0.05)
    assert ahead.ego.v_mps == 0.0
    stopped = agent("stopped", x_m=30.0, y_m=-4.8, yaw_rad=0.0, lane_id="E0_0")
    ahead = predict_observation(observation(straight_road(), ego, [stopped]), 2.5,
                                lookahead_m=60.0)
    assert ahead.ego.x_m == pytest.approx(30.0 - 4.5 - 2.0, abs=0.05)


def test_a_switching_light_is_never_predicted_more_permissive() -> None:
    assert predict_link(_link("G", 50.0, 1.0), 2.5, 10.0).state == "y"
    assert predict_link(_link("y", 50.0, 1.0), 2.5, 10.0).state == "r"
    assert predict_link(_link("r", 50.0, 1.0), 2.5, 10.0).state == "r"
    kept = predict_link(_link("G", 50.0, 4.0), 2.5, 10.0)
    assert (kept.state, kept.distance_m, kept.time_to_switch_s) == ("G", 40.0, pytest.approx(1.5))
    assert predict_link(_link("G", 5.0), 2.5, 10.0) is None  # passed by then
