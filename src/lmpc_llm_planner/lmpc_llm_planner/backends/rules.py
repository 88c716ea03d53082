"""A deterministic reasoner that applies traffic rules to the request's structured
inputs and answers the same JSON text an LLM would (so it goes through the same
validation and translation).

Rules (docs/lmpc_llm_planner.md, "The rules backend", has the numbers):
1. The ego tracks the candidate that follows its route.
2. The leader in the ego's lane and every agent within ``nearby_attention_m`` are
   attended, as are the agents the rules below reason about.
3. Gap acceptance in a left turn (paper Fig. 1; a right turn in left-hand traffic):
   oncoming agents whose straight path crosses the ego's turn path are compared by
   time: the agent's arrival at the crossing (constant speed) against the ego's time
   to clear it (accelerating from its speed); the difference must reach
   ``safe_gap_s`` (less after a "go": no flapping). Too far in to stop comfortably
   before the first oncoming lane -> commit and clear briskly (never stop inside the
   oncoming lanes). Gap too small -> stop before the stop line or the first oncoming
   lane (the braking interval whose stop lands nearest that point); far from the
   line the stop is put off to a later decision. Safe gap near / in the junction ->
   accelerate through; farther -> approach at ``approach_turn_speed_mps``.
4. An agent in the ego's own path ahead closing in (TTC under ``path_ttc_s``) ->
   braking bias, safety "high".
5. Otherwise go: accelerating (below 80 % of the speed limit) or neutral bias,
   normal weights.
Emergency requests run the same rules; only a threat in the ego's path with a TTC
under ``commit_ttc_s`` brakes at the strongest interval.
An instruction mentioning careful / conservative / cautious driving lengthens the
safe gap and raises the safety weight. The time and gap estimates are
APPROXIMATIONS (constant speeds, straight agent paths), documented in route.py.
"""
from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.config import RulesConfig
from lmpc_llm_planner.route import Maneuver, crossing, next_maneuver
from lmpc_llm_planner.scene import AgentView, Scene, wrap_rad

CONSERVATIVE_WORDS = re.compile(r"\b(careful|carefully|conservative|conservatively|cautious"
                                r"|cautiously|defensive|defensively|safe|safely|slow)\b", re.I)
CROSSING_MISS_M = 4.0
"""An agent's ray passing the ego's path farther than this does not cross it."""
CLEAR_MARGIN_M = 1.0
_GO_ZONE_M = 8.0
"""With a safe gap and the front this close to the stop line, the ego turns briskly
(accelerating) instead of holding its approach speed."""


def travel_time_s(dist_m: float, *, v0_mps: float, accel_mps2: float, vmax_mps: float) -> float:
    """Time to cover ``dist_m`` from ``v0_mps`` accelerating at ``accel_mps2`` up to
    ``vmax_mps`` (a speed above ``vmax_mps`` is kept)."""
    if dist_m <= 0.0:
        return 0.0
    vmax = max(vmax_mps, v0_mps)
    if v0_mps >= vmax:
        return dist_m / max(v0_mps, 1e-3)
    t_acc = (vmax - v0_mps) / accel_mps2
    d_acc = v0_mps * t_acc + 0.5 * accel_mps2 * t_acc**2
    if dist_m <= d_acc:
        return (-v0_mps + math.sqrt(v0_mps**2 + 2.0 * accel_mps2 * dist_m)) / accel_mps2
    return t_acc + (dist_m - d_acc) / vmax


@dataclass(frozen=True)
class Conflict:
    """An oncoming agent whose path crosses the ego's turn."""

    view: AgentView
    ego_s_m: float
    """Arc length along the ego's junction path to the crossing."""
    t_agent_s: float
    """When the agent reaches the crossing (constant speed)."""
    t_clear_s: float
    """When the ego would have cleared it (accelerating from its speed)."""
    zone_start_m: float
    """Arc length along the junction path where the agent's lane (its box width plus a
    margin) begins: the ego must not stop beyond it."""

    @property
    def gap_s(self) -> float:
        return self.t_agent_s - self.t_clear_s


@dataclass
class _Plan:
    attention: dict[str, str] = field(default_factory=dict)
    """id -> why (insertion order = the order of the reasoning)."""
    accel_index: int = 0
    steer_index: int = 0
    speed_set: bool = False
    """A rule chose the accel interval (the default "go" must not override it)."""
    weights: dict[str, str] = field(
        default_factory=lambda: {
            "tracking": "normal", "action": "normal", "smoothness": "normal", "safety": "normal",
        }
    )
    notes: list[str] = field(default_factory=list)

    def attend(self, view: AgentView, why: str) -> None:
        self.attention.setdefault(view.id, why)


