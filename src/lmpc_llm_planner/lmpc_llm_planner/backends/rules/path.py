"""The rules of the ego's own path: brake for an agent in it (rule 5), else go (rule 6).

Rule 5: an agent in the ego's path ahead (within the corridor of the chosen candidate)
that it closes in on (TTC under ``path_ttc_s``, ``commit_ttc_s`` in a committed turn), or
a standing / hard-braking vehicle in its lane (not a queue) -> a braking bias, safety
"high"; for a standing vehicle the ego stops about ``STANDOFF_M`` behind where it will
stand (room to steer round it). Traffic that only passes near the path (an oncoming car
in its own lane) is the turn rule's business.
Rule 6: otherwise go: accelerating (below 80 % of the speed limit) or neutral bias,
normal weights; close behind a leader in the path the MPC follows it on its own (hold,
creep, or stop short of a standing one)."""
from __future__ import annotations

import math
from typing import Optional

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_llm_planner.route import Maneuver, next_maneuver
from lmpc_llm_planner.scene import AgentView

from .emergency import brake_hard, brakes_hard
from .intervals import accel_index, brake_index, mildest_accel, neutral, stop_index
from .headway import slower_leader_in_change, wanted_gap_m
from .lane import beside_in_route_lane
from .plan import Plan, RuleInputs, changing_lanes, chosen_candidate
from .scene_helpers import (
    ALONG_RAD, HARD_BRAKE_MPS2, STANDOFF_M, distance_to_path, other_lane, queued_at_junction,
    route_path,
)

AGGRESSIVE_SPEED_FRACTION = 0.95
"""Aggressive style: on a clear way the ego speeds up until this fraction of the limit
(normal: 0.8) with ``AGGRESSIVE_ACCEL_MPS2``; the MPC's speed and control bounds apply."""
AGGRESSIVE_ACCEL_MPS2 = 2.0
CONSERVATIVE_SPEED_FRACTION = 0.65
"""Conservative style: on a clear way the ego speeds up only below this fraction of the
limit, holds up to 10 points above it and brakes mildly beyond (a slower approach)."""
BRISK_LATERAL_M = 5.0
"""Vehicles ahead / beside within this lateral offset (the ego's and the next lanes) must
leave the aggressive speed-up its headway gap (``clear_for_brisk``)."""
FOLLOWER_HEADWAY_S = 1.5
"""Conservative slowing needs no vehicle behind in the ego's lane closer than this
(at that vehicle's speed)."""


def path_threats(inp: RuleInputs, plan: Plan, *, committed: bool
                 ) -> tuple[list[AgentView], dict[str, float]]:
    """The agents in the chosen path the ego must brake for, and for those it should stop
    behind (standing or braking hard) the distance to that stop (id -> m)."""
    cfg = inp.cfg
    scene = inp.scene
    ego = scene.obs.ego
    path = route_path(scene, plan.ego_index)
    changing = changing_lanes(scene, plan)
    threats = []
    standoff: dict[str, float] = {}
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m <= 0.0:
            continue
        # a standing vehicle (a breakdown, not a queue) in my own lane, or one braking
        # hard towards a standstill: stop far enough behind where it will stand to
        # steer round it later (the constant-velocity TTC sees a braking car late)
        stopping = v.agent.v_mps < cfg.moving_speed_mps or \
            v.agent.a_mps2 < -HARD_BRAKE_MPS2
        stand = not changing and stopping and abs(k.heading_rel_rad) < ALONG_RAD and \
            not queued_at_junction(scene, v) and not other_lane(scene, v)
        if k.ttc_s is None and not stand:
            continue
        if path is not None:
            corridor = 0.5 * (ego.width_m + v.agent.width_m) + cfg.path_corridor_m
            if distance_to_path(path, v.agent.x_m, v.agent.y_m) > corridor:
                continue
        limit = cfg.path_ttc_s if not committed else cfg.commit_ttc_s
        stop_gap = k.gap_m - STANDOFF_M
        if v.agent.v_mps >= cfg.moving_speed_mps:
            stop_gap += v.agent.v_mps ** 2 / (2.0 * max(-v.agent.a_mps2, HARD_BRAKE_MPS2))
        short = stand and ego.v_mps >= cfg.moving_speed_mps and \
            stop_gap < ego.v_mps ** 2 / (2.0 * 2.0) + 1.5 * ego.v_mps
        if k.ttc_s is not None and k.ttc_s < limit:
            threats.append(v)
            if short:
                # closing in on a car braking hard: the constant-velocity TTC
                # underrates the braking needed (eoa seed 121 ended 4 m behind the
                # hazard, too close to steer round): brake for where it will stand
                # when that needs more
                need_ttc = k.closing_speed_mps ** 2 / (2.0 * max(k.gap_m - 2.0, 0.5))
                if ego.v_mps ** 2 / (2.0 * max(stop_gap, 0.5)) > need_ttc:
                    standoff[v.id] = stop_gap
        elif short:
            threats.append(v)
            standoff[v.id] = stop_gap
    return threats, standoff


