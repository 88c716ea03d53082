"""Rule 8: which lane of a multi-lane road to drive in (paper Fig. 5 / 7; docs/lmpc_rules.md).

Applies where the ego is offered neighbour-lane candidates (a normal lane of a multi-lane
edge, no junction choice ahead within the lookahead). Reasons, in order: leave a lane the
user said is closed, or one blocked by a stopped vehicle ahead (stopping ~10 m short of
it while the next lane has no gap); reach a lane that continues along the route before
the edge ends (late only when aggressive); overtake a slow leader through a faster
neighbour lane (never when conservative). A change needs a gap to the new leader and
follower (``LC_*``, scaled by the style); without one the ego keeps its lane and, when
the change is urgent, eases off so the gap behind a neighbour passes. Geometry:
ego-frame offsets (straight-road APPROXIMATION)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

from lmpc_msgs_py.messages import Lane
from lmpc_mpc.reference import Candidate

from lmpc_llm_planner.scene import AgentView, Scene

from .instruction import Intent
from .intervals import brake_index, mildest_accel, stop_index
from .plan import Plan, RuleInputs, sentence
from .scene_helpers import ALONG_RAD, HARD_BRAKE_MPS2, STANDOFF_M, queued_at_junction

LANE_MERGE_PER_CHANGE_M = 70.0
"""Road needed per lane change before the end of the edge (+ ``LANE_MERGE_SLACK_M``); the
aggressive style keeps its lane until ``LANE_MERGE_AGGRESSIVE`` of that is left."""
LANE_MERGE_SLACK_M = 60.0
LANE_MERGE_FORCE_M = 60.0
"""Aggressive style: this close to the end of the edge the route's lane change is made
along the route candidate without waiting for a gap (else the exit would be missed)."""
LANE_MERGE_AGGRESSIVE = 0.8
"""Aggressive style: the lane changes the route needs start within this fraction of
``need * LANE_MERGE_PER_CHANGE_M + LANE_MERGE_SLACK_M`` before the edge ends (others: at
once)."""
SLOW_LEADER_RANGE_M = 60.0
"""A leader in the ego's lane farther than this does not make it change lanes."""
SLOW_LEADER_GAIN_MPS = 2.0
"""A neighbour lane must be at least this much faster (its leader's speed, or the limit
with no leader in range) than the ego's lane for an overtake (aggressive: 1 m/s)."""
SLOW_LEADER_FRACTION = 0.8
"""A leader counts as slow below this fraction of the speed limit."""
CRAWLING_FRACTION = 0.4
"""A leader crawling below this fraction of the limit is overtaken even by the conservative
style (with its larger gaps) and while making room for an emergency vehicle (eoa dev
seeds 105, 106, 108: behind a hazard crawling at ~2 m/s either timed out)."""
AGGRESSIVE_OVERTAKE_AFTER_S = 1.0
"""Aggressive style: its shorter lane-change gaps apply only after the first second of an
episode (before, the normal gaps), while the simulation still inserts vehicles the first
observation did not show (eoa seed 104: one appeared 1 m behind in the target lane 0.3 s
after an overtake began)."""
LATE_MERGE_SPEED_DIFF_MPS = 4.0
"""Aggressive style: the late merge is made only into a lane whose vehicles near the ego
are at most this much slower than the ego (``slower_target_lane``)."""
LC_MIN_GAP_M = 6.0
"""Bumper gap to the new leader / follower a lane change needs at least."""
LC_HEADWAY_S = 0.8
"""Plus this many seconds at the follower's (rear) or the ego's (front) speed."""
LC_CLOSING_HORIZON_S = 3.0
"""Plus what a faster follower (or a slower new leader) closes in this long."""
LC_STYLE_FACTOR = {"conservative": 1.5, "normal": 1.0, "aggressive": 0.7}
"""Multiplies the lane-change gaps (an instruction never drops them below the minimum)."""
CLOSED_LOOKAHEAD_M = 400.0
"""A lane the user said is closed is left once the ego knows (it is on that lane of an
edge with a neighbour lane): the instruction is the only way to know beyond sensing."""