class RulesBackend:
    """The ``rules`` backend: deterministic, same inputs -> same text."""

    name = "rules"
    reported_latency_s = 0.0
    """The latency its decisions carry (a stand-in for an instant reasoner): the measured
    wall time (logged as ``measured_latency_s``) depends on the machine's load, and a
    value above one step would shift when a decision takes effect, so runs would not
    repeat. ``fixed_latency_s`` in the planner config still overrides it."""

    def __init__(self, config: Optional[RulesConfig] = None) -> None:
        self.config = config or RulesConfig()

    # -- Backend ---------------------------------------------------------------------------
    def complete(self, request: DecisionRequest) -> BackendReply:
        """Answer with the decision JSON (the stage's part in chained mode)."""
        t0 = time.perf_counter()
        answer = self.decide(request)
        if request.stage != "all":
            answer = {"reasoning": answer["reasoning"], request.stage: answer[request.stage]}
        text = json.dumps(answer, separators=(",", ":"))
        return BackendReply(text=text, latency_s=time.perf_counter() - t0)

    # -- reasoning ------------------------------------------------------------------------
    def decide(self, request: DecisionRequest) -> dict[str, Any]:
        """The full answer object (all stages, or the emergency variant).

        An emergency request is answered by the same rules (a left turn that has
        committed keeps going, one that waits keeps waiting; the answer never flaps
        to "keep my speed" while stopped); only a threat ahead in the ego's own path
        makes it brake hard."""
        cfg = self.config
        scene = request.scene
        accel = request.accel_intervals_mps2
        steer = request.steer_intervals_rad
        emergency = request.mode == "emergency"
        plan = _Plan(accel_index=_neutral(accel), steer_index=_neutral(steer))
        careful = bool(request.instruction and CONSERVATIVE_WORDS.search(request.instruction))
        safe_gap_s = cfg.safe_gap_s * (cfg.conservative_gap_factor if careful else 1.0)
        if careful:
            plan.weights["safety"] = "high"
            plan.notes.append("The user asked for careful driving, so I keep larger gaps.")
        if emergency:
            plan.weights["safety"] = "high"
        previous_go = request.previous is not None and request.previous.accel_bias_mps2 >= 0.0
        lo_neutral = accel[_neutral(accel)][0]
        previous_stop = request.previous is not None and \
            request.previous.accel_bias_mps2 < lo_neutral

        ego = scene.obs.ego
        self._attend_defaults(scene, plan)
        turn = self._left_turn_rule(scene, plan, accel, steer, safe_gap_s, previous_go,
                                    emergency, previous_stop)
        if turn != "yield":
            self._path_rule(scene, plan, accel, emergency=emergency,
                            committed=turn == "commit")
        if not plan.speed_set:
            self._go(scene, plan, accel)
        if emergency:
            return {
                "reasoning": ("Emergency check. " + " ".join(plan.notes)).strip(),
                "action_guidance": _guidance(plan),
                "weight_adjustment": dict(plan.weights),
            }
        attention = list(plan.attention)
        encoding = {
            "ego_trajectory": scene.route_candidate_id,
            "attention": attention,
            "agent_trajectories": {
                aid: scene.agent(aid).closest_heading_id for aid in attention  # type: ignore
            },
        }
        ego_label = scene.ego_candidates[scene.route_candidate_id].label
        head = (
            f"I follow my route ({ego_label}) at {ego.v_mps:.1f} m/s."
            if scene.ego_candidates else ""
        )
        if attention:
            head += " I attend to " + ", ".join(
                f"{aid} ({why})" for aid, why in plan.attention.items()
            ) + "."
        return {
            "reasoning": " ".join([head] + plan.notes).strip(),
            "scenario_encoding": encoding,
            "action_guidance": _guidance(plan),
            "weight_adjustment": dict(plan.weights),
        }

    def _attend_defaults(self, scene: Scene, plan: _Plan) -> None:
        cfg = self.config
        route_ahead = set(scene.obs.map.ego_route[scene.obs.ego.route_index:][:4])
        leader: Optional[AgentView] = None
        for view in scene.agents:
            k = view.kin
            same_lane = (
                view.agent.lane_id is not None and view.agent.lane_id in route_ahead
            ) or (k.relation == "ahead" and k.motion == "same direction")
            if k.longitudinal_m > 0.0 and same_lane and k.longitudinal_m <= cfg.leader_range_m:
                if leader is None or k.longitudinal_m < leader.kin.longitudinal_m:
                    leader = view
        if leader is not None:
            plan.attend(leader, "leader in my lane")
        for view in scene.agents:
            if view.kin.distance_m <= cfg.nearby_attention_m:
                plan.attend(view, f"within {view.kin.distance_m:.0f} m")

    def _left_turn_rule(
        self,
        scene: Scene,
        plan: _Plan,
        accel: tuple[tuple[float, float], ...],
        steer: tuple[tuple[float, float], ...],
        safe_gap_s: float,
        previous_go: bool,
        emergency: bool,
        previous_stop: bool = False,
    ) -> str:
        """Rule 3 (gap acceptance of a left turn): "none" (no such turn ahead), "go",
        "yield" (stop before the stop line / the first oncoming lane) or "commit"
        (too far in to stop before the oncoming lanes: clear them briskly)."""
        cfg = self.config
        obs = scene.obs
        man = next_maneuver(obs, scene.lanes, max_distance_m=cfg.junction_attention_m)
        if man is None or man.dist_to_stop_line_m > cfg.junction_attention_m:
            return "none"
        yield_dirs = ("r", "R") if obs.map.left_hand_traffic else ("l", "L")
        if man.direction not in yield_dirs:
            return "none"
        turn = "right" if obs.map.left_hand_traffic else "left"
        ego = obs.ego
        half_len = 0.5 * ego.length_m
        conflicts = []
        for view in scene.agents:
            c = self._oncoming_conflict(scene, view, man, yield_dirs)
            if c is not None:
                conflicts.append(c)
        if man.inside_junction:
            plan.steer_index = _steer_for_path(man, steer)
        for c in conflicts:
            plan.attend(c.view, "oncoming, conflicts with my turn")
        # the ego's front to the first oncoming lane it must cross (the conflict zone)
        zone_m = min((c.zone_start_m for c in conflicts), default=None)
        front_to_zone = None if zone_m is None else \
            man.dist_to_stop_line_m + zone_m - half_len
        can_stop = front_to_zone is not None and front_to_zone > 0.0 and (
            ego.v_mps < cfg.moving_speed_mps
            or ego.v_mps ** 2 / (2.0 * front_to_zone) <= cfg.commit_decel_mps2)
        # hysteresis: once going, a gap that shrinks a little (estimates are noisy)
        # does not stop the ego again
        margin = safe_gap_s - (cfg.go_hysteresis_s if previous_go else 0.0)
        unsafe = [c for c in conflicts if c.gap_s < margin]
        if conflicts and not can_stop and (man.inside_junction or ego.v_mps > 1.0):
            # inside (or too close to stop before) the oncoming lanes: never stop there
            plan.accel_index = _accel_index(accel, cfg.turn_accel_mps2)
            plan.speed_set = True
            plan.weights["safety"] = "high"
            plan.notes.append(
                f"I am committed to the {turn} turn (I cannot stop before the oncoming "
                "lane any more), so I clear the junction briskly and keep a safe distance."
            )
            return "commit"
        if not unsafe:
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
            if man.inside_junction or man.dist_to_stop_line_m < half_len + _GO_ZONE_M:
                plan.accel_index = _accel_index(accel, cfg.turn_accel_mps2)
                plan.speed_set = True
            else:
                self._approach_turn(man, ego.v_mps, plan, accel)
            return "go"
        worst = min(unsafe, key=lambda c: (c.gap_s, c.view.id))
        # a new stop must be comfortable (as the MPC's own yield rule): otherwise commit;
        # a stop already under way may brake harder (else it would flip to "commit"
        # half-way as the distance shrinks)
        vmax_brake = max(-lo for lo, _ in accel) if previous_stop else cfg.commit_decel_mps2
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
            need = _required_decel(ego.v_mps, d_stop, cfg.moving_speed_mps)
            if need is None or need > vmax_brake:
                continue
            plan.speed_set = True
            # tracking stays "normal": the MPC's reference brakes with the bias anyway, and
            # a "low" tracking weight let the safety term push the ego sideways off its
            # lane when an oncoming car came near (usi seed 6)
            plan.weights.update(action="high", safety="high")
            reason = (
                f"I turn {turn} and must yield to oncoming {worst.view.id}: it reaches the "
                f"crossing in {worst.t_agent_s:.1f} s, I would need {worst.t_clear_s:.1f} s "
                f"to clear it (gap {worst.gap_s:.1f} s, enough from {margin:.1f} s)."
            )
            v = ego.v_mps
            if where == "stop line" and not emergency and v >= cfg.moving_speed_mps and \
                    d_stop - v * cfg.replan_s > v * v / (2.0 * cfg.commit_decel_mps2) + 5.0:
                # far from the line: braking to a stop now would stop well short of it.
                # Keep the speed until the next decision (stopping then is still
                # comfortable); the MPC itself yields to the attended oncoming cars.
                plan.accel_index = _neutral(accel)
                plan.notes.append(reason + f" I keep my speed for now and will stop before "
                                  f"the {where} ({d_stop:.0f} m) if the gap stays too small.")
                return "yield"
            plan.accel_index = _stop_index(accel, v, d_stop, d_limit, cfg.moving_speed_mps)
            plan.notes.append(reason + f" I stop before the {where} ({max(d_stop, 0.0):.0f} m,"
                              f" needs {need:.1f} m/s2) and wait for a gap.")
            return "yield"
        plan.accel_index = _accel_index(accel, cfg.turn_accel_mps2)
        plan.speed_set = True
        plan.weights["safety"] = "high"
        plan.notes.append(
            f"I am too close to stop before the crossing with {worst.view.id}; I commit to the "
            f"{turn} turn, clear it briskly and keep a safe distance."
        )
        return "commit"

    def _approach_turn(
        self, man: Maneuver, v_mps: float, plan: _Plan, accel: tuple[tuple[float, float], ...]
    ) -> None:
        """Slow to ``approach_turn_speed_mps`` by the stop line (a driver about to turn does;
        it also leaves room to react to traffic not yet in sensing range)."""
        cfg = self.config
        d = man.dist_to_stop_line_m - 0.5 * DEFAULT_VEHICLE.length_m
        v_turn = cfg.approach_turn_speed_mps
        if man.inside_junction or d <= 0.0:
            return
        if v_mps > v_turn + 0.5:
            need = (v_mps**2 - v_turn**2) / (2.0 * d)
            if need > 0.2:
                plan.accel_index = _brake_index(accel, need * cfg.brake_margin_factor, False)
                plan.speed_set = True
                # At "normal" the MPC barely follows a bias (tracking the speed limit wins).
                plan.weights["action"] = "high"
                plan.notes.append(f"I slow down to {v_turn:.0f} m/s for the turn.")
                return
        # at about the turn speed, hold it: an accelerating bias lasts until the next
        # decision (``replan_s``) and would arrive too fast to stop for a late gap
        if v_mps + _mid(accel[_mildest_accel(accel)]) * cfg.replan_s >= v_turn + 1.0:
            plan.accel_index = _neutral(accel)
            plan.speed_set = True
            plan.weights["action"] = "high"
            plan.notes.append(f"I keep about {v_turn:.0f} m/s for the turn.")

    def _oncoming_conflict(
        self, scene: Scene, view: AgentView, man: Maneuver, yield_dirs: tuple[str, ...]
    ) -> Optional[Conflict]:
        """The conflict when the agent is oncoming and its path crosses the ego's turn."""
        cfg = self.config
        ag = view.agent
        off_rad = abs(wrap_rad(ag.yaw_rad - man.approach_yaw_rad - math.pi))
        if off_rad > cfg.oncoming_heading_tol_rad:
            return None
        # On a lane whose connections all turn the same way as the ego (an opposite
        # left-turn lane in right-hand traffic) the agent's path does not cross ours.
        lane = scene.lanes.get(ag.lane_id or "")
        if lane is not None and not lane.internal and lane.successors and all(
            lk.direction in yield_dirs + ("t",) for lk in lane.successors
        ):
            return None
        cr = crossing(man.path, x_m=ag.x_m, y_m=ag.y_m, yaw_rad=ag.yaw_rad)
        if cr is None or cr.miss_m > CROSSING_MISS_M:
            return None
        clear_len = 0.5 * ag.length_m + 0.5 * ag.width_m + CLEAR_MARGIN_M
        if cr.agent_along_m < -clear_len:
            return None  # already past the crossing
        d_agent_front = cr.agent_along_m - 0.5 * ag.length_m - CLEAR_MARGIN_M
        if ag.v_mps < cfg.moving_speed_mps:
            if d_agent_front > 2.0:
                return None  # stopped short of the crossing: it is waiting
            t_agent = 0.0
        else:
            t_agent = max(0.0, d_agent_front) / ag.v_mps
        # The ego clears the crossing once its rear is past the agent's path.
        ego = scene.obs.ego
        d_clear = man.dist_to_stop_line_m + cr.ego_s_m + 0.5 * ego.length_m \
            + 0.5 * ag.width_m + CLEAR_MARGIN_M
        t_clear = travel_time_s(
            d_clear, v0_mps=ego.v_mps, accel_mps2=cfg.turn_accel_mps2,
            vmax_mps=cfg.turn_speed_mps,
        )
        zone = cr.ego_s_m - 0.5 * ag.width_m - CLEAR_MARGIN_M
        return Conflict(view, cr.ego_s_m, t_agent, t_clear, zone)

    def _path_rule(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...], *,
        emergency: bool, committed: bool
    ) -> None:
        """Rule 4: brake for an agent in the ego's own path ahead (within the corridor of
        its route candidate) that it closes in on. Traffic that only passes near the
        path (an oncoming car in its own lane) is the turn rule's business."""
        cfg = self.config
        ego = scene.obs.ego
        path = _route_path(scene)
        threats = []
        for v in scene.agents:
            k = v.kin
            if k.longitudinal_m <= 0.0 or k.ttc_s is None:
                continue
            if path is not None:
                corridor = 0.5 * (ego.width_m + v.agent.width_m) + cfg.path_corridor_m
                if _distance_to_path(path, v.agent.x_m, v.agent.y_m) > corridor:
                    continue
            limit = cfg.path_ttc_s if not committed else cfg.commit_ttc_s
            if k.ttc_s < limit:
                threats.append(v)
        if not threats:
            return
        worst = min(threats, key=lambda v: (v.kin.ttc_s, v.id))
        plan.attend(worst, f"closing in, {worst.kin.ttc_s:.1f} s to collision")
        need = worst.kin.closing_speed_mps**2 / (2.0 * max(worst.kin.gap_m - 2.0, 0.5))
        if emergency and worst.kin.ttc_s is not None and worst.kin.ttc_s < cfg.commit_ttc_s:
            plan.accel_index = _strongest_brake(accel)
            plan.weights.update(tracking="low", action="high")
        else:
            plan.accel_index = _brake_index(accel, need * self.config.brake_margin_factor,
                                            False)
        plan.speed_set = True
        plan.weights["safety"] = "high"
        plan.notes.append(
            f"{worst.id} is {worst.kin.gap_m:.0f} m {worst.kin.relation} in my path and I "
            f"close in at {worst.kin.closing_speed_mps:.1f} m/s, so I brake to keep a safe "
            "distance."
        )

    def _go(self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...]) -> None:
        ego = scene.obs.ego
        lane = scene.lanes.get(ego.lane_id or "")
        limit = lane.speed_limit_mps if lane is not None else DEFAULT_VEHICLE.max_speed_mps
        if ego.v_mps < 0.8 * limit:
            plan.accel_index = _mildest_accel(accel)
            if not plan.notes:
                plan.notes.append(
                    f"The way is clear; I speed up towards the {limit:.1f} m/s limit."
                )
        elif not plan.notes:
            plan.notes.append("The way is clear; I keep my speed.")


