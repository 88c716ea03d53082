"""The headway rule: behind a moving leader in the ego's lane keep a gap from which the ego
can still brake (or steer round it) if the leader brakes as hard as a car can
(``LEADER_BRAKE_MPS2``): the ego's stopping distance after a reaction time, minus the
leader's, plus ``STANDOFF_M`` to steer round it (aggressive: ``AGGRESSIVE_STANDOFF_M``, a
stop short of it only); at least the style's time gap (``style_headway_s``). The
MPC follows at its own (1 s) headway; too close, the rules brake gently (the mildest
braking interval) until the gap has opened, and hold the speed while it is only a little
short. During a lane change the leader of the lane being left does not count; the
conservative style keeps its gap to the leader of the lane it enters while that leader is
nearer than the follower there (the others leave that to the MPC)."""
from __future__ import annotations

from typing import Optional

from lmpc_llm_planner.route import next_maneuver
from lmpc_llm_planner.scene import AgentView, Scene

from .intervals import brake_index, neutral
from .lane import lane_state, lanes_on_edge
from .plan import Plan, RuleInputs, changing_lanes, chosen_candidate
from .scene_helpers import STANDOFF_M, lane_leader

HEADWAY_S = 2.0
"""Time gap the ego keeps at least behind a moving leader in its lane (rules headway)."""
HEADWAY_REACTION_S = 1.0
"""The ego's reaction time in that gap: an emergency decision comes only once the TTC to
the braking leader is under `emergency_ttc_s` (2 s), about a second after it starts braking
(eoa seed 2: the ego ended 3 m behind the hazard with 0.5 s here)."""
EGO_BRAKE_MPS2 = 5.0
"""The ego's braking in that gap (midpoint of the strongest braking interval)."""
LEADER_BRAKE_MPS2 = 8.0
"""How hard a leader may brake (eoa hazards brake at 8 m/s^2; a car's emergency braking)."""
HEADWAY_OPEN_FRACTION = 0.85
"""Below this fraction of the wanted gap the ego brakes gently to open it (above: holds)."""
HEADWAY_MIN_SPEED_MPS = 4.0
"""Below this speed the MPC's own following distance is enough (queues, creeping)."""


CONSERVATIVE_HEADWAY_S = 3.0
"""The time gap of the conservative style (the braking model's gap still applies)."""
CONSERVATIVE_OPEN_ROAD_HEADWAY_S = 4.0
"""The conservative time gap on the open road: no junction on the route within
``OPEN_ROAD_M`` (a longer gap there only costs time; before a junction it changes which
gap in the cross traffic the ego meets, and a 4 s gap everywhere deadlocked dev si 121)."""
OPEN_ROAD_M = 150.0
"""No junction connection on the route within this distance: the open road."""
AGGRESSIVE_STANDOFF_M = 5.0
"""The aggressive style's margin in the braking model's gap: it still stops this far
short of a leader braking as hard as a car can, but not far enough to steer round it
(issue 20: behind a platoon-speed leader normal and aggressive kept the same 19 m, and
the aggressive driver was no faster)."""

CONSERVATIVE_MERGE_RANGE_M = 60.0
"""Conservative style, changing lanes: a leader of either lane within this gap that is
slower than the ego makes it ease off (``slower_leader_in_change``)."""


def style_headway_s(inp: RuleInputs) -> float:
    """The time gap the rules keep behind a leader for the instructed style."""
    if inp.intent.style != "conservative":
        return HEADWAY_S
    scene = inp.scene
    if next_maneuver(scene.obs, scene.lanes, max_distance_m=OPEN_ROAD_M) is None:
        return CONSERVATIVE_OPEN_ROAD_HEADWAY_S
    return CONSERVATIVE_HEADWAY_S


def style_standoff_m(inp: RuleInputs) -> float:
    """The margin of the braking model's gap for the instructed style."""
    return AGGRESSIVE_STANDOFF_M if inp.intent.style == "aggressive" else STANDOFF_M