@dataclass(frozen=True)
class LaneView:
    """The ego's edge as the lane rule sees it."""

    here: Lane
    siblings: dict[int, Lane]
    """The edge's normal lanes by index."""
    by_lane: dict[str, int]
    """Offered ego candidate per lane it moves to (the first lane of its chain)."""
    route_lane: Optional[str]
    """The lane of this edge the route candidate ends on (it may jump several lanes)."""
    closed: frozenset[str]
    """Lanes the user said are closed."""
    route_needs_closed: bool
    """The route goes on only from closed lanes: the ego keeps to them (leaving one was
    undone by the route's lane change at the next decision: back and forth every 2.5 s
    for 95 s, lane dev seed 101)."""
    make_room: bool
    """The user asked to make room for an emergency vehicle: keep to the kerb lane."""
    ok_idx: list[int]
    """Indices of the lanes that continue along the route (open ones, if any)."""
    need: int
    """Lane changes the route needs before the edge ends."""
    toward: Optional[int]
    """The next lane towards the route's lanes (None: none needed)."""
    dist_end_m: float
    """Road left on this edge."""
    left_hand: bool


@dataclass(frozen=True)
class LeaderState:
    """The leader in the ego's lane and what it means for the lane choice."""

    lead: Optional[AgentView]
    blocked: bool
    """It stands (or brakes hard towards a standstill) in sensing range, not queued."""
    slow: bool
    """It drives below ``SLOW_LEADER_FRACTION`` of the limit within range."""


@dataclass(frozen=True)
class Want:
    """A lane the ego wants to move to, and why."""

    index: int
    why: str
    urgent: bool = False


def lane_rule(inp: RuleInputs, plan: Plan) -> str:
    """"keep", "change" or "wait" (a change is wanted but the gap is not there); "none"
    when the rule does not apply. Sets ``plan.ego_index`` whenever it applies."""
    lv = lane_view(inp.scene, inp.intent)
    if lv is None:
        return "none"
    lead = leader_state(inp, lv)
    chosen = choose_lane(inp, plan, lv, lead)
    if isinstance(chosen, str):
        return chosen
    keep_id = lv.by_lane[lv.here.id]
    if lead.lead is not None and lead.lead.kin.longitudinal_m <= SLOW_LEADER_RANGE_M:
        plan.attend(lead.lead, "leader in my lane")
    if chosen is None:
        plan.ego_index = keep_id
        return "keep"
    side = "left" if (chosen.index > lv.here.index) != lv.left_hand else "right"
    cand = change_candidate(inp.scene, lv, chosen.index)
    if cand is None:
        plan.ego_index = keep_id
        return "none"
    blocker = gap_blocker(inp, plan, crossed_lanes(inp.scene, lv, chosen.index, cand), side)
    if blocker is None:
        plan.ego_index = cand
        plan.notes.append(f"{sentence(chosen.why)}; the gap in the {side} lane is free, so "
                          f"I change to the {side} lane.")
        return "change"
    plan.ego_index = keep_id
    v, where = blocker
    plan.notes.append(f"{sentence(chosen.why)}, but {v.id} {where} in the {side} lane leaves "
                      "no safe gap yet, so I keep my lane for now.")
    return wait_for_gap(inp, plan, lv, lead, chosen, blocker)


