"""Rule 3: gap acceptance of a left turn (paper Fig. 1; a right turn in left-hand traffic).

Oncoming agents whose straight path crosses the ego's turn path are compared by time:
the agent's arrival at the crossing (constant speed) against the ego's time to clear it
(accelerating from its speed); the difference must reach ``safe_gap_s`` (less after a
"go": no flapping). Too far in to stop comfortably before the first oncoming lane ->
commit and clear briskly (never stop inside the oncoming lanes). Gap too small -> stop
before the stop line or the first oncoming lane (the braking interval whose stop lands
nearest that point); far from the line the stop is put off to a later decision. Safe gap
near / in the junction -> accelerate through; farther -> approach at
``approach_turn_speed_mps``."""
from __future__ import annotations

import math
from typing import Optional

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_llm_planner.route import Maneuver, crossing, next_maneuver
from lmpc_llm_planner.scene import AgentView, wrap_rad

from .intervals import Intervals, mid, neutral, required_decel, stop_index
from .junction import (
    CLEAR_MARGIN_M, GO_ZONE_M, Conflict, approach_turn, commit, go_accel_mps2, go_briskly,
    stop_brake_limit_mps2, stop_can_wait, travel_time_s,
)
from .plan import Plan, RuleInputs
from .scene_helpers import queued_behind

STARTING_MAX_MPS = 6.0
STARTING_MIN_ACCEL_MPS2 = 0.5
STARTING_WITHIN_M = 12.0
"""A crossing vehicle starting into the junction (``crossing_conflict``): slower than
this, accelerating at least this much, its front at most this far from the crossing."""
CROSSING_MISS_M = 4.0
"""An agent's ray passing the ego's path farther than this does not cross it."""


def left_turn_rule(inp: RuleInputs, plan: Plan) -> str:
    """"none" (no such turn ahead), "go", "yield" (stop before the stop line / the first
    oncoming lane) or "commit" (too far in to stop before the oncoming lanes: clear them
    briskly)."""
    cfg = inp.cfg
    obs = inp.scene.obs
    man = next_maneuver(obs, inp.scene.lanes, max_distance_m=cfg.junction_attention_m)
    if man is None or man.dist_to_stop_line_m > cfg.junction_attention_m:
        return "none"
    yield_dirs = ("r", "R") if obs.map.left_hand_traffic else ("l", "L")
    if man.direction not in yield_dirs:
        return "none"
    turn = "right" if obs.map.left_hand_traffic else "left"
    ego = obs.ego
    go_accel = go_accel_mps2(inp)
    conflicts = []
    for view in inp.scene.agents:
        c = oncoming_conflict(inp, view, man, yield_dirs, go_accel)
        if c is None:
            c = crossing_conflict(inp, view, man, go_accel)
        if c is not None:
            conflicts.append(c)
    if man.inside_junction:
        plan.steer_index = steer_for_path(man, inp.steer)
    for c in conflicts:
        plan.attend(c.view, f"{c.what}, conflicts with my turn")
    # the ego's front to the first oncoming lane it must cross (the conflict zone)
    zone_m = min((c.zone_start_m for c in conflicts), default=None)
    front_to_zone = None if zone_m is None else \
        man.dist_to_stop_line_m + zone_m - 0.5 * ego.length_m
    can_stop = front_to_zone is not None and front_to_zone > 0.0 and (
        ego.v_mps < cfg.moving_speed_mps
        or ego.v_mps ** 2 / (2.0 * front_to_zone) <= cfg.commit_decel_mps2)
    # hysteresis: once going, a gap that shrinks a little (estimates are noisy)
    # does not stop the ego again
    # a queue behind a waiting ego: accept the gap a driver under that pressure takes
    # (the hysteresis margin, never less); every second waited holds them up too
    queued = queued_behind(inp.scene)
    margin = inp.safe_gap_s - (cfg.go_hysteresis_s if inp.previous_go or queued is not None
                               else 0.0)
    unsafe = [c for c in conflicts if c.gap_s < margin]
    if conflicts and not can_stop and (man.inside_junction or ego.v_mps > 1.0):
        # inside (or too close to stop before) the oncoming lanes: never stop there
        return commit(inp, plan, (
            f"I am committed to the {turn} turn (I cannot stop before the oncoming "
            "lane any more), so I clear the junction briskly and keep a safe distance."))
    if not unsafe:
        return _turn_go(inp, plan, man, conflicts, turn=turn, margin=margin)
    return _turn_yield(inp, plan, man, unsafe, turn=turn, margin=margin,
                       front_to_zone=front_to_zone)


