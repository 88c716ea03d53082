"""Insertion guard: SUMO never inserts a vehicle into the ego's body (issue 23).

SUMO knows an externally moved ego only on the one lane ``moveToXY`` mapped it to. Half-way
through a lane change the ego's body covers two lanes, and SUMO sees the other one free: a
vehicle waiting to depart there (a scene's initial vehicle SUMO could not insert at t = 0
and kept pending, or a flow's vehicle) is inserted where the ego is (lane 104 at 5 s
latency: the truck ``v11``, pending for 8.2 s, inserted on the ego's body).

The guard works on what SUMO did in a step, so it covers every way of departing (initial
placement, later departures, flows, external traffic files) with the same code:

- **hold** (after each ``simulationStep``): every vehicle SUMO inserted in that step
  (``simulation.getDepartedIDList``) whose box overlaps an ego's box grown by
  :data:`MARGIN_M` ahead and behind, :data:`MARGIN_LAT_M` on each side and
  :data:`HEADWAY_S` x the ego's speed ahead is taken out again (``vehicle.remove``). SUMO
  inserts vehicles at the very end of a step, after every vehicle moved and changed lanes,
  so no driver has reacted to it yet; the bridge reads its observation after the hold, so
  the ego never sees it either. The guard keeps what re-adds it: the rest of its route,
  its type, lane, position (front bumper), speed, speed factor and stops.
- **release** (before each ``simulationStep``, after the egos were moved): a held vehicle
  whose insertion box is clear of every (grown) ego box is added again with ``depart=
  "now"``, the same id and all of the above; SUMO inserts it in that step when its own
  insertion checks pass (else it waits in SUMO's queue like any pending vehicle, and the
  hold applies again if it is later inserted into an ego).

Deterministic: the order is SUMO's departure order and the held vehicles' ids, no
randomness is drawn (the re-added vehicle keeps its speed factor; SUMO draws nothing else
for it at insertion for a fixed lane, position and speed). ``held_insertions`` counts
hold events (a vehicle held, released and held again counts twice). Persons are not
guarded (SUMO inserts them on sidewalks and crossings; open).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Container, Mapping

from lmpc_bridge.geometry import OrientedBox, boxes_overlap
from lmpc_bridge.participants import yaw_from_sumo_angle

MARGIN_M = 1.5
"""Clearance (m) added ahead of and behind an ego's box for the overlap test."""
MARGIN_LAT_M = 0.3
"""Clearance (m) added on each side of an ego's box: small, so a vehicle inserted in the
next lane beside an ego centred in its own lane (3.2 m lanes: 1.05 m between a truck and
the ego) is not held."""
HEADWAY_S = 1.0
"""An ego's box is also grown ahead by this time at its speed (a vehicle standing 5 m in
front of an ego at 10 m/s cannot be avoided either)."""

_LOG = logging.getLogger(__name__)


def guard_box(x_m: float, y_m: float, yaw_rad: float, length_m: float, width_m: float,
              v_mps: float) -> OrientedBox:
    """An ego's box (centre ``x_m``, ``y_m``) grown by the margins above."""
    ahead = MARGIN_M + HEADWAY_S * max(v_mps, 0.0)
    shift = (ahead - MARGIN_M) / 2.0
    return OrientedBox(x_m + shift * math.cos(yaw_rad), y_m + shift * math.sin(yaw_rad),
                       yaw_rad, length_m + MARGIN_M + ahead, width_m + 2.0 * MARGIN_LAT_M)


@dataclass(frozen=True)
class HeldVehicle:
    """A vehicle taken back after its insertion into an ego, and how to add it again."""

    vehicle_id: str
    edges: tuple[str, ...]
    type_id: str
    lane_index: int
    lane_id: str
    pos_m: float
    speed_mps: float
    speed_factor: float
    stops: tuple[tuple[str, float, int, float, int, float, float], ...]
    """(edge, end position, lane index, duration, flags, start position, until) each."""
    box: OrientedBox
    held_at_s: float
    egos: tuple[str, ...] = ()
    """The egos whose (grown) box it overlapped."""