def path_rule(inp: RuleInputs, plan: Plan, *, committed: bool) -> None:
    """Rule 5: brake for the most urgent threat in the path (none: nothing changes)."""
    cfg = inp.cfg
    ego = inp.scene.obs.ego
    threats, standoff = path_threats(inp, plan, committed=committed)
    if not threats:
        return
    worst = min(threats, key=lambda v: (v.kin.ttc_s if v.kin.ttc_s is not None
                                        else math.inf, v.id))
    ttc_txt = f"{worst.kin.ttc_s:.1f} s to collision" if worst.kin.ttc_s is not None \
        else "standing"
    plan.attend(worst, f"closing in, {ttc_txt}")
    if worst.id in standoff:
        need = ego.v_mps ** 2 / (2.0 * max(standoff[worst.id], 0.5))
    else:
        need = worst.kin.closing_speed_mps**2 / (2.0 * max(worst.kin.gap_m - 2.0, 0.5))
    if brakes_hard(inp, worst):
        brake_hard(inp, plan)
    else:
        plan.accel_index = brake_index(inp.accel, need * cfg.brake_margin_factor, False)
    plan.speed_set = True
    plan.weights["safety"] = "high"
    if worst.id in standoff:
        what = "stands" if worst.agent.v_mps < cfg.moving_speed_mps else "brakes hard"
        plan.notes.append(
            f"{worst.id} {what} {worst.kin.gap_m:.0f} m ahead in my lane, so I brake to "
            f"stop about {STANDOFF_M:.0f} m behind where it stands (room to steer round it)."
        )
    else:
        plan.notes.append(
            f"{worst.id} is {worst.kin.gap_m:.0f} m {worst.kin.relation} in my path and I "
            f"close in at {worst.kin.closing_speed_mps:.1f} m/s, so I brake to keep a safe "
            "distance."
        )