def lane_view(scene: Scene, intent: Intent) -> Optional[LaneView]:
    """The :class:`LaneView` of the ego's edge, or None where the rule does not apply (no
    candidates, a single-lane edge, or only junction choices offered)."""
    obs = scene.obs
    ego = obs.ego
    here = scene.lanes.get(ego.lane_id or "")
    if here is None or here.internal or not scene.ego_candidates:
        return None
    siblings = scene.edge_lanes(here)
    if len(siblings) < 2:
        return None
    by_lane = offered_by_lane(scene, here)
    # the route candidate may jump several lanes: it counts for the lane it ends on
    route_c = scene.ego_candidates[scene.route_candidate_id]
    route_lane = next((lid for lid in route_c.lane_ids
                       if lid in scene.lanes and scene.lanes[lid].edge_id == here.edge_id),
                      None)
    if here.id not in by_lane or len(set(by_lane) | {route_lane or here.id}) < 2:
        return None  # only junction choices offered: the turn rules decide
    left_hand = obs.map.left_hand_traffic
    closed = closed_lanes(intent, siblings, left_hand=left_hand)
    # the lanes that continue along the route (and how far this edge still goes)
    continuing = continuing_lanes(scene, here, siblings)
    dist_end_m = max(0.0, here.length_m - ego.lane_pos_m)
    open_ok = sorted(ln.index for ln in continuing if ln.id not in closed)
    ok_idx = open_ok or sorted(ln.index for ln in continuing)
    need, toward = changes_toward(here.index, ok_idx)
    return LaneView(here=here, siblings=siblings, by_lane=by_lane, route_lane=route_lane,
                    closed=closed, route_needs_closed=bool(closed) and not open_ok,
                    make_room=intent.make_room, ok_idx=ok_idx, need=need, toward=toward,
                    dist_end_m=dist_end_m, left_hand=left_hand)


def changes_toward(index: int, ok_idx: list[int]) -> tuple[int, Optional[int]]:
    """(lane changes from lane ``index`` to the nearest lane of ``ok_idx``, the next lane
    on the way there; None when ``index`` is one of them or there are none)."""
    need = min((abs(i - index) for i in ok_idx), default=0)
    if need == 0:
        return 0, None
    nearest = min(ok_idx, key=lambda i: (abs(i - index), i))
    return need, index + (1 if nearest > index else -1)


def offered_by_lane(scene: Scene, here: Lane) -> dict[str, int]:
    """The offered ego candidates per lane of ``here``'s edge they move to (the first lane
    of their chain; the first candidate wins)."""
    by_lane: dict[str, int] = {}
    for c in scene.ego_candidates:
        if not c.lane_ids or c.candidate_id in scene.leaving_ids:
            # a lane change (or keeping the lane) whose path then leaves the route: the
            # route candidate makes that change instead (a short edge before a
            # junction, issue 21), so the lane rule cannot pick it
            continue
        first = c.lane_ids[0]
        lane = scene.lanes.get(first)
        if lane is not None and lane.edge_id == here.edge_id and first not in by_lane:
            by_lane[first] = c.candidate_id
    return by_lane


def closed_lanes(intent: Intent, siblings: dict[int, Lane], *, left_hand: bool
                 ) -> frozenset[str]:
    """The ids of the outer lanes the user said are closed ("right": the rightmost)."""
    n = max(siblings) + 1
    closed = set()
    for side in intent.closed_sides:
        outer = 0 if (side == "right") != left_hand else n - 1
        if outer in siblings:
            closed.add(siblings[outer].id)
    return frozenset(closed)


def continuing_lanes(scene: Scene, here: Lane, siblings: dict[int, Lane]) -> list[Lane]:
    """Lanes of the ego's edge from which its route goes on (any lane when the route
    ends on this edge or its next edge is not in the map)."""
    route = scene.obs.map.ego_route
    nxt_edge: Optional[str] = None
    seen_here = False
    for lid in route:
        lane = scene.lanes.get(lid)
        if lane is None or lane.internal:
            continue
        if lane.edge_id == here.edge_id:
            seen_here = True
        elif seen_here:
            nxt_edge = lane.edge_id
            break
    if nxt_edge is None:
        return list(siblings.values())
    out = []
    for ln in siblings.values():
        for lk in ln.successors:
            to = scene.lanes.get(lk.to_lane)
            if to is not None and to.edge_id == nxt_edge:
                out.append(ln)
                break
    return out or list(siblings.values())


