"""Bezier reference candidates (DESIGN §4, paper "Scenario Encoding"), pure Python + numpy.

The same function builds the candidates of the ego and of every agent: the
control points are the vehicle's position and a few well-spread points on the
centerline of one reachable lane path (the current lane ahead, a neighbour lane
of the same edge, or - near a junction - one outgoing connection through its
internal lane). Up to three candidates per vehicle.

Approximations (said here so nobody is surprised):
- a Bezier curve of degree M only approximates its control polygon, so in a
  sharp turn the curve cuts the corner by a little (we use 5 points along the
  lookahead to keep that small);
- where a lane path ends inside the map snapshot (dead end, edge of the map),
  it is extended straight along its last heading so every candidate has the
  requested lookahead.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import EgoState, Lane, LaneLink, MapSnapshot
from lmpc_mpc.polyline import (  # noqa: F401 (re-exported under the old private names)
    Polyline as _Polyline, dedupe as _dedupe, gradient as _gradient, wrap_angle as _wrap)

POINTS_ALONG = 10
"""Control points placed on the lane path besides the vehicle position."""
CURVATURE_DENSITY_M = 200.0
"""Control points are spread by arc length weighted with ``1 + this * |curvature|``
(curvature averaged over 4 m), so they crowd into turns: a 90 degree left turn of
radius 9.6 m is then followed within ~0.7 m instead of ~5 m with even spacing."""
MAX_HEADING_OFF_RAD = math.radians(60.0)
"""A lane is only a vehicle's lane if its direction is within this of the vehicle's yaw."""
_DIRECTION_ORDER = {"s": 0, "l": 1, "r": 2, "L": 3, "R": 4, "t": 5, "invalid": 6}
_TURN_WORDS = {
    "s": "go straight through the junction",
    "l": "turn left at the junction",
    "L": "bear left at the junction",
    "r": "turn right at the junction",
    "R": "bear right at the junction",
    "t": "make a U-turn at the junction",
    "invalid": "cross the junction",
}


class ReferencePathError(ValueError):
    """A reference could not be built (bad input geometry)."""


# --- Bezier ------------------------------------------------------------------------------
def bezier_points(control_points: Sequence[Sequence[float]] | np.ndarray, n: int) -> np.ndarray:
    """``n`` points of the Bezier curve of ``control_points`` at uniform curve parameter.

    Bernstein form (stable enough for the degrees used here, at most 15).
    Returns an ``(n, 2)`` array whose first / last rows are the first / last control point.
    """
    cp = np.asarray(control_points, dtype=float)
    if cp.ndim != 2 or cp.shape[1] != 2 or cp.shape[0] < 2:
        raise ReferencePathError(f"control points must be (m>=2, 2), got shape {cp.shape}")
    if n < 2:
        raise ReferencePathError(f"need at least 2 samples, got {n}")
    return _bernstein(cp.shape[0] - 1, n) @ cp


@lru_cache(maxsize=64)
def _bernstein(deg: int, n: int) -> np.ndarray:
    """(n, deg+1) Bernstein basis at uniform parameters (cached: it only depends on the
    degree and the sample count). Read-only."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    coeff = np.array([math.comb(deg, i) for i in range(deg + 1)], dtype=float)[None, :]
    i = np.arange(deg + 1)[None, :]
    basis = coeff * t**i * (1.0 - t) ** (deg - i)
    basis.setflags(write=False)
    return basis


@dataclass(frozen=True)
class Candidate:
    """One reference candidate of a vehicle: a Bezier curve and what it means."""

    candidate_id: int
    """0..2 in the order the candidates were built (0 = keep going as now)."""
    control_points: tuple[tuple[float, float], ...]
    """First = the vehicle's position, then points on the lane path's centerline."""
    label: str
    """Words for the prompt, e.g. "turn left at the junction"."""
    lane_ids: tuple[str, ...] = ()
    """Lanes (incl. internal junction lanes) the candidate follows."""

    def sample(self, n: int = 50) -> np.ndarray:
        """``(n, 2)`` points along the curve."""
        return bezier_points(self.control_points, n)

    def length_m(self) -> float:
        """Arc length of the curve (dense polyline approximation)."""
        pts = self.sample(200)
        return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))


