"""The ego's next manoeuvre along its route, read from the map (no SUMO intent).

Plain Python. The conflict geometry is an APPROXIMATION: the ego's path through
the junction is the polyline of the route's internal (junction) lanes; an agent's
path is a straight ray along its heading.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from lmpc_mpc.reference import route_path, route_progress
from lmpc_msgs_py.messages import Lane, LaneLink, StopLine
from lmpc_msgs_py.observation import Observation

MAX_SEARCH_LANES = 12


@dataclass(frozen=True)
class Maneuver:
    """The first junction connection ahead on the ego's route."""

    approach_lane_id: str
    """The normal lane that ends at the junction."""
    link: LaneLink
    """Its connection the route takes (``direction`` tells the manoeuvre)."""
    path: np.ndarray
    """(n, 2) centerline through the junction (the route's internal lanes), may be empty."""
    dist_to_stop_line_m: float
    """Along the route from the ego's centre to the stop line; negative once past it."""
    inside_junction: bool
    stop_line: Optional[StopLine]
    approach_yaw_rad: float
    """Heading of the approach lane where it meets the junction."""

    @property
    def direction(self) -> str:
        return self.link.direction


def _link_to(lane: Lane, nxt: str) -> Optional[LaneLink]:
    for lk in lane.successors:
        if lk.via_lane == nxt or lk.to_lane == nxt:
            return lk
    return None


def _end_yaw(lane: Lane) -> float:
    (x0, y0), (x1, y1) = lane.centerline[-2], lane.centerline[-1]
    return math.atan2(y1 - y0, x1 - x0)


def next_maneuver(
    obs: Observation, lanes: Mapping[str, Lane], *, max_distance_m: float = 200.0
) -> Optional[Maneuver]:
    """The first junction connection on the route ahead of the ego, or None.

    The ego is placed on its route by projection onto the route polyline
    (``lmpc_mpc.reference.route_progress``: every route lane, internal ones included,
    searched from the bridge's monotone ``route_index``), not by SUMO's lane guess,
    which inside a junction may name another connection's internal lane. Returns
    None when the map has no route or no connection lies within ``max_distance_m``.
    """
    route = route_path(obs.map)
    if route is None:
        return None
    s_ego = route_progress(obs.map, obs.ego)
    if s_ego is None:
        return None
    ids = route.lane_ids
    j = route.lane_at(s_ego)
    here = lanes.get(ids[j])
    if here is None:
        return None
    inside = here.internal
    start = j
    # walk back to the approach lane when already inside the junction
    while start > 0 and (lanes.get(ids[start]) is None or lanes[ids[start]].internal):
        start -= 1
    for k in range(start, min(len(ids) - 1, start + MAX_SEARCH_LANES)):
        lane = lanes.get(ids[k])
        if lane is None or lane.internal:
            continue
        link = _link_to(lane, ids[k + 1])
        if link is None:
            continue
        stop_s = float(route.lane_start_m[k + 1])
        dist = stop_s - s_ego
        if dist > max_distance_m:
            return None
        pts: list[tuple[float, float]] = []
        m = k + 1
        while m < len(ids) and ids[m] in lanes and lanes[ids[m]].internal:
            pts.extend(lanes[ids[m]].centerline)
            m += 1
        if m < len(ids) and s_ego > float(route.lane_start_m[m]) and k >= start:
            continue  # this junction is behind the ego already
        stop = next((sl for sl in obs.map.stop_lines if sl.lane_id == lane.id), None)
        return Maneuver(
            approach_lane_id=lane.id,
            link=link,
            path=np.asarray(pts, dtype=float).reshape(-1, 2),
            dist_to_stop_line_m=dist,
            inside_junction=inside or dist < 0.0,
            stop_line=stop,
            approach_yaw_rad=_end_yaw(lane),
        )
    return None


def _progress_on(path: np.ndarray, x_m: float, y_m: float) -> float:
    """Arc length along ``path`` of the point nearest to (x, y) (vertex approximation)."""
    if len(path) == 0:
        return 0.0
    d = np.hypot(path[:, 0] - x_m, path[:, 1] - y_m)
    k = int(np.argmin(d))
    seg = np.hypot(*np.diff(path[: k + 1], axis=0).T) if k > 0 else np.zeros(0)
    return float(np.sum(seg))


def arc_lengths(path: np.ndarray) -> np.ndarray:
    """Cumulative arc length at each vertex of ``path`` (starts at 0)."""
    if len(path) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])


@dataclass(frozen=True)
class Crossing:
    """Where an agent's straight path crosses the ego's junction path."""

    ego_s_m: float
    """Arc length along the junction path (from the stop line) to the crossing."""
    agent_along_m: float
    """Distance from the agent's centre along its heading to the crossing (<0: passed)."""
    miss_m: float
    """Lateral distance of the crossing point from the agent's ray."""


def crossing(path: np.ndarray, *, x_m: float, y_m: float, yaw_rad: float) -> Optional[Crossing]:
    """The vertex of ``path`` nearest to the agent's heading ray (dense paths work best)."""
    if len(path) < 2:
        return None
    dense = _densify(path, step_m=0.5)
    s = arc_lengths(dense)
    h = np.array([math.cos(yaw_rad), math.sin(yaw_rad)])
    rel = dense - np.array([x_m, y_m])
    along = rel @ h
    lateral = np.abs(rel[:, 0] * h[1] - rel[:, 1] * h[0])
    k = int(np.argmin(lateral))
    return Crossing(ego_s_m=float(s[k]), agent_along_m=float(along[k]), miss_m=float(lateral[k]))


def _densify(path: np.ndarray, *, step_m: float) -> np.ndarray:
    out = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(math.ceil(float(np.hypot(*(b - a))) / step_m)))
        for f in np.arange(1, n + 1) / n:
            out.append(a + f * (b - a))
    return np.asarray(out)