def lane_state(scene: Scene, lane_id: str) -> tuple[Optional[AgentView], Optional[AgentView]]:
    """(leader, follower) on ``lane_id``, by the ego-frame longitudinal offset."""
    lead: Optional[AgentView] = None
    follow: Optional[AgentView] = None
    for v in scene.agents:
        # along the lane (the ego itself may stand turned half-way into a swerve)
        if v.agent.lane_id != lane_id or abs(v.kin.heading_rel_rad) > ALONG_RAD:
            continue
        lon = v.kin.longitudinal_m
        if lon >= 0.0 and (lead is None or lon < lead.kin.longitudinal_m):
            lead = v
        if lon < 0.0 and (follow is None or lon > follow.kin.longitudinal_m):
            follow = v
    return lead, follow


def leader_state(inp: RuleInputs, lv: LaneView) -> LeaderState:
    """The leader in the ego's lane: blocking (standing, or braking hard towards a
    standstill close ahead, eoa hazards brake at 8 m/s^2: take the free neighbour lane
    early, while there is still room to steer round it) or slow."""
    cfg = inp.cfg
    scene = inp.scene
    lead_here, _ = lane_state(scene, lv.here.id)
    if lead_here is None:
        return LeaderState(None, blocked=False, slow=False)
    stopping = lead_here.agent.v_mps < cfg.moving_speed_mps \
        or (lead_here.agent.a_mps2 < -HARD_BRAKE_MPS2
            and lead_here.kin.longitudinal_m <= SLOW_LEADER_RANGE_M)
    blocked = stopping \
        and lead_here.kin.longitudinal_m <= scene.obs.agents.sensing_range_m \
        and not queued_at_junction(scene, lead_here)
    slow = lead_here.kin.longitudinal_m <= SLOW_LEADER_RANGE_M \
        and lead_here.agent.v_mps < SLOW_LEADER_FRACTION * lv.here.speed_limit_mps
    return LeaderState(lead_here, blocked=blocked, slow=slow)


def choose_lane(inp: RuleInputs, plan: Plan, lv: LaneView, lead: LeaderState
                ) -> Union[str, Want, None]:
    """The first reason that applies: a closed lane, a blocked lane, the route's lane (made
    at once along the route candidate: "change"), a slow leader; None: keep the lane."""
    style = inp.intent.style
    merge_m = lv.need * LANE_MERGE_PER_CHANGE_M + LANE_MERGE_SLACK_M
    # towards the lane the route needs: at once (normal, conservative: measured on
    # lane seeds 100-124, merging late into the slower traffic cost more in gaps and
    # harsh braking than the fast lane saved in time), late only when aggressive
    # aggressive: merging late into a much slower lane means squeezing in among its cars
    # at speed (lane seeds 110/118 collided): then at once, as the other styles
    urgent_merge = lv.need > 0 and (style != "aggressive"
                                    or lv.dist_end_m < merge_m * LANE_MERGE_AGGRESSIVE
                                    or slower_target_lane(inp, lv) is not None)
    want: Optional[Want] = None
    if lv.here.id in lv.closed and lv.route_needs_closed:
        plan.notes.append("The user says my lane is closed ahead, but my route goes on only "
                          "from it, so I keep it.")
    elif lv.here.id in lv.closed and lv.dist_end_m <= CLOSED_LOOKAHEAD_M:
        want = _leave_closed(lv)
    if want is None and lead.blocked and lead.lead is not None:
        want = _pass_blocked(lv, lead.lead)
    if want is None and urgent_merge and lv.toward is not None:
        if merge_along_route(inp, plan, lv):
            return "change"
        want = Want(lv.toward, f"my route needs {lv.need} lane change(s) within "
                    f"{lv.dist_end_m:.0f} m", urgent=lv.dist_end_m < merge_m)
    if want is None and lv.make_room:
        # after the route's own (urgent) change: towards the kerb it eases off for a gap
        # (lane 23: the make-room change first, never easing off, found no gap for 40 s)
        want = _make_room(lv)
    crawling = lead.lead is not None \
        and lead.lead.agent.v_mps < CRAWLING_FRACTION * lv.here.speed_limit_mps
    if want is None and lead.slow and lead.lead is not None and (
            crawling or (style != "conservative" and not lv.make_room)):
        want = overtake(inp, lv, lead.lead)
    return want