def go_rule(inp: RuleInputs, plan: Plan) -> None:
    """Rule 6 (when no rule chose the speed): follow a close leader in the path, else
    speed up below 80 % of the limit or keep the speed; with a style (``speed_style``)
    aggressive speeds up briskly to 95 %, conservative gently to 65 % and holds to 75 %,
    both held to with the action weight "high" except before a roundabout."""
    scene = inp.scene
    ego = scene.obs.ego
    lane = scene.lanes.get(ego.lane_id or "")
    limit = lane.speed_limit_mps if lane is not None else DEFAULT_VEHICLE.max_speed_mps
    beside = beside_in_route_lane(inp)
    if beside is not None:
        # let it draw ahead and merge behind it (speeding up alongside it left the MPC
        # to cut in ahead of it at the end of the lane)
        plan.accel_index = brake_index(inp.accel, 1.0, False)
        plan.weights["action"] = "high"
        plan.notes.append(f"{beside.id} is beside me in the lane my route needs; I ease "
                          "off to merge behind it.")
        return
    close = None if changing_lanes(scene, plan) else close_leader_in_path(inp, plan)
    if close is not None:
        _follow(inp, plan, close)
        return
    style = speed_style(inp, plan)
    # the conservative band brakes only above 75 %
    slows = style == "conservative" and \
        ego.v_mps >= (CONSERVATIVE_SPEED_FRACTION + 0.1) * limit
    # the style's speed is held to (action weight "high"; at "normal" the MPC tracks the
    # limit whatever the bias) except before a roundabout, where the entry gap decides:
    # held there, a changed arrival met other gaps (rab training seeds 10000-10049: the
    # style's time order per scene 47 -> 40 of 50); there the roundabout rule's
    # hold_speed keeps a speed-up it could not slow down from (rab 10049)
    held = style != "normal" and not _enters_ring(
        inp, next_maneuver(scene.obs, scene.lanes))
    easing = slower_leader_in_change(inp, plan) if style == "conservative" else None
    if easing is not None:
        # the held band speed kept the conservative driver from the slowing the MPC did for
        # the normal one; it entered the slower lane faster and closer behind its leader
        # (lane training seeds 10006, 10016, 10029; dev 112)
        plan.accel_index = brake_index(inp.accel, 0.0, True)  # the mildest braking
        plan.weights["action"] = "high"
        plan.notes.append(f"The user asked for careful driving; while I change lanes I ease "
                          f"off towards the {easing.agent.v_mps:.1f} m/s of {easing.id} "
                          f"({easing.kin.gap_m:.0f} m ahead).")
    elif plan.hold_speed is not None and not slows:
        # a junction rule found a speed-up unsafe: keep the speed (with the action weight
        # "normal" the MPC would track the speed limit rather than the neutral bias)
        plan.accel_index = neutral(inp.accel)
        plan.weights["action"] = "high"
        plan.notes.append(plan.hold_speed)
    elif style == "conservative" and changing_lanes(scene, plan) and not slows:
        # no held speed while changing lanes: the MPC slows as it does for the normal driver
        # (a held band speed kept it from that: lane dev 112), without the normal's speed-up
        # (above 75 % of the limit the band's held mild braking below still applies)
        plan.accel_index = neutral(inp.accel)
        plan.notes.append("The user asked for careful driving; I do not speed up while I "
                          "change lanes.")
    elif style == "aggressive" and ego.v_mps < AGGRESSIVE_SPEED_FRACTION * limit:
        plan.accel_index = accel_index(inp.accel, AGGRESSIVE_ACCEL_MPS2)
        if held:
            plan.weights["action"] = "high"
        plan.notes.append(f"The way is clear and the user is in a hurry; I speed up "
                          f"briskly towards the {limit:.1f} m/s limit.")
    elif style == "conservative" and ego.v_mps >= CONSERVATIVE_SPEED_FRACTION * limit:
        if slows:
            plan.accel_index = brake_index(inp.accel, 0.0, True)  # the mildest braking
        if held:  # (si dev 120 went 9.7 -> 13.3 m/s in one period without)
            plan.weights["action"] = "high"
        plan.notes.append(f"The user asked for careful driving; I keep below "
                          f"{CONSERVATIVE_SPEED_FRACTION:.0%} of the {limit:.1f} m/s limit.")
    elif style == "conservative" and held:
        # a gentle speed-up (the mildest accelerating interval) instead of the MPC's own
        # pull towards the limit
        plan.accel_index = mildest_accel(inp.accel)
        plan.weights["action"] = "high"
        plan.notes.append(f"The way is clear; the user asked for careful driving, so I "
                          f"speed up gently towards {CONSERVATIVE_SPEED_FRACTION:.0%} of "
                          f"the {limit:.1f} m/s limit.")
    elif ego.v_mps < 0.8 * limit:
        plan.accel_index = mildest_accel(inp.accel)
        if not plan.notes:
            plan.notes.append(
                f"The way is clear; I speed up towards the {limit:.1f} m/s limit."
            )
    elif not plan.notes:
        plan.notes.append("The way is clear; I keep my speed.")