# --- map index (cached per snapshot) -----------------------------------------------------
@dataclass(frozen=True)
class RoutePath:
    """The ego's whole route as one polyline: every lane of ``map.ego_route`` (internal
    junction lanes included, in route order) chained centreline to centreline."""

    line: _Polyline
    lane_ids: tuple[str, ...]
    lane_start_m: np.ndarray
    """Arc length on ``line`` where each lane of ``lane_ids`` starts."""
    sharp_turns: tuple[tuple[float, float], ...] = ()
    """(start, end) arc lengths of the route's junctions that turn by more than
    ``SHARP_TURN_RAD`` (a run of internal lanes; :func:`sharp_turn_path`)."""
    jumps: tuple[tuple[float, float, float, float], ...] = ()
    """Lane changes the route needs (the next route lane does not start where the last
    one ends): (arc length where the next lane starts, length of the joining segment,
    offset x, y from that start back to the last lane's end)."""

    def lane_at(self, s_m: float) -> int:
        """Index into ``lane_ids`` of the lane at arc length ``s_m``."""
        return int(np.clip(np.searchsorted(self.lane_start_m, s_m, side="right") - 1, 0,
                           len(self.lane_ids) - 1))


@dataclass
class _MapIndex:
    lanes: dict[str, Lane]
    lines: dict[str, _Polyline]
    by_edge: dict[str, list[Lane]] = field(default_factory=dict)
    route: Optional[RoutePath] = None

    @cached_property
    def _reach_boxes(self) -> tuple[list[str], np.ndarray]:
        """Per lane (in ``lines`` order) its centreline's bounding box grown by the
        distance at which :func:`_locate` still takes the lane (half its width + 2 m, and
        1 mm against rounding): a point outside is farther than that from the lane."""
        ids = list(self.lines)
        boxes = np.empty((len(ids), 4))
        for i, lid in enumerate(ids):
            pts, reach = self.lines[lid].pts, self.lanes[lid].width_m * 0.5 + 2.0 + 1e-3
            boxes[i, :2] = pts.min(axis=0) - reach
            boxes[i, 2:] = pts.max(axis=0) + reach
        return ids, boxes

    def lanes_near(self, x_m: float, y_m: float) -> list[str]:
        """The lanes :func:`_locate` may take at (x, y), in ``lines`` order: a city map
        has hundreds of lanes, and projecting onto each took ~1.7 ms a call."""
        ids, b = self._reach_boxes
        inside = (b[:, 0] <= x_m) & (x_m <= b[:, 2]) & (b[:, 1] <= y_m) & (y_m <= b[:, 3])
        return [ids[i] for i in np.flatnonzero(inside)]


_CACHE: "OrderedDict[tuple[int, int, float], tuple[MapSnapshot, _MapIndex]]" = OrderedDict()


def _index(map_: MapSnapshot) -> _MapIndex:
    key = (id(map_), map_.version, map_.stamp_s)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is map_:
        return hit[1]
    lanes = {ln.id: ln for ln in map_.lanes}
    lines = {ln.id: _Polyline.of(ln.centerline) for ln in map_.lanes}
    by_edge: dict[str, list[Lane]] = {}
    for ln in map_.lanes:
        by_edge.setdefault(ln.edge_id, []).append(ln)
    idx = _MapIndex(lanes, lines, by_edge, _route_path(map_, lanes, lines))
    _CACHE[key] = (map_, idx)  # holding the map keeps id() unique while cached
    while len(_CACHE) > 4:
        _CACHE.popitem(last=False)
    return idx


def _route_path(map_: MapSnapshot, lanes: dict[str, Lane], lines: dict[str, _Polyline]
                ) -> Optional[RoutePath]:
    ids: list[str] = []
    for lid in map_.ego_route:
        if lid not in lanes or (ids and ids[-1] == lid):
            continue
        if ids:
            # insert the internal lane of the connection when the route skips it
            for lk in lanes[ids[-1]].successors:
                if lk.to_lane == lid and lk.via_lane and lk.via_lane in lanes \
                        and lk.via_lane != ids[-1]:
                    ids.append(lk.via_lane)
                    break
        ids.append(lid)
    if not ids:
        return None
    pts: list[np.ndarray] = []
    starts: list[int] = []
    for lid in ids:
        starts.append(sum(len(p) for p in pts))
        pts.append(lines[lid].pts)
    line = _Polyline.of(np.concatenate(pts, axis=0))
    # dedupe may drop a joint point: map every lane's first vertex to the deduped line
    first = [np.asarray(lines[lid].pts[0]) for lid in ids]
    lane_start = np.array([line.project(float(p[0]), float(p[1]))[0] for p in first])
    lane_start[0] = 0.0
    lane_start = np.maximum.accumulate(lane_start)
    jumps = []
    for i in range(1, len(ids)):
        end, start = lines[ids[i - 1]].pts[-1], lines[ids[i]].pts[0]
        gap = float(math.hypot(*(end - start)))
        if gap > _JUMP_M:
            jumps.append((float(lane_start[i]), gap, float(end[0] - start[0]),
                          float(end[1] - start[1])))
    sharp: list[tuple[float, float]] = []
    i = 0
    while i < len(ids):
        if not lanes[ids[i]].internal:
            i += 1
            continue
        j = i
        while j + 1 < len(ids) and lanes[ids[j + 1]].internal:
            j += 1
        # from the heading the route enters the junction with to the one it leaves with
        ends = ([lines[ids[i - 1]].pts[-2:]] if i > 0 else []) + \
            [lines[lid].pts for lid in ids[i:j + 1]] + \
            ([lines[ids[j + 1]].pts[:2]] if j + 1 < len(ids) else [])
        turn = _turned_rad(*ends)
        if abs(turn) > SHARP_TURN_RAD:
            end_m = float(lane_start[j + 1]) if j + 1 < len(ids) else line.length_m
            sharp.append((float(lane_start[i]), end_m))
        i = j + 1
    return RoutePath(line, tuple(ids), lane_start, tuple(sharp), tuple(jumps))


