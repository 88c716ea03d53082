"""Trailing followers in the safety term, and the RTI's extra steps after a jump.

Both come from the usi seeds 8 / 17 collisions with ``solver: sqp_rti`` (see
docs/lmpc_mpc.md, "RTI as the default"): a follower's constant-speed forecast ran through
the braking ego and the safety term made the plan dodge it sideways; and one
Gauss-Newton step from a far guess (a jump of the reference) was far from the optimum.
"""
import dataclasses

import numpy as np
import pytest

from lmpc_mpc.config import MpcConfigError, SOLVER_ENV, load_mpc_config
from lmpc_mpc.obstacles import obstacle_rows
from lmpc_mpc.solver import MpcProblem, MpcSolver, Obstacle, simulate_bicycle

CFG = load_mpc_config().model_copy(update={"solver": "fatrop"})
N, DT = CFG.horizon, CFG.dt_s
_ADAPTIVE = 4
"""``rti_iterations`` of the adaptive RTI under test (the packaged default is 1)."""
T = np.arange(N + 1) * DT


def _braking_reference(*, v0_mps: float, stop_at_m: float, decel_mps2: float) -> np.ndarray:
    """(N+1, 4) reference on y = 0 from x = 0: v0, braked at ``decel`` to stop at
    ``stop_at_m`` (the controller's stop-line / braking-bias profile, simplified)."""
    rows = []
    s, v = 0.0, v0_mps
    for _ in range(N + 1):
        rows.append((s, 0.0, 0.0, v))
        v_new = min(v, (2.0 * decel_mps2 * max(stop_at_m - s, 0.0)) ** 0.5)
        s += 0.5 * (v + v_new) * DT
        v = v_new
    return np.array(rows)


def _stopping_problem(obstacles: tuple[Obstacle, ...]) -> MpcProblem:
    """The ego at 7.2 m/s is asked to stop within 8 m (faster than its smoothness
    weights let it): the plan overshoots the reference, as at usi seed 8, t = 7.6 s."""
    ref = _braking_reference(v0_mps=7.2, stop_at_m=8.0, decel_mps2=3.2)
    return MpcProblem(x0=(0.0, 0.0, 0.0, 7.2), u_prev=(0.2, 0.0), u_prev2=(0.2, 0.0),
                      reference=ref, reference_curvature_1pm=np.zeros(N + 1),
                      weights=CFG.decision_space.weights_for(None),
                      bias_accel_mps2=np.full(N, -3.0),
                      obstacles=obstacles)


def _car(name: str, *, x_m: float, y_m: float, vx_mps: float, vy_mps: float = 0.0
         ) -> Obstacle:
    return Obstacle(name, np.c_[x_m + vx_mps * T, y_m + vy_mps * T], 4.5, 1.8)


@pytest.mark.parametrize("solver", ["fatrop", "sqp_rti"])
def test_a_trailing_followers_forecast_does_not_push_the_ego_aside(solver: str) -> None:
    """The follower, 12 m behind in the ego's lane at 7.3 m/s, is forecast at constant
    speed *through* the stopping ego. It must not count: the plan stays in the lane and
    is the plan without it (before: the plan swerved up to 5 m aside, FATROP failed)."""
    follower = _car("follower", x_m=-12.0, y_m=0.0, vx_mps=7.3)
    assert follower.xy_m[-1, 0] > 8.0  # the forecast really passes the ego's stop point
    mpc = MpcSolver(CFG.model_copy(update={"solver": solver}))
    with_it = mpc.solve(_stopping_problem((follower,)))
    mpc.reset()
    without = mpc.solve(_stopping_problem(()))
    assert with_it.success and without.success, (with_it.status, without.status)
    assert float(np.max(np.abs(with_it.predicted[:, 1]))) < 0.1
    assert with_it.u0[0] == pytest.approx(without.u0[0], abs=1e-3)
    assert with_it.u0[0] < -1.0  # it brakes


def test_only_in_lane_followers_going_our_way_are_left_out() -> None:
    """Slot rows' ``on`` flag: the trailing follower is off over the whole horizon; an
    overtaker in the next lane and a car merging from behind (both outside the zone's
    half-width at stage 0) count once level or ahead, as before."""
    mpc = MpcSolver(CFG)
    prob = _stopping_problem((
        _car("follower", x_m=-12.0, y_m=0.0, vx_mps=7.3),
        _car("overtaker", x_m=-12.0, y_m=3.2, vx_mps=12.0),
        _car("merging", x_m=-12.0, y_m=-3.2, vx_mps=12.0, vy_mps=0.5),
        _car("standing_behind", x_m=-10.0, y_m=0.0, vx_mps=0.0)))
    ref = np.asarray(prob.reference)
    rows = obstacle_rows(prob.obstacles, ref, ref[:, 2], config=mpc.config, vehicle=mpc.vehicle)
    assert rows is not None
    on = rows[:, :, 5]
    assert not on[0].any()  # follower: never
    assert not on[3].any()  # standing behind: never comes level
    for i in (1, 2):  # overtaker, merging: off while behind, on once level or ahead
        assert on[i, 0] == 0.0 and on[i, -1] == 1.0, (i, on[i])


