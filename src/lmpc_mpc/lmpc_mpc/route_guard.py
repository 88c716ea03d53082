"""Does a decision's reference curve leave the ego's route? (the MPC's route guard)

The planner picks one of up to three candidates (0-2). Near a junction they are the
outgoing connections of the ego's *current* lane; when the route needs another lane
(a lane change on a short edge before the junction), none of them may follow the route,
and a weak decision maker can pick one that turns onto a road the route does not take.
The MPC then tracks the route reference instead (``MpcController``), counts it and says
so; the decision's speed guidance, weights and attention still apply.

The route **corridor** is every lane the map holds of the route's edges (parallel lanes
too: a lane change stays on the route), the route's own junction lanes, and the junction
lanes of every connection from a route edge to a route edge (changing lanes inside the
junction, as the baseline does, is on the route). A curve **leaves the route** when a
point of it is more than ``ROUTE_LEAVE_M`` from every centreline of the corridor while the
route still goes on there (points past the end of the route polyline, beyond the target,
do not count: there the route does not continue elsewhere). 3 m: a lane is ~3.2 m wide,
so a curve between two corridor lanes is at most ~1.6 m from one of them, and a Bezier
cuts a turn by under 1 m (``reference.CURVATURE_DENSITY_M``); a wrong turn or going
straight where the route turns is farther than 3 m within a few metres into the junction.

Plain Python + numpy (no ROS), cached per map snapshot.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lmpc_msgs_py.messages import MapSnapshot
from lmpc_mpc.reference import route_path

ROUTE_LEAVE_M = 3.0
"""A curve point farther than this from every corridor lane has left the route."""
ROUTE_END_SLACK_M = 1.0
"""Points projecting within this of the route polyline's end (or beyond) are not tested."""
_INTERNAL_DEPTH = 4


@dataclass(frozen=True)
class _Corridor:
    a: np.ndarray
    d: np.ndarray
    len2: np.ndarray
    lane_ids: frozenset[str]

    def distances_m(self, pts: np.ndarray) -> np.ndarray:
        """Distance of each of the (M, 2) points to the nearest corridor centreline."""
        px = pts[:, 0, None] - self.a[None, :, 0]
        py = pts[:, 1, None] - self.a[None, :, 1]
        t = np.clip((px * self.d[None, :, 0] + py * self.d[None, :, 1]) / self.len2, 0.0, 1.0)
        ex = px - t * self.d[None, :, 0]
        ey = py - t * self.d[None, :, 1]
        return np.sqrt(np.min(ex * ex + ey * ey, axis=1))


_CACHE: "OrderedDict[tuple[int, int, float], tuple[MapSnapshot, Optional[_Corridor]]]" = \
    OrderedDict()


def route_corridor_lanes(map_: MapSnapshot) -> frozenset[str]:
    """Ids of the corridor's lanes (see the module docstring)."""
    c = _corridor(map_)
    return frozenset() if c is None else c.lane_ids


def _corridor(map_: MapSnapshot) -> Optional[_Corridor]:
    key = (id(map_), map_.version, map_.stamp_s)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is map_:
        return hit[1]
    lanes = {ln.id: ln for ln in map_.lanes}
    route_edges = {lanes[lid].edge_id for lid in map_.ego_route
                   if lid in lanes and not lanes[lid].internal}
    ids = {lid for lid in map_.ego_route if lid in lanes}
    ids |= {ln.id for ln in map_.lanes if not ln.internal and ln.edge_id in route_edges}
    for lid in list(ids):
        lane = lanes[lid]
        if lane.internal:
            continue
        for lk in lane.successors:
            to = lanes.get(lk.to_lane)
            if to is None or to.edge_id not in route_edges or not lk.via_lane:
                continue
            # the connection's junction lanes (split in several at an internal junction)
            chain, depth = lk.via_lane, 0
            while chain in lanes and lanes[chain].internal and depth < _INTERNAL_DEPTH:
                ids.add(chain)
                nxt = [s.to_lane for s in lanes[chain].successors
                       if s.to_lane in lanes and lanes[s.to_lane].internal]
                chain, depth = (nxt[0] if nxt else ""), depth + 1
    corridor: Optional[_Corridor] = None
    if ids:
        starts, ends = [], []
        for lid in sorted(ids):
            pts = np.asarray(lanes[lid].centerline, dtype=float).reshape(-1, 2)
            if len(pts) == 1:
                pts = np.vstack([pts, pts])
            starts.append(pts[:-1])
            ends.append(pts[1:])
        a = np.concatenate(starts)
        d = np.concatenate(ends) - a
        corridor = _Corridor(a, d, np.maximum(np.einsum("ij,ij->i", d, d), 1e-12),
                             frozenset(ids))
    _CACHE[key] = (map_, corridor)  # holding the map keeps id() unique while cached
    while len(_CACHE) > 4:
        _CACHE.popitem(last=False)
    return corridor


@dataclass(frozen=True)
class RouteLeave:
    """Where a curve leaves the route: its point and distance from the corridor."""

    x_m: float
    y_m: float
    dist_m: float
    along_m: float
    """Arc length along the curve to that point."""


def leaves_route(map_: MapSnapshot, points: np.ndarray) -> Optional[RouteLeave]:
    """The first point of the (M, 2) curve ``points`` off the route corridor while the
    route goes on, or None (also None without a route in the map)."""
    corridor = _corridor(map_)
    route = route_path(map_)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if corridor is None or route is None or len(pts) == 0:
        return None
    dist = corridor.distances_m(pts)
    off = np.nonzero(dist > ROUTE_LEAVE_M)[0]
    if len(off) == 0:
        return None
    s_route, _ = route.line.project_many(pts[off])
    goes_on = s_route < route.line.length_m - ROUTE_END_SLACK_M
    if not np.any(goes_on):
        return None
    i = int(off[int(np.argmax(goes_on))])
    along = float(np.sum(np.hypot(*np.diff(pts[: i + 1], axis=0).T))) if i > 0 else 0.0
    return RouteLeave(float(pts[i, 0]), float(pts[i, 1]), float(dist[i]), along)
