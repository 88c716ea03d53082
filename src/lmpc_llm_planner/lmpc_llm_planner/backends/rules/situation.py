"""Rule 11: situational text of the user (``instruction.py``; docs/lmpc_rules.md) that the
speed rules take in, run last so it only ever LOWERS the acceleration bias the other rules
chose (never a faster or a later stop):

- pedestrians crossing at the next junction: approach it at most
  ``PEDESTRIAN_APPROACH_MPS`` (the safety weight high) from ``PEDESTRIAN_LOOKAHEAD_M``
  before its stop line; no junction ahead within that (a motorway, the junction passed):
  the reasoning says the text does not apply yet;
- an emergency vehicle to make room for: the lane rule moves to the kerb lane on a
  multi-lane road; where the road has no lane to give (a single lane, or the route needs
  the inner lane) the ego slows to ``MAKE_ROOM_FRACTION`` of the limit;
- a closed lane on a road with one lane: nothing to do, said in the reasoning.

"The next junction" is an APPROXIMATION: the first stop line along the route ahead where
lanes of two or more edges meet, the light is signalized, or the lane offers two or more
directions (a plain join of two road pieces is not one)."""
from __future__ import annotations

from typing import Optional

from lmpc_msgs_py.messages import Lane, StopLine

from lmpc_llm_planner.scene import Scene

from .intervals import brake_index, mid, mildest_accel, neutral
from .plan import Plan, RuleInputs

PEDESTRIAN_APPROACH_MPS = 4.0
"""The speed (m/s, ~15 km/h) the ego approaches a junction with pedestrians crossing."""
PEDESTRIAN_LOOKAHEAD_M = 60.0
"""From this far before the junction's stop line (along the route)."""
MAKE_ROOM_FRACTION = 0.6
"""Making room with no lane to give: at most this fraction of the speed limit."""
_SLOWING_MARGIN_M = 5.0
"""The approach speed is reached this far before the stop line."""


def situation_rule(inp: RuleInputs, plan: Plan) -> None:
    """Take the situational parts of the instruction into the plan (see the module)."""
    intent = inp.intent
    scene = inp.scene
    here = scene.lanes.get(scene.obs.ego.lane_id or "")
    if intent.pedestrians_ahead:
        _pedestrians(inp, plan, here)
    if intent.make_room and here is not None and not here.internal:
        if len(scene.edge_lanes(here)) < 2 or _kept_inner_lane(inp, plan, here):
            limit = here.speed_limit_mps
            _cap_speed(inp, plan, MAKE_ROOM_FRACTION * limit, None)
            plan.notes.append("The user asks me to make room for an emergency vehicle; "
                              "there is no lane to give here, so I slow down to "
                              f"{MAKE_ROOM_FRACTION * limit:.0f} m/s.")
    if intent.closed_sides and here is not None and not here.internal \
            and len(scene.edge_lanes(here)) < 2:
        plan.notes.append("The user says a lane is closed; my road has one lane here, so "
                          "that changes nothing yet.")


def _pedestrians(inp: RuleInputs, plan: Plan, here: Optional[Lane]) -> None:
    ahead = next_junction_m(inp.scene) if here is not None and not here.internal else None
    if ahead is None:
        plan.notes.append("The user says pedestrians are crossing at the next junction; "
                          f"there is none within {PEDESTRIAN_LOOKAHEAD_M:.0f} m ahead, so "
                          "that changes nothing yet.")
        return
    plan.weights["safety"] = "high"
    _cap_speed(inp, plan, PEDESTRIAN_APPROACH_MPS, ahead)
    plan.notes.append(f"Pedestrians are crossing at the junction {ahead:.0f} m ahead (the "
                      f"user says), so I approach it at {PEDESTRIAN_APPROACH_MPS:.0f} m/s "
                      "at most.")


def _cap_speed(inp: RuleInputs, plan: Plan, cap_mps: float, dist_m: Optional[float]) -> None:
    """Lower the plan's acceleration bias so the ego is at ``cap_mps`` ``dist_m`` ahead
    (less the margin; None: soon, at the mildest braking)."""
    accel = inp.accel
    v = inp.scene.obs.ego.v_mps
    if v > cap_mps:
        d = max(1.0, (dist_m if dist_m is not None else 0.0) - _SLOWING_MARGIN_M)
        need = (v * v - cap_mps * cap_mps) / (2.0 * d) if dist_m is not None else 0.0
        idx = brake_index(accel, need, hold=need <= 0.0)
    elif v > 0.8 * cap_mps:
        idx = neutral(accel)
    else:
        idx = mildest_accel(accel)
    if mid(accel[idx]) < mid(accel[plan.accel_index]):
        plan.accel_index = idx


def _kept_inner_lane(inp: RuleInputs, plan: Plan, here: Lane) -> bool:
    """On an inner lane and not moving to the kerb (the route needs the lane, or no gap)."""
    if here.index == 0:
        return False
    cand = plan.ego_index if plan.ego_index is not None else inp.scene.route_candidate_id
    if not inp.scene.ego_candidates:
        return True
    ids = inp.scene.ego_candidates[cand].lane_ids
    first = inp.scene.lanes.get(ids[0]) if ids else None
    return first is None or first.index >= here.index


def next_junction_m(scene: Scene) -> Optional[float]:
    """Distance (m, along the route) to the stop line of the next junction ahead within
    ``PEDESTRIAN_LOOKAHEAD_M`` (see the module doc), or None."""
    obs = scene.obs
    ego = obs.ego
    route = obs.map.ego_route
    incoming: dict[str, set[str]] = {}
    stops: dict[str, StopLine] = {}
    for sl in obs.map.stop_lines:
        lane = scene.lanes.get(sl.lane_id)
        if lane is not None:
            incoming.setdefault(sl.junction_id, set()).add(lane.edge_id)
            stops[sl.lane_id] = sl
    dist = 0.0
    start = ego.route_index if 0 <= ego.route_index < len(route) else 0
    for k, lid in enumerate(route[start:]):
        lane = scene.lanes.get(lid)
        if lane is None:
            return None
        dist += lane.length_m - (ego.lane_pos_m if k == 0 else 0.0)
        if dist > PEDESTRIAN_LOOKAHEAD_M:
            return None
        stop = stops.get(lid)
        if stop is not None and (stop.signalized or len(incoming[stop.junction_id]) >= 2
                                 or len({lk.direction for lk in lane.successors}) >= 2):
            return max(0.0, dist)
    return None