# -- helpers --------------------------------------------------------------------------------
def _guidance(plan: _Plan) -> dict[str, int]:
    return {"accel_interval": plan.accel_index, "steer_interval": plan.steer_index}


def _mid(iv: tuple[float, float]) -> float:
    return 0.5 * (iv[0] + iv[1])


def _neutral(intervals: tuple[tuple[float, float], ...]) -> int:
    containing = [i for i, (lo, hi) in enumerate(intervals) if lo <= 0.0 <= hi]
    pool = containing or list(range(len(intervals)))
    return min(pool, key=lambda i: (abs(_mid(intervals[i])), i))


def _strongest_brake(intervals: tuple[tuple[float, float], ...]) -> int:
    return min(range(len(intervals)), key=lambda i: (_mid(intervals[i]), i))


def _accel_index(intervals: tuple[tuple[float, float], ...], want_mps2: float) -> int:
    """The mildest accelerating interval whose midpoint reaches ``want_mps2`` (else the
    strongest one)."""
    positive = sorted((i for i, iv in enumerate(intervals) if _mid(iv) > 0.0),
                      key=lambda i: _mid(intervals[i]))
    if not positive:
        return _neutral(intervals)
    for i in positive:
        if _mid(intervals[i]) >= 0.9 * want_mps2:
            return i
    return positive[-1]


