"""Shared conflicts an ego sees on its map (issue 18): narrow sections, junctions, merges.

A **narrow section** is a lane of the ego's route whose centreline is, reversed, the
centreline of a lane of another edge (within ``SAME_POINT_M`` at both ends): one lane used
by both directions (SUMO bidi edges, family ``narrow``). Everything is measured along the
ego's route from its front bumper (``EgoState.lane_pos_m`` is SUMO's front position):

- entry / exit: start and end of the section lane (exit: the ego's REAR has left it);
- hold point: where a yielding ego waits, ``HOLD_MARGIN_M`` before the first lane of the
  junction(s) leading into the section (the junction is the taper where the two lanes of
  the road come together: an ego waiting inside it would block the one coming out).

A **junction** conflict zone is the passage of the ego's route through a junction (its
consecutive internal lanes) when a connection from another incoming edge of the same
junction crosses it or ends on the same lane (a foe). The whole junction is ONE zone
(``junction:<id>``, the same for every ego): one movement (``via`` = the ego's first
internal lane) holds it at a time. A junction whose connections all end on the same edge
is a **merge** (``merge:<id>``, two roads into one lane). Both: entry at the stop line
(start of the first internal lane), exit when the ego's rear has left the junction, hold
point ``JUNCTION_HOLD_MARGIN_M`` before the stop line; ``oncoming`` are vehicles on the
foe connections or moving towards them within ``ONCOMING_WINDOW_M``. Junction lanes next
to a narrow section (its tapers) belong to the section, not to a junction conflict.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from lmpc_msgs_py.coordination import ConflictView
from lmpc_msgs_py.messages import Agent, Lane, MapSnapshot
from lmpc_msgs_py.observation import Observation

SAME_POINT_M = 0.5
HOLD_MARGIN_M = 5.0
JUNCTION_HOLD_MARGIN_M = 1.0
"""A yielding ego waits with its front this far (plus its standstill gap) before the stop
line of a junction or merge."""
FOE_GAP_M = 1.0
"""Two connections of a junction whose centrelines come this close are foes."""
LOOKAHEAD_M = 150.0
"""A section farther ahead than this is not reported."""
ONCOMING_WINDOW_M = 30.0
"""A vehicle this close to the section's far entry, moving, counts as oncoming."""
ONCOMING_MIN_SPEED_MPS = 0.5
LOOKBACK_M = 100.0
"""A passed section is reported (with its ``inbound`` vehicles) up to this far behind."""


@dataclass(frozen=True)
class Section:
    conflict_id: str
    via: str
    """The section lane on the ego's route."""
    partner: str
    """The lane of the other direction (same centreline, reversed)."""
    route_index: int
    hold_index: int
    """Route index of the first lane of the junction(s) before the section."""
    feeders: tuple[str, ...]
    """Lanes that lead into ``partner`` (the other direction's approach and junction)."""
    own_junction: tuple[str, ...] = ()
    """The junction lanes that lead into ``via`` (the ego's own taper; for a junction or
    merge: the ego's own internal lanes through it)."""
    kind: str = "narrow"
    end_index: int = -1
    """Route index of the conflict's last lane (-1: ``route_index``)."""
    partners: tuple[str, ...] = ()
    """All lanes of the other directions (a junction: the foe connections' lanes)."""
    hold_margin_m: float = HOLD_MARGIN_M

    @property
    def last_index(self) -> int:
        return self.route_index if self.end_index < 0 else self.end_index

    @property
    def foe_lanes(self) -> tuple[str, ...]:
        return self.partners or (self.partner,)


def _close(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) <= SAME_POINT_M


def shared_sections(mp: MapSnapshot) -> tuple[Section, ...]:
    """The shared conflicts on ``mp``'s ego route (narrow sections, junctions, merges), in
    route order."""
    narrow = narrow_sections(mp)
    claimed: set[int] = set()
    internal = {ln.id for ln in mp.lanes if ln.internal}
    for sec in narrow:
        claimed.update(range(sec.hold_index, sec.route_index + 1))
        k = sec.route_index + 1
        while k < len(mp.ego_route) and mp.ego_route[k] in internal:
            claimed.add(k)  # the taper after the section
            k += 1
    found = [*narrow, *junction_conflicts(mp, claimed)]
    return tuple(sorted(found, key=lambda s: s.route_index))


