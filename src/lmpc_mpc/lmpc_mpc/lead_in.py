"""The lead-in of a reference path for an ego standing turned away from it (used by
:class:`lmpc_mpc.controller.MpcController`)."""
from __future__ import annotations

import math

import numpy as np

_LEAD_IN_OFF_RAD = math.radians(60.0)
_LEAD_IN_M = 6.0
_LEAD_IN_RADIUS_M = 6.0
_TURNED_AWAY_M = 2.0


def _bearing_off(path: np.ndarray, cum: np.ndarray, ahead_m: float, x_m: float, y_m: float,
                 yaw_rad: float) -> tuple[int, float]:
    """(index, signed angle from the ego's heading) of the path point ``ahead_m`` along
    the path (``cum``: its cumulative length; the last point when it is shorter)."""
    k = min(int(np.searchsorted(cum, ahead_m)), len(path) - 1)
    d = path[k] - np.array([x_m, y_m])
    return k, math.remainder(math.atan2(d[1], d[0]) - yaw_rad, 2.0 * math.pi)


def _cumulative(path: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])


def lead_in(path: np.ndarray, x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """The path, started along the ego's heading when its first metres leave the ego
    more than 60 degrees off it (the ego stopped turned away from its path, e.g. after
    dodging inside a junction): the car cannot reverse or turn on the spot, and with a
    reference pointing sideways or back the MPC stayed at rest (a local minimum; usi
    seed 23). The lead-in is an arc of ``_LEAD_IN_RADIUS_M`` (steer ~0.42 rad) from the
    ego's heading round to the bearing of the path point ``_LEAD_IN_M`` ahead, then the
    path from that point on (an approximation of a kinematically feasible rejoin)."""
    cum = _cumulative(path)
    if cum[-1] < 2.0 * _LEAD_IN_M:
        return path
    k, turn = _bearing_off(path, cum, _LEAD_IN_M, x_m, y_m, yaw_rad)
    if abs(turn) <= _LEAD_IN_OFF_RAD:
        return path
    side = 1.0 if turn > 0.0 else -1.0
    r = _LEAD_IN_RADIUS_M
    phi = np.linspace(0.0, abs(turn), max(3, int(abs(turn) * r / 0.5) + 1))
    cx = x_m - side * r * math.sin(yaw_rad)
    cy = y_m + side * r * math.cos(yaw_rad)
    arc = np.column_stack([cx + side * r * np.sin(yaw_rad + side * phi),
                           cy - side * r * np.cos(yaw_rad + side * phi)])
    return np.vstack([arc, path[k + 1:]]) if k + 1 < len(path) else arc


def turned_away(path: np.ndarray, x_m: float, y_m: float, yaw_rad: float) -> bool:
    """The path's start (its point ``_TURNED_AWAY_M`` ahead) lies more than
    ``_LEAD_IN_OFF_RAD`` off the ego's heading: the ego stands turned away from its path,
    not merely at the start of a tight turn (where the point 6 m ahead may be)."""
    _, turn = _bearing_off(path, _cumulative(path), _TURNED_AWAY_M, x_m, y_m, yaw_rad)
    return abs(turn) > _LEAD_IN_OFF_RAD