def _turned_rad(*pieces: np.ndarray) -> float:
    """Signed heading change along polyline pieces (the sum of the turns between their
    consecutive segments; the gap between two pieces, a lane change, is no segment)."""
    parts = [np.diff(_dedupe(np.asarray(p, dtype=float)), axis=0) for p in pieces]
    d = np.concatenate([p for p in parts if len(p)], axis=0) if any(len(p) for p in parts) \
        else np.zeros((0, 2))
    if len(d) < 2:
        return 0.0
    h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return float(h[-1] - h[0])


def index_map(map_: MapSnapshot) -> None:
    """Build the per-map lookups now (lane polylines, the route polyline, the lanes'
    reach boxes) rather than in the first control step that needs them: on the city map
    (978 lanes) that step's set-up took ~10 ms more. The same cache the lookups use, so
    nothing they return changes."""
    _index(map_)._reach_boxes  # a cached_property: computed here, kept with the index


def route_path(map: MapSnapshot) -> Optional[RoutePath]:
    """The ego's route as one polyline (cached per map snapshot), or None without one."""
    return _index(map).route


SHARP_TURN_RAD = math.radians(100.0)
"""A route junction (a run of internal lanes) turning by more than this is a sharp turn:
the MPC then tracks the route's own centreline through it (:func:`sharp_turn_path`).
The ego routes of the five families turn by at most 90 degrees at a junction
(seeds 0-24; docs/lmpc_mpc.md). 100, not 110: examples/city.yaml's right turn of 109.9
degrees through a 4.75 m radius (the car turns no tighter than ~4.2 m) was left to the
Bezier references, and lmpc-rules ran wide onto the oncoming lanes there."""
SHARP_EXIT_M = 5.0
"""The sharp-turn path is kept this far past the turn's end (the car straightens out)."""
SHARP_LANE_CHANGE_M = 20.0
"""Over this length a lane change of the route is faded in on the sharp-turn path."""
_JUMP_M = 0.5
SHARP_SMOOTH_M = 2.0
"""Half-width of the moving average that rounds the polyline corners of the centreline in
:func:`sharp_turn_path` (applied twice: a triangular kernel of +-2 m)."""


def sharp_turn_near(route: Optional[RoutePath], progress_m: Optional[float],
                    ahead_m: float) -> bool:
    """The ego (at ``progress_m`` on ``route``) is within ``ahead_m`` before one of the
    route's sharp turns, or in it, or less than ``SHARP_EXIT_M`` past it."""
    if route is None or progress_m is None or not route.sharp_turns:
        return False
    return any(a - ahead_m <= progress_m <= b + SHARP_EXIT_M for a, b in route.sharp_turns)


