"""Interval helpers of the rules: pick an index of the configured acceleration / steering
interval pools (the request's ``accel_intervals_mps2`` / ``steer_intervals_rad``) for a
wanted acceleration, a stop distance or a hold. Each interval is ``(lo, hi)``; the rules
reason with its midpoint. ``mid`` and ``neutral`` are the shared vocabulary's
(``lmpc_msgs_py.vocabulary``): the band the MPC and the planner call neutral is one."""
from __future__ import annotations

from typing import Optional

from lmpc_msgs_py.vocabulary import midpoint as mid
from lmpc_msgs_py.vocabulary import neutral_index as neutral

__all__ = ["Intervals", "accel_index", "brake_index", "mid", "mildest_accel", "neutral",
           "required_decel", "stop_index", "strongest_brake"]

Intervals = tuple[tuple[float, float], ...]
"""An interval pool: ``(lo, hi)`` per index."""


def strongest_brake(intervals: Intervals) -> int:
    return min(range(len(intervals)), key=lambda i: (mid(intervals[i]), i))


def accel_index(intervals: Intervals, want_mps2: float) -> int:
    """The mildest accelerating interval whose midpoint reaches ``want_mps2`` (else the
    strongest one)."""
    positive = sorted((i for i, iv in enumerate(intervals) if mid(iv) > 0.0),
                      key=lambda i: mid(intervals[i]))
    if not positive:
        return neutral(intervals)
    for i in positive:
        if mid(intervals[i]) >= 0.9 * want_mps2:
            return i
    return positive[-1]


def stop_index(intervals: Intervals, v_mps: float, d_stop_m: float,
               d_limit_m: Optional[float], still_mps: float) -> int:
    """The braking interval whose midpoint stops the ego (v^2 / 2a: the MPC brakes at the
    bias until it stands) nearest to ``d_stop_m`` without passing ``d_limit_m`` (nor the
    stop point by more than 1 m without a limit); stopped: the mildest (hold)."""
    braking = [i for i, iv in enumerate(intervals) if mid(iv) < 0.0]
    if not braking:
        return neutral(intervals)
    if v_mps < still_mps:
        return max(braking, key=lambda i: (mid(intervals[i]), -i))
    limit = max(d_stop_m + 1.0, d_limit_m if d_limit_m is not None else d_stop_m + 1.0)
    fits = [i for i in braking if v_mps ** 2 / (-2.0 * mid(intervals[i])) <= limit]
    if not fits:
        return min(braking, key=lambda i: (mid(intervals[i]), i))
    return min(fits, key=lambda i: (abs(v_mps ** 2 / (-2.0 * mid(intervals[i])) - d_stop_m),
                                    i))


def mildest_accel(intervals: Intervals) -> int:
    positive = [i for i, iv in enumerate(intervals) if mid(iv) > 0.0]
    if not positive:
        return neutral(intervals)
    return min(positive, key=lambda i: (mid(intervals[i]), i))


def brake_index(intervals: Intervals, need_mps2: float, hold: bool) -> int:
    """The mildest braking interval whose midpoint brakes at least ``need_mps2``
    (``hold``: the mildest braking interval, to stay stopped)."""
    braking = sorted(
        (i for i, iv in enumerate(intervals) if mid(iv) < 0.0), key=lambda i: -mid(intervals[i])
    )
    if not braking:
        return neutral(intervals)
    if hold:
        return braking[0]
    for i in braking:
        if -mid(intervals[i]) >= need_mps2:
            return i
    return braking[-1]


def required_decel(v_mps: float, dist_m: float, still_mps: float) -> Optional[float]:
    """v^2 / 2d; None when the distance is gone while still moving."""
    if v_mps < still_mps:
        return 0.0
    if dist_m <= 0.1:
        return None
    return v_mps**2 / (2.0 * dist_m)
