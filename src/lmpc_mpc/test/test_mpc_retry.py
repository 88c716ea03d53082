"""A FATROP solve that fails is solved once more by IPOPT (``MpcConfig.retry_solver:
ipopt``, opt-in).

FATROP's failure is injected (its compiled function reports "not converged" for the
chosen steps, the numbers it computed are kept): what is tested is what happens next -
IPOPT from the same warm start and parameters, its solution used and warm-starting the
next step, the counts, the status; ``retry_solver: none`` and a realtime solver whose
retry size is not built yet keep today's failure path (shifted plan, then the brake).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcSolver

CFG = load_mpc_config().model_copy(update={"retry_solver": "ipopt"})
LEAD = S.agent("lead", x_m=40.0, y_m=-4.8, yaw_rad=0.0, v_mps=4.0)


class _Failing:
    """A compiled solver function whose stats say "not converged" while ``on``."""

    def __init__(self, fn: Any) -> None:
        self.fn = fn
        self.on = False
        self.calls = 0

    def __call__(self, **kw: Any) -> Any:
        self.calls += 1
        return self.fn(**kw)

    def stats(self) -> dict[str, Any]:
        st = dict(self.fn.stats())
        if self.on:
            st.update(success=False, return_status=1)
        return st


def _drive(solver: MpcSolver, fail_at: set[int], steps: int = 8
           ) -> tuple[list[Any], _Failing]:
    """``steps`` closed-loop steps behind a slower car, FATROP failing at ``fail_at``."""
    solver.reset()
    ctrl = MpcController(solver.config, solver=solver)
    n_slots = solver.slots_for(2)  # the lead and its hedge at most
    comp = solver.compiled(n_slots)
    failing = _Failing(comp.solver)
    solver._compiled[n_slots] = replace(comp, solver=failing)

    def before_step(k: int) -> None:
        failing.on = k in fail_at

    try:
        log = S.closed_loop(ctrl, S.straight_road(), (10.0, -4.8, 0.0, 8.0), steps,
                            lambda t: [LEAD], lane_id="E0_0", before_step=before_step)
    finally:
        solver._compiled[n_slots] = comp
    return [c for _, _, c in log], failing


def test_a_failed_fatrop_solve_is_solved_by_ipopt() -> None:
    plain, _ = _drive(MpcSolver(CFG), set())
    solver = MpcSolver(CFG)
    ctls, failing = _drive(solver, {3, 4})
    assert failing.calls == 8  # FATROP still tries every step
    assert solver.retries == 2 and solver.rescues == 2
    assert [c.mode for c in ctls] == [c.mode for c in plain] == ["baseline"] * 8
    for c, p in zip(ctls, plain):
        # both solve the same NLP to tolerance: the same controls to ~1e-3
        assert c.accel_mps2 == pytest.approx(p.accel_mps2, abs=2e-3)
        assert c.steer_rad == pytest.approx(p.steer_rad, abs=2e-3)


def _statuses(solver: MpcSolver, fail_at: set[int], steps: int) -> list[str]:
    """The solve statuses of ``_drive``."""
    statuses: list[str] = []
    real = solver.solve

    def solve(problem: Any) -> Any:
        res = real(problem)
        statuses.append(res.status)
        return res

    solver.solve = solve  # type: ignore[method-assign]
    try:
        _drive(solver, fail_at, steps)
    finally:
        del solver.solve
    return statuses


def test_the_retry_s_status_says_what_failed() -> None:
    statuses = _statuses(MpcSolver(CFG), {2}, 3)
    said = "Solve_Succeeded (IPOPT after FATROP: not converged: failed (1))"
    assert statuses[2].startswith(said) and not statuses[1].startswith(said), statuses


def test_a_rescue_far_from_the_previous_plan_is_not_trusted() -> None:
    """A rescued plan moving a control beyond ``retry_max_move_*`` from the shifted previous
    plan fails the step (another optimum of the problem, not the one being tracked)."""
    solver = MpcSolver(CFG.model_copy(update={"retry_max_move_accel_mps2": 1e-6}))
    statuses = _statuses(solver, {3}, 5)
    assert solver.retries == 1 and solver.rescues == 0
    assert "not trusted" in statuses[3] and "IPOPT after FATROP" in statuses[3], statuses
    ctls, _ = _drive(solver, {3}, 5)
    assert ctls[3].mode == "shifted"


def test_no_retry_without_a_previous_plan() -> None:
    """The first solve of an episode has no plan to check a rescue against: not retried."""
    solver = MpcSolver(CFG)
    ctls, _ = _drive(solver, {0}, 2)
    assert solver.retries == 0 and ctls[0].mode != "baseline"


def test_without_a_retry_a_failed_solve_falls_back_as_before() -> None:
    solver = MpcSolver(CFG.model_copy(update={"retry_solver": "none"}))
    ctls, _ = _drive(solver, {3, 4})
    assert [c.mode for c in ctls][3:5] == ["shifted", "shifted"]
    assert solver.retries == 0


def test_realtime_retries_only_with_the_retry_built_at_warm_up() -> None:
    """In realtime a retry must not build its solver inside a step: warm_up builds it;
    a size it has not built is not retried (the step fails as without a retry)."""
    # a budget no loaded test machine overruns: what is tested is when a retry happens
    solver = MpcSolver(CFG.model_copy(update={"time_budget_s": 5.0}))
    solver.enforce_time_budget = True
    ctls, _ = _drive(solver, {3})
    assert ctls[3].mode == "shifted" and solver.retries == 0
    solver.warm_up()
    ctls, _ = _drive(solver, {3})
    assert ctls[3].mode == "baseline" and solver.retries == 1 and solver.rescues == 1
    assert np.isfinite(ctls[3].accel_mps2)


def test_realtime_does_not_retry_a_step_already_over_its_budget() -> None:
    solver = MpcSolver(CFG.model_copy(update={"time_budget_s": 1e-6}))
    solver.enforce_time_budget = True
    solver.warm_up()
    ctls, _ = _drive(solver, {3})
    assert solver.retries == 0 and ctls[3].mode != "baseline"