def speed_style(inp: RuleInputs, plan: Plan) -> str:
    """The style that sets the clear-way speed here: the user's, except where it must not
    (then "normal", as without an instruction). Never in an emergency decision (lane seeds
    109/110/118: speeding up briskly while the emergency checks ran ended in collisions);
    aggressive only where :func:`clear_for_brisk` finds the way clear; conservative never
    slows inside a junction, on a roundabout or with a vehicle close behind (stopping
    there blocks traffic or invites a rear-end collision)."""
    style = inp.intent.style
    if inp.emergency or style == "normal":
        return "normal"
    if style == "aggressive":
        return style if clear_for_brisk(inp, plan) else "normal"
    here = inp.scene.lanes.get(inp.scene.obs.ego.lane_id or "")
    if here is None or here.internal or here.roundabout or close_follower(inp) is not None:
        return "normal"
    return style


def clear_for_brisk(inp: RuleInputs, plan: Plan) -> bool:
    """The rules' own gap checks allow the aggressive speed-up: not changing lanes (nor
    along a route candidate that crosses lanes), no light or roundabout entry ahead
    (``_junction_ahead``), and every vehicle ahead
    or beside in the ego's or a next lane (laterally within ``BRISK_LATERAL_M``) still
    at least the headway rule's gap (``wanted_gap_m``) away after ``replan_s`` of
    speeding up to the speed that brings."""
    cfg = inp.cfg
    scene = inp.scene
    ego = scene.obs.ego
    if changing_lanes(scene, plan) or _crosses_lanes(inp, plan) or _junction_ahead(inp):
        return False
    lane = scene.lanes.get(ego.lane_id or "")
    limit = lane.speed_limit_mps if lane is not None else DEFAULT_VEHICLE.max_speed_mps
    t = cfg.replan_s
    v0 = ego.v_mps
    v1 = max(v0, min(v0 + AGGRESSIVE_ACCEL_MPS2 * t, AGGRESSIVE_SPEED_FRACTION * limit))
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m <= -0.5 * ego.length_m or abs(k.lateral_m) > BRISK_LATERAL_M \
                or k.motion == "oncoming":
            continue
        vl = max(v.agent.v_mps, 0.0)
        closing = max(0.0, 0.5 * (v0 + v1) * t - vl * t)
        if k.gap_m < wanted_gap_m(v1, vl) + closing:
            return False
    return True


def _crosses_lanes(inp: RuleInputs, plan: Plan) -> bool:
    """The chosen candidate's lanes on the ego's edge include another lane than its own."""
    scene = inp.scene
    here = scene.lanes.get(scene.obs.ego.lane_id or "")
    if here is None or not scene.ego_candidates:
        return False
    cand = plan.ego_index if plan.ego_index is not None else scene.route_candidate_id
    for lid in scene.ego_candidates[cand].lane_ids:
        ln = scene.lanes.get(lid)
        if ln is not None and ln.edge_id == here.edge_id and ln.id != here.id:
            return True
    return False


def _junction_ahead(inp: RuleInputs) -> bool:
    """Inside a junction, or a signalized stop line or a roundabout entry on the route
    within ``junction_attention_m``: the light is unknown to the rules, and a fast
    approach to a roundabout turns its gap check into a commit or a long wait."""
    scene = inp.scene
    man = next_maneuver(scene.obs, scene.lanes, max_distance_m=inp.cfg.junction_attention_m)
    if man is None:
        return False
    if man.inside_junction or _enters_ring(inp, man):
        return True
    return any(sl.lane_id == man.approach_lane_id and sl.signalized
               for sl in scene.obs.map.stop_lines)


def _enters_ring(inp: RuleInputs, man: Optional[Maneuver]) -> bool:
    """The junction connection ``man`` (None: none ahead) enters a roundabout."""
    ring = None if man is None else inp.scene.lanes.get(man.link.to_lane)
    return ring is not None and ring.roundabout


def close_follower(inp: RuleInputs) -> Optional[AgentView]:
    """A vehicle behind in the ego's lane closer than ``FOLLOWER_HEADWAY_S`` at its speed
    (at least ``STANDOFF_M``): braking in front of it invites a rear-end collision."""
    for v in inp.scene.agents:
        k = v.kin
        if k.longitudinal_m >= 0.0 or abs(k.heading_rel_rad) > ALONG_RAD \
                or abs(k.lateral_m) > 1.8:
            continue
        if k.gap_m < max(STANDOFF_M, FOLLOWER_HEADWAY_S * v.agent.v_mps):
            return v
    return None