def _turn_go(inp: RuleInputs, plan: Plan, man: Maneuver, conflicts: list[Conflict], *,
             turn: str, margin: float) -> str:
    """Every oncoming gap is safe: turn now (near / in the junction), keep the speed the
    gap was judged at, or approach at the turn speed when nothing conflicts."""
    ego = inp.scene.obs.ego
    if conflicts:
        plan.notes.append(
            f"I turn {turn}; the oncoming gap is {min(c.gap_s for c in conflicts):.1f} "
            f"s beyond my clearing time (enough from {margin:.1f} s), so I turn now."
        )
    else:
        plan.notes.append(
            f"I turn {turn} at the junction ahead; no oncoming traffic conflicts, "
            "so I go."
        )
    if man.inside_junction or man.dist_to_stop_line_m < 0.5 * ego.length_m + GO_ZONE_M:
        go_briskly(inp, plan)
    elif conflicts:
        # the gap was judged at the current speed: keep it (slowing down to the
        # turn speed first turned accepted gaps into missed ones); the MPC slows
        # for the curve itself
        plan.accel_index = neutral(inp.accel)
        plan.speed_set = True
        plan.notes.append("I keep my speed up to the junction.")
    else:
        approach_turn(inp, plan, man, ego.v_mps)
    return "go"


def _turn_yield(inp: RuleInputs, plan: Plan, man: Maneuver, unsafe: list[Conflict], *,
                turn: str, margin: float, front_to_zone: Optional[float]) -> str:
    """A gap is too small: stop before the stop line or, past it, before the first
    oncoming lane (keeping the speed for now when far out); commit when neither stop is
    comfortable."""
    cfg = inp.cfg
    ego = inp.scene.obs.ego
    half_len = 0.5 * ego.length_m
    worst = min(unsafe, key=lambda c: (c.gap_s, c.view.id))
    vmax_brake = stop_brake_limit_mps2(inp)
    # where to stop: before the stop line, or (past it) before the first oncoming lane
    targets = []
    if man.dist_to_stop_line_m - half_len - cfg.stop_margin_m > 0.0:
        targets.append((man.dist_to_stop_line_m - half_len - cfg.stop_margin_m,
                        "stop line"))
    if front_to_zone is not None:
        targets.append((front_to_zone - cfg.stop_margin_m, "oncoming lane"))
    # the farthest the ego may stop: before the first oncoming lane it must cross
    d_limit = front_to_zone - cfg.stop_margin_m if front_to_zone is not None else None
    for d_stop, where in targets:
        need = required_decel(ego.v_mps, d_stop, cfg.moving_speed_mps)
        if need is None or need > vmax_brake:
            continue
        plan.speed_set = True
        # tracking stays "normal": the MPC's reference brakes with the bias anyway, and
        # a "low" tracking weight let the safety term push the ego sideways off its
        # lane when an oncoming car came near (usi seed 6)
        plan.weights.update(action="high", safety="high")
        reason = (
            f"I turn {turn} and must yield to {worst.what} {worst.view.id}: it reaches the "
            f"crossing in {worst.t_agent_s:.1f} s, I would need {worst.t_clear_s:.1f} s "
            f"to clear it (gap {worst.gap_s:.1f} s, enough from {margin:.1f} s)."
        )
        v = ego.v_mps
        if where == "stop line" and stop_can_wait(inp, v, d_stop):
            # Keep the speed until the next decision (stopping then is still
            # comfortable); the MPC itself yields to the attended oncoming cars.
            plan.accel_index = neutral(inp.accel)
            plan.notes.append(reason + f" I keep my speed for now and will stop before "
                              f"the {where} ({d_stop:.0f} m) if the gap stays too small.")
            return "yield"
        plan.accel_index = stop_index(inp.accel, v, d_stop, d_limit, cfg.moving_speed_mps)
        plan.notes.append(reason + f" I stop before the {where} ({max(d_stop, 0.0):.0f} m,"
                          f" needs {need:.1f} m/s2) and wait for a gap.")
        return "yield"
    return commit(inp, plan, (
        f"I am too close to stop before the crossing with {worst.view.id}; I commit to the "
        f"{turn} turn, clear it briskly and keep a safe distance."))


def oncoming_conflict(inp: RuleInputs, view: AgentView, man: Maneuver,
                      yield_dirs: tuple[str, ...], go_accel_mps2: float) -> Optional[Conflict]:
    """The conflict when the agent is oncoming and its path crosses the ego's turn."""
    cfg = inp.cfg
    ag = view.agent
    off_rad = abs(wrap_rad(ag.yaw_rad - man.approach_yaw_rad - math.pi))
    if off_rad > cfg.oncoming_heading_tol_rad:
        return None
    # On a lane whose connections all turn the same way as the ego (an opposite
    # left-turn lane in right-hand traffic) the agent's path does not cross ours.
    lane = inp.scene.lanes.get(ag.lane_id or "")
    if lane is not None and not lane.internal and lane.successors and all(
        lk.direction in yield_dirs + ("t",) for lk in lane.successors
    ):
        return None
    return _conflict(inp, view, man, go_accel_mps2, "oncoming")


