"""What the NLP and the RTI solvers share: the problem layout, its symbols and bounds,
and the internal vehicle model (CasADi).

A kinematic bicycle about the box centre (the bridge's plant, ``lmpc_bridge.dynamics``),
integrated with one explicit midpoint (RK2) step per stage. The state (NX) is
x, y, yaw, v plus earlier controls (two accel / steer pairs), so the smoothness
terms stay stage-local (FATROP's stage-wise structure).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from lmpc_msgs_py.vehicle import VehicleParams

NX = 8
NU = 2
NREF = 6  # per stage: x, y, yaw, v, curvature of the reference; accel bias A_hat_a,k
NOBS = 6
N_W = 14  # pos, v, yaw, steer_trk, s_a, s_d, g_a, g_d, l_a, l_d, saf, (unused), bias_d, lat


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
