"""Junction turns sharper than 110 degrees (issue 21: the random and spider nets).

A right turn of 123 degrees through a junction lane of radius 4.4 m (the car turns no
tighter than ~4.2 m at full steer), as on the random net: the MPC tracks the route's own
centreline there (``reference.sharp_turn_path``) and the car stays on its lanes. On main
the Bezier reference cut the turn and the lead-in (meant for a car turned away from its
path) replaced the rest of it by a 6 m arc mid-turn: the car ran wide, off the route.
"""
import math

import numpy as np
import pytest

from lmpc_msgs_py.messages import LaneLink, MapSnapshot, TargetArea
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.reference import _Polyline, route_candidate, route_path
from lmpc_mpc.solver import MpcSolver, simulate_bicycle

CFG = load_mpc_config()


def sharp_junction(turn_deg: float = 123.0, radius_m: float = 4.4, *,
                   arc_points: int = 12) -> MapSnapshot:
    """An approach lane northbound along x = 0 up to the junction at the origin, a right
    turn of ``turn_deg`` through an internal lane of ``radius_m``, the exit lane 100 m
    straight on (and a straight-on connection, so the junction has two directions)."""
    a0 = math.pi  # the arc's centre lies to the right (east) of the approach
    arc = S._arc(radius_m, 0.0, radius_m, a0, a0 - math.radians(turn_deg),
                 n=arc_points)
    end = np.array(arc[-1])
    heading = math.pi / 2 - math.radians(turn_deg)
    out_end = end + 100.0 * np.array([math.cos(heading), math.sin(heading)])
    lanes = (
        S._lane("A_0", S._line(0.0, -100.0, 0.0, 0.0), successors=[
            LaneLink(to_lane="B_0", via_lane=":J_0_0", direction="s"),
            LaneLink(to_lane="C_0", via_lane=":J_1_0", direction="r")]),
        S._lane(":J_0_0", S._line(0.0, 0.0, 0.0, 8.0), internal=True,
                successors=[LaneLink(to_lane="B_0", direction="s")]),
        S._lane("B_0", S._line(0.0, 8.0, 0.0, 108.0)),
        S._lane(":J_1_0", arc, internal=True,
                successors=[LaneLink(to_lane="C_0", direction="r")]),
        S._lane("C_0", S._line(float(end[0]), float(end[1]), float(out_end[0]),
                               float(out_end[1]))),
    )
    target = end + 80.0 * np.array([math.cos(heading), math.sin(heading)])
    return MapSnapshot(stamp_s=0.0, lanes=lanes, ego_route=("A_0", ":J_1_0", "C_0"),
                       target=TargetArea(lane_ids=("C_0",), center=tuple(target),
                                         radius_m=10.0))


def test_only_junctions_turning_more_than_100_degrees_are_sharp() -> None:
    assert route_path(sharp_junction(123.0)).sharp_turns
    # examples/city.yaml's right turn from edge 5 onto 28: 109.9 degrees, radius 4.75 m
    assert route_path(sharp_junction(109.9, radius_m=4.75)).sharp_turns
    assert route_path(sharp_junction(105.0, radius_m=8.0)).sharp_turns
    assert not route_path(sharp_junction(95.0, radius_m=4.75)).sharp_turns
    assert not route_path(sharp_junction(90.0)).sharp_turns


def test_the_route_reference_in_a_sharp_turn_keeps_to_the_centreline(
        solver: MpcSolver) -> None:
    m = sharp_junction()
    centre = route_path(m).line
    # the ego entering the turn, 0.3 m outside the centreline, yawed 20 deg into it
    ego = S.ego_state(x_m=-0.3, y_m=0.5, yaw_rad=math.radians(70.0), v_mps=3.5,
                      lane_id=":J_1_0", route_index=1)
    ctrl = MpcController(CFG, solver=solver)
    ctrl.compute(S.observation(m, ego))
    path = ctrl.reference_path
    # beyond the first 6 m (the ego's offset fades out) and through the turn (15 m)
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    dev = centre.project_many(path[(along > 6.0) & (along < 15.0)])[1]
    assert dev.max() < 0.4
    # the Bezier route candidate from the same pose cuts the turn by more (0.66 m)
    bez = route_candidate(m, ego).sample(200)
    along_b = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(bez, axis=0).T))])
    assert centre.project_many(bez[(along_b > 6.0) & (along_b < 15.0)])[1].max() \
        > 1.5 * dev.max()


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


@pytest.mark.parametrize("turn_deg,radius_m", [(130.0, 4.0), (109.9, 4.75)])
def test_the_car_turns_sharp_on_its_route(solver: MpcSolver, turn_deg: float,
                                          radius_m: float) -> None:
    """Closed loop (the solver's bicycle, steer rate limited as the bridge does): from
    40 m before the junction at 10 m/s, through a 130-degree turn of radius 4 m drawn with
    5 points (SUMO draws junction lanes coarsely), onto the exit lane. On main the car
    ran wide: 15.4 m off its route (126 degrees, 4.2 m, 4 points: 14.0 m); here < 0.5 m.
    And examples/city.yaml's 109.9-degree turn of radius 4.75 m, which the 110-degree
    threshold left to the Bezier references (the rules' decisions there ran off route)."""
    m = sharp_junction(turn_deg, radius_m, arc_points=5)
    centre: _Polyline = route_path(m).line
    solver.reset()
    ctrl = MpcController(CFG, solver=solver)
    x = np.array([0.0, -40.0, math.pi / 2, 10.0])
    steer = 0.0
    worst = 0.0
    rate = ctrl.vehicle.max_steer_rate_radps * CFG.dt_s
    for k in range(150):
        ego = S.ego_state(x_m=float(x[0]), y_m=float(x[1]),
                          yaw_rad=float(math.remainder(x[2], 2 * math.pi)),
                          v_mps=float(x[3]), stamp_s=k * CFG.dt_s, seq=k, steer_rad=steer,
                          route_index=0 if x[1] < 0.0 else 1)
        ctl = ctrl.compute(S.observation(m, ego))
        steer = float(np.clip(ctl.steer_rad, steer - rate, steer + rate))
        x = simulate_bicycle(x, np.array([[ctl.accel_mps2, steer]]), dt_s=CFG.dt_s)[1]
        worst = max(worst, float(centre.project(float(x[0]), float(x[1]))[1]))
    s_end, _, _ = centre.project(float(x[0]), float(x[1]))
    assert worst < 1.0  # on its lanes (the bridge's off-route tolerance is 5 m)
    assert s_end > 100.0 + 9.0 + 60.0  # well out along the exit lane
