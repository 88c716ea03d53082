"""Static map of a scene as a ``MapSnapshot`` (lanes, links, stop lines, ego route, target).

Read once per scene from the SUMO network file with ``sumolib`` (plain file
parsing, no running simulation). Also provides :class:`RouteGeometry`, the ego
route as lanes with lengths, for route progress and distance to the target.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from lmpc_msgs_py.messages import Lane, LaneLink, MapSnapshot, StopLine, TargetArea

from lmpc_bridge.scenarios.base import Scene, SceneError

_DIRECTIONS = {"s", "l", "r", "t", "L", "R"}
MAP_RADIUS_M = 300.0
"""Lanes with any centerline point within this distance of the ego route are in the map."""


@dataclass(frozen=True)
class RouteGeometry:
    """The ego route as a lane sequence (internal junction lanes included) with lengths."""

    lane_ids: tuple[str, ...]
    lengths_m: tuple[float, ...]
    target_pos_m: float
    """Target position along the last lane."""

    def index_of(self, lane_id: str | None, *, previous_index: int) -> int:
        """Route index of ``lane_id``; off-route lanes keep the previous index (monotonic)."""
        if lane_id:
            for i in range(previous_index, len(self.lane_ids)):
                if self.lane_ids[i] == lane_id:
                    return i
            edge = lane_id.rsplit("_", 1)[0]
            for i in range(previous_index, len(self.lane_ids)):
                if self.lane_ids[i].rsplit("_", 1)[0] == edge:
                    return i  # a parallel lane of the same edge: same progress
        return previous_index

    def dist_to_target_m(self, route_index: int, lane_pos_m: float) -> float:
        """Distance along the route from ``lane_pos_m`` on lane ``route_index`` to the target."""
        last = len(self.lane_ids) - 1
        if route_index >= last:
            return max(self.target_pos_m - lane_pos_m, 0.0)
        remaining = max(self.lengths_m[route_index] - lane_pos_m, 0.0)
        remaining += sum(self.lengths_m[route_index + 1:last])
        return remaining + self.target_pos_m


def _read_net(net_file: str) -> Any:
    import sumolib

    return sumolib.net.readNet(net_file, withInternal=True)


def _allows_ego(lane: Any) -> bool:
    return bool(lane.allows("passenger"))


def _route_lanes(net: Any, scene: Scene) -> list[str]:
    """The ego route as lanes: on every route edge the lane the ego should be on.

    Generic (any junction shape, any number of lanes): working backwards from the
    target lanes, keep on each route edge the lanes (open to passenger cars) that
    connect to a kept lane of the next edge. The first lane is the ego's depart
    lane if it can reach the target, else the nearest (by index) lane that can:
    the difference is a lane change the ego has to make on the first edge
    (``lane`` / ``construction`` families). Then walk forward, preferring the
    connection that keeps the lane index, following internal lanes.
    """
    edges = scene.ego_route_edges
    targets = {lid for lid in scene.target.lane_ids if net.getLane(lid).getEdge().getID()
               == edges[-1]}
    if not targets:
        targets = {lane.getID() for lane in net.getEdge(edges[-1]).getLanes() if _allows_ego(lane)}
    good: list[set[str]] = [set() for _ in edges]
    good[-1] = targets
    for i in range(len(edges) - 2, -1, -1):
        good[i] = {lane.getID() for lane in net.getEdge(edges[i]).getLanes()
                   if _allows_ego(lane) and any(c.getToLane().getID() in good[i + 1]
                                                for c in lane.getOutgoing())}
        if not good[i]:
            raise SceneError(f"route of scene {scene.family}/{scene.seed}: no lane of edge "
                             f"{edges[i]} leads to the target lanes {sorted(targets)}")
    first_lanes = net.getEdge(edges[0]).getLanes()
    depart = first_lanes[scene.ego_depart_lane]
    if depart.getID() in good[0]:
        lane = depart
    else:
        lane = min((ln for ln in first_lanes if ln.getID() in good[0]),
                   key=lambda ln: abs(ln.getIndex() - depart.getIndex()))
    lanes = [lane.getID()]
    for i, next_edge in enumerate(edges[1:], start=1):
        conns = [c for c in lane.getOutgoing() if c.getToLane().getID() in good[i]]
        if not conns:
            raise SceneError(f"route of scene {scene.family}/{scene.seed}: lane {lane.getID()} "
                             f"has no connection to edge {next_edge}")
        conn = min(conns, key=lambda c: (abs(c.getToLane().getIndex() - lane.getIndex()),
                                         c.getToLane().getIndex()))
        via = conn.getViaLaneID()
        while via:  # follow the chain of internal lanes (split at internal junctions)
            lanes.append(via)
            inner = [c for c in net.getLane(via).getOutgoing()
                     if c.getToLane().getID() == conn.getToLane().getID()]
            via = inner[0].getViaLaneID() if inner else ""
        lane = conn.getToLane()
        lanes.append(lane.getID())
    return lanes


def _link(conn: Any) -> LaneLink:
    tls = conn.getTLSID() or None
    index = conn.getTLLinkIndex()
    direction = conn.getDirection()
    return LaneLink(
        to_lane=conn.getToLane().getID(),
        via_lane=conn.getViaLaneID() or None,
        direction=direction if direction in _DIRECTIONS else "invalid",
        signalized=tls is not None,
        tls_id=tls,
        link_index=index if (tls is not None and index >= 0) else None,
    )


@dataclass(frozen=True)
class LaneAttributes:
    """Per-lane facts from the net file, copied into the ``Lane`` message.

    Generic (from the net file only): neighbours are the lanes of the same edge
    with index +-1 (SUMO: higher index = further left) that share a vehicle class
    with this lane; ``roundabout`` is true for the lanes of edges that netconvert
    put in a ``<roundabout>`` and for the internal lanes inside its nodes.
    """

    lane_id: str
    allowed_classes: tuple[str, ...]
    left_neighbour: str | None
    right_neighbour: str | None
    roundabout: bool

    @property
    def drivable(self) -> bool:
        """Open to passenger cars (False for sidewalks, bike lanes, closed lanes)."""
        return "passenger" in self.allowed_classes


_VCLASSES = ("passenger", "truck", "bus", "bicycle", "pedestrian", "motorcycle", "custom1")


def lane_attributes(scene: Scene) -> dict[str, LaneAttributes]:
    """Permissions, neighbours and roundabout membership of every lane of the scene's net."""
    net = _read_net(str(scene.net_file))
    ring_edges: set[str] = set()
    ring_nodes: set[str] = set()
    for rb in net.getRoundabouts():
        ring_edges.update(rb.getEdges())
        ring_nodes.update(rb.getNodes())
    out: dict[str, LaneAttributes] = {}
    for edge in net.getEdges(withInternal=True):
        lanes = edge.getLanes()
        internal = edge.getFunction() != ""
        in_ring = edge.getID() in ring_edges or (
            internal and edge.getID()[1:].rsplit("_", 1)[0] in ring_nodes)
        for lane in lanes:
            allowed = tuple(c for c in _VCLASSES if lane.allows(c))

            def neighbour(offset: int, lane: Any = lane, allowed: tuple = allowed) -> str | None:
                j = lane.getIndex() + offset
                if not 0 <= j < len(lanes):
                    return None
                other = lanes[j]
                return other.getID() if any(other.allows(c) for c in allowed) else None

            out[lane.getID()] = LaneAttributes(
                lane_id=lane.getID(), allowed_classes=allowed, left_neighbour=neighbour(1),
                right_neighbour=neighbour(-1), roundabout=in_ring)
    return out