def _open_neighbours(lv: LaneView) -> list[int]:
    return [i for i in (lv.here.index - 1, lv.here.index + 1)
            if i in lv.siblings and lv.siblings[i].id not in lv.closed]


def _make_room(lv: LaneView) -> Optional[Want]:
    """Towards the kerb lane (index 0) for an emergency vehicle, where the route goes on
    from it and it is open; not urgent (no easing off for a gap: passing a standing
    vehicle through an inner lane comes first)."""
    if lv.here.index == 0 or 0 not in lv.ok_idx:
        return None  # on it, or the route needs an inner lane here: keep it
    return Want(lv.here.index - 1, "the user asks me to make room for an emergency "
                "vehicle, so I move towards the kerb lane")


def _leave_closed(lv: LaneView) -> Optional[Want]:
    open_nb = _open_neighbours(lv)
    if not open_nb:
        return None
    toward = lv.toward
    return Want(min(open_nb, key=lambda i: (abs(i - (toward or i)), i)),
                "the user says my lane is closed ahead", urgent=True)


def _pass_blocked(lv: LaneView, lead_here: AgentView) -> Optional[Want]:
    open_nb = _open_neighbours(lv)
    if not open_nb:
        return None
    # prefer the side towards the route, else the overtaking side
    over = lv.here.index - 1 if lv.left_hand else lv.here.index + 1
    return Want(min(open_nb, key=lambda i: (i != lv.toward, i != over, i)),
                f"{lead_here.id} stands in my lane {lead_here.kin.gap_m:.0f} m ahead",
                urgent=True)


def merge_along_route(inp: RuleInputs, plan: Plan, lv: LaneView) -> bool:
    """Take the candidate one lane towards the route's lanes (or the route candidate) now:
    True when chosen (always unless aggressive and the edge's end is still far)."""
    scene = inp.scene
    here, toward = lv.here, lv.toward
    step_c = lv.by_lane.get(lv.siblings[toward].id) if toward in lv.siblings else None
    if step_c is None and lv.route_lane is not None and lv.route_lane != here.id:
        step_c = scene.route_candidate_id
    if step_c is None or not (inp.intent.style != "aggressive"
                              or lv.dist_end_m < LANE_MERGE_FORCE_M
                              or slower_target_lane(inp, lv) is not None):
        return False
    if inp.intent.style == "aggressive" and toward in lv.siblings \
            and close_in(inp, lv.siblings[toward].id) is not None:
        # the late merge leaves the MPC little road to find the gap: with a car beside
        # or within LC_MIN_GAP_M in the target lane, wait for a gap as any other change
        # does (lane seed 10055, training: merged without the gap test into the car
        # beside)
        return False
    # the route candidate, as before rule 8 existed: the MPC merges along it
    # and its safety term keeps the gaps; SUMO drivers make room. A strict gap
    # test here found no gap in dense slow traffic (lane seed 119 missed its
    # exit), and a missed exit costs a 200 s timeout.
    for lid in lanes_on_edge(scene, scene.ego_candidates[step_c], here.edge_id):
        for v in scene.agents:
            if v.agent.lane_id == lid and abs(v.kin.longitudinal_m) < 40.0:
                plan.attend(v, "in the lane I merge into")
    plan.ego_index = step_c
    plan.notes.append(
        f"My route needs {lv.need} lane change(s) within {lv.dist_end_m:.0f} m; I "
        "move towards that lane now and keep safe gaps.")
    return True