def sharp_turn_path(route: RoutePath, x_m: float, y_m: float, progress_m: float,
                    lookahead_m: float, *, ds_m: float = 0.25) -> np.ndarray:
    """A path along the route's own centreline from ``progress_m`` on, for sharp turns.

    The Bezier candidates (10 control points over the lookahead, :func:`route_candidate`)
    follow a junction turn of ~120 degrees through a ~4.4 m radius (the car turns no
    tighter than ~4.2 m at full steer) poorly: they cut it, and rebuilt from a pose in
    the turn they curl back. Here: the route polyline sampled every ``ds_m``; a lane
    change the route needs (its polyline jumps sideways) faded in over
    ``SHARP_LANE_CHANGE_M`` after the jump; the corners rounded by a moving average
    (twice over +-``SHARP_SMOOTH_M``: ~0.1 m inside a 4.4 m arc); and the ego's offset
    from it at ``progress_m`` faded out over the first few metres (a raised cosine over
    4 m + 2x the offset), so the path starts at the ego. ``(M, 2)``."""
    line = route.line
    pad = 2.0 * SHARP_SMOOTH_M
    ss = np.arange(progress_m - pad, progress_m + lookahead_m + pad + 0.5 * ds_m, ds_m)
    c = line.at(ss)
    keep = np.ones(len(ss), dtype=bool)
    for s_j, gap, dx, dy in route.jumps:
        keep &= ~((ss > s_j - gap) & (ss < s_j))  # the joining segment itself
        after = ss >= s_j
        w = 0.5 * (1.0 + np.cos(np.pi * np.clip((ss[after] - s_j) / SHARP_LANE_CHANGE_M,
                                                0.0, 1.0)))
        c[after] += w[:, None] * np.array([dx, dy])[None, :]
    c, ss = c[keep], ss[keep]
    k = max(1, int(round(SHARP_SMOOTH_M / ds_m)))
    kernel = np.ones(2 * k + 1) / (2 * k + 1)
    for _ in range(2):
        c = np.column_stack([np.convolve(np.pad(c[:, j], k, mode="edge"), kernel,
                                         mode="valid") for j in range(2)])
    inside = (ss >= progress_m - 1e-9) & (ss <= progress_m + lookahead_m + 1e-9)
    c, along = c[inside], ss[inside] - progress_m
    off = np.array([x_m, y_m]) - c[0]
    blend_m = 4.0 + 2.0 * float(np.hypot(off[0], off[1]))
    w = 0.5 * (1.0 + np.cos(np.pi * np.clip(along / blend_m, 0.0, 1.0)))
    return _dedupe(c + w[:, None] * off[None, :])


ROUTE_BACK_SLACK_M = 0.5
"""Route progress may go back this little (projection noise while stopped)."""
ROUTE_SEARCH_AHEAD_M = 30.0
"""Without a previous progress, the ego is looked for on its route from the start of
its route lane (``ego.route_index``) to this far past that lane's end (a junction)."""


def route_progress(map: MapSnapshot, ego: EgoState, *,
                   previous_m: Optional[float] = None) -> Optional[float]:
    """Arc length of the ego on its route polyline (:func:`route_path`), or None.

    Robust off the path: the ego is projected onto the route polyline itself (all
    route lanes, internal ones included), not onto SUMO's lane guess (inside a
    junction SUMO may name another internal lane). Monotone: with ``previous_m`` the
    search window is ``[previous - slack, previous + reach]``, so the progress never
    jumps back to an earlier part of the route; without it, the window starts at the
    bridge's ``route_index`` lane (which only moves forward).
    """
    route = route_path(map)
    if route is None:
        return None
    j = -1
    if 0 <= ego.route_index < len(map.ego_route):
        lid = map.ego_route[ego.route_index]
        if lid in route.lane_ids:
            j = route.lane_ids.index(lid)
    hint_lo = float(route.lane_start_m[j]) if j >= 0 else 0.0
    hint_hi = (float(route.lane_start_m[j + 1]) if j + 1 < len(route.lane_ids)
               else route.line.length_m) + ROUTE_SEARCH_AHEAD_M if j >= 0 else math.inf
    if previous_m is None or previous_m < hint_lo - 10.0:
        lo, hi = hint_lo - 1.0, hint_hi
    else:
        lo = previous_m - ROUTE_BACK_SLACK_M
        hi = previous_m + 5.0 + 1.0 * max(ego.v_mps, 0.0)
    s, _ = route.line.project_window(ego.x_m, ego.y_m, lo, hi)
    return s if previous_m is None else max(s, previous_m - ROUTE_BACK_SLACK_M)


def _locate(idx: _MapIndex, x_m: float, y_m: float, yaw_rad: float,
            lane_id: Optional[str]) -> Optional[tuple[str, float]]:
    """The vehicle's lane and its arc length on it, or None when no lane fits."""
    if lane_id is not None and lane_id in idx.lanes:
        s, _, _ = idx.lines[lane_id].project(x_m, y_m)
        return lane_id, s
    best: Optional[tuple[float, str, float]] = None
    for lid in idx.lanes_near(x_m, y_m):
        s, dist, heading = idx.lines[lid].project(x_m, y_m)
        off = abs(_wrap(heading - yaw_rad))
        if off > MAX_HEADING_OFF_RAD or dist > idx.lanes[lid].width_m * 0.5 + 2.0:
            continue
        score = dist + 2.0 * off
        if best is None or score < best[0]:
            best = (score, lid, s)
    return None if best is None else (best[1], best[2])


def _pick_link(links: Sequence[LaneLink]) -> Optional[LaneLink]:
    """The straightest successor link (the one "continue" takes)."""
    if not links:
        return None
    return min(links, key=lambda lk: _DIRECTION_ORDER.get(lk.direction, 9))


