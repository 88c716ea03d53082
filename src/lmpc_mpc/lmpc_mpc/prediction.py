"""Predicted agent positions over the horizon (constant speed along a Bezier candidate).

This is a deliberately simple model (the paper's): an agent keeps its current
speed along the chosen curve; beyond the curve's end it goes on straight. It
does not model braking, yielding or car following of the agent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from lmpc_msgs_py.messages import Agent, MapSnapshot
from lmpc_mpc.reference import (
    WRONG_WAY_RAD,
    Candidate,
    bezier_points,
    candidates_for_pose,
    closest_heading,
    heading_off_rad,
    straight_candidate,
)

_SAMPLES = 120


@dataclass(frozen=True)
class AgentForecast:
    """One agent's predicted box centres over the horizon, with its size."""

    agent_id: str
    xy_m: np.ndarray
    """(N+1, 2) positions at t = k dt, k = 0..N (row 0 = now)."""
    length_m: float
    width_m: float
    v_mps: float
    candidate: tuple[tuple[float, float], ...]
    """The control points the forecast followed (for display and logs)."""


@lru_cache(maxsize=256)
def _sampled(control_points: tuple[tuple[float, float], ...]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples of the curve, their cumulative arc length and the unit direction of its
    last segment (zero for a degenerate one), cached per curve: the controller reuses an
    agent's curve for several steps (read-only arrays)."""
    pts = bezier_points(control_points, _SAMPLES)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    tail = pts[-1] - pts[-2]
    norm = float(np.hypot(*tail))
    tail = tail / norm if norm > 1e-9 else np.zeros(2)
    for arr in (pts, cum, tail):
        arr.setflags(write=False)
    return pts, cum, tail


def _curve(control_points: Sequence[Sequence[float]]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_sampled`` of the points: a tuple of float pairs is its own cache key (the
    callers' usual form), anything else is converted first."""
    try:
        return _sampled(control_points)
    except TypeError:  # unhashable (lists, arrays)
        return _sampled(tuple((float(p[0]), float(p[1])) for p in control_points))


def predict_along(control_points: Sequence[Sequence[float]], *, v_mps: float, horizon: int,
                  dt_s: float, start_xy_m: tuple[float, float] | None = None) -> np.ndarray:
    """(horizon+1, 2) positions at constant speed along the Bezier curve of the points.

    ``start_xy_m``: where the agent is now; the forecast starts at the closest
    point of the curve to it (a decision's curve may be a few steps old)."""
    pts, cum, tail = _curve(control_points)
    s_start = 0.0
    if start_xy_m is not None:
        start = np.asarray(start_xy_m, dtype=float)
        i = int(np.argmin(np.hypot(*(pts - start).T)))
        s_start = float(cum[i])
        if i == len(pts) - 1:
            # an agent already past the curve's end (a decision a few seconds old) goes
            # on from its projection onto the straight continuation, not from the end
            s_start += max(0.0, float((start - pts[-1]) @ tail))
    s = s_start + np.arange(horizon + 1) * dt_s * max(0.0, float(v_mps))
    out = np.empty((horizon + 1, 2))
    out[:, 0] = np.interp(s, cum, pts[:, 0])
    out[:, 1] = np.interp(s, cum, pts[:, 1])
    if s[-1] > cum[-1]:  # s only grows: past the end from some k on
        beyond = s > cum[-1]
        out[beyond] = pts[-1] + (s[beyond, None] - cum[-1]) * tail
    return out


def baseline_candidate(map_: MapSnapshot, agent: Agent, *, lookahead_m: float) -> Candidate:
    """The agent's candidate closest to its current heading (the baseline's guess)."""
    cands = candidates_for_pose(map_, x_m=agent.x_m, y_m=agent.y_m, yaw_rad=agent.yaw_rad,
                                lane_id=agent.lane_id, lookahead_m=lookahead_m)
    best = closest_heading(cands, agent.yaw_rad)
    if heading_off_rad(best, agent.yaw_rad) > WRONG_WAY_RAD:
        # against its lane's direction (a pedestrian walking a crossing the other way was
        # forecast walking backwards, away from the ego's path: si 20 at a 2.5 s latency)
        return straight_candidate(agent.x_m, agent.y_m, agent.yaw_rad, lookahead_m)
    return best


def forecast(agent: Agent, control_points: Sequence[Sequence[float]] | None, *,
             map_: MapSnapshot, horizon: int, dt_s: float,
             lookahead_m: float = 60.0) -> AgentForecast:
    """Forecast ``agent`` along ``control_points`` (a Decision's prediction) or, when
    None, along its closest-heading candidate. A standing agent stays put."""
    if control_points is None:
        if agent.v_mps < 0.05:
            cps: tuple[tuple[float, float], ...] = (
                (agent.x_m, agent.y_m),
                (agent.x_m + math.cos(agent.yaw_rad), agent.y_m + math.sin(agent.yaw_rad)))
        else:
            cps = baseline_candidate(map_, agent, lookahead_m=lookahead_m).control_points
    else:
        cps = tuple((float(p[0]), float(p[1])) for p in control_points)
    # the decision's curve starts where the agent was when the planner looked
    xy = predict_along(cps, v_mps=agent.v_mps, horizon=horizon, dt_s=dt_s,
                       start_xy_m=(agent.x_m, agent.y_m))
    return AgentForecast(agent.id, xy, agent.length_m, agent.width_m, agent.v_mps, cps)
