"""The ego's kinematic bicycle (reference point: box centre) and the final control guard.

Model (shared with the MPC through ``lmpc_msgs_py.vehicle.VehicleParams``)::

    beta   = atan(lr / L * tan(delta))
    x'     = v cos(yaw + beta)
    y'     = v sin(yaw + beta)
    yaw'   = v / lr * sin(beta)
    v'     = a,   0 <= v <= max_speed

Controls are held constant over a step (zero-order hold). Integration: RK4 on
sub-steps; where the speed would cross 0 or ``max_speed_mps`` inside a sub-step,
the sub-step is split at the crossing time, so the speed bounds are exact
rather than clipped after the fact (no creeping backwards, no overshoot).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from lmpc_msgs_py.vehicle import VehicleParams

_EPS = 1e-12


@dataclass(frozen=True)
class EgoPose:
    """State of the bicycle model: box centre, heading, speed, and the steer in force."""

    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    steer_rad: float = 0.0
    a_mps2: float = 0.0
    """Acceleration actually realised over the last step (after the speed bounds)."""


class ClampedControl(NamedTuple):
    accel_mps2: float
    steer_rad: float
    clamped: bool
    """True if any bound, the rate limit, or the NaN rule changed the request."""


def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap to (-pi, pi]."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


CLAMP_TOL = 1e-6
"""A control changed by less than this is applied clamped but not flagged: the MPC meets
its steer-rate constraint within the solver's tolerance (a request 3e-8 rad over the rate
limit was flagged as a clamp, test_graph_injection in CI)."""


def clamp_control(accel_mps2: float | None, steer_rad: float | None, *, prev_steer_rad: float,
                  dt_s: float, vehicle: VehicleParams) -> ClampedControl:
    """Final guard before the vehicle: bounds, steer rate, NaN/Inf.

    accel in [-max_decel, max_accel]; steer in +-max_steer and within
    ``max_steer_rate * dt`` of ``prev_steer_rad``. A missing or non-finite
    accel is treated as a missing control: bounded braking (``safe_brake_mps2``);
    a missing or non-finite steer holds the previous steer. Both are flagged.
    """
    clamped = False
    if accel_mps2 is None or not math.isfinite(accel_mps2):
        accel, clamped = -vehicle.safe_brake_mps2, True
    else:
        accel = min(max(accel_mps2, -vehicle.max_decel_mps2), vehicle.max_accel_mps2)
        clamped = abs(accel - accel_mps2) > CLAMP_TOL
    if steer_rad is None or not math.isfinite(steer_rad):
        steer, clamped = prev_steer_rad, True
    else:
        steer = min(max(steer_rad, -vehicle.max_steer_rad), vehicle.max_steer_rad)
        max_delta = vehicle.max_steer_rate_radps * dt_s
        steer = min(max(steer, prev_steer_rad - max_delta), prev_steer_rad + max_delta)
        clamped = clamped or abs(steer - steer_rad) > CLAMP_TOL
    return ClampedControl(accel, steer, clamped)


def _derivative(state: tuple[float, float, float, float], accel: float, beta: float,
                lr_m: float) -> tuple[float, float, float, float]:
    _, _, yaw, v = state
    return (v * math.cos(yaw + beta), v * math.sin(yaw + beta), v / lr_m * math.sin(beta), accel)


def _rk4(state: tuple[float, float, float, float], accel: float, beta: float, lr_m: float,
         h: float) -> tuple[float, float, float, float]:
    k1 = _derivative(state, accel, beta, lr_m)
    s2 = tuple(s + 0.5 * h * k for s, k in zip(state, k1))
    k2 = _derivative(s2, accel, beta, lr_m)  # type: ignore[arg-type]
    s3 = tuple(s + 0.5 * h * k for s, k in zip(state, k2))
    k3 = _derivative(s3, accel, beta, lr_m)  # type: ignore[arg-type]
    s4 = tuple(s + h * k for s, k in zip(state, k3))
    k4 = _derivative(s4, accel, beta, lr_m)  # type: ignore[arg-type]
    return tuple(s + h / 6.0 * (a + 2 * b + 2 * c + d)  # type: ignore[return-value]
                 for s, a, b, c, d in zip(state, k1, k2, k3, k4))


def step_bicycle(pose: EgoPose, accel_mps2: float, steer_rad: float, *, dt_s: float,
                 vehicle: VehicleParams, substeps: int = 2) -> EgoPose:
    """Integrate the bicycle over ``dt_s`` with constant (accel, steer); exact speed bounds.

    The inputs are expected to be guarded already (:func:`clamp_control`).
    """
    beta = math.atan(vehicle.lr_m / vehicle.wheelbase_m * math.tan(steer_rad))
    state = (pose.x_m, pose.y_m, pose.yaw_rad, pose.v_mps)
    h = dt_s / substeps
    for _ in range(substeps):
        remaining = h
        accel = accel_mps2
        v = state[3]
        if accel < 0.0 and v + accel * remaining < 0.0:
            t_stop = v / -accel
            if t_stop > _EPS:
                state = _rk4(state, accel, beta, vehicle.lr_m, t_stop)
            state = (state[0], state[1], state[2], 0.0)
            remaining = 0.0  # standing still for the rest of the sub-step
        elif accel > 0.0 and v + accel * remaining > vehicle.max_speed_mps:
            t_max = max((vehicle.max_speed_mps - v) / accel, 0.0)
            if t_max > _EPS:
                state = _rk4(state, accel, beta, vehicle.lr_m, t_max)
            state = (state[0], state[1], state[2], vehicle.max_speed_mps)
            remaining -= t_max
            accel = 0.0
        if remaining > _EPS:
            state = _rk4(state, accel, beta, vehicle.lr_m, remaining)
        state = (state[0], state[1], state[2], min(max(state[3], 0.0), vehicle.max_speed_mps))
    realised_a = (state[3] - pose.v_mps) / dt_s
    return EgoPose(x_m=state[0], y_m=state[1], yaw_rad=wrap_angle_rad(state[2]), v_mps=state[3],
                   steer_rad=steer_rad, a_mps2=realised_a)
