"""Metrics on hand-made traces (answers worked out by hand in the comments)."""
from __future__ import annotations

import pytest

from lmpc_bridge.metrics import compute_metrics
from lmpc_bridge.record import NearbyVehicle, StepRecord


def nb(vid: str, *, v: float, v_max: float = 14.0, a: float = 0.0, gap: float = 50.0,
       affected: bool = False) -> NearbyVehicle:
    return NearbyVehicle(id=vid, kind="car", x_m=0.0, y_m=0.0, yaw_rad=0.0, v_mps=v,
                         v_max_mps=v_max, a_mps2=a, gap_m=gap, affected=affected)


def step(k: int, *nearby: NearbyVehicle, late: bool = False, clamped: bool = False,
         collided: str | None = None) -> StepRecord:
    return StepRecord(step=k, t_s=0.1 * k, x_m=0.0, y_m=0.0, yaw_rad=0.0, v_mps=5.0,
                      a_mps2=0.0, steer_rad=0.0, nearby=nearby, late=late, clamped=clamped,
                      collided_with=collided)


def test_hand_trace() -> None:
    steps = [
        # ineff: follower 14-10 = 4; the unaffected car does not count
        # pen_acc: follower a=-3 within 30 m -> 1; car b a=-5 but 40 m away -> 0
        # pen_dist: follower gap 6 -> 4; b gap 40 -> 0
        step(1, nb("f", v=10.0, a=-3.0, gap=6.0, affected=True), nb("b", v=0.0, a=-5.0, gap=40.0)),
        # ineff: 14-0 = 14 (yielding car) ; pen_acc: a=-2 exactly -> 0; pen_dist: 10-2 = 8
        step(2, nb("y", v=0.0, a=-2.0, gap=2.0, affected=True), late=True),
        # nobody around
        step(3, clamped=True),
        # affected car faster than its v_max counts 0, not negative; gap 0 -> 10
        step(4, nb("f", v=15.0, gap=0.0, affected=True, a=-6.0)),
    ]
    m = compute_metrics(steps, time_s=12.0)
    assert m.ineff == pytest.approx((4.0 + 14.0 + 0.0 + 0.0) / 4)
    assert m.pen_acc == pytest.approx((1.0 + 0.0 + 0.0 + 4.0) / 4)
    assert m.pen_dist == pytest.approx((4.0 + 8.0 + 0.0 + 10.0) / 4)
    expected_oc = 4.5 + 1.5 * 12.0 + 15 * 1.25 + 20 * 5.5
    assert m.overall_cost == pytest.approx(expected_oc)
    assert (m.steps, m.late_controls, m.clamped_controls, m.collisions) == (4, 1, 1, 0)


def test_empty_trace_and_collision_count() -> None:
    assert compute_metrics([], time_s=0.0).overall_cost == 0.0
    m = compute_metrics([step(1), step(2, collided="x")], time_s=0.2)
    assert m.collisions == 1
    assert m.overall_cost == pytest.approx(1.5 * 0.2)


def test_red_light_exclusion() -> None:
    """An affected vehicle held by a red light does not count for ineff; others still do."""
    red = NearbyVehicle(id="r", kind="car", x_m=0.0, y_m=0.0, yaw_rad=0.0, v_mps=0.0,
                        v_max_mps=14.0, a_mps2=-3.0, gap_m=8.0, affected=True,
                        affected_reason="follower", at_red_light=True)
    steps = [
        # red-light follower (14 m/s short) excluded; yielding car 14-4 = 10 counts
        # pen_acc still counts the red-light car (a=-3 -> 1) and pen_dist its gap (10-8 = 2)
        step(1, red, nb("y", v=4.0, gap=20.0, affected=True)),
        # the same follower once its light turned green: 14-6 = 8
        step(2, nb("r", v=6.0, gap=8.0, affected=True)),
    ]
    m = compute_metrics(steps, time_s=30.0)
    assert m.ineff == pytest.approx((10.0 + 8.0) / 2)
    assert m.pen_acc == pytest.approx(1.0 / 2)
    assert m.pen_dist == pytest.approx((2.0 + 2.0) / 2)
    assert m.overall_cost == pytest.approx(9.0 + 45.0 + 7.5 + 40.0)


def test_failed_episode_uses_the_time_limit() -> None:
    """A timeout enters with time = 200 s (the caller passes the limit): O.C. >= 300."""
    m = compute_metrics([step(1), step(2)], time_s=200.0)
    assert m.time_s == 200.0 and m.overall_cost == pytest.approx(300.0)
