"""External scenes: a YAML scene description on any SUMO network -> :class:`Scene`.

A scene file names a ``.net.xml``, optional route / flow files, optional
background traffic generated with SUMO's own ``randomTrips.py`` (seeded), the
ego's start (edge + position, or a point) and route (edge list, or routed to an
edge), the target area and optional warm-up seconds before the ego is inserted.
Relative paths are relative to the scene file. Example (``examples/city.yaml``)::

    name: city
    net: city.net.xml
    seed: 3
    background: {period_s: 1.5, end_s: 400, seed: 7}
    warmup_s: 30
    ego:
      start: {edge: "A0B0", pos_m: 15, lane: 0}
      speed_mps: 6
      to_edge: "C2C3"
    target: {pos_m: 40, radius_m: 4}

Every problem is one :class:`SceneError` naming the file, the field and the
reason: a bad field, a missing file, a net that cannot be parsed, an edge the
net does not have, a route with a gap, a destination that cannot be reached, an
element the messages cannot carry (an id over ``MAX_ID_CHARS``, a lane or vehicle
type over a schema bound: :mod:`lmpc_bridge.scenarios.limits`).
Problems only SUMO can see (a start that overlaps a vehicle, a net SUMO
refuses) are raised by :meth:`lmpc_bridge.sim.SumoSim.reset_scene`.

Routing (``to_edge``): fastest path (length / speed limit) over the net's lane
connections open to passenger cars — the same cost SUMO's default router uses
on an empty network; it ignores traffic (approximation).

The ids ``ego``, ``r_ego`` and ``ego_type`` are reserved for the ego.
"""
from __future__ import annotations

import hashlib
import heapq
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Annotated, Any, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lmpc_msgs_py.messages import MAX_ID_CHARS
from lmpc_msgs_py.yamlfile import field_path, read_mapping

from lmpc_bridge.demand import declared_demand
from lmpc_bridge.scenarios.base import DEFAULT_MAX_TIME_S, Scene, SceneError
from lmpc_bridge.scenarios.common import target_on_lanes, write_routes
from lmpc_bridge.scenarios.limits import check_demand, check_net_ids

EXTERNAL_VERSION = 2
"""Bump when the way a scene file becomes a Scene changes (cached builds are redone)."""
MAX_BEGIN_S = 31.0 * 86400.0
"""Latest ``begin_s`` accepted (a month of SUMO time; recorded days fit well inside)."""
SNAP_RADIUS_M = 10.0
"""A start or target point must lie within this distance of a lane the ego may use."""
EGO_CLASS = "passenger"

_Name = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
_EdgeId = Annotated[str, Field(min_length=1, max_length=MAX_ID_CHARS)]
_Pos = Annotated[float, Field(ge=0.0, le=1.0e5, allow_inf_nan=False)]
_Coord = Annotated[float, Field(ge=-1.0e6, le=1.0e6, allow_inf_nan=False)]


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StartSpec(_Spec):
    """Where the ego starts: ``edge`` (+ ``pos_m``, ``lane``) or a point (``x_m``, ``y_m``)."""

    edge: Optional[_EdgeId] = None
    pos_m: Optional[_Pos] = None
    """Front-bumper position along the edge (SUMO convention); default 10 m."""
    lane: Optional[Annotated[int, Field(ge=0, le=64)]] = None
    """Lane index (0 = rightmost); default: the rightmost lane open to cars."""
    x_m: Optional[_Coord] = None
    y_m: Optional[_Coord] = None

    @model_validator(mode="after")
    def _one_form(self) -> "StartSpec":
        by_edge = self.edge is not None
        by_point = self.x_m is not None or self.y_m is not None
        if by_edge == by_point:
            raise ValueError("give either 'edge' (with optional 'pos_m', 'lane') "
                             "or a point 'x_m' + 'y_m'")
        if by_point and (self.x_m is None or self.y_m is None or self.pos_m is not None
                         or self.lane is not None):
            raise ValueError("a point start needs both 'x_m' and 'y_m' and nothing else")
        return self


