"""A deterministic reasoner that applies traffic rules to the request's structured
inputs and answers the same JSON text an LLM would (so it goes through the same
validation and translation).

Rules (first version):
1. The ego tracks the candidate that follows its route.
2. The leader in the ego's lane and every agent within ``nearby_attention_m`` are
   attended, as are the agents the rules below reason about.
3. A left-turning vehicle yields to oncoming traffic (paper Fig. 1; a right turn in
   left-hand traffic): oncoming agents whose straight path crosses the ego's turn
   path are compared by time: the ego's time to clear the crossing (accelerating
   from its speed) against the agent's time to reach it (at constant speed). Gap
   below ``safe_gap_s`` -> stop before the stop line (or, once past it, before the
   crossing): braking bias from v^2 / 2d, action and safety "high", tracking "low".
   If it can no longer stop in time it commits, with safety "high".
4. Keep a safe distance: an agent ahead on a collision course with TTC under
   ``safe_gap_s`` -> braking bias, safety "high".
5. Otherwise go: accelerating (below 80 % of the speed limit) or neutral bias,
   normal weights.
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
        """The full answer object (all stages, or the emergency variant)."""
        cfg = self.config
        scene = request.scene
        accel = request.accel_intervals_mps2
        steer = request.steer_intervals_rad
        plan = _Plan(accel_index=_neutral(accel), steer_index=_neutral(steer))
        careful = bool(request.instruction and CONSERVATIVE_WORDS.search(request.instruction))
        safe_gap_s = cfg.safe_gap_s * (cfg.conservative_gap_factor if careful else 1.0)
        if careful:
            plan.weights["safety"] = "high"
            plan.notes.append("The user asked for careful driving, so I keep larger gaps.")

        if request.mode == "emergency":
            self._emergency(scene, plan, accel)
            return {
                "reasoning": " ".join(plan.notes),
                "action_guidance": _guidance(plan),
                "weight_adjustment": dict(plan.weights),
            }

        ego = scene.obs.ego
        self._attend_defaults(scene, plan)
        yielding = self._left_turn_rule(scene, plan, accel, steer, safe_gap_s)
        if not yielding:
            self._following_rule(scene, plan, accel, safe_gap_s)
        if not plan.speed_set:
            self._go(scene, plan, accel)
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
    ) -> bool:
        """Rule 3; True while the ego yields."""
        cfg = self.config
        obs = scene.obs
        man = next_maneuver(obs, scene.lanes, max_distance_m=cfg.junction_attention_m)
        if man is None or man.dist_to_stop_line_m > cfg.junction_attention_m:
            return False
        yield_dirs = ("r", "R") if obs.map.left_hand_traffic else ("l", "L")
        if man.direction not in yield_dirs:
            return False
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
        if not conflicts:
            plan.notes.append(
                f"I turn {turn} at the junction ahead; no oncoming traffic conflicts, so I go."
            )
            self._approach_turn(man, ego.v_mps, plan, accel)
            return False
        unsafe = [c for c in conflicts if c.gap_s < safe_gap_s]
        for c in conflicts:
            plan.attend(c.view, "oncoming, conflicts with my turn")
        if not unsafe:
            plan.notes.append(
                f"I turn {turn}; the oncoming gap is {min(c.gap_s for c in conflicts):.1f} s "
                f"(safe from {safe_gap_s:.1f} s), so I turn now."
            )
            self._approach_turn(man, ego.v_mps, plan, accel)
            return False
        worst = min(unsafe, key=lambda c: (c.gap_s, c.view.id))
        vmax_brake = max(-lo for lo, _ in accel)
        # Where to stop: before the stop line, or (past it) before the crossing.
        targets = []
        if man.dist_to_stop_line_m > 0.0:
            targets.append((man.dist_to_stop_line_m - half_len - cfg.stop_margin_m, "stop line"))
        crossing_d = man.dist_to_stop_line_m + worst.ego_s_m
        targets.append((crossing_d - half_len - 2.0, "crossing point"))
        for d_stop, where in targets:
            need = _required_decel(ego.v_mps, d_stop, cfg.moving_speed_mps)
            if need is not None and need <= vmax_brake:
                plan.accel_index = _brake_index(
                    accel, need * cfg.brake_margin_factor, ego.v_mps < cfg.moving_speed_mps
                )
                plan.speed_set = True
                plan.weights.update(tracking="low", action="high", safety="high")
                plan.notes.append(
                    f"I turn {turn} and must yield to oncoming {worst.view.id}: it reaches the "
                    f"crossing in {worst.t_agent_s:.1f} s, I would need {worst.t_clear_s:.1f} s "
                    f"to clear it (gap {worst.gap_s:.1f} s, safe from {safe_gap_s:.1f} s). "
                    f"I slow down and stop before the {where} "
                    f"({max(d_stop, 0.0):.0f} m, needs {need:.1f} m/s2) and wait for a gap."
                )
                return True
        plan.weights["safety"] = "high"
        plan.notes.append(
            f"I am too close to stop before the crossing with {worst.view.id}; I commit to the "
            f"{turn} turn and keep a safe distance."
        )
        return False

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
        if v_mps >= 0.8 * v_turn:
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
        return Conflict(view, cr.ego_s_m, t_agent, t_clear)

    def _following_rule(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...], safe_gap_s: float
    ) -> None:
        """Rule 4: brake for an agent ahead on a collision course."""
        threats = [
            v for v in scene.agents
            if v.kin.longitudinal_m > 0.0 and v.kin.ttc_s is not None and v.kin.ttc_s < safe_gap_s
        ]
        if not threats:
            return
        worst = min(threats, key=lambda v: (v.kin.ttc_s, v.id))
        plan.attend(worst, f"closing in, {worst.kin.ttc_s:.1f} s to collision")
        need = worst.kin.closing_speed_mps**2 / (2.0 * max(worst.kin.gap_m - 2.0, 0.5))
        plan.accel_index = _brake_index(accel, need * self.config.brake_margin_factor, False)
        plan.speed_set = True
        plan.weights["safety"] = "high"
        plan.notes.append(
            f"{worst.id} is {worst.kin.gap_m:.0f} m {worst.kin.relation} and I close in at "
            f"{worst.kin.closing_speed_mps:.1f} m/s, so I brake to keep a safe distance."
        )

    def _emergency(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...]
    ) -> None:
        threats = sorted(
            (v for v in scene.agents if v.kin.ttc_s is not None),
            key=lambda v: (v.kin.ttc_s, v.id),
        )
        ahead = [v for v in threats if v.kin.longitudinal_m > 0.0]
        plan.weights.update(safety="high")
        if ahead:
            w = ahead[0]
            plan.accel_index = _strongest_brake(accel)
            plan.weights.update(tracking="low", action="high")
            plan.notes.append(
                f"Emergency: {w.id} is {w.kin.gap_m:.0f} m {w.kin.relation}, "
                f"{w.kin.ttc_s:.1f} s to collision. I brake hard."
            )
        elif threats:
            plan.notes.append(
                f"Emergency: {threats[0].id} approaches from {threats[0].kin.relation}; braking "
                "would not help, I keep my speed and maximise safety."
            )
        else:
            plan.notes.append("Emergency check tripped but no agent is on a collision course now; "
                              "I keep my speed with high safety weight.")

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
