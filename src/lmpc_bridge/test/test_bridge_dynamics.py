"""Kinematic bicycle integration and the final control guard."""
from __future__ import annotations

import math

import pytest

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge.dynamics import EgoPose, clamp_control, step_bicycle

VEH = DEFAULT_VEHICLE


def run(pose: EgoPose, accel: float, steer: float, steps: int) -> list[EgoPose]:
    out = [pose]
    for _ in range(steps):
        out.append(step_bicycle(out[-1], accel, steer, dt_s=0.1, vehicle=VEH))
    return out


def test_straight_line_constant_accel() -> None:
    yaw = 0.7
    traj = run(EgoPose(1.0, 2.0, yaw, 5.0), 1.0, 0.0, 30)
    end = traj[-1]
    dist = 5.0 * 3.0 + 0.5 * 1.0 * 9.0
    assert end.v_mps == pytest.approx(8.0)
    assert end.x_m == pytest.approx(1.0 + dist * math.cos(yaw))
    assert end.y_m == pytest.approx(2.0 + dist * math.sin(yaw))
    assert end.yaw_rad == pytest.approx(yaw)


def test_constant_radius_turn() -> None:
    steer = 0.2
    v = 6.0
    beta = math.atan(VEH.lr_m / VEH.wheelbase_m * math.tan(steer))
    radius = VEH.lr_m / math.sin(beta)  # radius of the centre's circle
    traj = run(EgoPose(0.0, 0.0, 0.0, v), 0.0, steer, 60)
    # circle centre: perpendicular to the velocity direction (yaw + beta) at the start
    cx, cy = -radius * math.sin(beta), radius * math.cos(beta)
    for p in traj:
        assert math.hypot(p.x_m - cx, p.y_m - cy) == pytest.approx(radius, rel=1e-6)
    yaw_rate = v / VEH.lr_m * math.sin(beta)
    expected = math.remainder(yaw_rate * 6.0, 2 * math.pi)
    assert traj[-1].yaw_rad == pytest.approx(expected, abs=1e-9)


def test_braking_stops_exactly_without_reversing() -> None:
    traj = run(EgoPose(0.0, 0.0, 0.0, 3.0), -4.0, 0.0, 20)
    assert min(p.v_mps for p in traj) == 0.0
    xs = [p.x_m for p in traj]
    assert all(b >= a for a, b in zip(xs, xs[1:]))
    assert traj[-1].x_m == pytest.approx(3.0 ** 2 / (2 * 4.0))


def test_speed_cap() -> None:
    veh = VehicleParams(max_speed_mps=10.0)
    p = EgoPose(0.0, 0.0, 0.0, 9.0)
    for _ in range(20):
        p = step_bicycle(p, 3.0, 0.0, dt_s=0.1, vehicle=veh)
    assert p.v_mps == pytest.approx(10.0)
    # time to cap 1/3 s -> distance 9*1/3 + 1.5/9 + 10*(2-1/3)
    assert p.x_m == pytest.approx(9.0 / 3 + 1.5 / 9 + 10.0 * (2.0 - 1.0 / 3), rel=1e-9)


def test_clamp_bounds_and_rate() -> None:
    out = clamp_control(10.0, 0.5, prev_steer_rad=0.0, dt_s=0.1, vehicle=VEH)
    assert out.accel_mps2 == VEH.max_accel_mps2
    assert out.steer_rad == pytest.approx(VEH.max_steer_rate_radps * 0.1)
    assert out.clamped
    out = clamp_control(-20.0, -2.0, prev_steer_rad=-0.58, dt_s=0.1, vehicle=VEH)
    assert out.accel_mps2 == -VEH.max_decel_mps2
    assert out.steer_rad == -VEH.max_steer_rad
    ok = clamp_control(1.0, 0.05, prev_steer_rad=0.0, dt_s=0.1, vehicle=VEH)
    assert ok == (1.0, 0.05, False)
    # over the rate limit by the solver's tolerance (3e-8 rad): applied at the limit, not
    # flagged; by 1e-5: flagged
    limit = VEH.max_steer_rate_radps * 0.1
    tiny = clamp_control(1.0, limit + 3e-8, prev_steer_rad=0.0, dt_s=0.1, vehicle=VEH)
    assert tiny.steer_rad == pytest.approx(limit, abs=1e-12) and not tiny.clamped
    assert clamp_control(1.0, limit + 1e-5, prev_steer_rad=0.0, dt_s=0.1, vehicle=VEH).clamped


@pytest.mark.parametrize("bad", [math.nan, math.inf, None])
def test_nan_or_missing_control_brakes_and_holds_steer(bad) -> None:
    out = clamp_control(bad, bad, prev_steer_rad=0.1, dt_s=0.1, vehicle=VEH)
    assert out.accel_mps2 == -VEH.safe_brake_mps2
    assert out.steer_rad == 0.1
    assert out.clamped
