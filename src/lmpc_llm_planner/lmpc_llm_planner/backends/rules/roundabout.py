"""Rule 10: entering a roundabout; traffic on the ring has priority.

For each agent on the ring upstream of the ring lane the ego enters (along the ring's
lane links, at most ``RING_LOOKBACK_M``), its time to that lane's start (the merge point)
at its speed against the ego's time until its rear has passed the merge point
(accelerating at the go interval up to the ring's speed limit). A gap shorter than
``safe_gap_s`` (hysteresis as the left turn) -> stop before the yield line, "yield"; too
close to stop comfortably -> "commit"; else "go". APPROXIMATION: the merge point is the
end of the entry's junction lane, not where the two junction lanes meet inside the
junction; ring traffic's intent (exit before the merge point or not) is unknown, so
every ring agent upstream counts."""
from __future__ import annotations

from typing import Mapping, Optional

from lmpc_msgs_py.messages import Lane

from lmpc_llm_planner.config import RulesConfig
from lmpc_llm_planner.route import Maneuver, next_maneuver

from .intervals import neutral, required_decel, stop_index
from .junction import (
    CLEAR_MARGIN_M, GO_ZONE_M, Conflict, approach_turn, commit, go_accel_mps2, go_briskly,
    stop_brake_limit_mps2, stop_can_wait, travel_time_s,
)
from .plan import Plan, RuleInputs

RING_LOOKBACK_M = 60.0
"""Ring traffic this far (along the ring) before the ego's merge point counts."""


def roundabout_rule(inp: RuleInputs, plan: Plan) -> str:
    """"none" when the next junction on the route is not a roundabout entry, else "go",
    "yield" or "commit"."""
    cfg = inp.cfg
    scene = inp.scene
    man = next_maneuver(scene.obs, scene.lanes, max_distance_m=cfg.junction_attention_m)
    if man is None:
        return "none"
    approach = scene.lanes.get(man.approach_lane_id)
    ring = scene.lanes.get(man.link.to_lane)
    if approach is None or approach.roundabout or ring is None or not ring.roundabout:
        return "none"
    conflicts = ring_conflicts(inp, man, ring)
    if inp.ring_revisit_s is not None and not man.inside_junction:
        plan.revisit_s = inp.ring_revisit_s  # see the approach through, decision by decision
    for c in conflicts:
        plan.attend(c.view, "on the roundabout, has priority at my entry")
    margin = inp.safe_gap_s - (cfg.go_hysteresis_s if inp.previous_go else 0.0)
    unsafe = [c for c in conflicts if c.gap_s < margin]
    if not unsafe:
        return _enter(inp, plan, man, conflicts, margin=margin)
    return _give_way(inp, plan, man, unsafe, margin=margin)


def ring_conflicts(inp: RuleInputs, man: Maneuver, ring: Lane) -> list[Conflict]:
    """Every agent on the ring upstream of the ego's merge point, with its arrival there
    and the ego's time to have entered past it."""
    scene = inp.scene
    ego = scene.obs.ego
    via = scene.lanes.get(man.link.via_lane) if man.link.via_lane else None
    d_merge = man.dist_to_stop_line_m + (via.length_m if via is not None else 0.0)
    go_accel = go_accel_mps2(inp)
    conflicts: list[Conflict] = []
    for view in scene.agents:
        ag = view.agent
        lane = scene.lanes.get(ag.lane_id or "")
        if lane is None or not lane.roundabout:
            continue
        d = ring_distance_m(scene.lanes, lane, ag.lane_pos_m, ring.id, RING_LOOKBACK_M)
        if d is None:
            continue
        t_agent = max(d - 0.5 * ag.length_m - CLEAR_MARGIN_M, 0.0) / max(ag.v_mps, 0.5)
        t_clear = travel_time_s(d_merge + 0.5 * ego.length_m + 0.5 * ag.width_m
                                + CLEAR_MARGIN_M,
                                v0_mps=ego.v_mps, accel_mps2=go_accel,
                                vmax_mps=ring.speed_limit_mps)
        conflicts.append(Conflict(view, d_merge, t_agent, t_clear, 0.0))
    return conflicts


def _enter(inp: RuleInputs, plan: Plan, man: Maneuver, conflicts: list[Conflict], *,
           margin: float) -> str:
    """Every gap is safe: clear the merge point briskly when close and ring traffic comes;
    far out, approach slowly enough to stop for ring traffic that shows up later."""
    cfg = inp.cfg
    ego = inp.scene.obs.ego
    half_len = 0.5 * ego.length_m
    if conflicts:
        plan.notes.append(
            f"I enter the roundabout; the gap in the ring traffic is "
            f"{min(c.gap_s for c in conflicts):.1f} s beyond my clearing time "
            f"(enough from {margin:.1f} s).")
    # a ring car in sight that the ego would pass ahead of (every gap safe): go now and
    # keep that gap; approaching slowly first would close it (the oracle's regret on rab
    # lies in these early decisions: docs/ORACLE.md). Only when the rules decide again
    # soon (``ring_revisit_s``): a car that shows up later is seen within it.
    ahead = bool(conflicts) and inp.ring_revisit_s is not None
    if ahead or man.inside_junction or man.dist_to_stop_line_m < half_len + GO_ZONE_M:
        if conflicts:  # clear the merge point before the ring car arrives
            go_briskly(inp, plan)
    else:
        # approach slowly enough to stop at the yield line for ring traffic that
        # shows up later (ent* cars join the ring from the arm before mine); from
        # 12 m/s ten metres out the ego could only commit (rab seeds 19, 112).
        # Far out keep the speed while a comfortable slow-down after the next
        # decision is still possible (slowing from 70 m out cost seconds)
        v, v_turn = ego.v_mps, cfg.approach_turn_speed_mps
        d = man.dist_to_stop_line_m - half_len
        if v <= v_turn or not _can_slow_later(inp, v, d):
            approach_turn(inp, plan, man, v, next_s(inp))
        else:
            _hold_unless_room_to_speed_up(inp, plan, man, v, d)
    return "go"


