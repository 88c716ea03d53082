"""How close an agent is to the ego, and how soon they would touch: box gap, closing
speed and time to collision (TTC). One definition for the planner (prompt, emergency
check, its safety floor) and the MPC (its per-step safety floor); the planner imports
it from here (DESIGN §1: the planner may import ``lmpc_mpc``, not the other way).

An APPROXIMATION for deciding *whom to look at*, not for the safety term itself:
- TTC extrapolates both vehicles at constant velocity along their current headings; an
  agent is on a collision course when the miss distance at closest approach is below
  half the summed widths (for crossing traffic up to half the summed lengths) plus
  ``MISS_MARGIN_M``;
- the box gap uses each box's support (half extent) along the line of sight.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Protocol

import numpy as np

from lmpc_msgs_py.messages import Agent, EgoState

MISS_MARGIN_M = 1.0
"""Extra lateral clearance for the collision-course test."""
MIN_CLOSING_MPS = 0.1
"""Slower closing than this is no collision course (TTC None)."""


def wrap_rad(angle_rad: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    a = math.fmod(angle_rad + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


def support_m(length_m: float, width_m: float, yaw_rad: float, dir_rad: float) -> float:
    """Half extent of a ``length x width`` box of heading ``yaw_rad`` along ``dir_rad``."""
    th = dir_rad - yaw_rad
    return 0.5 * length_m * abs(math.cos(th)) + 0.5 * width_m * abs(math.sin(th))


@dataclass(frozen=True)
class Closeness:
    """Ego-to-agent closeness at one instant (no map)."""

    distance_m: float
    """Centre to centre."""
    gap_m: float
    """Approximate box-to-box gap (>= 0)."""
    closing_speed_mps: float
    """Rate at which the centre distance shrinks (negative: moving apart)."""
    ttc_s: Optional[float]
    """Time to collision when on a collision course (constant velocities), else None."""


def closeness(ego: EgoState, agent: Agent) -> Closeness:
    """Gap, closing speed and TTC of ``agent`` seen from ``ego`` (see the module doc)."""
    p = np.array([agent.x_m - ego.x_m, agent.y_m - ego.y_m])
    dist = float(np.hypot(*p))
    ve = np.array([ego.v_mps * math.cos(ego.yaw_rad), ego.v_mps * math.sin(ego.yaw_rad)])
    va = np.array([agent.v_mps * math.cos(agent.yaw_rad), agent.v_mps * math.sin(agent.yaw_rad)])
    vrel = va - ve
    los = math.atan2(p[1], p[0]) if dist > 1e-9 else ego.yaw_rad
    gap = max(0.0, dist - support_m(ego.length_m, ego.width_m, ego.yaw_rad, los)
              - support_m(agent.length_m, agent.width_m, agent.yaw_rad, los))
    closing = float(-(p @ vrel) / dist) if dist > 1e-9 else 0.0
    ttc = None
    vv = float(vrel @ vrel)
    if closing > MIN_CLOSING_MPS and vv > 1e-9:
        t_star = float(-(p @ vrel) / vv)
        miss = float(np.hypot(*(p + vrel * t_star)))
        crossing = abs(math.sin(wrap_rad(agent.yaw_rad - ego.yaw_rad)))
        radius = (0.5 * (ego.width_m + agent.width_m) + MISS_MARGIN_M
                  + 0.5 * crossing * max(0.0, ego.length_m + agent.length_m
                                         - ego.width_m - agent.width_m))
        if miss < radius:
            ttc = gap / closing
    return Closeness(distance_m=dist, gap_m=gap, closing_speed_mps=closing, ttc_s=ttc)


class _Near(Protocol):
    @property
    def distance_m(self) -> float: ...

    @property
    def gap_m(self) -> float: ...

    @property
    def closing_speed_mps(self) -> float: ...


def must_attend(c: _Near, *, ego_v_mps: float, agent_v_mps: float, ttc_s: float,
                dist_m: float, reach_s: float) -> bool:
    """The safety floor's test (planner and MPC): an agent is attended whatever a
    decision says when it is closer (centre to centre) than ``dist_m`` plus what both
    can drive in ``reach_s`` (``reach_s`` = the MPC's horizon: such an agent can reach
    the ego's planned footprint within the horizon), or when it closes in so fast that
    the gap would be gone within ``ttc_s`` (gap / closing speed: the range-rate TTC,
    *without* the collision-course test of ``Closeness.ttc_s``).

    Deliberately a superset of "on a collision course": an oncoming car the ego will
    turn across is not on a constant-heading collision course until the ego turns
    (usi seed 17 with the local model: attended too late, the ego braked inside the
    junction and was hit), and a car keeping pace in the lane the ego merges into
    never closes in (lane: a planner attending nobody merged into such cars). Agents
    farther out cannot touch the MPC's plan within its horizon, so leaving them out is
    what attention can still decide."""
    closing = c.closing_speed_mps
    if c.distance_m < dist_m + reach_s * (max(ego_v_mps, 0.0) + max(agent_v_mps, 0.0)):
        return True
    return closing > MIN_CLOSING_MPS and c.gap_m < ttc_s * closing