def _follow(inp: RuleInputs, plan: Plan, close: AgentView) -> None:
    """Close behind ``close`` in the path: stay, creep or stop short of it when it stands,
    else keep the speed (the MPC follows it)."""
    cfg = inp.cfg
    accel = inp.accel
    ego = inp.scene.obs.ego
    standing = close.agent.v_mps < cfg.moving_speed_mps
    d_m = close.kin.gap_m - STANDOFF_M
    moving = ego.v_mps >= cfg.moving_speed_mps
    if standing and (d_m < 3.0 or (not moving and d_m < 8.0)):
        # close behind a standing vehicle: stay (an accelerating bias would push
        # the MPC into it, and from nearer the ego could not steer round it)
        plan.accel_index = brake_index(accel, 0.0, True)
        plan.weights["action"] = "high"
        plan.notes.append(f"{close.id} stands {close.kin.gap_m:.0f} m ahead in my "
                          "path, so I stay where I am.")
    elif standing and not moving:
        plan.accel_index = mildest_accel(accel)  # creep nearer, slowly
        plan.notes.append(f"I creep up behind {close.id}, standing ahead.")
    elif standing:
        # a neutral bias lets the MPC speed up to just behind it: brake to stop
        # about STANDOFF_M short of it instead
        plan.accel_index = stop_index(accel, ego.v_mps, d_m, None, cfg.moving_speed_mps)
        plan.weights["action"] = "high"
        plan.notes.append(f"{close.id} stands {close.kin.gap_m:.0f} m ahead in my "
                          f"path; I stop about {STANDOFF_M:.0f} m short of it.")
    elif other_lane(inp.scene, close):
        # ahead in the lane the path merges into: the MPC's reference joins that lane
        # only later, so it would not follow the car yet; let it draw ahead (as the lane
        # rule's wait for a gap does) and merge behind it
        plan.accel_index = brake_index(accel, 1.0, False)
        plan.weights["action"] = "high"
        plan.notes.append(f"{close.id} is ahead in the lane I merge into; I ease off to "
                          "merge behind it.")
    else:
        plan.accel_index = neutral(accel)
        if not plan.notes:
            plan.notes.append(f"I follow {close.id} ahead in my path.")


def close_leader_in_path(inp: RuleInputs, plan: Plan) -> Optional[AgentView]:
    """The nearest agent ahead within the corridor of the chosen path, closer than
    what the ego needs to follow it comfortably (two seconds, at least 15 m) and not
    faster than the ego: the MPC follows it on its own; speeding up would fight that."""
    scene = inp.scene
    ego = scene.obs.ego
    path = route_path(scene, plan.ego_index)
    merge_lanes = set(chosen_candidate(scene, plan).lane_ids) if scene.ego_candidates \
        else set()
    best: Optional[AgentView] = None
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m <= 0.0 or k.motion == "oncoming":
            continue
        standing = v.agent.v_mps < inp.cfg.moving_speed_mps and \
            not queued_at_junction(scene, v)
        reach_m = max(15.0, 2.0 * ego.v_mps, STANDOFF_M + 15.0 if standing else 0.0)
        if k.gap_m > reach_m or v.agent.v_mps > ego.v_mps + 1.0:
            continue
        if other_lane(scene, v) and v.agent.lane_id not in merge_lanes:
            # e.g. a standing car the ego is steering round in the next lane; but not a
            # car in the lane the chosen path merges into (lane seed 10014, training,
            # aggressive: sped up past one to merge in front of it, and hit it)
            continue
        if path is not None:
            corridor = 0.5 * (ego.width_m + v.agent.width_m) + inp.cfg.path_corridor_m
            if distance_to_path(path, v.agent.x_m, v.agent.y_m) > corridor:
                continue
        if best is None or k.gap_m < best.kin.gap_m:
            best = v
    return best
