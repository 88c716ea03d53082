"""A car standing at an angle beside the path reaches it with a corner (docs/lmpc_mpc.md,
"The ego's body, not its centre"; usi training seed 10032).

The crossing rules took an agent as on the path when its CENTRE came within half the two
widths + the lateral gap of the reference's centre line. A car standing at ~35 degrees to
the path with its centre 2.6 m off it is clear by that test, while its front corner is
0.6 m from the centre line: the ego drove past it, its side through the corner. The
corner test applies in a junction (the car or the ego on an internal lane), where cars
stand at angles to the ego's path; on a road it is left out (it stopped the ego passing a
stopped car round it).
"""
import math

import numpy as np
import pytest

from lmpc_msgs_py.messages import Agent
from lmpc_mpc import crossing as C
from lmpc_mpc import synthetic as S
from lmpc_mpc.closeness import closeness
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.obstacles import Obstacle
from lmpc_mpc.polyline import Polyline
from lmpc_mpc.solver import MpcSolver

CFG = load_mpc_config()
CLEAR_M = 0.9 + CFG.safety_lateral_gap_m  # the ego's half width + the lateral gap
ANGLED_YAW = -0.6  # pointing 34 degrees towards the path


def _standing(x: float, lateral: float, yaw: float | None) -> Obstacle:
    return Obstacle("car", np.tile([x, lateral], (CFG.horizon + 1, 1)), 4.5, 1.8,
                    yaw_rad=yaw, junction=True)


def test_a_corner_of_a_car_at_an_angle_reaches_the_path() -> None:
    line = Polyline.of([(0.0, 0.0), (100.0, 0.0)])
    # centre 2.6 m off the path: clear of it by half the two widths + the gap (2.4 m)
    assert 2.6 > 1.8 + CFG.safety_lateral_gap_m
    s = C._body_on_path(line, _standing(30.0, 2.6, ANGLED_YAW), CLEAR_M)
    # its front right corner: 30 + 2.25 cos(0.6) - 0.9 sin(0.6), 0.59 m off the path
    assert s == pytest.approx(30.0 + 2.25 * math.cos(0.6) - 0.9 * math.sin(0.6), abs=1e-6)
    # parallel to the path at the same distance: its side 1.7 m off, clear
    assert C._body_on_path(line, _standing(30.0, 2.6, 0.0), CLEAR_M) is None
    # heading unknown; or behind the ego (the path starts at the ego)
    assert C._body_on_path(line, _standing(30.0, 2.6, None), CLEAR_M) is None
    assert C._body_on_path(line, _standing(-8.0, 2.6, ANGLED_YAW), CLEAR_M) is None


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


# standing nose towards the ego's lane: centre 2.6 m left of the ego's lane centre
# (y = -4.8), its front right corner 0.59 m from it; on a junction's internal lane
CAR = S.agent("angled", x_m=60.0, y_m=-4.8 + 2.6, yaw_rad=ANGLED_YAW, lane_id=":J_0_0")


def _min_gap_m(states: list[np.ndarray]) -> float:
    """The smallest box-to-box gap between the ego along ``states`` and the car."""
    return min(closeness(S.ego_state(x_m=float(x[0]), y_m=float(x[1]), yaw_rad=float(x[2]),
                                     v_mps=float(x[3])), CAR).gap_m for x in states)


def _drive(solver: MpcSolver, car: Agent = CAR) -> list[np.ndarray]:
    """12 s from 8 m/s on the straight road, the MPC baseline, the car standing."""
    solver.reset()
    ctrl = MpcController(CFG, solver=solver)
    log = S.closed_loop(ctrl, S.straight_road(), (10.0, -4.8, 0.0, 8.0), 120,
                        lambda t: [car])
    return [x for _, x, _ in log]


def test_the_ego_stops_short_of_the_corner(solver: MpcSolver,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    corner_x = 60.0 + 2.25 * math.cos(0.6) - 0.9 * math.sin(0.6)
    states = _drive(solver)
    front = max(s[0] for s in states) + 2.25
    assert front < corner_x - 0.5, f"the ego's front came to {front:.2f} m, corner {corner_x:.2f}"
    assert states[-1][3] < 0.3 and _min_gap_m(states) > 0.1
    # the same car on a road lane: left to the centre test, the ego drives on
    on_road = _drive(solver, CAR.model_copy(update={"lane_id": "E0_1"}))
    assert max(s[0] for s in on_road) > corner_x + 4.5
    # the test without the body: the ego drives on past the car, through its corner
    monkeypatch.setattr(C, "_BODY_SPEED_MPS", 0.0)
    blind = _drive(solver)
    assert max(s[0] for s in blind) > corner_x + 4.5
    assert _min_gap_m(blind) == 0.0