def wanted_gap_m(v_mps: float, leader_v_mps: float, headway_s: float = HEADWAY_S,
                 standoff_m: float = STANDOFF_M) -> float:
    """The gap the ego keeps at ``v_mps`` behind a leader driving ``leader_v_mps``."""
    v, vl = v_mps, leader_v_mps
    return max(headway_s * v, v * HEADWAY_REACTION_S + v * v / (2.0 * EGO_BRAKE_MPS2)
               - vl * vl / (2.0 * LEADER_BRAKE_MPS2) + standoff_m)


def entered_lane_neighbours(scene: Scene, plan: Plan
                            ) -> tuple[Optional[AgentView], Optional[AgentView]]:
    """(leader, follower) in the lane the chosen lane-change candidate enters (the
    candidate's other lane on the ego's edge)."""
    here = scene.lanes.get(scene.obs.ego.lane_id or "")
    if here is None:
        return None, None
    entered = [lid for lid in lanes_on_edge(scene, chosen_candidate(scene, plan), here.edge_id)
               if lid != here.id]
    return lane_state(scene, entered[0]) if entered else (None, None)


def headway_rule(inp: RuleInputs, plan: Plan) -> None:
    """Drop back (mildest braking) or hold the speed behind a leader that is too close."""
    scene = inp.scene
    v = scene.obs.ego.v_mps
    if v < HEADWAY_MIN_SPEED_MPS:
        return
    if not changing_lanes(scene, plan):
        leader = lane_leader(scene)
    elif inp.intent.style == "conservative":
        # the leader of the lane being left does not matter; the conservative driver keeps
        # its headway to the one of the lane it enters (lane dev seeds: merging at once
        # with its gentler braking it entered closer behind that leader than normal did)
        leader, follower = entered_lane_neighbours(scene, plan)
        if leader is not None and follower is not None \
                and follower.kin.gap_m <= leader.kin.gap_m:
            # dropping back trades the gap ahead for the one behind: it keeps the middle of
            # the gap it enters, not a headway the gap does not have
            return
    else:
        return
    if leader is None or leader.agent.v_mps < inp.cfg.moving_speed_mps:
        return  # standing: the stand-off rules (path, go) handle it
    vl = leader.agent.v_mps
    want = wanted_gap_m(v, vl, style_headway_s(inp), style_standoff_m(inp))
    gap = leader.kin.gap_m
    if gap >= want:
        return
    where = "in the lane I change to" if changing_lanes(scene, plan) else "in my lane"
    plan.attend(leader, f"leader {where}")
    plan.speed_set = True
    if gap < HEADWAY_OPEN_FRACTION * want and v > vl - 1.0 or (
            inp.intent.style == "conservative" and slower_leader_in_change(inp, plan)):
        plan.weights["action"] = "high"
        plan.accel_index = brake_index(inp.accel, 0.5, False)
        plan.notes.append(
            f"{leader.id} drives {gap:.0f} m ahead {where} at {vl:.1f} m/s; I drop "
            f"back to about {want:.0f} m so I can still brake or steer round it if it "
            "brakes hard.")
    else:
        plan.accel_index = neutral(inp.accel)
        if not changing_lanes(scene, plan):
            # changing lanes the speed is not held: the MPC slows for the lane being left
            # as it does for the normal driver (a held speed kept it from that: lane dev 112)
            plan.weights["action"] = "high"
        plan.notes.append(
            f"I follow {leader.id} ({gap:.0f} m ahead) and keep about {want:.0f} m, "
            "enough to brake or steer round it if it brakes hard.")


def slower_leader_in_change(inp: RuleInputs, plan: Plan) -> Optional[AgentView]:
    """While changing lanes: the slower of the leaders of the lane being left and the lane
    entered, if it moves, is within ``CONSERVATIVE_MERGE_RANGE_M`` and is slower than the
    ego by more than 0.5 m/s (None otherwise)."""
    scene = inp.scene
    if not changing_lanes(scene, plan):
        return None
    v = scene.obs.ego.v_mps
    leaders = [lane_leader(scene), entered_lane_neighbours(scene, plan)[0]]
    slower = [a for a in leaders if a is not None and a.kin.gap_m < CONSERVATIVE_MERGE_RANGE_M
              and inp.cfg.moving_speed_mps <= a.agent.v_mps < v - 0.5]
    return min(slower, key=lambda a: (a.agent.v_mps, a.id)) if slower else None