def lanes_on_edge(scene: Scene, candidate: Candidate, edge_id: str) -> list[str]:
    """The lanes of ``candidate`` on the edge ``edge_id`` (the ego's: where a lane-change
    candidate leaves the ego's lane and enters the next one)."""
    return [lid for lid in candidate.lane_ids
            if (ln := scene.lanes.get(lid)) is not None and ln.edge_id == edge_id]


def slower_target_lane(inp: RuleInputs, lv: LaneView) -> Optional[float]:
    """The speed of the slowest vehicle in the next lane towards the route's lanes, from
    beside the ego to ``SLOW_LEADER_RANGE_M`` ahead, when it drives
    ``LATE_MERGE_SPEED_DIFF_MPS`` slower than the ego (else None)."""
    if lv.toward is None or lv.toward not in lv.siblings:
        return None
    target = lv.siblings[lv.toward].id
    ego = inp.scene.obs.ego
    slowest: Optional[float] = None
    for v in inp.scene.agents:
        lon = v.kin.longitudinal_m
        if v.agent.lane_id == target and -ego.length_m <= lon <= SLOW_LEADER_RANGE_M \
                and v.agent.v_mps < ego.v_mps - LATE_MERGE_SPEED_DIFF_MPS:
            slowest = v.agent.v_mps if slowest is None else min(slowest, v.agent.v_mps)
    return slowest


def overtake(inp: RuleInputs, lv: LaneView, lead_here: AgentView) -> Optional[Want]:
    """The fastest open neighbour lane (its leader's speed, or the limit) that beats the
    slow leader by ``SLOW_LEADER_GAIN_MPS``; away from the route's lanes only when
    aggressive with road enough to come back."""
    style = inp.intent.style
    here = lv.here
    gain = SLOW_LEADER_GAIN_MPS * (0.5 if style == "aggressive" else 1.0)
    best: Optional[tuple[float, int]] = None
    for i in (here.index - 1, here.index + 1):
        nb = lv.siblings.get(i)
        if nb is None or nb.id in lv.closed:
            continue
        # moving away from the route lanes only with road enough to come back
        need_after = min((abs(j - i) for j in lv.ok_idx), default=0)
        if need_after > lv.need and (
                style != "aggressive"
                or lv.dist_end_m < (need_after * LANE_MERGE_PER_CHANGE_M
                                    + LANE_MERGE_SLACK_M) * 2.0):
            continue  # away from the lanes the route needs: aggressive only
        lead_nb, _ = lane_state(inp.scene, nb.id)
        v_nb = nb.speed_limit_mps if lead_nb is None or \
            lead_nb.kin.longitudinal_m > SLOW_LEADER_RANGE_M else lead_nb.agent.v_mps
        if v_nb - lead_here.agent.v_mps >= gain and (best is None or v_nb > best[0]):
            best = (v_nb, i)
    if best is None:
        return None
    side = "left" if (best[1] > here.index) != lv.left_hand else "right"
    return Want(best[1], f"{lead_here.id} ahead drives {lead_here.agent.v_mps:.1f} m/s, "
                f"the {side} lane is faster, so I overtake")


def change_candidate(scene: Scene, lv: LaneView, want: int) -> Optional[int]:
    """The offered candidate into lane index ``want``, else the route candidate when it
    goes that way (it may cross the lane to its end); None: no candidate goes there."""
    here = lv.here
    cand = lv.by_lane.get(lv.siblings[want].id)
    if cand is None and lv.route_lane is not None:
        rl = scene.lanes[lv.route_lane]
        if (rl.index - here.index) * (want - here.index) > 0:
            cand = scene.route_candidate_id
    return cand


