"""The ego's yaw across +-pi (docs/lmpc_mpc.md, "Heading across +-pi").

The bridge sends the ego's yaw wrapped to (-pi, pi]; the MPC's plan carries a continuous
yaw. Heading west and turning across pi, the yaw of the next step's x0 is 2 pi from the
shifted plan that warm-starts the solve. Before the fix the warm start kept that jump
between its first two stages: the solve failed, or converged to a loop at full steer (rab
training seed 10089: a planned circle into the roundabout's island, the exit missed).
"""
import math

import numpy as np
import pytest

from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import NU, NX, MpcSolver

CFG = load_mpc_config()


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


def test_the_warm_start_follows_x0_across_pi(solver: MpcSolver) -> None:
    n = CFG.horizon
    solver.reset()
    warm = np.zeros((n + 1, NX + NU))  # stages (x, u), as the solver keeps them
    warm[:, 2] = np.linspace(3.13, 3.43, n + 1)  # the last plan: on across pi
    warm[:, 3] = 8.0
    solver._warm, solver._warm_slots = warm, CFG.agent_slot_sizes[0]
    x0 = np.zeros(NX)
    x0[2] = math.remainder(3.15, 2.0 * math.pi)  # one step on, wrapped: -3.133
    x0[3] = 8.0
    guess = solver._initial_guess(x0, CFG.agent_slot_sizes[0])
    yaw = np.array([guess[k * (NX + NU) + 2] for k in range(n + 1)])
    assert yaw[0] == pytest.approx(x0[2])
    # continuous from x0 on: the shifted plan moved by -2 pi, not left 2 pi away
    assert np.max(np.abs(np.diff(yaw))) < 0.05
    assert yaw[1] == pytest.approx(warm[2, 2] - 2.0 * math.pi)


def test_heading_west_across_pi_needs_no_fallback(solver: MpcSolver) -> None:
    """Westbound on ``B_0`` (y = 60), 0.5 m right of the lane (north): it steers back and its
    yaw crosses pi (the bridge's wrapped yaw jumps from +pi to -pi)."""
    solver.reset()
    ctrl = MpcController(CFG, solver=solver)
    log = S.closed_loop(ctrl, S.arc_road(), (-5.0, 60.5, math.pi, 8.0), 80)
    assert max(x[2] for _, x, _ in log) > math.pi  # the plant's yaw went past pi
    st = ctrl.stats()
    assert st.solver_failures == 0 and st.shifted == 0 and st.brakes == 0
    assert all(c.mode == "baseline" for _, _, c in log)
    assert abs(log[-1][1][1] - 60.0) < 0.1  # back on the lane centre
