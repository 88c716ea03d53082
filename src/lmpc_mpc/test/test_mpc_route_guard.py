"""The route guard: a decision whose candidate leaves the ego's route is not followed."""
from __future__ import annotations

import math

import numpy as np
import pytest

from lmpc_msgs_py.messages import BezierTrajectory, Decision, WeightLevels
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.reference import candidates_for_pose
from lmpc_mpc.route_guard import ROUTE_LEAVE_M, leaves_route, route_corridor_lanes
from lmpc_mpc.solver import MpcSolver

CFG = load_mpc_config()


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


def _junction_candidates(turn: str) -> tuple[object, list]:
    m = S.four_way_junction(ego_turn=turn)
    cands = candidates_for_pose(m, x_m=1.6, y_m=-30.0, yaw_rad=math.pi / 2, lane_id="S_in_0",
                                lookahead_m=60.0)
    return m, cands


@pytest.mark.parametrize("turn", ["l", "s", "r"])
def test_only_the_route_connection_stays_on_the_route(turn: str) -> None:
    m, cands = _junction_candidates(turn)
    assert [c.label.split()[0] for c in cands] == ["go", "turn", "turn"]
    route_lane = {"l": "W_out_0", "s": "N_out_0", "r": "E_out_0"}[turn]
    for c in cands:
        leave = leaves_route(m, c.sample(200))
        if route_lane in c.lane_ids:
            assert leave is None, c.label
        else:
            # it leaves inside or just beyond the junction box (the stop line is 22 m on)
            assert leave is not None and leave.dist_m > ROUTE_LEAVE_M, c.label
            assert 22.0 < leave.along_m < 45.0, (c.label, leave)
    # the corridor: the route's lanes and the junction lanes between route edges only
    assert route_corridor_lanes(m) == {"S_in_0", route_lane,
                                       {"l": ":J_1_0", "s": ":J_0_0", "r": ":J_2_0"}[turn]}


def test_a_curve_past_the_end_of_the_route_is_not_leaving() -> None:
    m = S.four_way_junction(ego_turn="s")
    # straight on, 40 m beyond the end of the route's last lane (N_out_0 ends at y = 100)
    pts = np.column_stack([np.full(50, 1.6), np.linspace(60.0, 140.0, 50)])
    assert leaves_route(m, pts) is None
    # ... but swerving off the route before its end is
    pts[:, 0] = np.linspace(1.6, 12.0, 50)
    assert leaves_route(m, pts) is not None


def _decision(cand) -> Decision:
    return Decision(stamp_s=0.0, seq=1, decision_id=f"d{cand.candidate_id}", source="mock",
                    latency_s=0.0, ttl_s=20.0,
                    ego_trajectory=BezierTrajectory(candidate_id=cand.candidate_id,
                                                    control_points=cand.control_points),
                    accel_interval=CFG.decision_space.neutral_accel_index,
                    steer_interval=CFG.decision_space.neutral_steer_index,
                    weights=WeightLevels(), space_hash=CFG.decision_space.space_hash)


def _drive(solver: MpcSolver, m, decision: Decision, steps: int) -> MpcController:
    ctrl = MpcController(CFG, solver=solver)
    ctrl.reset()
    ctrl.on_decision(decision)
    x, y, yaw, v = 1.6, -30.0, math.pi / 2, 6.0
    for k in range(steps):
        t = round(k * CFG.dt_s, 6)
        ego = S.ego_state(x_m=x, y_m=y, yaw_rad=yaw, v_mps=v, stamp_s=t, seq=k,
                          lane_id=None)
        ctl = ctrl.compute(S.observation(m, ego))
        x, y, yaw, v = (float(r) for r in ctrl.predicted[1]) if ctrl.predicted is not None \
            else (x, y, yaw, v)
        assert ctl.mode == ("baseline" if k == 0 else "decision")  # in force from dt on
    return ctrl


def test_a_decision_for_the_wrong_turn_follows_the_route(solver: MpcSolver) -> None:
    """Route: left at the junction. The decision picks "go straight" (candidate 0): the
    MPC keeps the decision (mode, speed guidance) but tracks the route and turns left."""
    m, cands = _junction_candidates("l")
    straight = cands[0]
    assert "W_out_0" not in straight.lane_ids
    ctrl = _drive(solver, m, _decision(straight), 80)
    st = ctrl.stats()
    assert st.route_overrides == 1  # counted once per decision, not per step
    assert ctrl.reference_id is None
    assert ctrl.route_override_note is not None and "leaves the route" in \
        ctrl.route_override_note
    # the car went left (west), not on north past the junction
    assert ctrl.reference_path is not None
    end = ctrl.reference_path[-1]
    assert end[0] < -15.0 and end[1] < 10.0


def test_a_decision_for_the_route_is_followed(solver: MpcSolver) -> None:
    m, cands = _junction_candidates("l")
    left = next(c for c in cands if "W_out_0" in c.lane_ids)
    ctrl = _drive(solver, m, _decision(left), 10)
    assert ctrl.stats().route_overrides == 0
    assert ctrl.reference_id == left.candidate_id
    assert ctrl.route_override_note is None