def crossed_lanes(scene: Scene, lv: LaneView, want: int, cand: int) -> list[Lane]:
    """The lanes the change crosses up to its target (the route candidate's own lane when
    it is the one chosen)."""
    here, siblings = lv.here, lv.siblings
    end = want
    if cand == scene.route_candidate_id and lv.route_lane is not None:
        end = scene.lanes[lv.route_lane].index
    return [siblings[i] for i in range(min(here.index, end), max(here.index, end) + 1)
            if i != here.index and i in siblings]


def gap_blocker(inp: RuleInputs, plan: Plan, crossed: list[Lane], side: str
                ) -> Optional[tuple[AgentView, str]]:
    """The leader / follower in the crossed lanes closest inside its needed gap
    (``LC_*`` scaled by the style; beside the ego: gap 0), with "ahead" / "behind"; every
    one of them is attended."""
    ego = inp.scene.obs.ego
    blocker: Optional[tuple[AgentView, str]] = None
    for ln in crossed:
        lead_nb, follow_nb = lane_state(inp.scene, ln.id)
        for v, where in ((lead_nb, "ahead"), (follow_nb, "behind")):
            if v is None:
                continue
            plan.attend(v, f"in the {side} lane {where}")
            gap = v.kin.gap_m
            need_gap = change_gap_m(inp, v, where)
            if v.kin.longitudinal_m > -0.5 * ego.length_m and \
                    v.kin.longitudinal_m < 0.5 * ego.length_m + v.agent.length_m:
                gap = 0.0  # beside me
            if gap < need_gap and (blocker is None or gap < blocker[0].kin.gap_m):
                blocker = (v, where)
    return blocker


def wait_for_gap(inp: RuleInputs, plan: Plan, lv: LaneView, lead: LeaderState, want: Want,
                 blocker: tuple[AgentView, str]) -> str:
    """No gap for the wanted change yet: stop ``STANDOFF_M`` behind a blocking vehicle (or
    creep up to that point); an urgent change lets the car in the target lane draw ahead
    or gets ahead of a faster one behind. Returns "wait"."""
    cfg = inp.cfg
    accel = inp.accel
    ego = inp.scene.obs.ego
    lead_here = lead.lead
    if lead.blocked and lead_here is not None and not plan.speed_set:
        # wait far enough behind the standing vehicle to steer round it later (a car
        # cannot reverse, and from a few metres the swerve is out of its steering reach)
        d_stop = lead_here.kin.gap_m - STANDOFF_M
        if lead_here.agent.v_mps >= cfg.moving_speed_mps:  # braking: where it will stand
            d_stop += lead_here.agent.v_mps ** 2 / (
                2.0 * max(-lead_here.agent.a_mps2, HARD_BRAKE_MPS2))
        if ego.v_mps < cfg.moving_speed_mps and d_stop > 8.0:
            plan.accel_index = mildest_accel(accel)  # creep up to the stand-off point
        else:
            # a braking bias (a neutral one lets the MPC speed up to just behind it)
            plan.accel_index = stop_index(accel, ego.v_mps, max(d_stop, 0.0), None,
                                          cfg.moving_speed_mps)
            plan.notes.append(f"I stop about {STANDOFF_M:.0f} m behind {lead_here.id} "
                              "so I can still steer round it.")
        plan.speed_set = True
        plan.weights["action"] = "high"
        return "wait"
    v, where = blocker
    if want.urgent and where == "ahead" and v.agent.v_mps < ego.v_mps + 1.0 \
            and not plan.speed_set:
        # let the car beside / ahead in the target lane draw ahead, then merge behind it
        plan.accel_index = brake_index(accel, 1.0, False)
        plan.speed_set = True
    elif want.urgent and where == "behind" and not plan.speed_set:
        if inp.intent.style == "aggressive" and \
                not room_ahead_of_follower(inp, lv.siblings[want.index]):
            # no room for the ego between it and the target lane's leader: getting
            # ahead of it cannot end in a gap; drop back and merge behind it (lane seed
            # 10055, training, aggressive: sped up beside the follower below a leader
            # 9 m ahead of it, ran out of road and merged into the follower)
            plan.accel_index = brake_index(accel, 1.0, False)
            plan.speed_set = True
            plan.notes.append(f"There is no room in front of {v.id}, so I drop back to "
                              "merge behind it.")
        elif ego.v_mps < 0.8 * lv.here.speed_limit_mps:
            # a faster car behind in the target lane: get ahead of it if I can
            plan.accel_index = mildest_accel(accel)
            plan.speed_set = True
    return "wait"