def narrow_sections(mp: MapSnapshot) -> tuple[Section, ...]:
    """The narrow sections on ``mp``'s ego route, in route order."""
    lanes = {ln.id: ln for ln in mp.lanes}
    out = []
    for i, lid in enumerate(mp.ego_route):
        lane = lanes.get(lid)
        if lane is None or lane.internal:
            continue
        for other in mp.lanes:
            if other.internal or other.edge_id == lane.edge_id:
                continue
            if _close(lane.centerline[0], other.centerline[-1]) \
                    and _close(lane.centerline[-1], other.centerline[0]):
                hold = i
                while hold > 0 and lanes.get(mp.ego_route[hold - 1]) is not None \
                        and lanes[mp.ego_route[hold - 1]].internal:
                    hold -= 1
                feeders = _feeders(mp, other.id)
                own = tuple(f for f in _feeders(mp, lid) if lanes[f].internal)
                cid = "narrow:" + "|".join(sorted((lane.edge_id, other.edge_id)))
                out.append(Section(conflict_id=cid, via=lid, partner=other.id, route_index=i,
                                   hold_index=hold, feeders=feeders, own_junction=own,
                                   partners=(other.id,)))
                break
    return tuple(out)


def junction_of(lane: Lane) -> str:
    """The junction id of an internal lane (SUMO ``:<junction>_<link>_<lane>``)."""
    return lane.edge_id[1:].rsplit("_", 1)[0]


def _chain(lanes: dict[str, Lane], via: str) -> tuple[str, ...]:
    """``via`` and the internal lanes that follow it (split at internal junctions)."""
    out = [via]
    while len(out) < 8:
        nxt = [s.via_lane or s.to_lane for s in lanes[out[-1]].successors
               if lanes.get(s.via_lane or s.to_lane) is not None
               and lanes[s.via_lane or s.to_lane].internal]
        if not nxt or nxt[0] in out:
            break
        out.append(nxt[0])
    return tuple(out)


def _polyline(lanes: dict[str, Lane], chain: tuple[str, ...]) -> list[tuple[float, float]]:
    return [tuple(p) for lid in chain for p in lanes[lid].centerline]  # type: ignore[misc]


def _seg_dist(p: tuple[float, float], q: tuple[float, float], a: tuple[float, float],
              b: tuple[float, float]) -> float:
    """Distance between the segments pq and ab (0 when they cross)."""
    def cross(o: tuple[float, float], u: tuple[float, float], w: tuple[float, float]) -> float:
        return (u[0] - o[0]) * (w[1] - o[1]) - (u[1] - o[1]) * (w[0] - o[0])

    d1, d2 = cross(a, b, p), cross(a, b, q)
    d3, d4 = cross(p, q, a), cross(p, q, b)
    if d1 * d2 < 0.0 and d3 * d4 < 0.0:
        return 0.0

    def pt_seg(x: tuple[float, float], u: tuple[float, float], w: tuple[float, float]
               ) -> float:
        dx, dy = w[0] - u[0], w[1] - u[1]
        n = dx * dx + dy * dy
        f = 0.0 if n <= 0.0 else min(max(((x[0] - u[0]) * dx + (x[1] - u[1]) * dy) / n, 0.0),
                                     1.0)
        return math.hypot(x[0] - u[0] - f * dx, x[1] - u[1] - f * dy)

    return min(pt_seg(p, a, b), pt_seg(q, a, b), pt_seg(a, p, q), pt_seg(b, p, q))