def _route_path(scene: Scene) -> Optional[np.ndarray]:
    """(n, 2) points of the ego's route candidate (None without candidates)."""
    if not scene.ego_candidates:
        return None
    return scene.ego_candidates[scene.route_candidate_id].sample(60)


def _distance_to_path(path: np.ndarray, x_m: float, y_m: float) -> float:
    """Distance from (x, y) to the polyline ``path``."""
    a = path[:-1]
    d = np.diff(path, axis=0)
    len2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    t = np.clip(((x_m - a[:, 0]) * d[:, 0] + (y_m - a[:, 1]) * d[:, 1]) / len2, 0.0, 1.0)
    ex = x_m - a[:, 0] - t * d[:, 0]
    ey = y_m - a[:, 1] - t * d[:, 1]
    return float(np.sqrt(np.min(ex * ex + ey * ey)))


def _stop_index(intervals: tuple[tuple[float, float], ...], v_mps: float, d_stop_m: float,
                d_limit_m: Optional[float], still_mps: float) -> int:
    """The braking interval whose midpoint stops the ego (v^2 / 2a: the MPC brakes at the
    bias until it stands) nearest to ``d_stop_m`` without passing ``d_limit_m`` (nor the
    stop point by more than 1 m without a limit); stopped: the mildest (hold)."""
    braking = [i for i, iv in enumerate(intervals) if _mid(iv) < 0.0]
    if not braking:
        return _neutral(intervals)
    if v_mps < still_mps:
        return max(braking, key=lambda i: (_mid(intervals[i]), -i))
    limit = max(d_stop_m + 1.0, d_limit_m if d_limit_m is not None else d_stop_m + 1.0)
    fits = [i for i in braking if v_mps ** 2 / (-2.0 * _mid(intervals[i])) <= limit]
    if not fits:
        return min(braking, key=lambda i: (_mid(intervals[i]), i))
    return min(fits, key=lambda i: (abs(v_mps ** 2 / (-2.0 * _mid(intervals[i])) - d_stop_m),
                                    i))


