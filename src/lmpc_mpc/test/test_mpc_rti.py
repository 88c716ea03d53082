"""SQP real-time iteration (``solver: sqp_rti``): agreement with the NLP, failures, config."""
import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import MpcConfigError, SOLVER_ENV, load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcProblem, MpcSolver, Obstacle, simulate_bicycle

CFG = load_mpc_config().model_copy(update={"solver": "fatrop"})
RTI = CFG.model_copy(update={"solver": "sqp_rti", "rti_fallback": False,
                             "rti_max_move_accel_mps2": 20.0, "rti_max_move_steer_rad": 2.0})
"""The RTI alone: every step it computes is taken (no step-size limit), a step it cannot
compute is a failure (no FATROP fallback)."""
HYBRID = CFG.model_copy(update={"solver": "sqp_rti"})
"""``sqp_rti`` as configured: FATROP answers a step the RTI does not deliver."""


@pytest.fixture(scope="module")
def rti() -> MpcSolver:
    return MpcSolver(RTI)


@pytest.fixture(scope="module")
def fatrop() -> MpcSolver:
    return MpcSolver(CFG)


def _lead_problem(*, gap_m: float, v0: float, lead_v: float) -> MpcProblem:
    """Ego on y = 0 at v0, reference at 10 m/s straight on, a car ``gap_m`` ahead in the
    same lane at ``lead_v``: the safety term is active (the reference runs into it)."""
    n, dt = CFG.horizon, CFG.dt_s
    t = np.arange(n + 1) * dt
    ref = np.c_[v0 * t, np.zeros(n + 1), np.zeros(n + 1), np.full(n + 1, 10.0)]
    lead = Obstacle("lead", np.c_[gap_m + lead_v * t, np.zeros(n + 1)], 4.5, 1.8)
    return MpcProblem(x0=(0.0, 0.0, 0.0, v0), u_prev=(0.0, 0.0), u_prev2=(0.0, 0.0),
                      reference=ref, reference_curvature_1pm=np.zeros(n + 1),
                      weights=CFG.decision_space.weights_for(None), obstacles=(lead,))


def test_converged_rti_matches_the_nlp_with_the_safety_term_active(
        rti: MpcSolver, fatrop: MpcSolver) -> None:
    """From a cold start the RTI takes ``rti_cold_iterations`` Gauss-Newton steps; with the
    slack form of the safety term its optimum is the NLP's (same cost, same bounds)."""
    prob = _lead_problem(gap_m=14.0, v0=9.0, lead_v=3.0)
    fatrop.reset()
    ref = fatrop.solve(prob)
    rti.reset()
    got = rti.solve(prob)
    assert ref.success and got.success, (ref.status, got.status)
    assert ref.u0[0] < -1.0  # the lead car really makes it brake
    # FATROP stops at a KKT tolerance of 1e-3; a few 1e-2 m/s^2 is agreement
    assert got.u0[0] == pytest.approx(ref.u0[0], abs=0.05)
    assert np.allclose(got.controls[:, 0], ref.controls[:, 0], atol=0.1)
    assert np.allclose(got.predicted, ref.predicted, atol=0.1)


def test_one_warm_step_tracks_a_moving_problem(rti: MpcSolver, fatrop: MpcSolver) -> None:
    """Warm-started from the shifted previous solution, one or two steps per control step
    follow the NLP's solution as the lead car comes closer (closed loop, RK4 plant)."""
    rti.reset()
    fatrop.reset()
    x = np.array([0.0, 0.0, 0.0, 9.0])
    diffs = []
    for k in range(25):
        base = _lead_problem(gap_m=20.0 - 6.0 * k * CFG.dt_s, v0=float(x[3]), lead_v=3.0)
        prob = dataclasses.replace(base, x0=tuple(float(v) for v in x))
        got, ref = rti.solve(prob), fatrop.solve(prob)
        assert got.success and ref.success
        diffs.append(abs(got.u0[0] - ref.u0[0]))
        x = simulate_bicycle(x, np.array([got.u0]), dt_s=CFG.dt_s)[1]
        x[0] = 0.0  # keep the ego at the problem's origin (the lead moves instead)
    assert max(diffs) < 0.05, diffs
    assert float(np.median(diffs)) < 0.01, diffs


def test_infeasible_start_is_a_failure(rti: MpcSolver) -> None:
    veh = DEFAULT_VEHICLE
    n = CFG.horizon
    v0 = veh.max_speed_mps + 3.0 * veh.max_decel_mps2 * CFG.dt_s + 5.0
    t = np.arange(n + 1) * CFG.dt_s
    ref = np.c_[15.0 * t, np.zeros(n + 1), np.zeros(n + 1), np.full(n + 1, 15.0)]
    prob = MpcProblem(x0=(0.0, 0.0, 0.0, v0), u_prev=(0.0, 0.0), u_prev2=(0.0, 0.0),
                      reference=ref, reference_curvature_1pm=np.zeros(n + 1),
                      weights=CFG.decision_space.weights_for(None))
    rti.reset()
    res = rti.solve(prob)
    assert not res.success and "QP failed" in res.status
    assert np.all(np.isfinite(res.predicted)) and all(math.isfinite(u) for u in res.u0)


def _nan_answers(qp: Any, monkeypatch: pytest.MonkeyPatch) -> Any:
    """Make ``qp``'s HPIPM solver answer with non-finite numbers; returns the real one
    (set it back with ``monkeypatch.setattr(qp, "_qp", real)``)."""
    real = qp._qp

    class NanQp:
        def __call__(self, **kw):
            out = real(**kw)
            return {**out, "x": out["x"] * np.nan}

        def stats(self):
            return real.stats()

    monkeypatch.setattr(qp, "_qp", NanQp())
    return real


