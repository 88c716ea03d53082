"""The CasADi MPC of DESIGN §4 (kinematic bicycle, LanguageMPC cost): FATROP, IPOPT or RTI.

Problem (stage-wise, so FATROP's structure detection finds the OCP):

- state ``s_k = (x, y, yaw, v, a_{k-1}, delta_{k-1}, a_{k-2}, delta_{k-2})``: the box centre
  pose and speed of the kinematic bicycle plus the two previous controls, carried so
  the first and second differences of ``A`` stay stage-local;
- control ``A_k = (a_k, delta_k)``, dynamics one explicit midpoint (RK2) step of length
  ``dt`` (within 8 mm of the plant over the horizon; see :func:`midpoint_step`);
- cost ``sum_k C_trk + C_act + C_saf``:
  ``C_trk = W_x (e_lon^2 + f_lat e_lat^2) + W_v (v - v_ref)^2 + W_yaw 2(1 - cos(yaw - yaw_ref))
  + W_steer (delta - delta_ref)^2`` (``delta_ref`` from the reference curvature);
  (position error in the reference frame, the lateral part weighted ``f_lat`` =
  ``lateral_weight_factor`` more, so the baseline brakes rather than leaves its lane);
  ``C_act = (A - A_hat)^T W_s (A - A_hat) + dA^T W_g dA + d2A^T W_l d2A``;
  ``C_saf = w_saf sum_i on_i max(0, d_hat_ik - d_ik)^2`` with
  ``d_hat_ik = g_i + h_ik v_k`` (gap + half-lengths, time headway only for agents ahead)
  and ``d_ik`` the distance to the agent's predicted centre measured in the reference
  frame with the lateral axis stretched by ``rho_ik`` (so the safe zone is an ellipse
  whose side clearance is the half-widths plus a side gap: a car passing in the next
  lane is not penalised, a car ahead is kept a headway away). ``d_ik`` enters
  *linearised* at a guess of the ego position per stage (``obstacles.halfplanes``), so
  the term is convex; only obstacles that can matter at a stage get a slot there
  (``obstacles.pack``);
- hard bounds: ``a``, ``delta``, ``v`` (``VehicleParams``) and the steer rate.

Every weight, the bias, the reference, the obstacle half-planes and their slots are
parameters of one compiled problem per number of obstacle slots *per stage*
(``agent_slot_sizes``, all built on first use). Unused slots have ``on = 0`` and add no
cost. Variables are declared in stage order (x_0, u_0, x_1, ...), the previous two
controls ride in the state, so FATROP's manual structure (nx 8, nu 2) holds exactly.

``solver: sqp_rti`` solves the same problem by real-time iteration instead
(:mod:`lmpc_mpc.rti`: Gauss-Newton QPs with HPIPM, warm-started from the shifted
previous solution: one step per control step, more (up to ``rti_iterations``) while a
step still moves a planned control by more than ``rti_step_*``); the parameters, the
obstacle packing and the fallbacks are shared. A step the RTI does not deliver (its QP
failed, a cold iteration still moving, a warm step moving a planned control by more than
``rti_max_move_*``) is solved by FATROP from the same warm start (``rti_fallback``, on by
default: the hybrid of docs/lmpc_mpc.md).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Optional, Sequence

import casadi as ca
import numpy as np

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams
from lmpc_msgs_py.vocabulary import ResolvedWeights
from lmpc_mpc.config import MpcConfig
from lmpc_mpc.model import (  # noqa: F401 (NREF, midpoint_step: re-exported)
    BIG, N_W, NOBS, NREF, NU, NX, CostParams, bicycle_function, box_bounds, midpoint_step,
    stage_symbols)
from lmpc_mpc import codegen, solver_cache
from lmpc_mpc.rti import RtiQp
from lmpc_mpc.obstacles import MpcInputError, Obstacle, pack, slots_for
_TOL = 1e-3
"""NLP tolerance (scaled KKT error; FATROP and IPOPT). 1e-3 m / 1e-3 m/s^2 is far below
what a 0.1 s control step can use; 1e-4 costs one more iteration (5 -> 6 median)."""
_MU_INIT = 1e-1
"""FATROP's initial barrier parameter. Smaller values save iterations (1e-3: 6 -> 4
median) but keep the solution in the warm start's basin: in the oncoming-car test the
ego then crept behind the passed car instead of turning (see docs/lmpc_mpc.md)."""


SOLVERS = ("fatrop", "ipopt", "sqp_rti")
"""Selectable solvers: the NLP with FATROP's or IPOPT's interior-point method, or the
real-time iteration (one Gauss-Newton QP per step, HPIPM; :mod:`lmpc_mpc.rti`)."""


@dataclass(frozen=True)
class MpcProblem:
    """Everything one solve needs, in numbers (built by the controller)."""

    x0: tuple[float, float, float, float]
    """Current (x_m, y_m, yaw_rad, v_mps) of the box centre."""
    u_prev: tuple[float, float]
    """The control applied in the previous step (accel_mps2, steer_rad)."""
    u_prev2: tuple[float, float]
    """The control applied two steps ago."""
    reference: np.ndarray
    """(N+1, 4) rows (x, y, yaw, v) of the time-parameterised reference."""
    reference_curvature_1pm: np.ndarray
    """(N+1,) curvature of the reference path (gives the steer reference)."""
    weights: ResolvedWeights
    bias: tuple[float, float] = (0.0, 0.0)
    """A_hat = (accel_mps2, steer_rad)."""
    bias_accel_mps2: Optional[np.ndarray] = None
    """(N,) the acceleration bias per control step (None: ``bias[0]`` at every step).
    A braking bias can only hold while the car moves: the controller sets it to 0 once
    the reference (braked at the bias rate) has stopped, so the MPC brakes at the
    asked rate instead of spreading a smaller deceleration over the horizon."""
    obstacles: tuple[Obstacle, ...] = ()


@dataclass(frozen=True)
class MpcResult:
    """Outcome of one solve. ``u0`` and ``predicted`` are only meaningful on success."""

    success: bool
    status: str
    u0: tuple[float, float]
    predicted: np.ndarray
    """(N+1, 4) rows (x, y, yaw, v) of the predicted ego states."""
    solve_time_s: float
    iterations: int
    controls: np.ndarray = field(default_factory=lambda: np.zeros((0, NU)))
    """(N, 2) planned controls (the shifted-plan fallback uses them)."""
    solve_cpu_s: float = math.nan
    """Process CPU time of the solve (a loaded machine inflates it less than wall)."""


def rk4_step(f: ca.Function, s: ca.SX, u: ca.SX, dt_s: float) -> ca.SX:
    """One RK4 step of ``s' = f(s, u)``."""
    k1 = f(s, u)
    k2 = f(s + 0.5 * dt_s * k1, u)
    k3 = f(s + 0.5 * dt_s * k2, u)
    k4 = f(s + dt_s * k3, u)
    return s + dt_s / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def simulate_bicycle(x0: Sequence[float] | np.ndarray, controls: np.ndarray, *, dt_s: float,
                     vehicle: VehicleParams = DEFAULT_VEHICLE) -> np.ndarray:
    """Roll the same model out in numpy (RK4): (len(controls)+1, 4) states."""
    ratio = vehicle.lr_m / vehicle.wheelbase_m

    def f(s: np.ndarray, u: np.ndarray) -> np.ndarray:
        beta = math.atan(ratio * math.tan(u[1]))
        return np.array([s[3] * math.cos(s[2] + beta), s[3] * math.sin(s[2] + beta),
                         s[3] / vehicle.lr_m * math.sin(beta), u[0]])

    out = np.empty((len(controls) + 1, 4))
    out[0] = x0
    for k, u in enumerate(np.asarray(controls, dtype=float)):
        s = out[k]
        k1 = f(s, u)
        k2 = f(s + 0.5 * dt_s * k1, u)
        k3 = f(s + 0.5 * dt_s * k2, u)
        k4 = f(s + dt_s * k3, u)
        out[k + 1] = s + dt_s / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1, 3] = max(out[k + 1, 3], 0.0)
    return out