class EgoSpec(_Spec):
    start: StartSpec
    speed_mps: Annotated[float, Field(ge=0.0, le=40.0, allow_inf_nan=False)] = 0.0
    route: Optional[list[_EdgeId]] = Field(default=None, min_length=1, max_length=2000)
    """Edge list starting with the start edge (else routed to ``to_edge`` / the target)."""
    to_edge: Optional[_EdgeId] = None

    @model_validator(mode="after")
    def _route_form(self) -> "EgoSpec":
        if self.route is not None and self.to_edge is not None:
            raise ValueError("give either 'route' (an edge list) or 'to_edge', not both")
        return self


class TargetSpecIn(_Spec):
    """Target area: on ``edge`` (default the last route edge) at ``pos_m``, or a point."""

    edge: Optional[_EdgeId] = None
    pos_m: Optional[_Pos] = None
    """Distance from the edge start; default 30 m (clipped to the edge)."""
    x_m: Optional[_Coord] = None
    y_m: Optional[_Coord] = None
    radius_m: Annotated[float, Field(gt=0.0, le=100.0, allow_inf_nan=False)] = 5.0

    @model_validator(mode="after")
    def _one_form(self) -> "TargetSpecIn":
        by_point = self.x_m is not None or self.y_m is not None
        if by_point and (self.x_m is None or self.y_m is None or self.edge is not None
                         or self.pos_m is not None):
            raise ValueError("a point target needs both 'x_m' and 'y_m' and no 'edge'/'pos_m'")
        return self


class BackgroundSpec(_Spec):
    """Background traffic from SUMO's ``randomTrips.py`` (passenger cars, seeded)."""

    period_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 2.0
    """Mean seconds between two inserted vehicles (``randomTrips.py -p``)."""
    end_s: Annotated[float, Field(gt=0.0, le=86400.0, allow_inf_nan=False)] = 600.0
    """Trips depart from ``begin_s`` of the scene until ``begin_s + end_s``."""
    seed: Annotated[int, Field(ge=0)] = 0
    fringe_factor: Annotated[float, Field(ge=1.0, le=1000.0)] = 5.0
    """Trips start / end on the fringe this many times more often (through traffic)."""
    min_distance_m: Annotated[float, Field(ge=0.0, le=1.0e5)] = 100.0


class SceneFile(_Spec):
    """The scene description (YAML). Paths are relative to the file."""

    name: Optional[_Name] = None
    """Scenario name in records (default: the file's stem)."""
    net: str = Field(min_length=1)
    routes: list[str] = Field(default_factory=list, max_length=64)
    """Route / flow / additional files with background traffic (SUMO XML)."""
    background: Optional[BackgroundSpec] = None
    seed: Annotated[int, Field(ge=0)] = 0
    """SUMO's ``--seed`` (driver noise, randomised departures)."""
    begin_s: Annotated[float, Field(ge=0.0, le=MAX_BEGIN_S, allow_inf_nan=False)] = 0.0
    """SUMO time to start at (``--begin``): a recorded demand file departs at the hour it
    was recorded (e.g. 25200 = 7:00). Vehicles departing earlier are not loaded."""
    warmup_s: Annotated[float, Field(ge=0.0, le=3600.0, allow_inf_nan=False)] = 0.0
    """Simulated seconds after ``begin_s`` before the ego is inserted (traffic fills the net)."""
    max_time_s: Annotated[float, Field(gt=0.0, le=3600.0,
                                       allow_inf_nan=False)] = DEFAULT_MAX_TIME_S
    ego: EgoSpec
    target: TargetSpecIn = TargetSpecIn()
    description: str = Field(default="", max_length=1000)


def _field_errors(path: Path, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors(include_url=False):
        loc = field_path(err)
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; see README 'Your own network')"
        lines.append(f"  field '{loc}': {msg}")
    return f"scene file {path}: {len(lines)} bad field(s):\n" + "\n".join(lines)


def load_scene_file(path: str | Path) -> SceneFile:
    """Read and validate a scene file (SceneError with one line per bad field)."""
    path = Path(path)
    data = read_mapping(path, what="scene file", error=SceneError)
    try:
        return SceneFile.model_validate(data)
    except ValidationError as exc:
        raise SceneError(_field_errors(path, exc)) from None


# --- network queries ---------------------------------------------------------------------
def _drivable(lane: Any) -> bool:
    return bool(lane.allows(EGO_CLASS))


