"""The other road users as the bridge sees them: one SUMO context-subscription entry
converted to our frame (:class:`Seen`), and which of them the ego holds down (the
``affected`` flags of the per-step record that ``metrics.step_ineff`` counts).

Shared by the single-ego :class:`lmpc_bridge.sim.SumoSim` and the multi-ego
:class:`lmpc_bridge.multi_sim.MultiSumoSim`, so both count penalties alike.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import traci.constants as tc

from lmpc_bridge.dynamics import wrap_angle_rad
from lmpc_bridge.geometry import OrientedBox, box_gap_m
from lmpc_bridge.record import NearbyVehicle
from lmpc_bridge.shadow import shadow_id

MAX_AGENT_ACCEL_MPS2 = 15.0
AFFECTED_RADIUS_M = 50.0
RED_LIGHT_RADIUS_M = 30.0
"""An affected vehicle whose next light within this distance is red / yellow is not counted."""

VEHICLE_VARS = (
    tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_ACCELERATION, tc.VAR_LENGTH,
    tc.VAR_WIDTH, tc.VAR_LANE_ID, tc.VAR_LANEPOSITION, tc.VAR_SIGNALS, tc.VAR_VEHICLECLASS,
    tc.VAR_ALLOWED_SPEED, tc.VAR_MAXSPEED,
)
PERSON_VARS = (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_LANE_ID,
               tc.VAR_LANEPOSITION)
_PERSON_LENGTH_M, _PERSON_WIDTH_M = 0.5, 0.5  # the subscription cannot give a person's size

# getSignals bits (SUMO TraCI docs, "signalling")
SIG_RIGHT, SIG_LEFT, SIG_BRAKE = 1 << 0, 1 << 1, 1 << 3

_KIND_BY_VCLASS = {
    "passenger": "car", "private": "car", "taxi": "car", "evehicle": "car", "emergency": "car",
    "authority": "car", "army": "car", "vip": "car", "custom1": "car", "custom2": "car",
    "truck": "truck", "trailer": "truck", "delivery": "truck",
    "bus": "bus", "coach": "bus", "tram": "bus",
    "motorcycle": "motorcycle", "moped": "motorcycle",
    "bicycle": "bicycle", "pedestrian": "pedestrian",
}


def clip(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def yaw_from_sumo_angle(angle_deg: float) -> float:
    """SUMO angle (degrees clockwise from north) -> yaw (rad counter-clockwise from east)."""
    return wrap_angle_rad(math.radians(90.0 - angle_deg))


def sumo_angle_from_yaw(yaw_rad: float) -> float:
    return (90.0 - math.degrees(yaw_rad)) % 360.0


@dataclass(frozen=True)
class Seen:
    """One participant as the context subscription reports it (converted to our frame)."""

    id: str
    kind: str
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    a_mps2: float
    length_m: float
    width_m: float
    lane_id: str | None
    lane_pos_m: float
    signals: int
    v_max_mps: float

    def box(self) -> OrientedBox:
        return OrientedBox(self.x_m, self.y_m, self.yaw_rad, self.length_m, self.width_m)


def convert(vid: str, vals: dict[int, Any]) -> Seen:
    """One subscription entry (vehicle or person) in our frame: the box centre (SUMO
    reports the front bumper), yaw, kind from the vehicle class, the allowed speed."""
    is_vehicle = tc.VAR_VEHICLECLASS in vals
    yaw = yaw_from_sumo_angle(float(vals.get(tc.VAR_ANGLE, 90.0)))
    if is_vehicle:
        length = float(vals.get(tc.VAR_LENGTH, 4.5))
        width = float(vals.get(tc.VAR_WIDTH, 1.8))
        kind = _KIND_BY_VCLASS.get(str(vals.get(tc.VAR_VEHICLECLASS, "")), "car")
        accel = float(vals.get(tc.VAR_ACCELERATION, 0.0))
        signals = int(vals.get(tc.VAR_SIGNALS, 0))
        v_max = min(float(vals.get(tc.VAR_ALLOWED_SPEED, 0.0)),
                    float(vals.get(tc.VAR_MAXSPEED, 70.0)))
    else:
        length, width, kind = _PERSON_LENGTH_M, _PERSON_WIDTH_M, "pedestrian"
        accel, signals = 0.0, 0
        v_max = 1.5
    fx, fy = vals[tc.VAR_POSITION]
    x = fx - length / 2.0 * math.cos(yaw)
    y = fy - length / 2.0 * math.sin(yaw)
    lane = vals.get(tc.VAR_LANE_ID) or None
    return Seen(id=vid, kind=kind, x_m=x, y_m=y, yaw_rad=yaw,
                v_mps=float(vals.get(tc.VAR_SPEED, 0.0)),
                a_mps2=clip(accel, -MAX_AGENT_ACCEL_MPS2, MAX_AGENT_ACCEL_MPS2),
                length_m=length, width_m=width, lane_id=lane,
                lane_pos_m=float(vals.get(tc.VAR_LANEPOSITION, 0.0)),
                signals=signals, v_max_mps=v_max)


def nearby_records(traci: Any, ego_id: str, seen: Mapping[str, Seen], ego_box: OrientedBox,
                   *, foes_query: bool = True) -> tuple[NearbyVehicle, ...]:
    """Every participant in sensing range with its gap to the ego's box and its
    ``affected`` flag (:func:`affected_vehicles`), sorted by id."""
    gaps = {vid: box_gap_m(ego_box, s.box()) for vid, s in seen.items()}
    affected = affected_vehicles(traci, ego_id, seen, gaps, foes_query=foes_query)
    return tuple(
        NearbyVehicle(id=s.id, kind=s.kind, x_m=s.x_m, y_m=s.y_m, yaw_rad=s.yaw_rad,
                      v_mps=s.v_mps, v_max_mps=s.v_max_mps, a_mps2=s.a_mps2,
                      gap_m=gaps[s.id], affected=s.id in affected,
                      affected_reason=affected.get(s.id, ""),
                      at_red_light=s.id in affected and at_red_light(traci, s.id),
                      length_m=s.length_m, width_m=s.width_m)
        for s in sorted(seen.values(), key=lambda s: s.id)
    )


def affected_vehicles(traci: Any, ego_id: str, seen: Mapping[str, Seen],
                      gaps: Mapping[str, float], *, foes_query: bool = True) -> dict[str, str]:
    """Vehicles whose speed the ego holds down (for ``ineff``), with the reason.

    - ``follower``: SUMO's follower of the ego within 50 m;
    - ``leader``: vehicles within 50 m whose car-following leader is the ego;
    - ``yielding``: junction foes of the ego within 50 m (SUMO ``getJunctionFoes``)
      that are braking (a < -0.5 m/s²) or slow (v < 0.5 v_max) with no other
      leader within 30 m, i.e. nothing but the ego explains their slowing.
    Vehicles at a red / yellow light within 30 m stay flagged here and are marked
    ``at_red_light`` in the record; ``metrics.step_ineff`` leaves them out.
    ``foes_query=False`` skips the junction foes (libsumo 1.28 crashes in
    ``getJunctionFoes`` at an "unregulated" junction).
    """
    out: dict[str, str] = {}
    try:
        follower = traci.vehicle.getFollower(ego_id, AFFECTED_RADIUS_M)
        if follower and follower[0] and follower[0] in seen:
            out[follower[0]] = "follower"
    except Exception:  # noqa: BLE001 - off-network ego has no follower
        pass
    for vid, gap in gaps.items():
        if vid in out or gap > AFFECTED_RADIUS_M or seen[vid].kind == "pedestrian":
            continue
        if leader_of(traci, vid, AFFECTED_RADIUS_M) in (ego_id, shadow_id(ego_id)):
            out[vid] = "leader"
    try:
        foes = traci.vehicle.getJunctionFoes(ego_id, AFFECTED_RADIUS_M) if foes_query else ()
    except Exception:  # noqa: BLE001
        foes = ()
    for foe in foes:
        vid = foe[0]
        s = seen.get(vid)
        if s is None or vid in out:
            continue
        slowing = s.a_mps2 < -0.5 or s.v_mps < 0.5 * s.v_max_mps
        if slowing and leader_of(traci, vid, 30.0) in (None, ego_id):
            out[vid] = "yielding"
    return out


def leader_of(traci: Any, vid: str, dist_m: float) -> str | None:
    try:
        leader = traci.vehicle.getLeader(vid, dist_m)
    except Exception:  # noqa: BLE001
        return None
    return leader[0] if leader and leader[0] else None


def at_red_light(traci: Any, vid: str) -> bool:
    try:
        upcoming = traci.vehicle.getNextTLS(vid)
    except Exception:  # noqa: BLE001
        return False
    return bool(upcoming) and upcoming[0][2] <= RED_LIGHT_RADIUS_M \
        and upcoming[0][3] in "rRyYu"


def foes_query_ok(net: Any, route_edges: Any) -> bool:
    """False when the route ends at an "unregulated" junction (no right-of-way data,
    e.g. netgenerate --spider centres), where libsumo 1.28 crashes (SIGSEGV) in
    ``getJunctionFoes``."""
    return not any((net.getEdge(e).getToNode().getType() or "") == "unregulated"
                   for e in route_edges)