def crossing_conflict(inp: RuleInputs, view: AgentView, man: Maneuver,
                      go_accel_mps2: float) -> Optional[Conflict]:
    """The conflict with a vehicle of the crossing road that moves towards the ego's turn.
    It should yield, but a SUMO car does not see an ego placed by ``moveToXY`` coming
    until that is on the junction's internal lane: one that has started from its line
    keeps going (usi training seed 10005: it moved off with the ego, SUMO stopped it in
    the junction, and it restarted into the ego passing in front of it). Standing ones
    wait."""
    cfg = inp.cfg
    ag = view.agent
    off_rad = abs(abs(wrap_rad(ag.yaw_rad - man.approach_yaw_rad)) - 0.5 * math.pi)
    if off_rad > cfg.oncoming_heading_tol_rad or not (
            cfg.moving_speed_mps <= ag.v_mps < STARTING_MAX_MPS
            and ag.a_mps2 >= STARTING_MIN_ACCEL_MPS2):
        return None
    c = _conflict(inp, view, man, go_accel_mps2, "crossing")
    if c is None or c.t_agent_s * ag.v_mps > STARTING_WITHIN_M:
        return None
    return c


def _conflict(inp: RuleInputs, view: AgentView, man: Maneuver, go_accel_mps2: float,
              what: str) -> Optional[Conflict]:
    cfg = inp.cfg
    ag = view.agent
    cr = crossing(man.path, x_m=ag.x_m, y_m=ag.y_m, yaw_rad=ag.yaw_rad)
    if cr is None or cr.miss_m > CROSSING_MISS_M:
        return None
    clear_len = 0.5 * ag.length_m + 0.5 * ag.width_m + CLEAR_MARGIN_M
    if cr.agent_along_m < -clear_len:
        return None  # already past the crossing
    d_agent_front = cr.agent_along_m - 0.5 * ag.length_m - CLEAR_MARGIN_M
    ego = inp.scene.obs.ego
    if ag.v_mps < cfg.moving_speed_mps:
        if d_agent_front > 2.0:
            return None  # stopped short of the crossing: it is waiting
        if man.inside_junction and ego.v_mps < cfg.moving_speed_mps and d_agent_front > 0.0:
            # both standing, the ego inside the junction, the agent short of the crossing:
            # it waits for the ego (traffic in the junction goes first). Taken as
            # arriving "in 0 s", the ego waited for it and it for the ego until the
            # timeout (si 110 at latency 0, a car stopped 1-2 m short of the crossing)
            return None
        t_agent = 0.0
    else:
        t_agent = max(0.0, d_agent_front) / ag.v_mps
    # The ego clears the crossing once its rear is past the agent's path.
    d_clear = man.dist_to_stop_line_m + cr.ego_s_m + 0.5 * ego.length_m \
        + 0.5 * ag.width_m + CLEAR_MARGIN_M
    d_line = max(0.0, man.dist_to_stop_line_m)
    if ego.v_mps > cfg.turn_speed_mps and d_line > 0.0:
        # faster than the turn: about this speed to the line, then the turn speed (the
        # MPC slows for the curve; assuming the approach speed through the junction
        # overrated the gap)
        t_clear = d_line / ego.v_mps + (d_clear - d_line) / cfg.turn_speed_mps
    else:
        t_clear = travel_time_s(
            d_clear, v0_mps=ego.v_mps, accel_mps2=go_accel_mps2,
            vmax_mps=cfg.turn_speed_mps,
        )
    zone = cr.ego_s_m - 0.5 * ag.width_m - CLEAR_MARGIN_M
    return Conflict(view, cr.ego_s_m, t_agent, t_clear, zone, what)


def steer_for_path(man: Maneuver, steer: Intervals) -> int:
    """Steer interval matching the mean curvature of the junction path (kinematic bicycle)."""
    path = man.path
    if len(path) < 3:
        return neutral(steer)
    d = path[1:] - path[:-1]
    yaws = [math.atan2(dy, dx) for dx, dy in d]
    turn = sum(wrap_rad(b - a) for a, b in zip(yaws[:-1], yaws[1:]))
    length = float(sum(math.hypot(dx, dy) for dx, dy in d))
    if length < 1e-3:
        return neutral(steer)
    delta = math.atan(DEFAULT_VEHICLE.wheelbase_m * turn / length)
    inside = [i for i, (lo, hi) in enumerate(steer) if lo <= delta <= hi]
    if inside:
        return min(inside, key=lambda i: (abs(mid(steer[i]) - delta), i))
    return min(range(len(steer)), key=lambda i: (abs(mid(steer[i]) - delta), i))