def _edge(net: Any, edge_id: str, what: str, where: Path) -> Any:
    if not net.hasEdge(edge_id) or net.getEdge(edge_id).getFunction() != "":
        raise SceneError(f"scene file {where}: {what}: the network has no edge {edge_id!r}")
    edge = net.getEdge(edge_id)
    if not any(_drivable(lane) for lane in edge.getLanes()):
        raise SceneError(f"scene file {where}: {what}: edge {edge_id!r} has no lane open to "
                         f"passenger cars")
    return edge


def _successor_edges(edge: Any) -> set[str]:
    return {c.getToLane().getEdge().getID() for lane in edge.getLanes() if _drivable(lane)
            for c in lane.getOutgoing() if _drivable(c.getToLane())}


def fastest_route(net: Any, from_edge: str, to_edge: str) -> list[str] | None:
    """Fastest edge path (length / speed) over connections open to passenger cars."""
    if from_edge == to_edge:
        return [from_edge]

    def cost(edge_id: str) -> float:
        lanes = [ln for ln in net.getEdge(edge_id).getLanes() if _drivable(ln)]
        return min(ln.getLength() / max(ln.getSpeed(), 0.1) for ln in lanes)

    best: dict[str, float] = {from_edge: 0.0}
    back: dict[str, str] = {}
    heap = [(0.0, from_edge)]
    while heap:
        d, e = heapq.heappop(heap)
        if e == to_edge:
            path = [e]
            while path[-1] != from_edge:
                path.append(back[path[-1]])
            return path[::-1]
        if d > best.get(e, math.inf):
            continue
        for nxt in _successor_edges(net.getEdge(e)):
            nd = d + cost(nxt)
            if nd < best.get(nxt, math.inf):
                best[nxt], back[nxt] = nd, e
                heapq.heappush(heap, (nd, nxt))
    return None


def _nearest_lane(net: Any, x: float, y: float, *, edges: Optional[set[str]] = None
                  ) -> tuple[Any, float, float]:
    """(lane, position along it, distance) of the drivable normal lane nearest to (x, y)."""
    from sumolib.geomhelper import polygonOffsetAndDistanceToPoint

    best: tuple[Any, float, float] | None = None
    for edge in net.getEdges(withInternal=False):
        if edges is not None and edge.getID() not in edges:
            continue
        for lane in edge.getLanes():
            if not _drivable(lane):
                continue
            shape = lane.getShape()
            xs = [p[0] for p in shape]
            ys = [p[1] for p in shape]
            if (x < min(xs) - SNAP_RADIUS_M or x > max(xs) + SNAP_RADIUS_M
                    or y < min(ys) - SNAP_RADIUS_M or y > max(ys) + SNAP_RADIUS_M):
                continue
            offset, dist = polygonOffsetAndDistanceToPoint((x, y), shape)
            if dist >= 0 and (best is None or dist < best[2]):
                best = (lane, float(offset), float(dist))
    if best is None or best[2] > SNAP_RADIUS_M:
        raise SceneError(f"point ({x:.1f}, {y:.1f}) is not within {SNAP_RADIUS_M:.0f} m of a "
                         f"lane open to passenger cars")
    return best


# --- background traffic ------------------------------------------------------------------
def _random_trips(net_file: Path, out: Path, bg: BackgroundSpec, begin_s: float) -> Path:
    """Seeded background trips with SUMO's own randomTrips.py (validated by duarouter)."""
    import sumo

    tools = Path(sumo.SUMO_HOME) / "tools"
    cmd = [sys.executable, str(tools / "randomTrips.py"), "-n", str(net_file),
           "-o", str(out), "-r", str(out.with_suffix(".rou.xml")), "--seed", str(bg.seed),
           "-b", f"{begin_s:g}", "-e", f"{begin_s + bg.end_s:g}",
           "-p", f"{bg.period_s:g}", "--fringe-factor", f"{bg.fringe_factor:g}",
           "--min-distance", f"{bg.min_distance_m:g}", "--prefix", "bg",
           "--vehicle-class", EGO_CLASS, "--validate",
           "--trip-attributes", 'departLane="best" departSpeed="max"']
    env = dict(os.environ, SUMO_HOME=str(sumo.SUMO_HOME))
    env["PATH"] = str(Path(sumo.SUMO_HOME) / "bin") + os.pathsep + env.get("PATH", "")
    try:
        # cwd: randomTrips / duarouter write side files next to where they run
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env,
                              check=False, cwd=out.parent)
    except subprocess.TimeoutExpired:
        raise SceneError("randomTrips.py took over 600 s: ask for fewer background trips "
                         "(larger background.period_s or smaller end_s)") from None
    if proc.returncode != 0 or not out.is_file():
        raise SceneError(f"randomTrips.py failed ({proc.returncode}) for background traffic: "
                         f"{(proc.stderr or proc.stdout).strip()[-800:]}")
    return out