@dataclass
class InsertionGuard:
    """The held vehicles of one episode and the hold events so far (see module docstring)."""

    held: dict[str, HeldVehicle] = field(default_factory=dict)
    count: int = 0
    by_ego: dict[str, int] = field(default_factory=dict)
    """Hold events per ego whose (grown) box the insertion overlapped."""
    log: list[tuple[str, tuple[str, ...]]] = field(default_factory=list)
    """(line, egos concerned) per hold and per release."""

    def copy(self) -> "InsertionGuard":
        return InsertionGuard(held=dict(self.held), count=self.count, by_ego=dict(self.by_ego),
                              log=list(self.log))

    def lines(self, ego_id: str | None = None) -> tuple[str, ...]:
        """The log lines (of holds and releases concerning ``ego_id``; None: all)."""
        return tuple(line for line, egos in self.log if ego_id is None or ego_id in egos)

    def _note(self, line: str, egos: tuple[str, ...]) -> None:
        self.log.append((line, egos))
        _LOG.info(line)

    def hold_overlapping(self, traci: Any, ego_boxes: Mapping[str, OrientedBox], *,
                         now_s: float, skip: Container[str] = ()) -> list[str]:
        """After a step: take out the vehicles inserted in it that overlap a (grown) ego
        box (``ego_boxes``: ego id -> its grown box); returns their ids."""
        departed = [v for v in traci.simulation.getDepartedIDList() if v not in skip]
        out = []
        for vid in departed:
            box = _box_of(traci, vid)
            egos = [eid for eid, g in sorted(ego_boxes.items()) if boxes_overlap(g, box)]
            if not egos:
                continue
            held = _capture(traci, vid, box, now_s, tuple(egos))
            traci.vehicle.remove(vid)
            self.held[vid] = held
            self.count += 1
            for eid in egos:
                self.by_ego[eid] = self.by_ego.get(eid, 0) + 1
            line = (f"{now_s:.1f} s: held {vid} ({held.type_id}) back, SUMO inserted it at "
                    f"{held.pos_m:.1f} m on {held.lane_id}, on the body of "
                    f"{', '.join(egos)}")
            self._note(line, held.egos)
            out.append(vid)
        return out

    def release_clear(self, traci: Any, ego_boxes: Mapping[str, OrientedBox], *,
                      now_s: float) -> list[str]:
        """Before a step (egos moved): add again the held vehicles whose spot is clear of
        every (grown) ego box; returns their ids."""
        out = []
        for vid in sorted(self.held):
            h = self.held[vid]
            if any(boxes_overlap(g, h.box) for g in ego_boxes.values()):
                continue
            _re_add(traci, h)
            del self.held[vid]
            line = f"{now_s:.1f} s: released {vid} (held {now_s - h.held_at_s:.1f} s)"
            self._note(line, h.egos)
            out.append(vid)
        return out


def _box_of(traci: Any, vid: str) -> OrientedBox:
    fx, fy = traci.vehicle.getPosition(vid)
    yaw = yaw_from_sumo_angle(traci.vehicle.getAngle(vid))
    length = float(traci.vehicle.getLength(vid))
    return OrientedBox(fx - length / 2.0 * math.cos(yaw), fy - length / 2.0 * math.sin(yaw),
                       yaw, length, float(traci.vehicle.getWidth(vid)))


def _capture(traci: Any, vid: str, box: OrientedBox, now_s: float,
             egos: tuple[str, ...]) -> HeldVehicle:
    v = traci.vehicle
    route = tuple(v.getRoute(vid))[int(v.getRouteIndex(vid)):]
    stops = tuple(
        (str(s.lane).rsplit("_", 1)[0], float(s.endPos), int(str(s.lane).rsplit("_", 1)[1]),
         float(s.duration), int(s.stopFlags), float(s.startPos), float(s.until))
        for s in v.getStops(vid))
    return HeldVehicle(
        vehicle_id=vid, edges=route, type_id=str(v.getTypeID(vid)),
        lane_index=int(v.getLaneIndex(vid)), lane_id=str(v.getLaneID(vid)),
        pos_m=float(v.getLanePosition(vid)), speed_mps=float(v.getSpeed(vid)),
        speed_factor=float(v.getSpeedFactor(vid)), stops=stops, box=box, held_at_s=now_s,
        egos=egos)


def _re_add(traci: Any, h: HeldVehicle) -> None:
    route_id = f"!held!{h.vehicle_id}"
    try:
        traci.route.add(route_id, list(h.edges))
    except Exception:  # noqa: BLE001 - held before: the route exists (the same edges)
        pass
    v = traci.vehicle
    v.add(h.vehicle_id, route_id, typeID=h.type_id, depart="now",
          departLane=str(h.lane_index), departPos=f"{h.pos_m:.3f}",
          departSpeed=f"{h.speed_mps:.3f}")
    v.setSpeedFactor(h.vehicle_id, h.speed_factor)
    for edge, end, lane, duration, flags, start, until in h.stops:
        v.setStop(h.vehicle_id, edge, pos=end, laneIndex=lane, duration=duration,
                  flags=flags, startPos=start, until=until)