def _chain(idx: _MapIndex, start: Sequence[str], length_m: float,
           s0_m: float) -> tuple[_Polyline, tuple[str, ...]]:
    """Concatenate the given lanes (following ``via_lane``), then the straightest
    successors, until ``length_m`` beyond ``s0_m`` on the first lane is covered."""
    pts: list[np.ndarray] = []
    ids: list[str] = []
    covered = -s0_m
    queue = list(start)
    guard = 0
    while queue and guard < 64:
        guard += 1
        lid = queue.pop(0)
        if lid not in idx.lanes or (ids and ids[-1] == lid):
            continue
        # insert the internal lane of the connection when the list skips it
        if ids and ids[-1] in idx.lanes:
            for lk in idx.lanes[ids[-1]].successors:
                if lk.to_lane == lid and lk.via_lane and lk.via_lane in idx.lanes \
                        and lk.via_lane != ids[-1]:
                    pts.append(idx.lines[lk.via_lane].pts)
                    ids.append(lk.via_lane)
                    covered += idx.lines[lk.via_lane].length_m
        pts.append(idx.lines[lid].pts)
        ids.append(lid)
        covered += idx.lines[lid].length_m
        if not queue and covered < length_m:
            link = _pick_link(idx.lanes[lid].successors)
            if link is not None and link.to_lane in idx.lanes and link.to_lane not in ids:
                queue.append(link.to_lane)
    return _Polyline.of(np.concatenate(pts, axis=0)), tuple(ids)


def _control_points(line: _Polyline, s0_m: float, x_m: float, y_m: float,
                    lookahead_m: float) -> tuple[tuple[float, float], ...]:
    ds = 0.1
    ss = np.arange(s0_m, s0_m + lookahead_m + 0.5 * ds, ds)
    p = line.at(ss)
    d = _gradient(p, ds)
    dd = _gradient(d, ds)
    kappa = np.abs(d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0])
    win = min(41, len(kappa))
    kappa = np.convolve(kappa, np.ones(win) / win, mode="same")
    w = 1.0 + CURVATURE_DENSITY_M * kappa
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * ds)])
    s = np.interp(np.arange(1, POINTS_ALONG + 1) / POINTS_ALONG, cum / cum[-1], ss)
    pts = line.at(s)
    return ((float(x_m), float(y_m)),) + tuple(map(tuple, pts.tolist()))


def _side(line_from: _Polyline, s_m: float, other: _Polyline) -> float:
    """Signed lateral offset of ``other`` from ``line_from`` at ``s_m`` (+ = left)."""
    p = line_from.at([s_m, s_m + 1.0])
    t = p[1] - p[0]
    s_o, _, _ = other.project(float(p[0, 0]), float(p[0, 1]))
    q = other.at(s_o)[0] - p[0]
    return float(t[0] * q[1] - t[1] * q[0])