def _poly_gap(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> float:
    return min(_seg_dist(a[i], a[i + 1], b[j], b[j + 1])
               for i in range(len(a) - 1) for j in range(len(b) - 1))


def junction_conflicts(mp: MapSnapshot, claimed: set[int] = frozenset()  # type: ignore
                       ) -> tuple[Section, ...]:
    """The junctions (and merges) on ``mp``'s ego route with a foe connection (see the
    module docstring); route indices in ``claimed`` belong to a narrow section."""
    lanes = {ln.id: ln for ln in mp.lanes}
    route = mp.ego_route
    # every connection of the map: (incoming lane, its internal chain, exit lane)
    conns: dict[str, list[tuple[str, tuple[str, ...], Optional[str]]]] = {}
    for ln in mp.lanes:
        if ln.internal:
            continue
        for s in ln.successors:
            if s.via_lane and s.via_lane in lanes:
                chain = _chain(lanes, s.via_lane)
                conns.setdefault(junction_of(lanes[s.via_lane]), []).append(
                    (ln.id, chain, s.to_lane))
    out = []
    i = 0
    while i < len(route):
        lane = lanes.get(route[i])
        if lane is None or not lane.internal or i in claimed or i == 0:
            i += 1
            continue
        j = i
        while j + 1 < len(route) and route[j + 1] in lanes and lanes[route[j + 1]].internal:
            j += 1
        jid = junction_of(lane)
        own_in = lanes.get(route[i - 1])
        own_chain = tuple(route[i:j + 1])
        own_exit = route[j + 1] if j + 1 < len(route) else None
        own_poly = _polyline(lanes, own_chain)
        partners: list[str] = []
        feeders: list[str] = []
        for src, chain, to in conns.get(jid, ()):
            if own_in is None or lanes[src].edge_id == own_in.edge_id:
                continue
            if to == own_exit or _poly_gap(own_poly, _polyline(lanes, chain)) <= FOE_GAP_M:
                partners += [c for c in chain if c not in partners]
                feeders += [src] if src not in feeders else []
        if partners:
            exits = {lanes[to].edge_id for _, _, to in conns[jid] if to in lanes}
            kind = "merge" if len(exits) == 1 else "junction"
            out.append(Section(
                conflict_id=f"{kind}:{jid}", via=route[i], partner=partners[0],
                route_index=i, hold_index=i, feeders=tuple(feeders + partners),
                own_junction=own_chain, kind=kind, end_index=j, partners=tuple(partners),
                hold_margin_m=JUNCTION_HOLD_MARGIN_M))
        i = j + 1
    return tuple(out)


def _feeders(mp: MapSnapshot, lane_id: str) -> tuple[str, ...]:
    found: list[str] = []
    frontier = {lane_id}
    for _ in range(3):  # approach lane -> junction lane(s) -> the section
        nxt = set()
        for ln in mp.lanes:
            if ln.id in found or ln.id == lane_id:
                continue
            if any(s.to_lane in frontier or s.via_lane in frontier for s in ln.successors):
                found.append(ln.id)
                if ln.internal:
                    nxt.add(ln.id)
        frontier = nxt
        if not frontier:
            break
    return tuple(found)


def route_starts_m(mp: MapSnapshot) -> tuple[float, ...]:
    """Distance along the route from its start to the start of each route lane (+ the end)."""
    lanes = {ln.id: ln for ln in mp.lanes}
    s, out = 0.0, [0.0]
    for lid in mp.ego_route:
        s += lanes[lid].length_m if lid in lanes else 0.0
        out.append(s)
    return tuple(out)


def conflict_view(obs: Observation, section: Section,
                  starts: tuple[float, ...]) -> Optional[ConflictView]:
    """The ego's view of ``section`` now (None: passed, or farther than the look-ahead)."""
    ego = obs.ego
    front = starts[min(ego.route_index, len(starts) - 1)] + ego.lane_pos_m
    entry = starts[section.route_index] - front
    exit_rear = starts[section.last_index + 1] - (front - ego.length_m)
    if entry > LOOKAHEAD_M:
        return None
    if exit_rear <= 0.0:
        # passed: still reported while vehicles follow it through (``inbound``), so the
        # other direction waits for them too
        seen = inbound(obs, section)
        if not seen or exit_rear < -LOOKBACK_M:
            return None
        return ConflictView(conflict_id=section.conflict_id, kind=section.kind,
                            via=section.via, dist_to_entry_m=0.0, dist_to_exit_m=0.0,
                            inbound=seen)
    hold = starts[section.hold_index] - section.hold_margin_m - front
    return ConflictView(
        conflict_id=section.conflict_id, kind=section.kind,  # type: ignore[arg-type]
        via=section.via,
        dist_to_entry_m=max(entry, 0.0), dist_to_exit_m=max(exit_rear, max(entry, 0.0)),
        dist_to_hold_m=max(hold, 0.0), inside=entry <= 0.0,
        oncoming=oncoming(obs, section), inbound=inbound(obs, section))


def inbound(obs: Observation, section: Section) -> tuple[str, ...]:
    """Vehicles in the section or in the junction leading into it in the ego's direction
    (they can no longer stop for the other direction)."""
    lanes = {section.via, *section.own_junction}
    return tuple(sorted(a.id for a in obs.agents.agents if a.lane_id in lanes))[:100]


def oncoming(obs: Observation, section: Section) -> tuple[str, ...]:
    """Vehicles in the section's other direction, or moving into it from close by."""
    lanes = {ln.id: ln for ln in obs.map.lanes}
    out = []
    for a in obs.agents.agents:
        if a.lane_id in section.foe_lanes:
            out.append(a.id)
        elif a.lane_id in section.feeders and a.v_mps >= ONCOMING_MIN_SPEED_MPS:
            lane = lanes.get(a.lane_id)
            if lane is not None and (lane.internal
                                     or lane.length_m - a.lane_pos_m <= ONCOMING_WINDOW_M):
                out.append(a.id)
    return tuple(sorted(out))[:100]


def point_at(mp: MapSnapshot, starts: tuple[float, ...], s_m: float
             ) -> tuple[float, float, float, Lane, float]:
    """(x, y, yaw, lane, position on the lane) at route distance ``s_m``."""
    lanes = {ln.id: ln for ln in mp.lanes}
    k = max(0, min(len(mp.ego_route) - 1,
                   max(i for i in range(len(mp.ego_route)) if starts[i] <= s_m)))
    lane = lanes[mp.ego_route[k]]
    pos = min(max(s_m - starts[k], 0.0), lane.length_m)
    pts = lane.centerline
    seg_total = sum(math.dist(pts[j], pts[j + 1]) for j in range(len(pts) - 1)) or 1.0
    target = pos * seg_total / max(lane.length_m, 1e-6)
    acc = 0.0
    for j in range(len(pts) - 1):
        seg = math.dist(pts[j], pts[j + 1])
        if acc + seg >= target or j == len(pts) - 2:
            f = 0.0 if seg <= 0.0 else min(max((target - acc) / seg, 0.0), 1.0)
            x = pts[j][0] + f * (pts[j + 1][0] - pts[j][0])
            y = pts[j][1] + f * (pts[j + 1][1] - pts[j][1])
            yaw = math.atan2(pts[j + 1][1] - pts[j][1], pts[j + 1][0] - pts[j][0])
            return x, y, yaw, lane, pos
        acc += seg
    raise AssertionError("unreachable")


HOLD_LENGTH_M = 1.0
HOLD_WIDTH_M = 1.8


def hold_agent(obs: Observation, section: Section, starts: tuple[float, ...]) -> Agent:
    """A virtual standing obstacle whose rear is at the hold point (the ego stops behind
    it: the rules' headway rule and the MPC's leader limit both respect it)."""
    s_rear = starts[section.hold_index] - section.hold_margin_m
    x, y, yaw, lane, pos = point_at(obs.map, starts, s_rear + HOLD_LENGTH_M / 2.0)
    return Agent(id=f"hold_{section.via}", kind="car", x_m=x, y_m=y, yaw_rad=yaw, v_mps=0.0,
                 a_mps2=0.0, length_m=HOLD_LENGTH_M, width_m=HOLD_WIDTH_M, lane_id=lane.id,
                 lane_pos_m=min(pos + HOLD_LENGTH_M / 2.0, lane.length_m))