def _lane_problem(x: np.ndarray, u_prev: tuple[float, float], u_prev2: tuple[float, float],
                  *, lane_y_m: float) -> MpcProblem:
    ref = np.c_[x[0] + 8.0 * T, np.full(N + 1, lane_y_m), np.zeros(N + 1), np.full(N + 1, 8.0)]
    return MpcProblem(x0=tuple(float(v) for v in x), u_prev=u_prev, u_prev2=u_prev2,
                      reference=ref, reference_curvature_1pm=np.zeros(N + 1),
                      weights=CFG.decision_space.weights_for(None))


def _after_a_jump(rti_iterations: int) -> tuple[MpcProblem, MpcSolver]:
    """The RTI warm on a straight lane at 8 m/s for 10 steps, then the reference jumps
    3.5 m sideways (a new candidate): returns the jumped problem and the warm solver."""
    # the RTI alone (no step-size limit, no FATROP fallback): these tests are about its
    # own steps
    mpc = MpcSolver(CFG.model_copy(update={
        "solver": "sqp_rti", "rti_fallback": False, "rti_max_move_accel_mps2": 20.0,
        "rti_max_move_steer_rad": 2.0, "rti_iterations": rti_iterations}))
    x = np.array([0.0, 0.0, 0.0, 8.0])
    u1 = u2 = (0.0, 0.0)
    for _ in range(10):
        res = mpc.solve(_lane_problem(x, u1, u2, lane_y_m=0.0))
        assert res.success, res.status
        u2, u1 = u1, res.u0
        x = simulate_bicycle(x, np.array([res.u0]), dt_s=DT)[1]
    return _lane_problem(x, u1, u2, lane_y_m=3.5), mpc


def test_rti_iterates_after_a_jump_and_matches_the_nlp() -> None:
    """After the jump the first Gauss-Newton step moves the plan by metres per second
    squared, so the RTI takes more steps (``rti_iterations`` caps them) and lands on the
    NLP's answer; capped at one step (the default) it does not (seed 17, in small)."""
    prob, adaptive = _after_a_jump(_ADAPTIVE)
    nlp = MpcSolver(CFG).solve(prob)
    got = adaptive.solve(prob)
    assert nlp.success and got.success
    assert 1 < got.iterations <= _ADAPTIVE
    assert np.allclose(got.controls[:, 0], nlp.controls[:, 0], atol=0.1)
    assert got.u0[1] == pytest.approx(nlp.u0[1], abs=0.01)
    prob1, one = _after_a_jump(1)
    first = one.solve(prob1)
    assert first.iterations == 1
    assert float(np.max(np.abs(first.controls[:, 0] - nlp.controls[:, 0]))) > 0.5


def test_a_small_change_takes_one_step() -> None:
    """On a steady lane the adaptive RTI stays at one QP per control step (more only
    after a jump), so it costs what the one-step RTI costs there."""
    prob, mpc = _after_a_jump(_ADAPTIVE)
    steady = dataclasses.replace(prob, reference=_lane_problem(
        np.asarray(prob.x0), prob.u_prev, prob.u_prev2, lane_y_m=0.0).reference)
    assert mpc.solve(steady).iterations == 1


def test_solver_env_can_set_the_rti_step_cap(monkeypatch: pytest.MonkeyPatch) -> None:
    """``LMPC_MPC_SOLVER=sqp_rti:K`` selects the RTI with ``rti_iterations = K`` (the
    benchmark's way to run a variant); a cap on another solver is an error."""
    monkeypatch.setenv(SOLVER_ENV, "sqp_rti:3")
    cfg = load_mpc_config()
    assert (cfg.solver, cfg.rti_iterations) == ("sqp_rti", 3)
    for bad in ("fatrop:2", "sqp_rti:x", "sqp_rti:0"):
        monkeypatch.setenv(SOLVER_ENV, bad)
        with pytest.raises(MpcConfigError):
            load_mpc_config()


def test_rti_max_iterations_caps_the_qp_and_fails_safely() -> None:
    """``max_iterations`` caps HPIPM's iterations per step for ``sqp_rti`` (it needs ~5):
    with a cap of 1 the solve fails (and the controller falls back), as FATROP's does."""
    prob = _stopping_problem(())
    capped = MpcSolver(CFG.model_copy(update={"solver": "sqp_rti", "max_iterations": 1}))
    res = capped.solve(prob)
    assert not res.success and "QP failed" in res.status, res.status
    assert MpcSolver(CFG.model_copy(update={"solver": "sqp_rti"})).solve(prob).success
