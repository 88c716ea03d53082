"""SQP real-time iteration (RTI) of the MPC: one Gauss-Newton QP per control step.

The same problem as :mod:`lmpc_mpc.solver` (same state, controls, parameters, bounds,
cost weights), rewritten so that one structured QP approximates it well:

- **cost as a sum of squares** ``sum r_j(w, p)^2``. Every term is a square already except
  the yaw error ``2(1 - cos e) = (2 sin(e/2))^2``; the Gauss-Newton Hessian ``2 J^T J``
  is positive semi-definite by construction (the exact Lagrangian Hessian, with the
  bicycle's curvature, diverged in an earlier probe near obstacles);
- **safety term with slacks**: ``w_saf max(0, short)^2`` becomes ``w_saf s^2`` with
  ``s >= short``, ``s >= 0`` - the same value at the optimum, but a QP constraint instead
  of a kink, so the QP sees the term switch on within the step. ``short`` at stage k+1
  is written with ``x_{k+1} = F(x_k, u_k)`` (the dynamics expression) so the slack can be
  a control of stage k (the QP interface has no controls at stage N);
- **linearisation** of the dynamics, steer-rate and safety rows at the current guess
  (the shifted previous solution), full step, no line search.

The QP has the stage structure ``[x0 u0 x1 u1 ... xN]`` with the gap rows of each stage
before its path rows, which HPIPM's (and FATROP's) CasADi conic interface needs. A step
whose QP fails, or that gives non-finite numbers, is a failure (the caller then uses the
shifted previous plan, then brakes). An approximation of the NLP's optimum: one step
from a good guess converges over consecutive control steps, not within one; the caller
(:meth:`lmpc_mpc.solver.MpcSolver._solve_rti`) takes further steps while a step is
large (a far guess after a jump), see :meth:`RtiQp.iterate`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import casadi as ca
import numpy as np

from lmpc_msgs_py.vehicle import VehicleParams
from lmpc_mpc.model import (
    BIG, NOBS, NREF, NU, NX, CostParams, bicycle_function, box_bounds, midpoint_step,
    stage_symbols)
_SLACK_REG = 1e-4
"""Weight on every slack squared (also unused ones): keeps the QP Hessian positive
definite in the slacks, so an unused slot's slack is exactly 0 and not free."""
QP_SOLVERS = ("hpipm",)
"""Structure-exploiting QP solvers the RTI can use. FATROP's CasADi *conic* interface
was tried: 359 iterations and ~100 ms per QP here (it is tuned as an NLP solver)."""
_HPIPM_OPTIONS = {"mode": "speed_abs", "iter_max": 50, "warm_start": 0,
                  "res_g_max": 1e-4, "res_b_max": 1e-4, "res_d_max": 1e-4,
                  "res_m_max": 1e-4}
"""HPIPM: the "speed_abs" IPM with absolute residual tolerances 1e-4 takes 5 iterations
here (``balance`` with its default 1e-8: 15) and moves the solution by < 4e-5 (m, rad,
m/s) against ``balance`` (measured over a 60-step closed loop with 10 agents)."""


class RtiError(RuntimeError):
    """The RTI QP could not be built (a wrong layout or an unknown QP solver)."""


@dataclass(frozen=True)
class RtiStep:
    """Outcome of :meth:`RtiQp.iterate`."""

    ok: bool
    status: str
    z: np.ndarray
    """The new iterate (stage-wise variables, slacks included); only meaningful if ok."""
    qp_iterations: int
    """QP solver iterations summed over the SQP steps taken."""
    sqp_steps: int
    last_move: tuple[float, float] = (0.0, 0.0)
    """How far the last step taken moved the planned controls: the largest change of an
    acceleration (m/s^2) and of a steering angle (rad) over the horizon."""