def next_s(inp: RuleInputs) -> float:
    """Sim time from this decision's observation until the next decision acts: the
    revisit plus the expected latency when the rules ask to be asked again near the ring
    (``RuleInputs.ring_react_s``), else ``replan_s``."""
    return inp.ring_react_s if inp.ring_react_s is not None else inp.cfg.replan_s


def _can_slow(cfg: RulesConfig, v_mps: float, d_m: float) -> bool:
    """At ``v_mps``, ``d_m`` before the yield line, the ego can slow to the turn speed
    comfortably (``commit_decel_mps2``) and short of the go zone."""
    v_turn = cfg.approach_turn_speed_mps
    return d_m > (v_mps * v_mps - v_turn * v_turn) / (2.0 * cfg.commit_decel_mps2) + GO_ZONE_M


def _can_slow_later(inp: RuleInputs, v_mps: float, d_m: float) -> bool:
    """The same when the next decision acts (``next_s``), at ``v_mps`` until then."""
    return _can_slow(inp.cfg, v_mps, d_m - v_mps * next_s(inp))


def _hold_unless_room_to_speed_up(inp: RuleInputs, plan: Plan, man: Maneuver, v_mps: float,
                                  d_m: float) -> None:
    """Far from the yield line: the way-is-clear rule would speed up towards the limit,
    and that speed-up lasts until the next decision. Where the ego could no longer slow
    comfortably after it (checked as if it accelerated at ``turn_accel_mps2`` for
    ``next_s``), the go rule keeps the speed instead (``Plan.hold_speed``): rab seed
    10049 (training) sped up from 9.3 to 12.5 m/s 50 m out, was then too close to stop
    for the ring car it had not seen yet, committed, and was hit in the entry."""
    cfg = inp.cfg
    approach = inp.scene.lanes.get(man.approach_lane_id)
    limit = approach.speed_limit_mps if approach is not None else v_mps
    t_next = next_s(inp)
    v_up = min(max(limit, v_mps), v_mps + cfg.turn_accel_mps2 * t_next)
    d_up = d_m - 0.5 * (v_mps + v_up) * t_next
    if v_up > v_mps and not _can_slow(cfg, v_up, d_up):
        plan.hold_speed = ("I keep my speed: after speeding up I could not slow down "
                           "comfortably for the roundabout.")


def _give_way(inp: RuleInputs, plan: Plan, man: Maneuver, unsafe: list[Conflict], *,
              margin: float) -> str:
    """A ring gap is too small: stop at the yield line (keeping the speed for now when far
    out), or commit when that stop is not comfortable."""
    cfg = inp.cfg
    ego = inp.scene.obs.ego
    worst = min(unsafe, key=lambda c: (c.gap_s, c.view.id))
    v = ego.v_mps
    d_stop = man.dist_to_stop_line_m - 0.5 * ego.length_m - cfg.stop_margin_m
    need = required_decel(v, d_stop, cfg.moving_speed_mps)
    if man.inside_junction or need is None or need > stop_brake_limit_mps2(inp):
        return commit(inp, plan, (
            f"I am too close to stop before the roundabout's yield line with "
            f"{worst.view.id} coming; I enter briskly and keep a safe distance."))
    plan.speed_set = True
    plan.weights.update(action="high", safety="high")
    reason = (f"I must give way to {worst.view.id} on the roundabout: it reaches my "
              f"entry in {worst.t_agent_s:.1f} s, I would need {worst.t_clear_s:.1f} s "
              f"to enter (gap {worst.gap_s:.1f} s, enough from {margin:.1f} s).")
    if stop_can_wait(inp, v, d_stop, next_s(inp)):
        plan.accel_index = neutral(inp.accel)  # far: stopping now would stop well short
        plan.notes.append(reason + f" I keep my speed for now and stop at the yield line "
                          f"({d_stop:.0f} m) if the gap stays too small.")
        return "yield"
    plan.accel_index = stop_index(inp.accel, v, d_stop, None, cfg.moving_speed_mps)
    plan.notes.append(reason + f" I stop at the yield line ({max(d_stop, 0.0):.0f} m) "
                      "and wait for a gap.")
    return "yield"


def ring_distance_m(lanes: Mapping[str, Lane], start: Lane, pos_m: float, goal_id: str,
                    max_m: float) -> Optional[float]:
    """Distance along roundabout lanes from ``pos_m`` on ``start`` to the start of lane
    ``goal_id`` (following lane links and their junction lanes), or None when it is not
    reached within ``max_m`` (or ``start`` is ``goal_id``: past the merge point)."""
    best: Optional[float] = None
    frontier = [(max(start.length_m - pos_m, 0.0), start)]
    seen: set[str] = set()
    while frontier:
        d, lane = frontier.pop()
        if lane.id == goal_id or lane.id in seen or d > max_m:
            continue
        seen.add(lane.id)
        for lk in lane.successors:
            via = lanes.get(lk.via_lane) if lk.via_lane else None
            dd = d + (via.length_m if via is not None else 0.0)
            if lk.to_lane == goal_id:
                best = dd if best is None else min(best, dd)
                continue
            nxt = lanes.get(lk.to_lane)
            if nxt is not None and nxt.roundabout:
                frontier.append((dd + nxt.length_m, nxt))  # distance to its end
    return best if best is not None and best <= max_m else None
