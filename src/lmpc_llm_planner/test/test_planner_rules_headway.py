"""The rules backend's following headway, early swerve round a hard-braking leader and gap
acceptance with a queue behind (docs/lmpc_rules.md, "Issue 3 pass"), on hand-made
observations: the two-lane straight road of ``lmpc_mpc.synthetic.straight_road`` and the
junction of conftest.py. No ROS, no SUMO."""
from __future__ import annotations

import math

from lmpc_mpc import synthetic as syn
from rules_kit import CAR_LENGTH_M, accel_mid, ask, car, road_obs
from rules_kit import chosen_label as label

from lmpc_msgs_py.messages import Agent


# -- headway behind a moving leader -------------------------------------------------------------
def test_too_close_behind_a_leader_drops_back(road, planner_config, mpc_config):
    # 12 m bumper gap at 12 m/s: the MPC's 1 s headway, too short to brake or steer round
    # a leader braking at 8 m/s^2
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 12.0, v_mps=12.0)
    w, scene = ask(road_obs(road, [lead], v_mps=12.0), planner_config, mpc_config)
    assert accel_mid(w, mpc_config) < 0.0
    assert "lead" in w.scenario_encoding.attention
    assert w.weight_adjustment.action == "high"
    assert not label(w, scene).startswith("change to the")  # same speed: no overtaking


def test_leader_at_a_safe_distance_is_not_braked_for(road, planner_config, mpc_config):
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 45.0, v_mps=12.0)
    w, _ = ask(road_obs(road, [lead], v_mps=12.0), planner_config, mpc_config)
    assert accel_mid(w, mpc_config) >= 0.0


def test_wanted_headway_grows_with_speed(road, planner_config, mpc_config):
    """The gap below which the ego drops back is larger at a higher common speed."""
    def threshold_m(v_mps: float) -> float:
        for gap in range(5, 80):
            lead = car("lead", x_m=50.0 + CAR_LENGTH_M + gap, v_mps=v_mps)
            w, _ = ask(road_obs(road, [lead], v_mps=v_mps), planner_config, mpc_config)
            if accel_mid(w, mpc_config) >= -0.5:  # neutral or faster: gap accepted
                return float(gap)
        return math.inf

    slow, fast = threshold_m(8.0), threshold_m(13.0)
    assert slow < fast < math.inf


# -- a leader braking hard: swerve early ---------------------------------------------------------
def test_hard_braking_leader_takes_free_neighbour_lane(road, planner_config, mpc_config):
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 25.0, v_mps=10.0, a_mps2=-8.0)
    w, scene = ask(road_obs(road, [lead], v_mps=12.0), planner_config, mpc_config)
    assert label(w, scene).startswith("change to the left")


def test_hard_braking_leader_with_occupied_neighbour_lane_brakes(road, planner_config,
                                                                 mpc_config):
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 25.0, v_mps=10.0, a_mps2=-8.0)
    beside = car("beside", x_m=51.0, v_mps=12.0, left=True)
    w, scene = ask(road_obs(road, [lead, beside], v_mps=12.0), planner_config, mpc_config)
    assert not label(w, scene).startswith("change to the")
    assert accel_mid(w, mpc_config) < 0.0


def test_leader_keeping_its_speed_is_not_swerved_round(road, planner_config, mpc_config):
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 25.0, v_mps=12.0)
    w, scene = ask(road_obs(road, [lead], v_mps=12.0), planner_config, mpc_config)
    assert not label(w, scene).startswith("change to the")


# -- gap acceptance with a queue behind the waiting ego ----------------------------------------
def _smallest_accepted_y_m(map_, obs_factory, oncoming_factory, planner_config, mpc_config,
                           behind: list[Agent]) -> float:
    """Nearest position of an oncoming car at which the waiting ego turns (accelerates)."""
    for y in range(5, 150):
        obs = obs_factory(map_, ego_y_m=-11.5, ego_v_mps=0.0,
                          agents=[oncoming_factory("car1", y_m=float(y), v_mps=10.0), *behind])
        w, _ = ask(obs, planner_config, mpc_config)
        if accel_mid(w, mpc_config) > 0.0:
            return float(y)
    return math.inf


def test_queue_behind_accepts_a_shorter_gap(left_turn_map, obs_factory, oncoming_factory,
                                            planner_config, mpc_config):
    follower = syn.agent("back", x_m=1.6, y_m=-11.5 - CAR_LENGTH_M - 2.5, yaw_rad=math.pi / 2,
                         v_mps=0.0, lane_id="S_in_0")
    alone = _smallest_accepted_y_m(left_turn_map, obs_factory, oncoming_factory,
                                   planner_config, mpc_config, [])
    queued = _smallest_accepted_y_m(left_turn_map, obs_factory, oncoming_factory,
                                    planner_config, mpc_config, [follower])
    assert queued < alone < math.inf
    # never below the hysteresis floor: at 10 m/s the difference is at most
    # go_hysteresis_s * 10 m (+ 1 m of the scan's step)
    assert alone - queued <= planner_config.rules.go_hysteresis_s * 10.0 + 1.0


def test_closing_on_a_hard_braking_leader_brakes_for_where_it_will_stand(
        road, planner_config, mpc_config):
    # 18 m behind a leader at 2 m/s braking at 8 m/s^2, closing at 9.5 m/s (TTC 1.9 s):
    # the constant-velocity need (9.5^2 / 32 = 2.8 m/s^2) would end the ego a few metres
    # behind it, out of steering reach; stopping 10 m short of where it stands needs ~8
    lead = car("lead", x_m=50.0 + CAR_LENGTH_M + 18.0, v_mps=2.0, a_mps2=-8.0)
    beside = car("beside", x_m=51.0, v_mps=11.5, left=True)  # no swerve possible
    w, scene = ask(road_obs(road, [lead, beside], v_mps=11.5), planner_config, mpc_config)
    strongest = min(0.5 * sum(iv) for iv in mpc_config.accel_intervals_mps2)
    assert accel_mid(w, mpc_config) == strongest
    assert "lead" in w.scenario_encoding.attention
    assert "behind where it stands" in w.reasoning
