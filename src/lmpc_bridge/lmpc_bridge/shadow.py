"""The ego's shadow: SUMO's drivers see an ego that stands across two lanes (issue 21).

SUMO keeps every vehicle on one lane: ``moveToXY`` maps the ego to the lane nearest its
front bumper, and SUMO's drivers on the neighbour lane do not see the part of the ego's
body that covers their lane. Moving through a lane change that lasts a second or two; an
ego that stops half-way (yielding at the junction after a short stub, or any stop in a
lane change) stands in that lane for as long as it waits, and a car coming along it runs
into the ego's tail (the baseline on the busy right-hand "inner" short-stub net with the
straight entry: hit from behind at 24.7 s after a 15 s wait, docs/lmpc_mpc.md).

The shadow makes that part of the body visible to SUMO: while the ego is slow
(:data:`MAX_SPEED_MPS`) and its body blocks a neighbour lane it is leaving (of the lane
SUMO put it on; the map's left / right neighbour; a car centred in that lane could not
pass it with :data:`CLEARANCE_M` to spare; the ego heads away from it), a standing vehicle
of the ego's size, id ``<ego>.shadow``, is placed on that neighbour lane with its front
where the ego's body reaches furthest along it. SUMO's drivers brake for it as for any
standing car (car following, lane changing, insertion). It is taken out when the ego is
faster than :data:`RELEASE_SPEED_MPS` or no longer blocks the lane. Not modelled (open): a
body reaching into the lane the ego heads for (its merge: the ego waits for a gap there;
a shadow made SUMO's drivers wait for the ego, the ego for them - eoa seed 3 stood 180 s),
a fast ego's footprint on two lanes (the ego passes through in ~1-2 s; the ego's own MPC
keeps its gaps there), and the body across a junction's internal lanes (SUMO's junction
logic handles the foes there).

The shadow is not traffic: the bridge leaves it out of observations, collisions, the
insertion guard and the entry count; a vehicle held down by it counts as held down by the
ego (``ineff``). Deterministic: no random number is drawn for it (its type copies the
ego's, which has no speed deviation drawn at insertion: the bridge places it at speed 0
with ``moveTo``). Plain Python geometry on the map's lane centrelines.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

from lmpc_bridge.geometry import OrientedBox

MAX_SPEED_MPS = 2.0
"""The ego is slow enough for a shadow (m/s): standing or creeping."""
RELEASE_SPEED_MPS = 3.0
"""Above this speed an existing shadow is taken out (hysteresis over MAX_SPEED_MPS)."""
CAR_WIDTH_M = 1.8
"""Width of the car the neighbour lane is kept passable for (SUMO drives it centred)."""
CLEARANCE_M = 0.2
"""The body blocks the neighbour lane when a car of CAR_WIDTH_M centred in it would pass
the body closer than this: depth into the lane > (lane width - CAR_WIDTH_M) / 2 -
CLEARANCE_M (0.5 m in a 3.2 m lane), and at least MIN_INTRUSION_M."""
MIN_INTRUSION_M = 0.1
LEAVING_YAW_RAD = 0.02
"""The ego is leaving the neighbour lane when its heading points away from it by more than
this (relative to its own lane's direction)."""
SHADOW_TYPE = "ego_shadow_type"

_LOG = logging.getLogger(__name__)


def shadow_id(ego_id: str) -> str:
    return f"{ego_id}.shadow"


@dataclass(frozen=True)
class LaneShape:
    """What the shadow needs of a lane: id, edge, index, centreline, width, neighbours."""

    id: str
    edge_id: str
    index: int
    centerline: tuple[tuple[float, float], ...]
    width_m: float
    length_m: float
    left: Optional[str]
    right: Optional[str]
    internal: bool


def lane_shapes(lanes: Sequence[Any]) -> dict[str, LaneShape]:
    """From the map's lanes (:class:`lmpc_msgs_py.messages.Lane`)."""
    out = {}
    for ln in lanes:
        out[ln.id] = LaneShape(id=ln.id, edge_id=ln.edge_id, index=ln.index,
                               centerline=tuple((float(x), float(y)) for x, y in ln.centerline),
                               width_m=ln.width_m, length_m=ln.length_m, left=ln.left_lane,
                               right=ln.right_lane, internal=ln.internal)
    return out


def _station(pt: tuple[float, float], line: Sequence[tuple[float, float]]
             ) -> tuple[float, float, float]:
    """(arc length of the nearest centreline point, distance to it, the centreline's
    direction there, rad)."""
    best_d, best_s, best_dir, s0 = math.inf, 0.0, 0.0, 0.0
    for (ax, ay), (bx, by) in zip(line[:-1], line[1:]):
        dx, dy = bx - ax, by - ay
        seg = math.hypot(dx, dy)
        if seg > 0.0:
            t = max(0.0, min(1.0, ((pt[0] - ax) * dx + (pt[1] - ay) * dy) / (seg * seg)))
            d = math.hypot(pt[0] - ax - t * dx, pt[1] - ay - t * dy)
            if d < best_d:
                best_d, best_s, best_dir = d, s0 + t * seg, math.atan2(dy, dx)
        s0 += seg
    return best_s, best_d, best_dir


def _body_points(box: OrientedBox) -> list[tuple[float, float]]:
    """Corners and side / end midpoints of the box."""
    c = box.corners()
    mids = [((c[i][0] + c[(i + 1) % 4][0]) / 2.0, (c[i][1] + c[(i + 1) % 4][1]) / 2.0)
            for i in range(4)]
    return [*c, *mids]


def blocking_depth_m(lane_width_m: float) -> float:
    """How far into a lane of that width the body blocks it (see CLEARANCE_M)."""
    return max((lane_width_m - CAR_WIDTH_M) / 2.0 - CLEARANCE_M, MIN_INTRUSION_M)


def intrusion(box: OrientedBox, ego_lane: Optional[str], lanes: Mapping[str, LaneShape]
              ) -> Optional[tuple[str, float]]:
    """(neighbour lane, position of the body's front along it) when the box blocks a
    neighbour lane of ``ego_lane`` that the ego is leaving: it reaches
    :func:`blocking_depth_m` past the lane's border and the ego heads away from it (its
    heading, relative to its own lane, turned away by more than :data:`LEAVING_YAW_RAD`).
    A body that reaches into the lane the ego heads for is the ego's merge, not a
    shadow: the ego waits for its gap there (SUMO's drivers would wait for a standing
    shadow, and the two would wait for each other)."""
    here = lanes.get(ego_lane or "")
    if here is None or here.internal or len(here.centerline) < 2:
        return None
    _, _, lane_dir = _station((box.x_m, box.y_m), here.centerline)
    rel = math.remainder(box.yaw_rad - lane_dir, 2.0 * math.pi)  # > 0: heading left
    leaving = ([here.right] if rel > LEAVING_YAW_RAD else
               [here.left] if rel < -LEAVING_YAW_RAD else [])
    pts = _body_points(box)
    for nb_id in leaving:
        nb = lanes.get(nb_id or "")
        if nb_id is None or nb is None or len(nb.centerline) < 2:
            continue
        limit = nb.width_m / 2.0 - blocking_depth_m(nb.width_m)
        inside = [(s, d) for s, d, _ in (_station(p, nb.centerline) for p in pts) if d <= limit]
        if inside:
            return nb_id, max(s for s, _ in inside)
    return None


@dataclass
class EgoShadow:
    """One ego's shadow in SUMO (see module docstring)."""

    ego_id: str
    lane_id: Optional[str] = None
    """The lane the shadow stands on (None: not in the simulation)."""
    pos_m: float = 0.0
    placements: int = 0
    """How often a shadow was put into the simulation (inserted into SUMO)."""
    refused: bool = False
    """SUMO refused a placement or move: no shadow for the rest of the episode."""
    log: list[str] = field(default_factory=list)

    @property
    def vehicle_id(self) -> str:
        return shadow_id(self.ego_id)

    def copy(self) -> "EgoShadow":
        return EgoShadow(ego_id=self.ego_id, lane_id=self.lane_id, pos_m=self.pos_m,
                         placements=self.placements, refused=self.refused, log=list(self.log))

    def update(self, traci: Any, box: OrientedBox, v_mps: float, ego_lane: Optional[str],
               lanes: Mapping[str, LaneShape], *, now_s: float) -> None:
        """Place, move or take out the shadow for the ego's box (after the ego's move
        was sent, before the simulation step). A SUMO refusal (e.g. the lane cannot take
        it) is logged and the shadow given up for the rest of the episode: it never ends
        the episode."""
        if self.refused:
            return
        try:
            self._update(traci, box, v_mps, ego_lane, lanes, now_s)
        except Exception as exc:  # noqa: BLE001 - libsumo raises its own types
            self._remove(traci, now_s, f"SUMO refused it: {exc}; no shadow in this episode")
            self.refused = True

    def _update(self, traci: Any, box: OrientedBox, v_mps: float, ego_lane: Optional[str],
                lanes: Mapping[str, LaneShape], now_s: float) -> None:
        limit = RELEASE_SPEED_MPS if self.lane_id is not None else MAX_SPEED_MPS
        want = intrusion(box, ego_lane, lanes) if v_mps <= limit else None
        if want is None:
            if self.lane_id is not None:
                self._remove(traci, now_s, "the ego is in one lane" if v_mps <= limit
                             else f"the ego moves at {v_mps:.1f} m/s")
            return
        lane_id, front_m = want
        lane = lanes[lane_id]
        pos = min(max(front_m, 0.1), lane.length_m)
        if self.lane_id is not None and lanes[self.lane_id].edge_id != lane.edge_id:
            self._remove(traci, now_s, "the ego's lane changed edge")
        vid = self.vehicle_id
        new = self.lane_id is None
        if new:
            _ensure_type(traci)
            route = f"r_{vid}_{lane.edge_id}"
            if route not in traci.route.getIDList():
                traci.route.add(route, [lane.edge_id])
            traci.vehicle.add(vid, route, typeID=SHADOW_TYPE, depart="now",
                              departLane=str(lane.index), departPos=f"{pos:.3f}",
                              departSpeed="0")
            self.lane_id = lane_id  # in SUMO now (a refusal below takes it out again)
            traci.vehicle.setSpeedMode(vid, 0)
            traci.vehicle.setLaneChangeMode(vid, 0)
        traci.vehicle.moveTo(vid, lane_id, pos)  # a pending shadow is inserted here
        traci.vehicle.setSpeed(vid, 0.0)
        self.lane_id, self.pos_m = lane_id, pos
        if new:
            self.placements += 1
            self._note(f"{now_s:.1f} s: {vid} placed on {lane_id} at {pos:.1f} m (the ego "
                       f"stands across two lanes)")

    def restore(self, traci: Any) -> None:
        """After SUMO restarted on a saved state: the shadow's TraCI settings again."""
        if self.lane_id is not None and self.vehicle_id in traci.vehicle.getIDList():
            traci.vehicle.setSpeedMode(self.vehicle_id, 0)
            traci.vehicle.setLaneChangeMode(self.vehicle_id, 0)

    def take_out(self, traci: Any, now_s: float, why: str) -> None:
        """Remove the shadow from the simulation (e.g. its ego left the episode)."""
        if self.lane_id is not None:
            self._remove(traci, now_s, why)

    def _remove(self, traci: Any, now_s: float, why: str) -> None:
        try:
            traci.vehicle.remove(self.vehicle_id)
        except Exception:  # noqa: BLE001 - already gone (e.g. arrived): nothing to take out
            pass
        self._note(f"{now_s:.1f} s: {self.vehicle_id} taken out ({why})")
        self.lane_id = None

    def _note(self, line: str) -> None:
        self.log.append(line)
        _LOG.info(line)


def _ensure_type(traci: Any) -> None:
    if SHADOW_TYPE not in traci.vehicletype.getIDList():
        traci.vehicletype.copy("ego_type", SHADOW_TYPE)
        traci.vehicletype.setSpeedDeviation(SHADOW_TYPE, 0.0)
        traci.vehicletype.setImperfection(SHADOW_TYPE, 0.0)