# --- candidates --------------------------------------------------------------------------
def candidates_for_pose(map: MapSnapshot, *, x_m: float, y_m: float, yaw_rad: float,
                        lane_id: str | None, lookahead_m: float = 60.0) -> list[Candidate]:
    """Up to three reference candidates of a vehicle at this pose.

    Near a junction (the lane ends within ``lookahead_m`` and has connections in
    two or more directions) the candidates are the outgoing connections
    (straight first, then left, right). Otherwise: keep the lane, and change to
    the left / right neighbour lane of the same edge where one exists. A vehicle
    on no known lane gets one straight candidate along its heading.
    """
    idx = _index(map)
    where = _locate(idx, x_m, y_m, yaw_rad, lane_id)
    if where is None:
        ahead = np.array([x_m, y_m]) + np.outer(
            lookahead_m * np.arange(1, POINTS_ALONG + 1) / POINTS_ALONG,
            [math.cos(yaw_rad), math.sin(yaw_rad)],
        )
        cps = ((float(x_m), float(y_m)),) + tuple((float(a), float(b)) for a, b in ahead)
        return [Candidate(0, cps, "continue straight ahead", ())]
    lid, s0 = where
    lane = idx.lanes[lid]
    remaining = idx.lines[lid].length_m - s0
    by_dir: dict[str, LaneLink] = {}
    for lk in sorted(lane.successors, key=lambda k: _DIRECTION_ORDER.get(k.direction, 9)):
        if lk.to_lane in idx.lanes:
            by_dir.setdefault(lk.direction, lk)
    out: list[Candidate] = []
    if remaining < lookahead_m and len(by_dir) >= 2 and not lane.internal:
        for lk in list(by_dir.values())[:3]:
            chain = [lid] + ([lk.via_lane] if lk.via_lane else []) + [lk.to_lane]
            line, ids = _chain(idx, chain, lookahead_m, s0)
            cps = _control_points(line, s0, x_m, y_m, lookahead_m)
            out.append(Candidate(len(out), cps, _TURN_WORDS.get(lk.direction, "cross"), ids))
        return out
    line, ids = _chain(idx, [lid], lookahead_m, s0)
    keep_label = "continue through the junction" if lane.internal else "continue in lane"
    link = _pick_link(lane.successors)
    if not lane.internal and link is not None and remaining < lookahead_m \
            and link.direction in ("l", "r", "L", "R", "t"):
        keep_label = f"continue in lane and {_TURN_WORDS[link.direction].split(' at ')[0]}" \
            " at the junction"
    out.append(Candidate(0, _control_points(line, s0, x_m, y_m, lookahead_m), keep_label, ids))
    if lane.internal:
        return out
    here = idx.lines[lid]
    neighbours = [ln for ln in idx.by_edge.get(lane.edge_id, ())
                  if abs(ln.index - lane.index) == 1 and not ln.internal]
    for nb in sorted(neighbours, key=lambda ln: -_side(here, s0, idx.lines[ln.id])):
        nline = idx.lines[nb.id]
        ns0, _, _ = nline.project(x_m, y_m)
        side = "left" if _side(here, s0, nline) > 0 else "right"
        line_nb, ids_nb = _chain(idx, [nb.id], lookahead_m, ns0)
        cps = _control_points(line_nb, ns0, x_m, y_m, lookahead_m)
        out.append(Candidate(len(out), cps, f"change to the {side} lane", ids_nb))
    return out[:3]


def route_candidate(map: MapSnapshot, ego: EgoState, *, lookahead_m: float = 60.0,
                    progress_m: Optional[float] = None) -> Candidate:
    """The baseline reference: the ego's route (``map.ego_route``) from its position.

    The ego is placed on the route polyline by :func:`route_progress` (``progress_m``
    if the caller tracks it), so off its lane (e.g. stopped inside the junction on a
    lane SUMO attributes to another connection) the reference still rejoins the
    route ahead and never points back along it.
    """
    idx = _index(map)
    route_line = idx.route
    if route_line is not None:
        s0 = progress_m if progress_m is not None else route_progress(map, ego)
        if s0 is not None:
            j = route_line.lane_at(s0)
            line = route_line.line
            if line.length_m - s0 < lookahead_m:
                # extend the route straight (paths leaving the snapshot are extended)
                tail = line.at([line.length_m + lookahead_m])
                line = _Polyline.of(np.vstack([line.pts, tail]))
            cps = _control_points(line, s0, ego.x_m, ego.y_m, lookahead_m)
            return Candidate(0, cps, "follow the route", route_line.lane_ids[j:])
    route = [lid for lid in map.ego_route if lid in idx.lanes]
    if not route:
        cands = candidates_for_pose(map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                                    lane_id=ego.lane_id, lookahead_m=lookahead_m)
        c = cands[0]
        return Candidate(0, c.control_points, "follow the route", c.lane_ids)
    start: Optional[int] = None
    if ego.lane_id in route:
        # a route rarely visits a lane twice; prefer the visit at / after the bridge's hint
        visits = [i for i, lid in enumerate(route) if lid == ego.lane_id]
        later = [i for i in visits if i >= min(ego.route_index, len(route) - 1)]
        start = later[0] if later else visits[0]
    if start is None:
        # off the route's lanes (e.g. mid lane change): the nearest route lane that fits
        best: Optional[tuple[float, int]] = None
        for i, lid in enumerate(route):
            s, dist, heading = idx.lines[lid].project(ego.x_m, ego.y_m)
            score = dist + 2.0 * abs(_wrap(heading - ego.yaw_rad))
            if best is None or score < best[0]:
                best = (score, i)
        start = best[1] if best is not None else 0
    s0, _, _ = idx.lines[route[start]].project(ego.x_m, ego.y_m)
    line, ids = _chain(idx, route[start:], lookahead_m, s0)
    cps = _control_points(line, s0, ego.x_m, ego.y_m, lookahead_m)
    return Candidate(0, cps, "follow the route", ids)


def heading_off_rad(cand: Candidate, yaw_rad: float) -> float:
    """How far (rad, 0..pi) the candidate's direction over its first stretch (the chord
    to the point a quarter along the curve) is from ``yaw_rad``."""
    pts = cand.sample(40)
    d = pts[10] - pts[0]
    if float(np.hypot(*d)) < 1e-6:
        return 0.0
    return abs(_wrap(math.atan2(d[1], d[0]) - yaw_rad))


