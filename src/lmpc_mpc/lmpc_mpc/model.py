"""What the NLP and the RTI solvers share: the problem layout, its symbols and bounds,
and the internal vehicle model (CasADi).

A kinematic bicycle about the box centre (the bridge's plant, ``lmpc_bridge.dynamics``),
integrated with one explicit midpoint (RK2) step per stage. The state (NX) is
x, y, yaw, v plus earlier controls (two accel / steer pairs), so the smoothness
terms stay stage-local (FATROP's stage-wise structure).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import casadi as ca

from lmpc_msgs_py.vehicle import VehicleParams
from lmpc_msgs_py.vocabulary import ResolvedWeights

NX = 8
NU = 2
NREF = 6  # per stage: x, y, yaw, v, curvature of the reference; accel bias A_hat_a,k
NOBS = 6


class CostParams(NamedTuple):
    """The problem-wide part of the parameter vector (after ``x0``), by name.

    Both solvers (``solver.MpcSolver``'s NLP, ``rti.RtiQp``) read their weights from
    :meth:`symbols`, and ``MpcSolver`` fills the numbers with :meth:`of` and :meth:`pack`:
    the order of the slots is this class's field order and nothing else. Each field is a
    float when packed and a CasADi symbol inside a problem. The per-stage parameters
    (reference, the per-stage acceleration bias, obstacles) follow in the vector."""

    w_pos: Any
    """W_x: squared position error to the reference (lateral: x ``lateral_factor``)."""
    w_v: Any
    """W_v: squared speed error."""
    w_yaw: Any
    """W_theta: yaw error, ``2 (1 - cos)``."""
    w_steer_ref: Any
    """Squared error of the steer angle to the reference's curvature steer angle."""
    w_bias_accel: Any
    """W_s, acceleration: squared distance to the (per-stage) acceleration bias."""
    w_bias_steer: Any
    """W_s, steer: squared distance to ``bias_steer_rad``."""
    w_g_accel: Any
    """W_g, acceleration: squared first difference."""
    w_g_steer: Any
    """W_g, steer: squared first difference."""
    w_l_accel: Any
    """W_l, acceleration: squared second difference."""
    w_l_steer: Any
    """W_l, steer: squared second difference."""
    w_saf: Any
    """w_saf: squared shortfall of the distance to each attended agent."""
    bias_steer_rad: Any
    """The steer bias A_hat_delta [rad]."""
    lateral_factor: Any
    """The lateral position error weighs this many times ``w_pos``."""

    @classmethod
    def of(cls, weights: ResolvedWeights, *, bias_steer_rad: float,
           lateral_factor: float) -> "CostParams":
        """The numbers of one problem: resolved weights, steer bias, lateral factor."""
        tr, ac, sm = weights.tracking, weights.action, weights.smoothness
        return cls(w_pos=tr.w_pos, w_v=tr.w_v, w_yaw=tr.w_yaw, w_steer_ref=tr.w_steer,
                   w_bias_accel=ac.w_accel, w_bias_steer=ac.w_steer,
                   w_g_accel=sm.w_g_accel, w_g_steer=sm.w_g_steer,
                   w_l_accel=sm.w_l_accel, w_l_steer=sm.w_l_steer,
                   w_saf=weights.safety.w_saf, bias_steer_rad=bias_steer_rad,
                   lateral_factor=lateral_factor)

    @classmethod
    def symbols(cls, w: ca.SX) -> "CostParams":
        """The slots of the symbol vector ``w`` (``StageSymbols.w``), by name."""
        return cls(*(w[i] for i in range(N_W)))

    def pack(self) -> tuple[float, ...]:
        """The numbers in slot order (what goes into the parameter vector)."""
        return tuple(float(v) for v in self)


N_W = len(CostParams._fields)
"""Length of the problem-wide weight block of the parameter vector."""


@dataclass(frozen=True)
class StageSymbols:
    """Parameters and variables of one problem, declared in stage order."""

    x0: ca.SX
    """Initial state (NX)."""
    w: ca.SX
    """Weights (N_W)."""
    stage_p: list[ca.SX]
    """Per stage 0..N: the reference (NREF) and the obstacle slots (NOBS each)."""
    xs: list[ca.SX]
    """States 0..N."""
    us: list[ca.SX]
    """Controls 0..N-1 (``nu`` wide: the RTI appends its safety slacks)."""


def stage_symbols(n: int, n_slots: int, nu: int = NU) -> StageSymbols:
    return StageSymbols(
        x0=ca.SX.sym("x0", NX), w=ca.SX.sym("w", N_W),
        stage_p=[ca.SX.sym(f"p{k}", NREF + NOBS * n_slots) for k in range(n + 1)],
        xs=[ca.SX.sym(f"x{k}", NX) for k in range(n + 1)],
        us=[ca.SX.sym(f"u{k}", nu) for k in range(n)])


BIG = 1e6
"""Stand-in for an unbounded variable."""


def box_bounds(veh: VehicleParams) -> tuple[list[float], list[float], list[float], list[float]]:
    """Hard bounds (x_lb, x_ub, u_lb, u_ub) on the state (incl. the carried previous
    controls) and on the controls (accel, steer)."""
    x_lb = [-BIG, -BIG, -BIG, 0.0, -veh.max_decel_mps2, -veh.max_steer_rad,
            -veh.max_decel_mps2, -veh.max_steer_rad]
    x_ub = [BIG, BIG, BIG, veh.max_speed_mps, veh.max_accel_mps2, veh.max_steer_rad,
            veh.max_accel_mps2, veh.max_steer_rad]
    return x_lb, x_ub, [-veh.max_decel_mps2, -veh.max_steer_rad], \
        [veh.max_accel_mps2, veh.max_steer_rad]


def bicycle_function(vehicle: VehicleParams) -> ca.Function:
    """``f(s, u)``: d/dt of (x, y, yaw, v) for controls (accel, steer)."""
    s = ca.SX.sym("s", 4)
    u = ca.SX.sym("u", 2)
    ratio = vehicle.lr_m / vehicle.wheelbase_m
    beta = ca.atan(ratio * ca.tan(u[1]))
    rhs = ca.vertcat(s[3] * ca.cos(s[2] + beta), s[3] * ca.sin(s[2] + beta),
                     s[3] / vehicle.lr_m * ca.sin(beta), u[0])
    return ca.Function("f", [s, u], [rhs])


def midpoint_step(f: ca.Function, s: ca.SX, u: ca.SX, dt_s: float) -> ca.SX:
    """One explicit midpoint (RK2) step of ``s' = f(s, u)``: the MPC's internal model.

    An approximation of the plant (the bridge integrates RK4 in two substeps): over a
    3 s horizon it is within 8 mm of a fine integration for |steer| <= 0.5 rad, while
    its exact Hessian costs 2.5x fewer operations than RK4's (the largest share of an
    interior-point iteration here)."""
    k1 = f(s, u)
    return s + dt_s * f(s + 0.5 * dt_s * k1, u)
