"""Translation of a validated wire decision into lmpc_msgs_py.Decision, and the safety floor."""
from __future__ import annotations

import math

import numpy as np
import pytest

from lmpc_msgs_py.codec import decode, encode
from lmpc_msgs_py.messages import Decision

from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.schema import LlmDecision
from lmpc_llm_planner.validation import DecisionMeta, apply_safety_floor, translate

META = DecisionMeta(decision_id="0-1", seq=1, source="rules", mode="normal", latency_s=0.3,
                    tokens_in=100, tokens_out=20, ttl_s=5.0)


def flat(points) -> list[float]:
    return [float(v) for p in points for v in p]


def wire(*, ego: int, attention: list[str], trajectories: dict[str, int], accel: int,
         steer: int) -> LlmDecision:
    return LlmDecision.model_validate({
        "reasoning": "test",
        "scenario_encoding": {"ego_trajectory": ego, "attention": attention,
                              "agent_trajectories": trajectories},
        "action_guidance": {"accel_interval": accel, "steer_interval": steer},
        "weight_adjustment": {"tracking": "low", "action": "high", "smoothness": "normal",
                              "safety": "high"},
    })


@pytest.fixture
def scene(left_turn_map, obs_factory, oncoming_factory):
    agents = [oncoming_factory("car1", y_m=30.0, v_mps=10.0),
              oncoming_factory("car2", y_m=60.0, v_mps=10.0)]
    return build_scene(obs_factory(left_turn_map, agents=agents), lookahead_m=60.0,
                       max_agents=20)


@pytest.mark.parametrize("accel, steer", [(0, 0), (2, 2), (5, 4), (3, 1)])
def test_decision_carries_indices_and_the_space_hash(scene, mpc_config, accel, steer):
    d = translate(wire(ego=0, attention=[], trajectories={}, accel=accel, steer=steer),
                  scene=scene, space=mpc_config, meta=META)
    assert (d.accel_interval, d.steer_interval) == (accel, steer)
    assert d.space_hash == mpc_config.space_hash
    assert "accel_bias_mps2" not in d.model_dump()  # the MPC turns indices into numbers
    a_lo, a_hi = mpc_config.accel_intervals_mps2[accel]
    s_lo, s_hi = mpc_config.steer_intervals_rad[steer]
    assert mpc_config.bias_for(accel, steer) == (0.5 * (a_lo + a_hi), 0.5 * (s_lo + s_hi))


def test_an_index_outside_the_space_is_refused(scene, mpc_config):
    with pytest.raises(IndexError, match="accel_index 6 out of range"):
        translate(wire(ego=0, attention=[], trajectories={}, accel=6, steer=0),
                  scene=scene, space=mpc_config, meta=META)


@pytest.mark.parametrize("ego_idx", [0, 1, 2])
def test_control_points_are_the_chosen_candidates(scene, mpc_config, ego_idx):
    d = translate(wire(ego=ego_idx, attention=["car1"], trajectories={"car1": 1}, accel=3,
                       steer=2), scene=scene, space=mpc_config, meta=META)
    ego_c = scene.ego_candidates[ego_idx]
    assert d.ego_trajectory.candidate_id == ego_idx
    assert flat(d.ego_trajectory.control_points) == pytest.approx(flat(ego_c.control_points))
    assert d.ego_trajectory.label == ego_c.label
    car1 = scene.agent("car1").candidates[1]
    (pred,) = d.agent_predictions
    assert pred.agent_id == "car1" and pred.trajectory.candidate_id == 1
    assert flat(pred.trajectory.control_points) == pytest.approx(flat(car1.control_points))


def test_attended_without_choice_gets_closest_heading(scene, mpc_config):
    d = translate(wire(ego=1, attention=["car2", "car2", "car1"], trajectories={}, accel=3,
                       steer=2), scene=scene, space=mpc_config, meta=META)
    assert d.attention == ("car2", "car1")  # repeats dropped, order kept
    for pred in d.agent_predictions:
        assert pred.trajectory.candidate_id == scene.agent(pred.agent_id).closest_heading_id


def test_decision_fields_and_wire_round_trip(scene, mpc_config):
    d = translate(wire(ego=1, attention=["car1"], trajectories={}, accel=1, steer=2),
                  scene=scene, space=mpc_config, meta=META)
    assert (d.source, d.latency_s, d.tokens_in, d.tokens_out, d.ttl_s) == \
        ("rules", 0.3, 100, 20, 5.0)
    assert d.weights.safety == "high" and d.weights.tracking == "low"
    assert d.stamp_s == scene.obs.stamp_s
    assert decode(encode(d), Decision) == d