def closest_heading(cands: Sequence[Candidate], yaw_rad: float) -> Candidate:
    """The candidate whose direction over its first stretch is closest to ``yaw_rad``.

    Ties go to the lower id (keep the lane / go straight)."""
    if not cands:
        raise ReferencePathError("closest_heading needs at least one candidate")
    return min(cands, key=lambda c: (round(heading_off_rad(c, yaw_rad), 6), c.candidate_id))


WRONG_WAY_RAD = math.pi / 2.0
"""An agent heading farther than this from every candidate of its lane goes against the
lane's drawn direction (a pedestrian on a crossing walks either way): it is forecast
straight on along its heading instead (``straight_candidate``)."""


def straight_candidate(x_m: float, y_m: float, yaw_rad: float, length_m: float) -> Candidate:
    """One straight-line candidate from (x, y) along ``yaw_rad`` (an APPROXIMATION for an
    agent off the lane map or going against its lane)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    pts = tuple((x_m + f * length_m * c, y_m + f * length_m * s) for f in (0.0, 0.5, 1.0))
    return Candidate(candidate_id=0, control_points=pts,
                     label="keep its current heading (off the lane map)", lane_ids=())


# --- time parameterisation ---------------------------------------------------------------
@dataclass(frozen=True)
class TimedReference:
    """A reference in time: ``states`` rows (x, y, yaw, v) at t = k dt, k = 0..N,
    and the path curvature at each row (for the steer reference)."""

    states: np.ndarray
    curvature_1pm: np.ndarray
    path: np.ndarray
    """The dense (M, 2) geometric path the states lie on."""


REFERENCE_DS_M = 0.5
"""Spacing of the dense resampling of the reference path (``timed_reference``'s default)."""
PathGeometry = tuple[_Polyline, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""``_path_geometry``'s (line, arc lengths, yaw, curvature, points)."""


def reference_path_points(points: np.ndarray) -> np.ndarray:
    """``points`` as an (m >= 2, 2) float array of finite coordinates, else
    ``ReferencePathError`` naming what is wrong (the controller brakes on it)."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ReferencePathError(f"path must be (m>=2, 2), got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ReferencePathError("path contains NaN or infinite coordinates")
    return pts


def _path_geometry(points: np.ndarray, ds_m: float) -> PathGeometry:
    """Dense resampling of a path: (line, arc lengths, yaw, curvature, points)."""
    line = _Polyline.of(points)
    length = max(line.length_m, ds_m)
    s = np.arange(0.0, length + ds_m, ds_m)
    xy = line.at(s)
    d = _gradient(xy, ds_m)
    dd = _gradient(d, ds_m)
    yaw = np.arctan2(d[:, 1], d[:, 0])
    speed2 = np.maximum(np.sum(d * d, axis=1), 1e-9)
    kappa = (d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0]) / speed2**1.5
    # smooth the numerical curvature a little (3-tap average) so the cap is not noisy
    if len(kappa) >= 3:
        kappa = np.convolve(np.pad(kappa, 1, mode="edge"), np.ones(3) / 3.0, mode="valid")
    return line, s, yaw, kappa, xy


def braking_envelope(v_cap_mps: np.ndarray, *, dec_mps2: float, ds_m: float) -> np.ndarray:
    """Largest speeds on a grid of spacing ``ds_m`` from which every later cap can be
    met braking at ``dec_mps2``: the recursion ``v[i] = min(cap[i], sqrt(v[i+1]^2 +
    2 dec ds))`` in closed form, ``v[i]^2 = min_{j>=i} cap[j]^2 + 2 dec ds (j - i)``
    (a reverse running minimum, no Python loop)."""
    cap = np.asarray(v_cap_mps, dtype=float)
    step2 = 2.0 * dec_mps2 * ds_m * np.arange(len(cap))
    return np.sqrt(np.maximum(
        np.minimum.accumulate((cap ** 2 + step2)[::-1])[::-1] - step2, 0.0))


def timed_reference(points: np.ndarray, *, v0_mps: float, v_max_mps: float, a_max_mps2: float,
                    a_lat_max_mps2: float, horizon: int, dt_s: float,
                    a_dec_mps2: float | None = None, stop_at_m: float | None = None,
                    s_limit_m: np.ndarray | None = None, ds_m: float = REFERENCE_DS_M,
                    geometry: PathGeometry | None = None) -> TimedReference:
    """Time-parameterise a path; see :func:`time_parameterize`. Also returns curvature.

    ``geometry``: ``_path_geometry(points, ds_m)`` if the caller has it already (the
    controller computes it once a step for this and its crossing rule's timing).

    ``stop_at_m``: arc length where the reference must come to rest (red light).
    ``a_dec_mps2``: deceleration the profile plans with (default ``2 * a_max``).
    ``s_limit_m``: (horizon+1,) largest arc length allowed at step k (a lead vehicle's
    predicted position minus a gap); the profile brakes for it with ``a_dec``.
    """
    pts = reference_path_points(points)
    dec = a_dec_mps2 if a_dec_mps2 is not None else 2.0 * a_max_mps2
    line, s, yaw, kappa, path_xy = geometry if geometry is not None \
        else _path_geometry(pts, ds_m)
    v_cap = np.minimum(v_max_mps, np.sqrt(a_lat_max_mps2 / np.maximum(np.abs(kappa), 1e-6)))
    if stop_at_m is not None:
        v_cap = np.where(s >= stop_at_m, 0.0, v_cap)
    v_b = braking_envelope(v_cap, dec_mps2=dec, ds_m=ds_m)
    end_v = float(v_b[-1])
    s_end = float(s[-1])
    n_s = len(s)
    v_b_list = v_b.tolist()
    limits = None if s_limit_m is None else np.asarray(s_limit_m, dtype=float).tolist()
    stop_cap = None if stop_at_m is None else max(float(stop_at_m), 0.0)
    # forward pass in plain floats (the hot loop of the controller): positions and
    # speeds only; the states are interpolated in one vectorised step below
    pos_k = [0.0] * (horizon + 1)
    v_k = [0.0] * (horizon + 1)
    pos, v = 0.0, max(0.0, float(v0_mps))
    for k in range(horizon + 1):
        if stop_cap is not None:
            pos = min(pos, stop_cap)
        pos_k[k] = pos
        v_k[k] = v
        if pos <= s_end:
            f = pos / ds_m
            i = min(int(f), n_s - 2) if n_s > 1 else 0
            w = min(max(f - i, 0.0), 1.0) if n_s > 1 else 0.0
            target = v_b_list[i] + w * (v_b_list[min(i + 1, n_s - 1)] - v_b_list[i])
        else:
            target = end_v
        if limits is not None and k + 1 < len(limits):
            room = max(0.0, limits[k + 1] - pos)
            target = min(target, math.sqrt(2.0 * dec * room))
        v_next = min(target, v + a_max_mps2 * dt_s) if v < target else max(target, v - dec * dt_s)
        prev = pos
        pos += 0.5 * (v + v_next) * dt_s
        if limits is not None and k + 1 < len(limits):
            # never backwards: a reference that reverses would pull the car back
            pos = max(prev, min(pos, limits[k + 1]))
            v_next = min(v_next, (pos - prev) / dt_s * 2.0)
        v = max(0.0, v_next)
    pos_a = np.array(pos_k)
    xy = line.at(pos_a)
    inside = pos_a <= s_end
    yaw_u = np.unwrap(yaw)
    yaws = np.where(inside, np.interp(pos_a, s, yaw_u), yaw[-1])
    curv = np.where(inside, np.interp(pos_a, s, kappa), 0.0)
    states = np.empty((horizon + 1, 4))
    states[:, 0:2] = xy
    states[:, 2] = (yaws + math.pi) % (2.0 * math.pi) - math.pi
    states[:, 3] = v_k
    return TimedReference(states=states, curvature_1pm=curv, path=path_xy)


def time_parameterize(points: np.ndarray, *, v0_mps: float, v_max_mps: float, a_max_mps2: float,
                      a_lat_max_mps2: float, horizon: int, dt_s: float) -> np.ndarray:
    """Rows (x, y, yaw, v) at t = k dt, k = 0..horizon, along the path ``points``.

    Speed starts at ``v0_mps``, rises at ``a_max_mps2`` towards ``v_max_mps``,
    capped in curves so the lateral acceleration stays below ``a_lat_max_mps2``
    (planned with a deceleration of ``2 * a_max``). Beyond the path's end the
    reference goes on straight.
    """
    return timed_reference(points, v0_mps=v0_mps, v_max_mps=v_max_mps, a_max_mps2=a_max_mps2,
                           a_lat_max_mps2=a_lat_max_mps2, horizon=horizon, dt_s=dt_s).states


def lane_at(map: MapSnapshot, *, x_m: float, y_m: float, yaw_rad: float,
            lane_id: str | None) -> Optional[Lane]:
    """The vehicle's lane (``lane_id`` if the map has it, else the best fitting lane)."""
    idx = _index(map)
    where = _locate(idx, x_m, y_m, yaw_rad, lane_id)
    return None if where is None else idx.lanes[where[0]]
