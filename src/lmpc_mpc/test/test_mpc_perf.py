"""The fast paths of the MPC agree with the plain definitions they replace."""
import math

import numpy as np
import pytest

from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.reference import _Polyline, braking_envelope, timed_reference
from lmpc_mpc.obstacles import halfplanes
from lmpc_mpc.solver import NOBS, MpcProblem, MpcSolver, Obstacle

CFG = load_mpc_config()


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


def test_project_many_matches_project() -> None:
    rng = np.random.default_rng(3)
    line = _Polyline.of(np.cumsum(rng.normal(size=(60, 2)), axis=0))
    pts = rng.normal(size=(200, 2)) * 6.0
    s_v, d_v = line.project_many(pts)
    for p, s, d in zip(pts, s_v, d_v):
        s1, d1, _ = line.project(float(p[0]), float(p[1]))
        assert s == pytest.approx(s1, abs=1e-9) and d == pytest.approx(d1, abs=1e-9)


def _backward_pass_loop(v_cap: np.ndarray, dec: float, ds: float) -> np.ndarray:
    v_b = v_cap.copy()
    for i in range(len(v_b) - 2, -1, -1):
        v_b[i] = min(v_b[i], math.sqrt(v_b[i + 1] ** 2 + 2.0 * dec * ds))
    return v_b


def test_braking_envelope_equals_the_backward_recursion() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        cap = np.where(rng.random(300) < 0.05, 0.0, rng.uniform(2.0, 14.0, 300))
        dec = float(rng.uniform(0.5, 6.0))
        fast = braking_envelope(cap, dec_mps2=dec, ds_m=0.5)
        assert np.allclose(fast, _backward_pass_loop(cap, dec, 0.5), atol=1e-9)


def test_timed_reference_stops_at_the_stop_point() -> None:
    pts = np.c_[np.linspace(0.0, 80.0, 81), np.zeros(81)]
    ref = timed_reference(pts, v0_mps=12.0, v_max_mps=12.0, a_max_mps2=1.5,
                          a_lat_max_mps2=2.5, horizon=60, dt_s=0.1, stop_at_m=30.0)
    assert ref.states[:, 0].max() <= 30.0 + 1e-9 and ref.states[-1, 3] < 0.2
    assert np.all(np.diff(ref.states[:, 3]) <= 1e-9)  # only braking from the limit


def test_halfplane_is_a_tangent_lower_bound_of_the_stretched_distance() -> None:
    rng = np.random.default_rng(5)
    n = CFG.horizon
    yaw = rng.uniform(-math.pi, math.pi, n + 1)
    rows = np.zeros((1, n + 1, NOBS))
    rows[0, :, 0:2] = rng.normal(size=(n + 1, 2)) * 10.0
    rows[0, :, 4] = rng.uniform(1.0, 6.0, n + 1)  # rho
    at = rows[0, :, 0:2] + rng.normal(size=(n + 1, 2)) * 5.0
    hp = halfplanes(rows, at[None], yaw)[0]

    def stretched(p: np.ndarray) -> np.ndarray:
        dx, dy = p[:, 0] - rows[0, :, 0], p[:, 1] - rows[0, :, 1]
        c, s = np.cos(yaw), np.sin(yaw)
        return np.hypot(c * dx + s * dy, rows[0, :, 4] * (-s * dx + c * dy))

    def lin(p: np.ndarray) -> np.ndarray:
        return hp[:, 0] * p[:, 0] + hp[:, 1] * p[:, 1] + hp[:, 2]

    assert np.allclose(lin(at), stretched(at), atol=1e-9)  # tangent at the guess
    for _ in range(20):
        p = at + rng.normal(size=(n + 1, 2)) * 8.0
        assert np.all(lin(p) <= stretched(p) + 1e-9)  # never above: conservative


def _problem(obstacles: tuple[Obstacle, ...]) -> MpcProblem:
    n = CFG.horizon
    t = np.arange(n + 1) * CFG.dt_s
    ref = np.c_[10.0 + 8.0 * t, np.full(n + 1, -4.8), np.zeros(n + 1), np.full(n + 1, 8.0)]
    return MpcProblem(x0=(10.0, -4.8, 0.0, 8.0), u_prev=(0.0, 0.0), u_prev2=(0.0, 0.0),
                      reference=ref, reference_curvature_1pm=np.zeros(n + 1),
                      weights=CFG.decision_space.weights_for(None), obstacles=obstacles)


def test_far_obstacles_get_no_slot_and_change_nothing(solver) -> None:
    n = CFG.horizon
    far = Obstacle("far", np.tile([400.0, 300.0], (n + 1, 1)), 4.5, 1.8)
    solver.reset()
    base = solver.solve(_problem(()))
    solver.reset()
    with_far = solver.solve(_problem((far,)))
    assert base.success and with_far.success
    assert solver._params(_problem((far,)))[2] == 0  # compiled without obstacle slots
    assert with_far.u0 == pytest.approx(base.u0, abs=1e-9)


def test_near_obstacle_gets_a_slot_and_brakes(solver) -> None:
    n = CFG.horizon
    stopped = Obstacle("car", np.tile([40.0, -4.8], (n + 1, 1)), 4.5, 1.8)
    solver.reset()
    free = solver.solve(_problem(()))
    solver.reset()
    res = solver.solve(_problem((stopped,)))
    _, _, n_slots = solver._params(_problem((stopped,)))
    assert n_slots >= 1 and res.success
    assert res.u0[0] < free.u0[0]  # it brakes for the car ahead
    assert res.predicted[:, 3].min() < 8.0 - 2.0
    assert res.predicted[-1, 0] < 40.0 - 4.5  # and plans to stay behind it


def test_iterations_stay_low_in_closed_loop(solver) -> None:
    from lmpc_mpc.controller import MpcController
    from lmpc_mpc.solver import simulate_bicycle
    solver.reset()
    ctrl = MpcController(CFG, solver=solver)
    m = S.straight_road(length_m=600.0)
    x = np.array([10.0, -4.8, 0.0, 10.0])
    iters = []
    for k in range(50):
        t = k * CFG.dt_s
        agents = [S.agent("lead", x_m=45.0 + 5.0 * t, y_m=-4.8, yaw_rad=0.0, v_mps=5.0,
                          lane_id="E0_0"),
                  S.agent("side", x_m=20.0 + 9.0 * t, y_m=-1.6, yaw_rad=0.0, v_mps=9.0,
                          lane_id="E0_1")]
        ego = S.ego_state(x_m=float(x[0]), y_m=float(x[1]), yaw_rad=float(x[2]),
                          v_mps=float(x[3]), stamp_s=t, seq=k, lane_id="E0_0")
        problem, _, _ = ctrl._problem(S.observation(m, ego, agents), None)
        res = solver.solve(problem)
        assert res.success
        iters.append(res.iterations)
        x = simulate_bicycle(x, np.array([res.u0]), dt_s=CFG.dt_s)[1]
    assert np.median(iters) <= 8 and max(iters) <= 20