def room_ahead_of_follower(inp: RuleInputs, target: Lane) -> bool:
    """The leader of ``target`` (ahead of the ego) leaves the lane-change gap a change in
    front of its follower needs (none in the lane ahead: room)."""
    lead_nb, _ = lane_state(inp.scene, target.id)
    if lead_nb is None:
        return True
    return lead_nb.kin.gap_m >= change_gap_m(inp, lead_nb, "ahead")


def change_gap_m(inp: RuleInputs, v: AgentView, where: str) -> float:
    """The bumper gap a lane change needs to ``v``, the new leader ("ahead") or follower
    ("behind") in the target lane: ``LC_MIN_GAP_M`` plus the style's share of the headway
    and of what the speed difference closes in ``LC_CLOSING_HORIZON_S``."""
    ego = inp.scene.obs.ego
    style = inp.intent.style
    if style == "aggressive" and inp.scene.obs.stamp_s < AGGRESSIVE_OVERTAKE_AFTER_S:
        style = "normal"
    style_f = LC_STYLE_FACTOR[style]
    if where == "ahead":
        closing = max(0.0, ego.v_mps - v.agent.v_mps)
        return LC_MIN_GAP_M + style_f * (LC_HEADWAY_S * ego.v_mps
                                         + LC_CLOSING_HORIZON_S * closing)
    closing = max(0.0, v.agent.v_mps - ego.v_mps)
    return LC_MIN_GAP_M + style_f * (LC_HEADWAY_S * v.agent.v_mps
                                     + LC_CLOSING_HORIZON_S * closing)


def close_in(inp: RuleInputs, lane_id: str) -> Optional[AgentView]:
    """A vehicle along ``lane_id`` beside the ego or closer than ``LC_MIN_GAP_M`` (box
    to box), the minimum gap of any lane change."""
    for v in inp.scene.agents:
        if v.agent.lane_id == lane_id and abs(v.kin.heading_rel_rad) <= ALONG_RAD \
                and v.kin.gap_m < LC_MIN_GAP_M:
            return v
    return None


def beside_in_route_lane(inp: RuleInputs) -> Optional[AgentView]:
    """Aggressive style, within the late merge's reach of the edge's end
    (``LANE_MERGE_AGGRESSIVE``) with the route's lane change still to be made: a vehicle
    in the next lane towards the route's lanes beside the ego or closer than
    ``LC_MIN_GAP_M`` (None otherwise). The late merge runs out of road: within the
    lookahead of the edge's end the route candidate merges (the lane rule no longer
    applies there) and the MPC cut in ahead of such a car (lane seeds 10055, training,
    and 119, development: the ego sped up beside it and merged into it)."""
    scene = inp.scene
    ego = scene.obs.ego
    here = scene.lanes.get(ego.lane_id or "")
    if inp.intent.style != "aggressive" or here is None or here.internal:
        return None
    siblings = scene.edge_lanes(here)
    need, toward = changes_toward(
        here.index, [ln.index for ln in continuing_lanes(scene, here, siblings)])
    if len(siblings) < 2 or toward is None:
        return None
    merge_m = need * LANE_MERGE_PER_CHANGE_M + LANE_MERGE_SLACK_M
    if here.length_m - ego.lane_pos_m >= merge_m * LANE_MERGE_AGGRESSIVE:
        return None
    target = siblings.get(toward)
    return None if target is None else close_in(inp, target.id)
