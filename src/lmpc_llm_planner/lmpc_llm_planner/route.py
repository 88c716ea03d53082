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

    Uses ``ego.lane_id`` / ``ego.route_index`` to find the ego on
    ``map.ego_route``; returns None when the ego is not on its route or no
    connection lies within ``max_distance_m``.
    """
    route = obs.map.ego_route
    ego = obs.ego
    if ego.lane_id is None:
        return None
    i = ego.route_index if ego.route_index < len(route) else -1
    if i < 0 or route[i] != ego.lane_id:
        if ego.lane_id not in route:
            return None
        i = route.index(ego.lane_id)
    here = lanes.get(route[i])
    if here is None:
        return None
    inside = here.internal
    # Walk back to the approach lane when already inside the junction.
    start = i
    while start > 0 and lanes.get(route[start], here).internal:
        start -= 1
    dist = 0.0 if inside else here.length_m - ego.lane_pos_m
    j = start
    for _ in range(MAX_SEARCH_LANES):
        lane = lanes.get(route[j])
        if lane is None or j + 1 >= len(route):
            return None
        link = _link_to(lane, route[j + 1])
        if link is not None and not lane.internal:
            pts = []
            k = j + 1
            while k < len(route) and route[k] in lanes and lanes[route[k]].internal:
                pts.extend(lanes[route[k]].centerline)
                k += 1
            stop = next((s for s in obs.map.stop_lines if s.lane_id == lane.id), None)
            if inside:
                dist = -_progress_on(np.asarray(pts, dtype=float), ego.x_m, ego.y_m)
            return Maneuver(
                approach_lane_id=lane.id,
                link=link,
                path=np.asarray(pts, dtype=float).reshape(-1, 2),
                dist_to_stop_line_m=dist,
                inside_junction=inside,
                stop_line=stop,
                approach_yaw_rad=_end_yaw(lane),
            )
        if j > start or inside:
            dist += lane.length_m
        if dist > max_distance_m:
            return None
        j += 1
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