def test_non_finite_qp_answer_is_a_failure_and_clears_the_warm_start(
        rti: MpcSolver, monkeypatch: pytest.MonkeyPatch) -> None:
    prob = _lead_problem(gap_m=30.0, v0=8.0, lead_v=8.0)
    rti.reset()
    assert rti.solve(prob).success
    n_slots = rti._warm_slots
    assert n_slots is not None
    qp = rti.rti(n_slots)
    real = _nan_answers(qp, monkeypatch)
    res = rti.solve(prob)
    assert not res.success and "non-finite" in res.status
    assert rti._warm is None
    monkeypatch.setattr(qp, "_qp", real)
    assert rti.solve(prob).success  # and it recovers from a cold start


def test_rti_controller_stops_behind_a_stopped_car(rti: MpcSolver) -> None:
    rti.reset()
    ctrl = MpcController(RTI, solver=rti)
    m = S.straight_road()
    car = S.agent("car1", x_m=80.0, y_m=-4.8, yaw_rad=0.0, lane_id="E0_0")
    log = S.closed_loop(ctrl, m, (10.0, -4.8, 0.0, 10.0), 120, lambda t: [car])
    for _, _, ctl in log:
        assert ctl.mode == "baseline", ctl.solver_status
    x = log[-1][1]
    ys = [s[1] for _, s, _ in log]
    gap = 80.0 - x[0] - 4.5
    assert x[3] < 0.3 and 0.8 < gap < 6.0
    assert max(abs(y + 4.8) for y in ys) < 0.5


def test_solver_env_overrides_the_file(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(SOLVER_ENV, "sqp_rti")
    assert load_mpc_config().solver == "sqp_rti"
    monkeypatch.setenv(SOLVER_ENV, "ipopt")
    assert load_mpc_config().solver == "ipopt"
    monkeypatch.setenv(SOLVER_ENV, "osqp")
    with pytest.raises(MpcConfigError, match="solver"):
        load_mpc_config()


def test_a_cold_iteration_still_moving_is_a_failure() -> None:
    """A cold start (or a reconverge after a decision) whose last Gauss-Newton step still
    moved a planned control by more than a warm step may (``rti_step_*``) has no solution
    yet: a failure (the caller's shifted plan, then the brake), as FATROP's unconverged
    solve is; the same problem with the default cold steps converges, and a warm step
    is never judged by it."""
    prob = _lead_problem(gap_m=14.0, v0=9.0, lead_v=3.0)
    one = MpcSolver(RTI.model_copy(update={"rti_cold_iterations": 1}))
    res = one.solve(prob)
    assert not res.success and "cold RTI still moving after 1 steps" in res.status, res.status
    assert one._warm is None
    five = MpcSolver(RTI)
    assert five.solve(prob).success
    warm = five.solve(dataclasses.replace(prob, x0=(0.5, 0.0, 0.0, 9.0)))
    assert warm.success and warm.iterations == 1


def test_a_warm_step_that_swings_the_plan_is_not_trusted() -> None:
    """A warm step moving a planned control by more than ``rti_max_move_*`` (the guess
    was far from the new problem: a standing car appears close ahead) is not delivered
    by the RTI alone; the hybrid answers it with FATROP's solution of the same problem
    and counts it. With the limits opened the RTI takes that step itself."""
    before, jumped = (_lead_problem(gap_m=60.0, v0=9.0, lead_v=9.0),
                      _lead_problem(gap_m=12.0, v0=9.0, lead_v=0.0))
    alone = MpcSolver(RTI.model_copy(update={"rti_max_move_accel_mps2": 3.0,
                                             "rti_max_move_steer_rad": 0.3}))
    assert alone.solve(before).success
    res = alone.solve(jumped)
    assert not res.success and "RTI step too large" in res.status, res.status
    hybrid = MpcSolver(HYBRID)
    assert hybrid.solve(before).success and hybrid.rti_fallbacks == 0
    got = hybrid.solve(jumped)
    assert got.success and "FATROP after the RTI: RTI step too large" in got.status
    assert hybrid.rti_fallbacks == 1
    ref = MpcSolver(CFG)
    ref.solve(before)
    want = ref.solve(jumped)
    assert got.u0 == pytest.approx(want.u0, abs=1e-9)  # FATROP's answer, same warm start
    loose = MpcSolver(RTI)
    loose.solve(before)
    took = loose.solve(jumped)
    assert took.success and took.iterations == 1, took.status


def test_the_hybrid_answers_a_failed_qp_with_fatrop(monkeypatch: pytest.MonkeyPatch) -> None:
    """An RTI QP that gives non-finite numbers: the hybrid's step is FATROP's, and the
    next step is the RTI's again, warm-started from FATROP's solution."""
    prob = _lead_problem(gap_m=30.0, v0=8.0, lead_v=8.0)
    hybrid = MpcSolver(HYBRID)
    assert hybrid.solve(prob).success
    qp = hybrid.rti(hybrid._warm_slots)
    real = _nan_answers(qp, monkeypatch)
    res = hybrid.solve(prob)
    assert res.success and "non-finite" in res.status and hybrid.rti_fallbacks == 1
    monkeypatch.setattr(qp, "_qp", real)
    nxt = hybrid.solve(prob)
    assert nxt.success and nxt.status.startswith("RTI_Step_Succeeded (1 step")
