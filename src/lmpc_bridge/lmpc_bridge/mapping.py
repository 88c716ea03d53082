"""Static map of a scene as a ``MapSnapshot`` (lanes, links, stop lines, ego route, target).

Read once per scene from the SUMO network file (plain file parsing, no running
simulation) with :func:`read_net`, a fast reader of the subset of ``sumolib``'s
net API that the map needs (sumolib itself takes ~4 s on a 3,000-edge city;
this reader ~1 s). Also provides :class:`RouteGeometry`, the ego route as lanes
with lengths, for route progress and distance to the target.

Nothing here assumes a template: any number of lanes, any junction shape or
type, internal lanes, crossings / walking areas, roundabouts, left-hand nets.
On big networks the map is clipped to lanes near the ego route so that the
encoded ``MapSnapshot`` stays within the codec's payload limit.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from lmpc_msgs_py.codec import MAX_PAYLOAD_BYTES, encode
from lmpc_msgs_py.messages import (
    MAX_LIST_LEN,
    Lane,
    LaneLink,
    MapSnapshot,
    StopLine,
    TargetArea,
)

from lmpc_bridge.scenarios.base import Scene, SceneError

_DIRECTIONS = {"s", "l", "r", "t", "L", "R"}
MAP_RADIUS_M = 300.0
"""Lanes with any centerline point within this distance of the ego route are in the map."""
MAP_BUDGET_BYTES = int(MAX_PAYLOAD_BYTES * 0.85)
"""Encoded map size above which the radius is shrunk (headroom below the codec's limit)."""
_CLIP_RADII_M = (200.0, 150.0, 100.0, 75.0, 50.0, 30.0, 15.0)
"""Radii tried in turn, after ``map_radius_m``, when the map is too big."""
_ROUTE_SAMPLE_M = 10.0
"""Spacing of the route samples that the lane distances are measured to."""


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


# --- fast net reader ---------------------------------------------------------------------
class NetNode:
    """A junction of the net (sumolib-compatible subset: ``getID``, ``getType``)."""

    __slots__ = ("_id", "_type", "coord")

    def __init__(self, node_id: str, node_type: str | None,
                 coord: tuple[float, float] = (0.0, 0.0)) -> None:
        self._id, self._type, self.coord = node_id, node_type, coord

    def getID(self) -> str:  # noqa: N802 - sumolib's names, so either net object fits
        return self._id

    def getType(self) -> str | None:  # noqa: N802
        return self._type


class NetConnection:
    """A lane-to-lane link (sumolib-compatible subset)."""

    __slots__ = ("_from", "_to", "_via", "_tls", "_index", "_dir", "_state")

    def __init__(self, from_lane: "NetLane", to_lane: "NetLane", *, via: str, tls: str,
                 link_index: int, direction: str, state: str) -> None:
        self._from, self._to, self._via = from_lane, to_lane, via
        self._tls, self._index, self._dir, self._state = tls, link_index, direction, state

    def getFromLane(self) -> "NetLane":  # noqa: N802
        return self._from

    def getToLane(self) -> "NetLane":  # noqa: N802
        return self._to

    def getViaLaneID(self) -> str:  # noqa: N802
        return self._via

    def getTLSID(self) -> str:  # noqa: N802
        return self._tls

    def getTLLinkIndex(self) -> int:  # noqa: N802
        return self._index

    def getDirection(self) -> str:  # noqa: N802
        return self._dir

    def getState(self) -> str:  # noqa: N802
        """SUMO link state: ``M`` major, ``m`` minor, ``=`` all-way stop, ``s`` stop,
        ``w`` right-before-left / zipper peers, ``o`` traffic light off..."""
        return self._state


class NetLane:
    """A lane (sumolib-compatible subset)."""

    __slots__ = ("_edge", "_index", "_id", "_speed", "_length", "_width", "_allowed",
                 "_shape", "_outgoing")

    def __init__(self, edge: "NetEdge", index: int, *, speed: float, length: float,
                 width: float, allowed: frozenset[str],
                 shape: list[tuple[float, float]]) -> None:
        self._edge, self._index = edge, index
        self._id = f"{edge.getID()}_{index}"
        self._speed, self._length, self._width = speed, length, width
        self._allowed, self._shape = allowed, shape
        self._outgoing: list[NetConnection] = []

    def getID(self) -> str:  # noqa: N802
        return self._id

    def getIndex(self) -> int:  # noqa: N802
        return self._index

    def getEdge(self) -> "NetEdge":  # noqa: N802
        return self._edge

    def getShape(self) -> list[tuple[float, float]]:  # noqa: N802
        return self._shape

    def getSpeed(self) -> float:  # noqa: N802
        return self._speed

    def getLength(self) -> float:  # noqa: N802
        return self._length

    def getWidth(self) -> float:  # noqa: N802
        return self._width

    def getOutgoing(self) -> list[NetConnection]:  # noqa: N802
        return self._outgoing

    def allows(self, vclass: str) -> bool:
        return vclass in self._allowed


class NetEdge:
    """An edge (sumolib-compatible subset)."""

    __slots__ = ("_id", "_function", "_from", "_to", "_lanes")

    def __init__(self, edge_id: str, function: str, from_node: NetNode | None,
                 to_node: NetNode | None) -> None:
        self._id, self._function = edge_id, function
        self._from, self._to = from_node, to_node
        self._lanes: list[NetLane] = []

    def getID(self) -> str:  # noqa: N802
        return self._id

    def getFunction(self) -> str:  # noqa: N802
        return self._function

    def getLanes(self) -> list[NetLane]:  # noqa: N802
        return self._lanes

    def getFromNode(self) -> NetNode | None:  # noqa: N802
        return self._from

    def getToNode(self) -> NetNode | None:  # noqa: N802
        return self._to

    def getLength(self) -> float:  # noqa: N802
        return self._lanes[0].getLength() if self._lanes else 0.0


@dataclass(frozen=True)
class NetRoundabout:
    nodes: tuple[str, ...]
    edges: tuple[str, ...]

    def getNodes(self) -> tuple[str, ...]:  # noqa: N802
        return self.nodes

    def getEdges(self) -> tuple[str, ...]:  # noqa: N802
        return self.edges


class NetFile:
    """A parsed ``.net.xml``: the subset of ``sumolib.net.Net`` the bridge uses.

    Same content as ``sumolib.net.readNet(path, withInternal=True)`` for these
    calls (checked by ``test_bridge_external_net``): internal, crossing and
    walking-area edges and their connections are in, macro connectors are out.
    """

    def __init__(self) -> None:
        self.edges: dict[str, NetEdge] = {}
        self.lanes: dict[str, NetLane] = {}
        self.nodes: dict[str, NetNode] = {}
        self.roundabouts: list[NetRoundabout] = []
        self.lefthand = False

    def getEdge(self, edge_id: str) -> NetEdge:  # noqa: N802
        return self.edges[edge_id]

    def hasEdge(self, edge_id: str) -> bool:  # noqa: N802
        return edge_id in self.edges

    def getLane(self, lane_id: str) -> NetLane:  # noqa: N802
        return self.lanes[lane_id]

    def getNode(self, node_id: str) -> NetNode:  # noqa: N802
        return self.nodes[node_id]

    def getEdges(self, withInternal: bool = True) -> list[NetEdge]:  # noqa: N802, N803
        if withInternal:
            return list(self.edges.values())
        return [e for e in self.edges.values() if e.getFunction() == ""]

    def getRoundabouts(self) -> list[NetRoundabout]:  # noqa: N802
        return self.roundabouts


_PED_FUNCTIONS = ("crossing", "walkingarea")


def _allowed_classes(allow: str | None, disallow: str | None) -> frozenset[str]:
    from sumolib.net.lane import SUMO_VEHICLE_CLASSES  # same normalisation as sumolib

    if allow is None and disallow is None:
        return frozenset(SUMO_VEHICLE_CLASSES)
    if disallow is None:
        return frozenset((allow or "").split())
    if disallow == "all":
        return frozenset()
    return frozenset(SUMO_VEHICLE_CLASSES.difference(disallow.split()))


def _shape(text: str) -> list[tuple[float, float]]:
    out = []
    for point in text.split():
        parts = point.split(",")
        out.append((float(parts[0]), float(parts[1])))
    return out


def read_net(net_file: str | Path) -> NetFile:
    """Parse a SUMO ``.net.xml`` (SceneError naming the file and the reason on failure)."""
    net = NetFile()
    skipped: set[str] = set()  # edges sumolib leaves out (macro connectors)
    edge: NetEdge | None = None
    pending: list[dict[str, str]] = []
    try:
        for _, elem in ET.iterparse(str(net_file), events=("start",)):
            tag, a = elem.tag, elem.attrib
            if tag == "lane" and edge is not None:
                net_lane = NetLane(edge, len(edge._lanes), speed=float(a["speed"]),
                                   length=float(a["length"]),
                                   width=float(a.get("width", 3.2)),
                                   allowed=_allowed_classes(a.get("allow"), a.get("disallow")),
                                   shape=_shape(a.get("shape", "")))
                edge._lanes.append(net_lane)
                net.lanes[net_lane.getID()] = net_lane
            elif tag == "edge":
                function = a.get("function", "")
                edge_id = a["id"]
                if function not in ("", "internal", *_PED_FUNCTIONS):
                    skipped.add(edge_id)
                    edge = None
                    continue
                if function:
                    node_id = edge_id[1:edge_id.rfind("_")]
                    from_id = to_id = node_id
                else:
                    from_id, to_id = a["from"], a["to"]
                from_node = net.nodes.setdefault(from_id, NetNode(from_id, None))
                to_node = net.nodes.setdefault(to_id, NetNode(to_id, None))
                edge = NetEdge(edge_id, function, from_node, to_node)
                net.edges[edge_id] = edge
            elif tag == "junction":
                edge = None
                node_id = a["id"]
                if node_id.startswith(":"):
                    continue
                node = net.nodes.setdefault(node_id, NetNode(node_id, None))
                node._type = a.get("type")
                node.coord = (float(a.get("x", 0.0)), float(a.get("y", 0.0)))
            elif tag == "connection":
                edge = None
                pending.append(dict(a))
            elif tag == "roundabout":
                net.roundabouts.append(NetRoundabout(tuple(a.get("nodes", "").split()),
                                                     tuple(a.get("edges", "").split())))
            elif tag == "net":
                net.lefthand = a.get("lefthand", "false").lower() in ("true", "1")
            elif tag not in ("neigh", "param", "stopOffset"):
                edge = None
            elem.clear()
    except (ET.ParseError, OSError, KeyError, ValueError) as exc:
        raise SceneError(f"cannot read SUMO network {net_file}: {exc}") from None
    for a in pending:
        from_id, to_id = a["from"], a["to"]
        if from_id in skipped or to_id in skipped:
            continue
        try:
            from_lane = net.edges[from_id].getLanes()[int(a["fromLane"])]
            to_lane = net.edges[to_id].getLanes()[int(a["toLane"])]
        except (KeyError, IndexError, ValueError) as exc:
            raise SceneError(f"SUMO network {net_file}: connection {from_id} -> {to_id} "
                             f"names a missing lane ({exc})") from None
        tls = a.get("tl", "")
        from_lane._outgoing.append(NetConnection(
            from_lane, to_lane, via=a.get("via", ""), tls=tls,
            link_index=int(a["linkIndex"]) if tls else -1, direction=a.get("dir", ""),
            state=a.get("state", "")))
    if not net.edges:
        raise SceneError(f"SUMO network {net_file} has no edges (is it a .net.xml?)")
    return net


def _read_net(net_file: str) -> Any:
    return read_net(net_file)


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
            # No lane leads straight into a good lane: enter edge i+1 on any car lane and
            # change lanes on it (multi-lane city routes; templates never need this).
            entry = {lane.getID() for lane in net.getEdge(edges[i + 1]).getLanes()
                     if _allows_ego(lane)}
            good[i] = {lane.getID() for lane in net.getEdge(edges[i]).getLanes()
                       if _allows_ego(lane) and any(c.getToLane().getID() in entry
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
        if lane.getID() not in good[i - 1]:
            # change lanes on the previous edge to one that connects (lane family, cities)
            parallel = [ln for ln in lane.getEdge().getLanes() if ln.getID() in good[i - 1]]
            if parallel:
                lane = min(parallel, key=lambda ln: abs(ln.getIndex() - lane.getIndex()))
                lanes[-1] = lane.getID()
        conns = [c for c in lane.getOutgoing() if c.getToLane().getID() in good[i]]
        if not conns:
            conns = [c for c in lane.getOutgoing() if c.getToLane().getEdge().getID()
                     == next_edge and _allows_ego(c.getToLane())]
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


def _short(text: str, keep: int = 60) -> str:
    return repr(text) if len(text) <= keep else f"{text[:keep]!r}... ({len(text)} characters)"


def _refused(scene: Scene, what: str, exc: ValidationError) -> SceneError:
    """One line: which map element the message schema refused, which field, why."""
    err = exc.errors(include_url=False)[0]
    loc = ".".join(str(p) for p in err["loc"])
    value = err.get("input")
    shown = _short(value) if isinstance(value, str) else repr(value)[:60]
    return SceneError(f"the map of scene {scene.family}/{scene.seed} cannot be sent: {what}: "
                      f"field '{loc}' = {shown}: {err['msg']} (lmpc_msgs_py.messages limits)")


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


def lane_attributes(scene: Scene, *, net: Any = None) -> dict[str, LaneAttributes]:
    """Permissions, neighbours and roundabout membership of every lane of the scene's net.

    ``net``: the already parsed net (:func:`read_net` or sumolib), else it is read.
    """
    if net is None:
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


def _route_samples(net: Any, route: list[str]) -> np.ndarray:
    """Points along the route lanes at most ``_ROUTE_SAMPLE_M`` apart (N x 2)."""
    pts: list[tuple[float, float]] = []
    for lane_id in route:
        shape = net.getLane(lane_id).getShape()
        for (x0, y0), (x1, y1) in zip(shape, shape[1:]):
            n = max(int(math.ceil(math.hypot(x1 - x0, y1 - y0) / _ROUTE_SAMPLE_M)), 1)
            pts.extend((x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n) for k in range(n))
        pts.append(shape[-1])
    return np.asarray(pts, dtype=float)


def _lane_distances_m(lanes: list[Any], samples: np.ndarray, cutoff_m: float) -> np.ndarray:
    """Per lane: the smallest distance of one of its shape points to a route sample.

    Vectorised (numpy, chunked): lanes outside the route's bounding box grown by
    ``cutoff_m`` get ``inf`` without the pairwise computation.
    """
    counts = np.fromiter((len(ln.getShape()) for ln in lanes), dtype=np.int64, count=len(lanes))
    flat = np.fromiter((c for ln in lanes for p in ln.getShape() for c in p), dtype=float,
                       count=int(counts.sum()) * 2).reshape(-1, 2)
    owner = np.repeat(np.arange(len(lanes)), counts)
    lo = samples.min(axis=0) - cutoff_m
    hi = samples.max(axis=0) + cutoff_m
    inside = np.all((flat >= lo) & (flat <= hi), axis=1)
    point_d = np.full(len(flat), np.inf)
    idx = np.nonzero(inside)[0]
    chunk = max(1, 4_000_000 // max(len(samples), 1))
    for i in range(0, len(idx), chunk):
        sel = idx[i:i + chunk]
        diff = flat[sel, None, :] - samples[None, :, :]
        point_d[sel] = np.sqrt(np.min(np.einsum("ijk,ijk->ij", diff, diff), axis=1))
    out = np.full(len(lanes), np.inf)
    np.minimum.at(out, owner, point_d)
    return out


def build_map(scene: Scene, *, map_radius_m: float = MAP_RADIUS_M,
              stamp_s: float = 0.0, net: Any = None,
              max_bytes: int = MAP_BUDGET_BYTES) -> tuple[MapSnapshot, RouteGeometry]:
    """Build the scene's ``MapSnapshot`` and the ego's ``RouteGeometry`` from its net file.

    Lanes within ``map_radius_m`` of the route are in the map (the route's lanes
    always). When the encoded map would exceed ``max_bytes`` or the schema's
    lane limit (big networks), the radius shrinks step by step (200, 150, ...,
    15 m) until it fits; ``SceneError`` if even the route alone does not.
    ``net``: an already parsed net (:func:`read_net`), else the scene's file is read.
    """
    if net is None:
        net = _read_net(str(scene.net_file))
    route = _route_lanes(net, scene)
    route_set = set(route)
    all_lanes = [lane for edge in net.getEdges(withInternal=True) for lane in edge.getLanes()]
    dist = _lane_distances_m(all_lanes, _route_samples(net, route), map_radius_m)
    attributes = lane_attributes(scene, net=net)
    lengths = tuple(float(net.getLane(lane_id).getLength()) for lane_id in route)
    geometry = RouteGeometry(lane_ids=tuple(route), lengths_m=lengths,
                             target_pos_m=scene.target.lane_pos_m)
    built: dict[str, tuple[Lane, StopLine | None]] = {}

    def lane_entry(lane: Any) -> tuple[Lane, StopLine | None]:
        if lane.getID() in built:
            return built[lane.getID()]
        edge = lane.getEdge()
        # crossings and walking areas lie inside the junction as well
        internal = edge.getFunction() in ("internal", "crossing", "walkingarea")
        shape = [(float(x), float(y)) for x, y in lane.getShape()]
        outgoing = lane.getOutgoing()
        attr = attributes[lane.getID()]
        try:
            msg = Lane(
                id=lane.getID(), edge_id=edge.getID(), index=lane.getIndex(),
                centerline=tuple(shape), width_m=float(lane.getWidth()),
                speed_limit_mps=float(lane.getSpeed()), length_m=float(lane.getLength()),
                internal=internal, successors=tuple(_link(c) for c in outgoing),
                allowed=attr.allowed_classes, left_lane=attr.left_neighbour,
                right_lane=attr.right_neighbour, roundabout=attr.roundabout,
            )
            stop = None
            to_node = edge.getToNode()
            if (not internal and outgoing and to_node is not None
                    and to_node.getType() not in ("dead_end",)):
                stop = StopLine(lane_id=lane.getID(), position=shape[-1],
                                junction_id=to_node.getID(),
                                signalized=any(c.getTLSID() for c in outgoing))
        except ValidationError as exc:
            raise _refused(scene, f"lane {_short(lane.getID())}", exc) from None
        built[lane.getID()] = (msg, stop)
        return msg, stop

    left_hand = bool(getattr(net, "lefthand", False))
    radii = (map_radius_m, *(r for r in _CLIP_RADII_M if r < map_radius_m))
    for radius in radii:
        chosen = [ln for ln, d in zip(all_lanes, dist) if ln.getID() in route_set
                  or d <= radius]
        if len(chosen) > MAX_LIST_LEN:
            continue
        entries = [lane_entry(ln) for ln in chosen]
        try:
            snapshot = MapSnapshot(
                stamp_s=stamp_s, lanes=tuple(e[0] for e in entries),
                stop_lines=tuple(e[1] for e in entries if e[1] is not None),
                ego_route=tuple(route),
                target=TargetArea(lane_ids=scene.target.lane_ids, center=scene.target.center,
                                  radius_m=scene.target.radius_m),
                left_hand_traffic=left_hand,
            )
        except ValidationError as exc:
            raise _refused(scene, "the map", exc) from None
        if len(encode(snapshot)) <= max_bytes:
            return snapshot, geometry
    raise SceneError(f"the map of scene {scene.family}/{scene.seed} does not fit in "
                     f"{max_bytes} bytes even with a {radii[-1]:.0f} m radius "
                     f"(route of {len(route)} lanes is too long: shorten it)")