class RtiQp:
    """The Gauss-Newton QP of one obstacle-slot count, built once (CasADi SX, expanded).

    Variables per stage k < N: ``x_k`` (8), ``u_k = (a, delta, s_1 .. s_m)`` with one slack
    per obstacle slot of stage k+1; stage N: ``x_N``. Parameters: the NLP's vector
    (``x0``, weights, per-stage reference and obstacle rows), see
    :meth:`lmpc_mpc.solver.MpcSolver._params`.
    """

    def __init__(self, *, horizon: int, dt_s: float, vehicle: VehicleParams, n_slots: int,
                 qp_solver: str = "hpipm", qp_iter_max: int = 50,
                 data: Optional[tuple[ca.Function, dict[str, np.ndarray]]] = None) -> None:
        """``data``: a :meth:`cache_entry` of the same inputs (loaded from the solver cache,
        ``lmpc_mpc.solver_cache``) instead of building the QP data function (~0.1-0.3 s
        per size; the QP solver itself is made anew: HPIPM's interface does not
        deserialise)."""
        if qp_solver not in QP_SOLVERS:
            raise RtiError(f"qp_solver must be one of {QP_SOLVERS}, got {qp_solver!r}")
        self.n = horizon
        self.n_slots = n_slots
        self.nu = NU + n_slots
        self.stage_len = NX + self.nu
        self.n_var = (horizon + 1) * NX + horizon * self.nu
        if qp_iter_max < 1:
            raise RtiError(f"qp_iter_max must be >= 1, got {qp_iter_max}")
        self._qp_iter_max = qp_iter_max
        if data is None:
            self._build(dt_s, vehicle)
        else:
            fn, arrays = data
            self._data = fn
            self._lbx, self._ubx = arrays["lbx"], arrays["ubx"]
            self._lbg, self._ubg = arrays["lbg"], arrays["ubg"]
            self.n_p = int(arrays["n_p"])
        self._make_qp(qp_solver)

    def cache_entry(self) -> tuple[ca.Function, dict[str, np.ndarray]]:
        """What the solver cache keeps of this QP: the data function and the bounds."""
        return self._data, {"lbx": self._lbx, "ubx": self._ubx, "lbg": self._lbg,
                            "ubg": self._ubg, "n_p": np.array(self.n_p)}

    # -- layout helpers ------------------------------------------------------------------
    def to_stages(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Split the variable vector into (N+1, 8) states and (N, 2 + m) controls."""
        n = self.n
        body = z[: n * self.stage_len].reshape(n, self.stage_len)
        xs = np.vstack([body[:, :NX], z[n * self.stage_len:][None, :]])
        return xs, body[:, NX:]

    def from_stages(self, xs: np.ndarray, us: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_stages` (``us`` may hold only the 2 real controls: the
        slacks are then set to 0)."""
        n = self.n
        z = np.zeros(self.n_var)
        body = z[: n * self.stage_len].reshape(n, self.stage_len)
        body[:, :NX] = xs[:n]
        body[:, NX:NX + us.shape[1]] = us
        z[n * self.stage_len:] = xs[n]
        return z

    # -- building ------------------------------------------------------------------------
    def _build(self, dt: float, veh: VehicleParams) -> None:
        n, m = self.n, self.n_slots
        f = bicycle_function(veh)
        sym = stage_symbols(n, m, self.nu)
        p_x0, p_w, p_st, xs, us = sym.x0, sym.w, sym.stage_p, sym.xs, sym.us
        c = CostParams.symbols(p_w)  # the weight slots, by name
        rate = veh.max_steer_rate_radps * dt
        x_lb, x_ub, u_lb, u_ub = box_bounds(veh)
        u_lb, u_ub = u_lb + [0.0] * m, u_ub + [BIG] * m  # the safety slacks are >= 0
        w_vars: list[ca.SX] = []
        res: list[ca.SX] = []
        g: list[ca.SX] = []
        lbx: list[float] = []
        ubx: list[float] = []
        lbg: list[float] = []
        ubg: list[float] = []
        sq = ca.sqrt
        for k in range(n + 1):
            x = xs[k]
            w_vars.append(x)
            if k == 0:
                lbx += [0.0] * NX  # placeholders: the initial state is fixed per call
                ubx += [0.0] * NX
            else:
                lbx += x_lb
                ubx += x_ub
                pk = p_st[k]
                cy, sy = ca.cos(pk[2]), ca.sin(pk[2])
                ex, ey = x[0] - pk[0], x[1] - pk[1]
                res += [sq(c.w_pos) * (cy * ex + sy * ey),
                        sq(c.w_pos * c.lateral_factor) * (-sy * ex + cy * ey),
                        sq(c.w_v) * (x[3] - pk[3]),
                        # 2 (1 - cos e) = (2 sin(e / 2))^2: the same yaw cost as a square
                        2.0 * sq(c.w_yaw) * ca.sin(0.5 * (x[2] - pk[2]))]
            if k == n:
                continue
            u = us[k]
            w_vars.append(u)
            lbx += u_lb
            ubx += u_ub
            nxt = ca.vertcat(midpoint_step(f, x[:4], u[:NU], dt), u[:NU], x[4], x[5])
            # gap rows first (F(x_k, u_k) - x_{k+1}: the "A B -I" layout of the interface)
            g.append(nxt - xs[k + 1])
            lbg += [0.0] * NX
            ubg += [0.0] * NX
            # path rows of stage k: steer rate, then the slack rows of stage k+1's slots
            g.append(u[1] - x[5])
            lbg.append(-rate)
            ubg.append(rate)
            pn = p_st[k + 1]
            for i in range(m):
                o = pn[NREF + NOBS * i: NREF + NOBS * (i + 1)]
                kx, ky, k0, gap, headway, on = o[0], o[1], o[2], o[3], o[4], o[5]
                short = gap + headway * nxt[3] - (kx * nxt[0] + ky * nxt[1] + k0)
                g.append(u[NU + i] - on * short)
                lbg.append(0.0)
                ubg.append(BIG)
                res.append(sq(c.w_saf * on + _SLACK_REG) * u[NU + i])
            kap = pn[4]
            d_ref = ca.atan(veh.wheelbase_m * kap)
            res += [sq(c.w_steer_ref) * (u[1] - d_ref),
                    sq(c.w_bias_accel) * (u[0] - p_st[k][5]),
                    sq(c.w_bias_steer) * (u[1] - c.bias_steer_rad),
                    sq(c.w_g_accel) * (u[0] - x[4]), sq(c.w_g_steer) * (u[1] - x[5]),
                    sq(c.w_l_accel) * (u[0] - 2 * x[4] + x[6]),
                    sq(c.w_l_steer) * (u[1] - 2 * x[5] + x[7])]
        w = ca.vertcat(*w_vars)
        p = ca.vertcat(p_x0, p_w, *p_st)
        r = ca.vertcat(*res)
        gg = ca.vertcat(*g)
        jr = ca.jacobian(r, w)
        jg = ca.jacobian(gg, w)
        hess = 2.0 * ca.mtimes(jr.T, jr)
        grad = 2.0 * ca.mtimes(jr.T, r)
        self._data = ca.Function("rti_qp_data", [w, p], [hess, grad, jg, gg, ca.sumsqr(r)],
                                 ["w", "p"], ["h", "g", "a", "c", "cost"])
        self.n_p = int(p.numel())
        self._lbx = np.array(lbx)
        self._ubx = np.array(ubx)
        self._lbg = np.array(lbg)
        self._ubg = np.array(ubg)

    def _make_qp(self, qp_solver: str) -> None:
        """The structured QP solver on the data function's Hessian and Jacobian patterns."""
        n, m = self.n, self.n_slots
        ng = [1 + m] * n + [0]
        opts: dict = {"N": n, "nx": [NX] * (n + 1), "nu": [self.nu] * n + [0], "ng": ng,
                      "error_on_fail": False, "print_time": False}
        opts["hpipm"] = {**_HPIPM_OPTIONS, "iter_max": self._qp_iter_max}
        self._qp = ca.conic("rti_qp", qp_solver, {"h": self._data.sparsity_out("h"),
                                                  "a": self._data.sparsity_out("a")}, opts)

    # -- solving -------------------------------------------------------------------------
    # Calling the HPIPM conic inside an MX function (data and QP in one call) segfaulted
    # in CasADi 3.8.2, so the two are called one after the other from Python.
    def iterate(self, z: np.ndarray, p: np.ndarray, x0: np.ndarray, *, steps: int = 1,
                accel_tol_mps2: float = 0.1, steer_tol_rad: float = 0.01) -> RtiStep:
        """Up to ``steps`` Gauss-Newton SQP steps from ``z`` (full steps, no line search).

        Stops early when a step changed no planned control by more than ``accel_tol_mps2``
        / ``steer_tol_rad``: the guess was then already close to the linearisation's
        optimum, and another step would move it by much less (the problem is a QP up
        to the bicycle's and the yaw's curvature)."""
        z = np.array(z, dtype=float)
        z[:NX] = x0  # the guess starts at the current state: the initial step is 0
        lbx = self._lbx.copy()
        ubx = self._ubx.copy()
        qp_iters = 0
        taken = 0
        move = (0.0, 0.0)
        for _ in range(steps):
            h, grad, a, c, _cost = self._data(z, p)
            lbx[:NX] = x0
            ubx[:NX] = x0
            c_np = np.asarray(c).ravel()
            sol = self._qp(h=h, g=grad, a=a, lbx=lbx - z, ubx=ubx - z,
                           lba=self._lbg - c_np, uba=self._ubg - c_np)
            stats = self._qp.stats()
            qp_iters += int(stats.get("iter_count", 0) or 0)
            taken += 1
            ok = bool(stats.get("success", False))
            dz = np.asarray(sol["x"]).ravel()
            if not ok:
                return RtiStep(False, f"QP failed ({stats.get('return_status', '?')})", z,
                               qp_iters, taken)
            if not np.all(np.isfinite(dz)):
                return RtiStep(False, "QP gave non-finite numbers", z, qp_iters, taken)
            z = z + dz
            du = dz[: self.n * self.stage_len].reshape(self.n, self.stage_len)[:, NX:NX + NU]
            move = (float(np.max(np.abs(du[:, 0]))), float(np.max(np.abs(du[:, 1]))))
            if move[0] <= accel_tol_mps2 and move[1] <= steer_tol_rad:
                break
        return RtiStep(True, "RTI_Step_Succeeded", z, qp_iters, taken, move)