def _mildest_accel(intervals: tuple[tuple[float, float], ...]) -> int:
    positive = [i for i, iv in enumerate(intervals) if _mid(iv) > 0.0]
    if not positive:
        return _neutral(intervals)
    return min(positive, key=lambda i: (_mid(intervals[i]), i))


def _brake_index(intervals: tuple[tuple[float, float], ...], need_mps2: float, hold: bool) -> int:
    """The mildest braking interval whose midpoint brakes at least ``need_mps2``
    (``hold``: the mildest braking interval, to stay stopped)."""
    braking = sorted(
        (i for i, iv in enumerate(intervals) if _mid(iv) < 0.0), key=lambda i: -_mid(intervals[i])
    )
    if not braking:
        return _neutral(intervals)
    if hold:
        return braking[0]
    for i in braking:
        if -_mid(intervals[i]) >= need_mps2:
            return i
    return braking[-1]


def _required_decel(v_mps: float, dist_m: float, still_mps: float) -> Optional[float]:
    """v^2 / 2d; None when the distance is gone while still moving."""
    if v_mps < still_mps:
        return 0.0
    if dist_m <= 0.1:
        return None
    return v_mps**2 / (2.0 * dist_m)


def _steer_for_path(man: Maneuver, steer: tuple[tuple[float, float], ...]) -> int:
    """Steer interval matching the mean curvature of the junction path (kinematic bicycle)."""
    path = man.path
    if len(path) < 3:
        return _neutral(steer)
    d = path[1:] - path[:-1]
    yaws = [math.atan2(dy, dx) for dx, dy in d]
    turn = sum(wrap_rad(b - a) for a, b in zip(yaws[:-1], yaws[1:]))
    length = float(sum(math.hypot(dx, dy) for dx, dy in d))
    if length < 1e-3:
        return _neutral(steer)
    delta = math.atan(DEFAULT_VEHICLE.wheelbase_m * turn / length)
    inside = [i for i, (lo, hi) in enumerate(steer) if lo <= delta <= hi]
    if inside:
        return min(inside, key=lambda i: (abs(_mid(steer[i]) - delta), i))
    return min(range(len(steer)), key=lambda i: (abs(_mid(steer[i]) - delta), i))