def test_safety_floor_adds_close_agent(left_turn_map, obs_factory, mpc_config):
    from lmpc_mpc import synthetic as syn

    near = syn.agent("near", x_m=1.6, y_m=-34.0, yaw_rad=math.pi / 2, v_mps=8.0,
                     lane_id="S_in_0")  # 6 m ahead in the ego's lane
    far = syn.agent("far", x_m=-1.6, y_m=80.0, yaw_rad=-math.pi / 2, v_mps=0.0,
                    lane_id="N_in_0")
    scene = build_scene(obs_factory(left_turn_map, agents=[near, far]), lookahead_m=60.0,
                        max_agents=20)
    d = translate(wire(ego=1, attention=[], trajectories={}, accel=3, steer=2),
                  scene=scene, space=mpc_config, meta=META)
    res = apply_safety_floor(d, scene=scene, ttc_s=3.0, dist_m=10.0, lookahead_m=60.0)
    assert res.added == ("near",)
    assert res.decision.attention == ("near",)
    assert [p.agent_id for p in res.decision.agent_predictions] == ["near"]
    # Nothing to add: the decision is returned unchanged.
    again = apply_safety_floor(res.decision, scene=scene, ttc_s=3.0, dist_m=10.0,
                               lookahead_m=60.0)
    assert again.added == () and again.decision == res.decision


def _emergency_wire():
    from lmpc_llm_planner.schema import EmergencyDecision

    return EmergencyDecision.model_validate({
        "reasoning": "brake",
        "action_guidance": {"accel_interval": 0, "steer_interval": 2},
        "weight_adjustment": {"tracking": "normal", "action": "normal", "smoothness": "normal",
                              "safety": "high"},
    })


def test_emergency_keeps_the_previous_trajectory_while_on_it(scene, mpc_config):
    """An emergency answer has no scenario encoding: it keeps the last decision's ego
    trajectory where that left the route (a lane change or turn under way is not pulled
    back to the route candidate); with no previous decision, once the ego is off that
    curve, or when the previous decision followed the route, the route candidate from
    the current pose; every offered agent is attended either way. (This map's other
    candidates are the junction's other turns, which leave the route: treated here as
    deviations that stay on it, ``leaving_ids`` emptied; the next test has the
    route-leaving case.)"""
    from dataclasses import replace

    scene = replace(scene, leaving_ids=frozenset())
    route, other, before, kept = _deviation_then_emergency(scene, mpc_config)
    assert kept.ego_trajectory == before.ego_trajectory
    assert set(kept.attention) == set(scene.agent_ids)
    fresh = translate(_emergency_wire(), scene=scene, space=mpc_config, meta=META)
    assert flat(fresh.ego_trajectory.control_points) == pytest.approx(flat(route.control_points))
    far = before.model_copy(update={"ego_trajectory": before.ego_trajectory.model_copy(
        update={"control_points": tuple((x + 10.0, y) for x, y in
                                        before.ego_trajectory.control_points)})})
    off = translate(_emergency_wire(), scene=scene, space=mpc_config, meta=META,
                    previous=far)
    assert off.ego_trajectory.candidate_id == scene.route_candidate_id
    on_route = translate(wire(ego=scene.route_candidate_id, attention=[], trajectories={},
                              accel=3, steer=2), scene=scene, space=mpc_config, meta=META)
    moved = on_route.model_copy(update={"ego_trajectory": on_route.ego_trajectory.model_copy(
        update={"control_points": tuple((x, y - 0.5) for x, y in
                                        on_route.ego_trajectory.control_points)})})
    again = translate(_emergency_wire(), scene=scene, space=mpc_config, meta=META,
                      previous=moved)  # an older route-following curve: the fresh one wins
    assert flat(again.ego_trajectory.control_points) == pytest.approx(flat(route.control_points))


def _deviation_then_emergency(scene, mpc_config):
    """The route candidate, a candidate > 5 m away from it, a decision taking that one,
    and an emergency answer translated with that decision as the previous one."""
    route = scene.ego_candidates[scene.route_candidate_id]
    other = next(i for i, c in enumerate(scene.ego_candidates)
                 if float(np.max(np.hypot(*(c.sample(50) - route.sample(50)).T))) > 5.0)
    before = translate(wire(ego=other, attention=[], trajectories={}, accel=3, steer=2),
                       scene=scene, space=mpc_config, meta=META)
    kept = translate(_emergency_wire(), scene=scene, space=mpc_config, meta=META,
                     previous=before)
    return route, other, before, kept


def test_emergency_does_not_keep_a_curve_along_a_candidate_leaving_the_route(scene,
                                                                             mpc_config):
    """Issue 21: an older decision's curve that now runs along a candidate leaving the
    route (``Scene.leaving_ids``: the wrong lane's straight-on choice before a short
    edge's lane change) is no manoeuvre to keep: the emergency answer takes the route
    candidate (kept, it took the ego straight on past its turn, off its route)."""
    from dataclasses import replace

    assert scene.leaving_ids  # this map's other candidates are turns off the route
    scene = replace(scene, leaving_ids=frozenset())
    route, other, before, kept = _deviation_then_emergency(scene, mpc_config)
    assert kept.ego_trajectory == before.ego_trajectory  # a deviation under way: kept
    leaving = replace(scene, leaving_ids=frozenset({other}))
    dropped = translate(_emergency_wire(), scene=leaving, space=mpc_config, meta=META,
                        previous=before)
    assert dropped.ego_trajectory.candidate_id == scene.route_candidate_id
    assert flat(dropped.ego_trajectory.control_points) == \
        pytest.approx(flat(route.control_points))