# --- the scene -------------------------------------------------------------------------
def _resolve(base: Path, name: str, what: str, where: Path) -> Path:
    path = (base / name).resolve()
    if not path.is_file():
        raise SceneError(f"scene file {where}: {what}: file {path} not found")
    return path


def _digest(spec: SceneFile, files: list[Path]) -> str:
    h = hashlib.sha256(spec.model_dump_json().encode())
    h.update(str(EXTERNAL_VERSION).encode())
    for f in files:
        st = f.stat()
        h.update(f"{f}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def build_external_scene(scene_file: str | Path, *, work_dir: Path,
                         seed: Optional[int] = None) -> Scene:
    """Validate ``scene_file`` against its network and build the :class:`Scene`.

    Writes the ego's routes file (``ego_type``, ``r_ego``) and the background
    trips under ``work_dir/external/<name>-<digest>/``; a build with the same
    inputs is reused (``scene.json``), so the launcher and the bridge build once.
    ``seed``: replaces the file's SUMO seed and its background-traffic seed
    (``benchmark.py --scene X --seeds 0-4``: one scene per seed).
    """
    from lmpc_bridge.mapping import build_map, read_net

    where = Path(scene_file).resolve()
    spec = load_scene_file(where)
    if seed is not None:
        if seed < 0:
            raise SceneError(f"seed must be >= 0, got {seed}")
        bg = spec.background
        spec = spec.model_copy(update={
            "seed": seed, "background": None if bg is None else bg.model_copy(
                update={"seed": seed})})
    base = where.parent
    net_file = _resolve(base, spec.net, "net", where)
    extra = [_resolve(base, r, f"routes[{i}]", where) for i, r in enumerate(spec.routes)]
    name = spec.name or where.stem.split(".")[0]
    scene_dir = Path(work_dir) / "external" / f"{name}-{_digest(spec, [net_file, *extra])}"
    cache = scene_dir / "scene.json"
    if cache.is_file():
        try:
            return Scene.from_json(cache.read_text())
        except (ValueError, KeyError, TypeError):
            pass  # rebuilt below
    net = read_net(net_file)
    check_net_ids(net, where=f"scene file {where}: net {net_file.name}")
    try:
        user_demand = declared_demand(extra)
    except ValueError as exc:
        raise SceneError(f"scene file {where}: routes: cannot read {exc}") from None
    check_demand(user_demand, where=f"scene file {where}: routes")

    # start
    st = spec.ego.start
    if st.edge is not None:
        start_edge = _edge(net, st.edge, "ego.start.edge", where)
        lanes = start_edge.getLanes()
        if st.lane is not None:
            if st.lane >= len(lanes) or not _drivable(lanes[st.lane]):
                raise SceneError(f"scene file {where}: ego.start.lane: edge {st.edge!r} has "
                                 f"no lane {st.lane} open to passenger cars "
                                 f"(it has {len(lanes)} lanes)")
            start_lane = lanes[st.lane]
        else:
            start_lane = next(ln for ln in lanes if _drivable(ln))
        pos = 10.0 if st.pos_m is None else st.pos_m
        if pos > start_lane.getLength():
            raise SceneError(f"scene file {where}: ego.start.pos_m: {pos:.1f} m is beyond the "
                             f"end of edge {st.edge!r} ({start_lane.getLength():.1f} m)")
    else:
        try:
            start_lane, pos, _ = _nearest_lane(net, float(st.x_m), float(st.y_m))  # type: ignore
        except SceneError as exc:
            raise SceneError(f"scene file {where}: ego.start: {exc}") from None
        start_edge = start_lane.getEdge()
    # A point start gives the centre; SUMO's depart position is the front bumper.
    if st.edge is None:
        pos = min(pos + 2.25, start_lane.getLength())

    # target edge (may be needed for routing)
    tg = spec.target
    target_lane = None
    if tg.x_m is not None:
        route_edges = set(spec.ego.route) if spec.ego.route else None
        try:
            target_lane, tpos, _ = _nearest_lane(net, float(tg.x_m), float(tg.y_m),  # type: ignore
                                                 edges=route_edges)
        except SceneError as exc:
            raise SceneError(f"scene file {where}: target: {exc}") from None
        target_edge_id = target_lane.getEdge().getID()
    else:
        target_edge_id = tg.edge
        tpos = 30.0 if tg.pos_m is None else tg.pos_m

    # route
    if spec.ego.route is not None:
        edges = list(spec.ego.route)
        for i, e in enumerate(edges):
            _edge(net, e, f"ego.route[{i}]", where)
        if edges[0] != start_edge.getID():
            raise SceneError(f"scene file {where}: ego.route: it must begin with the start edge "
                             f"{start_edge.getID()!r}, not {edges[0]!r}")
        for a, b in zip(edges, edges[1:]):
            if b not in _successor_edges(net.getEdge(a)):
                raise SceneError(f"scene file {where}: ego.route: unreachable: no lane of edge "
                                 f"{a!r} connects to edge {b!r} for passenger cars")
        if target_edge_id is not None and target_edge_id != edges[-1]:
            raise SceneError(f"scene file {where}: target.edge {target_edge_id!r} is not the "
                             f"last edge of ego.route ({edges[-1]!r})")
    else:
        dest = spec.ego.to_edge or target_edge_id
        if dest is None:
            raise SceneError(f"scene file {where}: ego: give 'route', 'to_edge' or a target "
                             f"edge / point (nowhere to drive to)")
        _edge(net, dest, "ego.to_edge" if spec.ego.to_edge else "target.edge", where)
        if target_edge_id is not None and target_edge_id != dest:
            raise SceneError(f"scene file {where}: target edge {target_edge_id!r} differs "
                             f"from ego.to_edge {dest!r}")
        path = fastest_route(net, start_edge.getID(), dest)
        if path is None:
            raise SceneError(f"scene file {where}: unreachable: no route for passenger cars "
                             f"from edge {start_edge.getID()!r} to edge {dest!r}")
        edges = path
    target_edge = _edge(net, edges[-1], "target.edge", where)
    target_lanes = [ln.getID() for ln in target_edge.getLanes() if _drivable(ln)]
    if target_lane is not None:
        target_lanes.remove(target_lane.getID())
        target_lanes.insert(0, target_lane.getID())
    length = net.getLane(target_lanes[0]).getLength()
    if len(edges) == 1 and tpos <= pos:
        tpos = min(pos + 30.0, length - 1.0)  # a target behind the start is never reached
        if tpos <= pos:
            raise SceneError(f"scene file {where}: target: the route is one edge and the "
                             f"start is at its end: give a route or a target further on")
    target = target_on_lanes(net, target_lanes, pos_m=tpos, radius_m=tg.radius_m)

    # files
    scene_dir.mkdir(parents=True, exist_ok=True)
    route_file = scene_dir / "ego.rou.xml"
    write_routes(route_file, vtypes=[], routes={"r_ego": edges}, vehicles=[])
    additional = list(extra)
    if spec.background is not None:
        additional.append(_random_trips(net_file, scene_dir / "background.trips.xml",
                                        spec.background, spec.begin_s))
    scene = Scene(
        family=name, seed=spec.seed, net_file=net_file, route_file=route_file,
        additional_files=tuple(additional), ego_route_edges=tuple(edges),
        ego_depart_lane=start_lane.getIndex(), ego_depart_pos_m=round(float(pos), 3),
        ego_depart_speed_mps=spec.ego.speed_mps, target=target, max_time_s=spec.max_time_s,
        description=spec.description or f"external scene {where.name}",
        params={"warmup_s": spec.warmup_s, "begin_s": spec.begin_s, "scene_file": str(where),
                "left_hand": int(bool(net.lefthand))},
        interaction="not checked (external scene)",
    )
    # every lane the map will carry must pass the message schema: refused here, one line
    # naming the lane, rather than in the bridge with a traceback
    try:
        build_map(scene, net=net)
    except SceneError as exc:
        raise SceneError(f"scene file {where}: {exc}") from None
    tmp = cache.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(json.loads(scene.to_json()), indent=1))
    os.replace(tmp, cache)
    return scene
