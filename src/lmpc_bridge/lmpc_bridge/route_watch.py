"""Is the ego still on its route? The bridge's off-route check (outcome ``off_route``).

The ego's route is the scene's edge list. A lane counts as **on the route** when it is

- any lane of a route edge (the parallel lanes too: a lane change is not leaving), or
- a lane inside a junction the route passes through (internal, crossing or walking-area
  lanes of the to-node of every route edge but the last): inside a junction SUMO's
  ``moveToXY(keepRoute=2)`` may name any connection's lane, and changing lanes inside
  the junction (as the baseline MPC does on a short edge) takes a connection the
  route's lane sequence does not list.

The ego is **off its route** when SUMO places it on a lane that is not on the route
*and* its centre is more than ``OFF_ROUTE_DIST_M`` from the centreline of every lane on
the route. The distance is the tolerance: a car that cuts a corner, or that SUMO maps
onto a cross street's lane at a junction's edge, stays within a few metres of its route;
one that took a wrong turn is 5 m clear of its route after ~5-16 m on the wrong road
(5 m straight out of a junction, ~16 m on an 18 degree fork). No time grace beyond that:
the distance already is one. A lane SUMO cannot name (None), or a lane on the route, counts
as on the route up to ``OFF_NETWORK_M`` from every lane of it: beyond, the ego is off its
route whatever lane SUMO names (SUMO keeps naming the last lane of a car moved off the
network: rab 10089 "drive aggressively", a training seed, left the ring off its exit arm
and drove on beyond the network for 165 s on the route's junction lane ``:R1_2_0``).

Plain Python + numpy: no SUMO call here (the bridge passes the lane SUMO reported).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

OFF_ROUTE_DIST_M = 5.0
"""Centre distance to every lane on the route beyond which a non-route lane is off-route."""
OFF_NETWORK_M = 15.0
"""Centre distance to every lane on the route beyond which the ego is off-route whatever
lane SUMO names (three lane widths past the tolerance: no cut corner gets there)."""


@dataclass(frozen=True)
class OffRoute:
    """The ego left its route: the lane SUMO put it on and how far it is from the route."""

    lane_id: str
    dist_m: float
    limit_m: float = OFF_ROUTE_DIST_M
    """The tolerance it passed (``OFF_NETWORK_M`` when SUMO still names a route lane)."""

    def detail(self) -> str:
        return (f"left its route: on lane {self.lane_id!r}, {self.dist_m:.1f} m from the "
                f"nearest lane of its route (tolerance {self.limit_m:.0f} m)")


class RouteWatch:
    """The set of lanes on the ego's route and their centrelines (built once per scene)."""

    def __init__(self, *, route_lanes: set[str], shapes: Sequence[Sequence[tuple[float, float]]]
                 ) -> None:
        self._lanes = frozenset(route_lanes)
        starts, ends = [], []
        for shape in shapes:
            pts = np.asarray(shape, dtype=float).reshape(-1, 2)
            if len(pts) == 1:
                pts = np.vstack([pts, pts])
            starts.append(pts[:-1])
            ends.append(pts[1:])
        self._a = np.concatenate(starts) if starts else np.zeros((0, 2))
        self._d = (np.concatenate(ends) if ends else np.zeros((0, 2))) - self._a
        self._len2 = np.maximum(np.einsum("ij,ij->i", self._d, self._d), 1e-12)

    @classmethod
    def of_net(cls, net: Any, route_edges: Sequence[str]) -> "RouteWatch":
        """From a parsed net (``lmpc_bridge.mapping.read_net`` or sumolib) and the route."""
        edges = set(route_edges)
        junctions = set()
        for e in route_edges[:-1]:
            node = net.getEdge(e).getToNode()
            if node is not None:
                junctions.add(node.getID())
        lanes: set[str] = set()
        shapes = []
        for edge in net.getEdges(withInternal=True):
            fn = edge.getFunction()
            on = edge.getID() in edges if fn == "" else (
                edge.getFromNode() is not None and edge.getFromNode().getID() in junctions)
            if not on:
                continue
            for lane in edge.getLanes():
                lanes.add(lane.getID())
                shapes.append(lane.getShape())
        return cls(route_lanes=lanes, shapes=shapes)

    def on_route_lane(self, lane_id: Optional[str]) -> bool:
        """True for a lane on the route, and for None (SUMO named no lane)."""
        return lane_id is None or lane_id in self._lanes

    def distance_m(self, x_m: float, y_m: float) -> float:
        """Distance from (x, y) to the nearest centreline of a lane on the route."""
        if len(self._a) == 0:
            return float("inf")
        px = x_m - self._a[:, 0]
        py = y_m - self._a[:, 1]
        t = np.clip((px * self._d[:, 0] + py * self._d[:, 1]) / self._len2, 0.0, 1.0)
        ex = px - t * self._d[:, 0]
        ey = py - t * self._d[:, 1]
        return float(np.sqrt(np.min(ex * ex + ey * ey)))

    def check(self, lane_id: Optional[str], x_m: float, y_m: float) -> Optional[OffRoute]:
        """``OffRoute`` when the ego at (x, y) on ``lane_id`` has left its route, else None."""
        dist = self.distance_m(x_m, y_m)
        limit = OFF_NETWORK_M if self.on_route_lane(lane_id) else OFF_ROUTE_DIST_M
        if dist <= limit:
            return None
        return OffRoute(lane_id=str(lane_id), dist_m=dist, limit_m=limit)