def build_map(scene: Scene, *, map_radius_m: float = MAP_RADIUS_M,
              stamp_s: float = 0.0) -> tuple[MapSnapshot, RouteGeometry]:
    """Build the scene's ``MapSnapshot`` and the ego's ``RouteGeometry`` from its net file."""
    net = _read_net(str(scene.net_file))
    route = _route_lanes(net, scene)
    route_pts = [p for lane_id in route for p in net.getLane(lane_id).getShape()]

    def near_route(shape: list[tuple[float, float]]) -> bool:
        return any(math.hypot(p[0] - q[0], p[1] - q[1]) <= map_radius_m
                   for p in shape for q in route_pts[:: max(len(route_pts) // 50, 1)])

    attributes = lane_attributes(scene)
    lanes: list[Lane] = []
    stop_lines: list[StopLine] = []
    for edge in net.getEdges(withInternal=True):
        # crossings and walking areas lie inside the junction as well
        internal = edge.getFunction() in ("internal", "crossing", "walkingarea")
        for lane in edge.getLanes():
            shape = [(float(x), float(y)) for x, y in lane.getShape()]
            if lane.getID() not in route and not near_route(shape):
                continue
            outgoing = lane.getOutgoing()
            lanes.append(Lane(
                id=lane.getID(), edge_id=edge.getID(), index=lane.getIndex(),
                centerline=tuple(shape), width_m=float(lane.getWidth()),
                speed_limit_mps=float(lane.getSpeed()), length_m=float(lane.getLength()),
                internal=internal, successors=tuple(_link(c) for c in outgoing),
                allowed=attributes[lane.getID()].allowed_classes,
                left_lane=attributes[lane.getID()].left_neighbour,
                right_lane=attributes[lane.getID()].right_neighbour,
                roundabout=attributes[lane.getID()].roundabout,
            ))
            to_node = edge.getToNode()
            if (not internal and outgoing and to_node is not None
                    and to_node.getType() not in ("dead_end",)):
                stop_lines.append(StopLine(
                    lane_id=lane.getID(), position=shape[-1], junction_id=to_node.getID(),
                    signalized=any(c.getTLSID() for c in outgoing)))
    lengths = tuple(float(net.getLane(lane_id).getLength()) for lane_id in route)
    geometry = RouteGeometry(lane_ids=tuple(route), lengths_m=lengths,
                             target_pos_m=scene.target.lane_pos_m)
    snapshot = MapSnapshot(
        stamp_s=stamp_s, lanes=tuple(lanes), stop_lines=tuple(stop_lines),
        ego_route=tuple(route),
        target=TargetArea(lane_ids=scene.target.lane_ids, center=scene.target.center,
                          radius_m=scene.target.radius_m),
    )
    return snapshot, geometry