@dataclass
class _Compiled:
    solver: ca.Function
    n_slots: int
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    n_p: int


class MpcSolver:
    """Builds (lazily, one per obstacle-slot count) and runs the MPC NLP."""

    def __init__(self, config: MpcConfig, vehicle: VehicleParams = DEFAULT_VEHICLE, *,
                 solver: Optional[str] = None) -> None:
        self.config = config
        self.vehicle = vehicle
        self.solver_name = solver or config.solver
        if self.solver_name not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver_name!r}")
        self.n = config.horizon
        self.dt_s = config.dt_s
        self._compiled: dict[int, _Compiled] = {}
        self._generated: set[int] = set()
        """Slot counts whose problem runs as generated C (:mod:`lmpc_mpc.codegen`)."""
        self._rti: dict[int, RtiQp] = {}
        self._fallback: Optional[MpcSolver] = None
        self.rti_fallbacks = 0
        """``sqp_rti``: steps FATROP solved because the RTI did not deliver them."""
        self._retry: Optional[MpcSolver] = None
        self.retries = 0
        """FATROP solves that failed and went to ``config.retry_solver``."""
        self.rescues = 0
        """Of those, the ones the retry solver delivered."""
        self._warm: Optional[np.ndarray] = None
        self._warm_slots: Optional[int] = None
        self._reconverge_next = False
        self.enforce_time_budget = config.enforce_time_budget
        """Realtime: a solve over ``time_budget_s`` (wall) fails. Off (sync / benchmark):
        success is decided by the iteration cap alone, an overrun is only counted."""
        self._cpu0 = 0.0
        self.over_budget = 0
        """Successful solves that took longer than ``time_budget_s`` (wall)."""

    # -- building ------------------------------------------------------------------------
    def slots_for(self, n_obstacles: int) -> int:
        """The smallest compiled size that holds ``n_obstacles``."""
        return slots_for(self.config, n_obstacles)

    def nlp_function(self, n_slots: int) -> ca.Function:
        """``J(w, p) -> (f, g)``: the NLP's objective and constraint rows at the stage-wise
        variables ``w`` (x_0, u_0, ..., x_N) and parameters ``p`` (what ``_params`` packs),
        uncompiled (for checks: ``lmpc_mpc.adp`` re-expresses the objective)."""
        nlp, *_ = self._nlp(n_slots)
        return ca.Function("J", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])

    def _nlp(self, n_slots: int) -> tuple[dict[str, Any], list[float], list[float],
                                          list[float], list[float]]:
        """The NLP (``x``, ``p``, ``f``, ``g``) and its bounds (lbx, ubx, lbg, ubg)."""
        n, dt, veh = self.n, self.dt_s, self.vehicle
        f = bicycle_function(veh)
        sym = stage_symbols(n, n_slots)
        p_x0, p_w, p_st, xs, us = sym.x0, sym.w, sym.stage_p, sym.xs, sym.us
        c = CostParams.symbols(p_w)  # the weight slots, by name
        rate = veh.max_steer_rate_radps * dt
        w_vars: list[ca.SX] = []
        g: list[ca.SX] = []
        lbg: list[float] = []
        ubg: list[float] = []
        lbx: list[float] = []
        ubx: list[float] = []
        x_lb, x_ub, u_lb, u_ub = box_bounds(veh)
        cost: Any = 0  # a CasADi expression after the first term
        # FATROP's stage layout: per stage k the gap-closing rows (x_{k+1} = F(x_k, u_k))
        # first, then the stage's path constraints.
        for k in range(n + 1):
            x = xs[k]
            w_vars.append(x)
            path_g: list[ca.SX] = []
            path_lb: list[float] = []
            path_ub: list[float] = []
            if k == 0:
                # the initial state is a parameter; speed may exceed the bound (e.g. a
                # downhill push) so stage 0 carries no state bounds, only this equality
                lbx += [-BIG] * NX
                ubx += [BIG] * NX
                path_g.append(x - p_x0)
                path_lb += [0.0] * NX
                path_ub += [0.0] * NX
            else:
                lbx += x_lb
                ubx += x_ub
                cost += self._stage_cost(x, p_st[k], n_slots, c.w_pos, c.w_v, c.w_yaw,
                                         c.w_saf, c.lateral_factor)
            if k < n:
                u = us[k]
                w_vars.append(u)
                lbx += u_lb
                ubx += u_ub
                nxt = midpoint_step(f, x[:4], u, dt)
                g.append(xs[k + 1] - ca.vertcat(nxt, u, x[4], x[5]))
                lbg += [0.0] * NX
                ubg += [0.0] * NX
                # steering rate bound: |delta_k - delta_{k-1}| <= rate * dt
                path_g.append(u[1] - x[5])
                path_lb.append(-rate)
                path_ub.append(rate)
                kap = p_st[k + 1][4]
                d_ref = ca.atan(veh.wheelbase_m * kap)
                cost += c.w_steer_ref * (u[1] - d_ref) ** 2
                # the acceleration bias is per stage (p_st[k][5], see MpcProblem)
                cost += (c.w_bias_accel * (u[0] - p_st[k][5]) ** 2
                         + c.w_bias_steer * (u[1] - c.bias_steer_rad) ** 2)
                cost += c.w_g_accel * (u[0] - x[4]) ** 2 + c.w_g_steer * (u[1] - x[5]) ** 2
                cost += (c.w_l_accel * (u[0] - 2 * x[4] + x[6]) ** 2
                         + c.w_l_steer * (u[1] - 2 * x[5] + x[7]) ** 2)
            g += path_g
            lbg += path_lb
            ubg += path_ub
        p_all = ca.vertcat(p_x0, p_w, *p_st)
        nlp = {"x": ca.vertcat(*w_vars), "p": p_all, "f": cost, "g": ca.vertcat(*g)}
        return nlp, lbx, ubx, lbg, ubg

    def _build(self, n_slots: int, extra: Optional[dict[str, Any]] = None) -> _Compiled:
        """Build the NLP of ``n_slots`` slots; ``extra``: more ``nlpsol`` options (the
        generated-C ones of :mod:`lmpc_mpc.codegen`)."""
        n = self.n
        nlp, lbx, ubx, lbg, ubg = self._nlp(n_slots)
        p_all = nlp["p"]
        lbg_a = np.array(lbg)
        ubg_a = np.array(ubg)
        equality = [bool(lo == hi) for lo, hi in zip(lbg, ubg)]
        budget = self.config.time_budget_s
        if self.solver_name == "fatrop":
            opts: dict[str, Any] = {
                "structure_detection": "manual",
                "N": n,
                "nx": [NX] * (n + 1),
                "nu": [NU] * n + [0],
                "ng": [NX + 1] + [1] * (n - 1) + [0],
                "equality": equality,
                "expand": True,
                "fatrop": {"print_level": 0, "max_iter": self.config.max_iterations,
                           "tol": _TOL, "mu_init": _MU_INIT},
                "print_time": False,
                "error_on_fail": False,
                "debug": False,
            }
        else:
            ipopt = {"print_level": 0, "max_iter": self.config.max_iterations, "tol": _TOL,
                     "sb": "yes", "warm_start_init_point": "no"}
            if self.enforce_time_budget:
                # only in realtime: a wall-time stop makes the result depend on load
                ipopt["max_wall_time"] = budget
            opts = {
                "expand": True,
                "ipopt": ipopt,
                "print_time": False,
                "error_on_fail": False,
            }
        solver = ca.nlpsol("mpc", self.solver_name, nlp, {**opts, **(extra or {})})
        return _Compiled(solver, n_slots, np.array(lbx), np.array(ubx), lbg_a, ubg_a,
                         int(p_all.numel()))

    @staticmethod
    def _stage_cost(x: ca.SX, p: ca.SX, n_slots: int, w_pos: ca.SX, w_v: ca.SX,
                    w_yaw: ca.SX, w_saf: ca.SX, lat_factor: ca.SX) -> ca.SX:
        xr, yr, yawr, vr = p[0], p[1], p[2], p[3]
        cy, sy = ca.cos(yawr), ca.sin(yawr)
        ex, ey = x[0] - xr, x[1] - yr
        # W_x is diagonal in the reference frame: the lateral error weighs lat_factor more
        e_lon = cy * ex + sy * ey
        e_lat = -sy * ex + cy * ey
        c = w_pos * (e_lon ** 2 + lat_factor * e_lat ** 2) + w_v * (x[3] - vr) ** 2
        c += w_yaw * 2.0 * (1.0 - ca.cos(x[2] - yawr))
        for i in range(n_slots):
            o = p[NREF + NOBS * i: NREF + NOBS * (i + 1)]
            # d_ik linearised per stage (see obstacles.halfplanes): the term is convex
            kx, ky, k0, gap, headway, on = o[0], o[1], o[2], o[3], o[4], o[5]
            short = ca.fmax(0.0, gap + headway * x[3] - (kx * x[0] + ky * x[1] + k0))
            c += w_saf * on * short ** 2
        return c

    def warm_up(self) -> None:
        """Build every compiled size now (~0.3 s each) so no step pays for it later."""
        for size in self.config.agent_slot_sizes:
            if self.solver_name == "sqp_rti":
                self.rti(size)
            else:
                self.compiled(size)
        if self.solver_name == "sqp_rti" and self.config.rti_fallback:
            self._nlp_fallback().warm_up()
        elif self._retries_to() is not None and self.enforce_time_budget:
            # realtime: a retry must not pay for its build inside a step (sync runs and
            # the benchmark build a retry size when it is first needed)
            self._retry_solver().warm_up()

    def _retries_to(self) -> Optional[str]:
        """The solver a failed solve of this one goes to (FATROP only), or None."""
        retry = self.config.retry_solver
        return retry if self.solver_name == "fatrop" and retry != "none" else None

    def _retry_solver(self) -> "MpcSolver":
        if self._retry is None:
            self._retry = MpcSolver(self.config, self.vehicle, solver=self._retries_to())
            self._retry.enforce_time_budget = self.enforce_time_budget
        return self._retry

    def _nlp_fallback(self) -> "MpcSolver":
        """The FATROP solver of the same problem that answers a step the RTI does not."""
        if self._fallback is None:
            self._fallback = MpcSolver(self.config, self.vehicle, solver="fatrop")
            self._fallback.enforce_time_budget = self.enforce_time_budget
        return self._fallback

    def rti(self, n_slots: int) -> RtiQp:
        """The RTI QP of ``n_slots`` obstacle slots (built on first use, ~0.1-0.3 s, or its
        data function loaded from the on-disk cache, ~0.01-0.03 s)."""
        if n_slots not in self._rti:
            key = solver_cache.entry_key(
                self.config.model_dump_json(), repr(self.vehicle), str(n_slots),
                self.solver_name)
            hit = solver_cache.load(key)
            # max_iterations caps the QP solver's iterations per step (an RTI step has no
            # NLP iterations to cap; HPIPM's own cap of 50 stays the upper limit): a QP
            # that needs more is a failed solve
            qp = RtiQp(horizon=self.n, dt_s=self.dt_s, vehicle=self.vehicle,
                       n_slots=n_slots, qp_solver=self.config.rti_qp_solver,
                       qp_iter_max=min(self.config.max_iterations, 50), data=hit)
            if hit is None:
                solver_cache.store(key, *qp.cache_entry())
            self._rti[n_slots] = qp
        return self._rti[n_slots]

    def compiled(self, n_slots: int) -> _Compiled:
        """The problem of ``n_slots`` obstacle slots (built on first use, ~0.1-1 s, or
        loaded from the on-disk cache, ~0.05 s: :mod:`lmpc_mpc.solver_cache`). The
        hybrid ``sqp_rti``'s NLP is that of its FATROP fallback."""
        if self.solver_name == "sqp_rti":
            return self._nlp_fallback().compiled(n_slots)
        if n_slots not in self._compiled:
            self._compiled[n_slots] = self._load_or_build(n_slots)
        return self._compiled[n_slots]

    def generated_sizes(self) -> set[int]:
        """Slot counts whose NLP runs as generated C (the hybrid's: its FATROP's)."""
        return self._fallback._generated if self._fallback is not None else self._generated

    def _load_or_build(self, n_slots: int) -> _Compiled:
        # the key holds what the problem is built from: not the codegen choice, and the time
        # budget only for IPOPT (its max_wall_time); FATROP's problem is the same in realtime
        key = solver_cache.entry_key(
            self.config.model_dump_json(exclude={"codegen", "enforce_time_budget"}),
            repr(self.vehicle), str(n_slots), self.solver_name,
            str(self.enforce_time_budget and self.solver_name == "ipopt"))
        if self.config.codegen != "off":
            # the generated C gives the same iterates, so where it is missing the
            # interpreted problem below is the same controller, only slower
            gen_key = solver_cache.entry_key(key, codegen.TAG)
            hit = solver_cache.load(gen_key)
            if hit is None and self.config.codegen == "build":
                hit = codegen.build_and_store(
                    lambda opts: self._entry(self._build(n_slots, opts)), gen_key)
            if hit is not None:
                self._generated.add(n_slots)
                return self._from_entry(hit, n_slots)
        hit = solver_cache.load(key)
        if hit is not None:
            return self._from_entry(hit, n_slots)
        built = self._build(n_slots)
        solver_cache.store(key, *self._entry(built))
        return built

    @staticmethod
    def _entry(built: _Compiled) -> tuple[ca.Function, dict[str, np.ndarray]]:
        return built.solver, {"lbx": built.lbx, "ubx": built.ubx, "lbg": built.lbg,
                              "ubg": built.ubg, "n_p": np.array(built.n_p)}

    @staticmethod
    def _from_entry(entry: tuple[ca.Function, dict[str, np.ndarray]], n_slots: int
                    ) -> _Compiled:
        fn, a = entry
        return _Compiled(fn, n_slots, a["lbx"], a["ubx"], a["lbg"], a["ubg"], int(a["n_p"]))

    def reset(self) -> None:
        """Forget the warm start (e.g. after a teleport or a new episode): the next solve is
        cold, so a pending ``reconverge`` is void. ``over_budget`` counts on, like the
        controller's counters (per process, not per episode)."""
        self._warm = None
        self._warm_slots = None
        self._reconverge_next = False

    def warm_state(self) -> tuple[Optional[np.ndarray], Optional[int], bool, int]:
        """What the next solve starts from (warm start, its slot count, the reconverge flag)
        and the over-budget count: ``set_warm_state`` of it makes the next solve repeat
        exactly (episode branching, ``lmpc_bridge.episode``)."""
        warm = None if self._warm is None else self._warm.copy()
        return (warm, self._warm_slots, self._reconverge_next, self.over_budget)

    def set_warm_state(self, state: tuple[Optional[np.ndarray], Optional[int], bool, int]
                       ) -> None:
        """Restore a ``warm_state``."""
        warm, self._warm_slots, self._reconverge_next, self.over_budget = state
        self._warm = None if warm is None else warm.copy()

    def reconverge(self) -> None:
        """The problem changed in a jump (a new decision: other weights, bias, attended
        agents): the next RTI solve iterates to convergence (``rti_cold_iterations``)
        from the shifted guess instead of taking one step. One Gauss-Newton step lags a
        jump by several control steps (late braking when a decision says brake)."""
        self._reconverge_next = True

    # -- parameters ----------------------------------------------------------------------
    def _params(self, prob: MpcProblem) -> tuple[np.ndarray, np.ndarray, int]:
        n, cfg, veh = self.n, self.config, self.vehicle
        ref = np.asarray(prob.reference, dtype=float)
        kap = np.asarray(prob.reference_curvature_1pm, dtype=float)
        if ref.shape != (n + 1, 4) or kap.shape != (n + 1,):
            raise MpcInputError(
                f"reference must be ({n + 1}, 4) and curvature ({n + 1},), got "
                f"{ref.shape} and {kap.shape}")
        a_lo, a_hi = -veh.max_decel_mps2, veh.max_accel_mps2
        d_lim = veh.max_steer_rad
        x0 = np.array([*prob.x0,
                       min(max(prob.u_prev[0], a_lo), a_hi), min(max(prob.u_prev[1], -d_lim),
                                                                 d_lim),
                       min(max(prob.u_prev2[0], a_lo), a_hi), min(max(prob.u_prev2[1], -d_lim),
                                                                  d_lim)], dtype=float)
        wv = CostParams.of(prob.weights, bias_steer_rad=prob.bias[1],
                           lateral_factor=cfg.lateral_weight_factor).pack()
        # unwrap the reference yaw next to the current yaw so 1 - cos never sees a jump
        yaw_ref = np.unwrap(np.concatenate([[prob.x0[2]], ref[:, 2]]))[1:]
        packed, n_slots = pack(prob.obstacles, ref, yaw_ref, config=cfg, vehicle=veh,
                               warm=self._warm)
        p = np.empty(NX + N_W + (n + 1) * (NREF + NOBS * n_slots))
        p[:NX] = x0
        p[NX:NX + N_W] = wv
        stage = p[NX + N_W:].reshape(n + 1, NREF + NOBS * n_slots)
        stage[:, 0:2] = ref[:, 0:2]
        stage[:, 2] = yaw_ref
        stage[:, 3] = ref[:, 3]
        stage[:, 4] = kap
        if prob.bias_accel_mps2 is None:
            stage[:, 5] = prob.bias[0]
        else:
            b_a = np.asarray(prob.bias_accel_mps2, dtype=float).ravel()
            if b_a.shape != (n,):
                raise MpcInputError(f"bias_accel_mps2 must be ({n},), got {b_a.shape}")
            stage[:n, 5] = b_a
            stage[n, 5] = b_a[-1]
        if packed is None:
            obs = stage[:, NREF:].reshape(n + 1, n_slots, NOBS)
            obs[:] = 0.0
            obs[..., 4] = 1.0
        else:
            stage[:, NREF:] = packed.reshape(n + 1, NOBS * n_slots)
        if not np.all(np.isfinite(p)):
            raise MpcInputError("MPC problem contains NaN or infinite numbers")
        return p, x0, n_slots

    def _initial_guess(self, x0: np.ndarray, n_slots: int) -> np.ndarray:
        n = self.n
        if self._warm is not None and self._warm_slots is not None:
            prev = self._warm
            xs = prev[:, :NX]
            us = prev[:, NX:]
            # shift by one stage, keep the last control, then re-anchor on x0
            us_s = np.vstack([us[1:n], us[n - 1:n]])
            xs_s = np.vstack([xs[1:], xs[-1:]])
            # the ego's yaw arrives wrapped to (-pi, pi]; the plan's yaw is continuous.
            # Heading across +-pi between two steps, the shifted plan lay 2 pi from x0's
            # yaw: a 2 pi jump between its first two stages, which the solver "closed"
            # by a loop at full steer (rab training seed 10089: a planned circle into
            # the roundabout's island, the exit missed, the ego off its route)
            turns = round((float(x0[2]) - float(xs_s[0, 2])) / (2.0 * math.pi))
            if turns:
                xs_s[:, 2] += 2.0 * math.pi * turns
            xs_s[0] = x0
        else:
            us_s = np.zeros((n, NU))
            us_s[:, 1] = x0[5]
            traj = simulate_bicycle(x0[:4], us_s, dt_s=self.dt_s, vehicle=self.vehicle)
            xs_s = np.zeros((n + 1, NX))
            xs_s[:, :4] = traj
            xs_s[:, 4:6] = np.vstack([x0[4:6], us_s])
            xs_s[:, 6:8] = np.vstack([x0[6:8], x0[4:6], us_s[:-1]])
        guess = np.empty((n + 1, NX + NU))
        guess[:, :NX] = xs_s
        guess[:n, NX:] = us_s
        return guess.ravel()[: (n + 1) * NX + n * NU]

    # -- solving -------------------------------------------------------------------------
    def solve(self, problem: MpcProblem) -> MpcResult:
        """Solve one step. Never returns an unconverged or non-finite solution as success."""
        if not self._compiled and not self._rti:
            self.warm_up()
        t0 = time.perf_counter()  # compiling is not part of the solve time
        self._cpu0 = time.process_time()
        try:
            p, x0, n_slots = self._params(problem)
        except MpcInputError as exc:
            return self._fail(f"bad input: {exc}", t0, 0)
        if self.solver_name == "sqp_rti":
            warm = (self._warm, self._warm_slots)  # the RTI step replaces them
            res = self._solve_rti(p, x0, n_slots, t0)
            if res.success or not self.config.rti_fallback:
                return res
            return self._solve_by_fallback(p, x0, n_slots, t0, warm, res.status)
        return self._solve_nlp(p, x0, n_slots, t0)

    def _solve_by_fallback(self, p: np.ndarray, x0: np.ndarray, n_slots: int, t0: float,
                           warm: tuple[Optional[np.ndarray], Optional[int]],
                           why: str) -> MpcResult:
        """FATROP on the step the RTI did not deliver (``why``), from the warm start the
        RTI had; its solution (or failure) is this step's, and warm-starts the next RTI
        step. The solve time counts both attempts."""
        fb = self._nlp_fallback()
        res = self._solve_in(fb, p, x0, n_slots, t0, warm)
        self.rti_fallbacks += 1
        self._warm, self._warm_slots = fb._warm, fb._warm_slots
        return replace(res, status=f"{res.status} (FATROP after the RTI: {why})"[:190])

    def _solve_in(self, other: "MpcSolver", p: np.ndarray, x0: np.ndarray, n_slots: int,
                  t0: float, warm: tuple[Optional[np.ndarray], Optional[int]]
                  ) -> MpcResult:
        """One NLP solve of this step by ``other`` (the RTI's FATROP fallback, FATROP's
        retry) from ``warm``, timed from this step's ``t0``; its overrun counts here. The
        caller takes ``other``'s new warm start if it keeps the result."""
        other._warm, other._warm_slots = warm
        other._cpu0 = self._cpu0
        res = other._solve_nlp(p, x0, n_slots, t0)
        self.over_budget += other.over_budget
        other.over_budget = 0
        return res

    def _solve_nlp(self, p: np.ndarray, x0: np.ndarray, n_slots: int,
                   t0: float) -> MpcResult:
        """One solve of the NLP (FATROP or IPOPT) with parameters ``p``."""
        n = self.n
        comp = self.compiled(n_slots)
        w0 = self._initial_guess(x0, n_slots)
        try:
            sol = comp.solver(x0=w0, p=p, lbx=comp.lbx, ubx=comp.ubx, lbg=comp.lbg,
                              ubg=comp.ubg)
        except RuntimeError as exc:  # CasADi raises on evaluation errors (NaN in a function)
            return self._fail(f"solver error: {str(exc).splitlines()[0][:120]}", t0, 0)
        elapsed = time.perf_counter() - t0
        stats = comp.solver.stats()
        ok = bool(stats.get("success", False))
        raw = stats.get("return_status", "unknown")
        status = ("Solve_Succeeded" if ok else f"failed ({raw})") if isinstance(raw, int) \
            else str(raw)
        iters = int(stats.get("iter_count", 0) or 0)
        wsol = np.asarray(sol["x"]).ravel()
        # variables are laid out stage-wise (x_0, u_0, x_1, u_1, ..., x_N)
        stage = np.empty((n + 1, NX + NU))
        stage.ravel()[: len(wsol)] = wsol
        stage[n, NX:] = stage[n - 1, NX:]
        xs = stage[:, :NX]
        us = stage[:n, NX:]
        why = None if ok else f"not converged: {status}"
        if ok and not (np.all(np.isfinite(xs)) and np.all(np.isfinite(us))):
            why = "non-finite solution"
        if why is None:
            return self._accept(stage, n_slots, status, t0, iters, elapsed)
        if self._retries_to() is not None and self._warm is not None and (
                not self.enforce_time_budget or (
                    n_slots in self._retry_solver()._compiled
                    and elapsed < self.config.time_budget_s)):
            # only from a previous plan (the rescue is checked against it); realtime: only
            # with the retry built (warm_up) and time left in the step's budget; IPOPT
            # stops at the budget's wall time, an overrun is a failure
            return self._solve_by_retry(p, x0, n_slots, t0, iters, why, w0)
        return self._fail(why, t0, iters, elapsed)

    def _solve_by_retry(self, p: np.ndarray, x0: np.ndarray, n_slots: int, t0: float,
                        iters: int, why: str, w0: np.ndarray) -> MpcResult:
        """``config.retry_solver`` on the step this solver failed (``why``), from the warm
        start this solve had (``w0``, the shifted previous plan): its solution is this
        step's, and warm-starts the next step, if it converged within
        ``retry_max_move_*`` of ``w0``'s controls; otherwise the step fails. Solve time
        and iterations count both attempts."""
        n = self.n
        plan = np.empty((n + 1, NX + NU))
        plan.ravel()[: len(w0)] = w0
        retry = self._retry_solver()
        res = self._solve_in(retry, p, x0, n_slots, t0, (self._warm, self._warm_slots))
        self.retries += 1
        name = retry.solver_name.upper()
        cfg = self.config
        if res.success:
            # trusted only near the plan it started from: the non-convex problem has other
            # optima, and IPOPT "converged" to full throttle and a hard left under a
            # decision braking and steering right (lane 18, "drive aggressively")
            move = np.max(np.abs(res.controls - plan[:n, NX:]), axis=0)
            if move[0] > cfg.retry_max_move_accel_mps2 or move[1] > cfg.retry_max_move_steer_rad:
                return self._fail(
                    f"{name} after FATROP ({why}) moved the plan by {move[0]:.2f} m/s^2, "
                    f"{move[1]:.3f} rad: not trusted"[:190], t0, iters + res.iterations,
                    res.solve_time_s)
        self.rescues += int(res.success)
        self._warm, self._warm_slots = retry._warm, retry._warm_slots
        return replace(res, status=f"{res.status} ({name} after FATROP: {why})"[:190],
                       iterations=iters + res.iterations)

    def _solve_rti(self, p: np.ndarray, x0: np.ndarray, n_slots: int,
                   t0: float) -> MpcResult:
        """One real-time iteration from the shifted previous solution: Gauss-Newton QP
        steps until one moves no planned control by more than ``rti_step_*`` (at most
        ``rti_iterations``; from a cold start ``rti_cold_iterations``, to 1e-3)."""
        n = self.n
        qp = self.rti(n_slots)
        cold = self._warm is None or self._reconverge_next
        self._reconverge_next = False
        guess = self._initial_guess(x0, n_slots)
        stage = np.empty((n + 1, NX + NU))
        stage.ravel()[: len(guess)] = guess
        z = qp.from_stages(stage[:, :NX], stage[:n, NX:])
        cfg = self.config
        steps = cfg.rti_cold_iterations if cold else cfg.rti_iterations
        # from a cold start (a plain roll-out) iterate close to convergence; warm, a step
        # that moved no planned control by more than rti_step_* ends the iteration: one
        # step from a good guess, more after a jump (one full step from a far guess
        # braked at -6 m/s^2 for three steps when the reference switched from stop to go,
        # usi seed 17; see docs/lmpc_mpc.md)
        tol = (1e-3, 1e-4) if cold else (cfg.rti_step_accel_mps2, cfg.rti_step_steer_rad)
        try:
            step = qp.iterate(z, p, x0, steps=steps, accel_tol_mps2=tol[0],
                              steer_tol_rad=tol[1])
        except RuntimeError as exc:  # CasADi raises on evaluation errors
            return self._fail(f"solver error: {str(exc).splitlines()[0][:120]}", t0, 0)
        elapsed = time.perf_counter() - t0
        if not step.ok:
            return self._fail(f"not converged: {step.status}", t0, step.sqp_steps, elapsed)
        if cold and (step.last_move[0] > cfg.rti_step_accel_mps2
                     or step.last_move[1] > cfg.rti_step_steer_rad):
            # a cold / reconverge iteration still moving a planned control by more than a
            # warm step may: no solution yet (si seed 24 lmpc-rules: such a plan read -1.6
            # then +3 m/s^2 and the ego entered a left turn too fast where FATROP, failing
            # on the same problem, braked): not delivered (FATROP answers it with
            # rti_fallback, else the shifted plan, then the brake)
            return self._fail(
                f"not converged: cold RTI still moving after {step.sqp_steps} steps "
                f"({step.last_move[0]:.2f} m/s^2, {step.last_move[1]:.3f} rad)",
                t0, step.sqp_steps, elapsed)
        if not cold and (step.last_move[0] > cfg.rti_max_move_accel_mps2
                         or step.last_move[1] > cfg.rti_max_move_steer_rad):
            # a full step that swings the plan: the linearisation was far from the problem
            # (dev rab 107 mpc: +3 / -3.5 / +3 m/s^2 and a steer into the ring's entry
            # lane); not delivered either
            return self._fail(
                f"RTI step too large ({step.last_move[0]:.2f} m/s^2, "
                f"{step.last_move[1]:.3f} rad)", t0, step.sqp_steps, elapsed)
        xs, us = qp.to_stages(step.z)
        out = np.empty((n + 1, NX + NU))
        out[:, :NX] = xs
        out[:n, NX:] = us[:, :NU]
        out[n, NX:] = out[n - 1, NX:]
        if not np.all(np.isfinite(out)):
            return self._fail("non-finite solution", t0, step.sqp_steps, elapsed)
        status = (f"{step.status} ({step.sqp_steps} step{'s' if step.sqp_steps > 1 else ''}, "
                  f"{step.qp_iterations} QP iterations)")
        # an RTI "iteration" is one Gauss-Newton SQP step (the NLP solvers' counterpart)
        return self._accept(out, n_slots, status, t0, step.sqp_steps, elapsed)

    def _accept(self, stage: np.ndarray, n_slots: int, status: str, t0: float, iters: int,
                elapsed: float) -> MpcResult:
        """A solution that passed the checks: budget, warm start, clipped first control."""
        n = self.n
        xs = stage[:, :NX]
        us = stage[:n, NX:]
        if elapsed > self.config.time_budget_s:
            self.over_budget += 1
        if elapsed > self.config.time_budget_s and self.enforce_time_budget:
            return self._fail(
                f"over time budget ({elapsed * 1e3:.1f} ms > "
                f"{self.config.time_budget_s * 1e3:.1f} ms)", t0, iters, elapsed)
        self._warm = stage
        self._warm_slots = n_slots
        veh = self.vehicle
        u0 = (float(np.clip(us[0, 0], -veh.max_decel_mps2, veh.max_accel_mps2)),
              float(np.clip(us[0, 1], -veh.max_steer_rad, veh.max_steer_rad)))
        return MpcResult(True, status, u0, xs[:, :4].copy(), elapsed, iters, us.copy(),
                         time.process_time() - self._cpu0)

    def _fail(self, status: str, t0: float, iters: int,
              elapsed: Optional[float] = None) -> MpcResult:
        # a failed solve must not seed the next one
        self._warm = None
        dt = elapsed if elapsed is not None else time.perf_counter() - t0
        return MpcResult(False, status, (0.0, 0.0), np.zeros((self.n + 1, 4)), dt, iters,
                         solve_cpu_s=time.process_time() - self._cpu0)
