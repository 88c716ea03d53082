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
6. Lane choice on multi-lane roads (rule 8, docs/lmpc_rules.md): leave a lane the user
   says is closed or one blocked by a standing vehicle (stopping ~10 m short of it while
   the next lane has no gap), move towards the lanes the route needs, overtake a slow
   leader (not when conservative); gap checks for the new leader / follower.
Emergency requests run the same rules (no lane choice: the answer has no scenario
encoding); only a threat in the ego's path with a TTC under ``commit_ttc_s`` brakes at
the strongest interval.
The instruction is parsed by ``parse_instruction`` (keyword rules): a style
(conservative: longer gaps, safety high, no overtaking; aggressive: shorter lane-change
gaps, overtaking, late merges — never shorter turn gaps), closed lanes, and refused
parts (ignore a light, a speed figure), which change nothing. The time and gap estimates are
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

from lmpc_msgs_py.messages import Lane
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.config import RulesConfig
from lmpc_llm_planner.route import Maneuver, crossing, next_maneuver
from lmpc_llm_planner.scene import AgentView, Scene, wrap_rad

CONSERVATIVE_WORDS = re.compile(
    r"\b(careful|carefully|conservative|conservatively|cautious|cautiously|defensive"
    r"|defensively|safe|safely|calm|calmly|gentle|gently|relaxed"
    # "slow" asks for slow driving, "slow traffic / cars" describes others
    r"|slow(ly)?(?!\s+(traffic|cars?|leaders?|vehicles?|trucks?|lanes?)))\b", re.I)
CROSSING_MISS_M = 4.0
"""An agent's ray passing the ego's path farther than this does not cross it."""
CLEAR_MARGIN_M = 1.0
_GO_ZONE_M = 8.0
"""With a safe gap and the front this close to the stop line, the ego turns briskly
(accelerating) instead of holding its approach speed."""

AGGRESSIVE_WORDS = re.compile(r"\b(aggressive|aggressively|assertive|assertively|hurry|rush"
                              r"|rushing|fast|faster|quick|quickly|sporty|overtake|overtaking"
                              r"|late|urgent|urgently)\b", re.I)
_NEGATION = re.compile(r"\b(not|don't|dont|never|no|avoid|without)\W+(\w+\W+){0,2}$", re.I)
CLOSED_LANE = re.compile(
    r"\b(?P<side>right|left)(?:most|-most| hand)?\s+lane\b[^.;!?]*?"
    r"\b(?:is|are|will be|gets)?\s*(?:closed|blocked|shut|under construction|"
    r"ends|ending)\b", re.I)
CLOSED_LANE_REV = re.compile(
    r"\b(?:closed|blocked|shut)\s+(?P<side>right|left)(?:most)?\s+lane\b", re.I)
UNSAFE_REQUEST = re.compile(
    r"\b(ignore|run|skip|disregard)\b[^.;!?]*\b(red|light|lights|signal|signals|rule|"
    r"rules|stop|sign|limit)\b|\b\d+(\.\d+)?\s*(m/s|mps|km/h|kmh|kph|mph)\b", re.I)

# -- lane choice on multi-lane roads (rule 8; docs/lmpc_rules.md) ---------------------------
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
LC_MIN_GAP_M = 6.0
"""Bumper gap to the new leader / follower a lane change needs at least."""
LC_HEADWAY_S = 0.8
"""Plus this many seconds at the follower's (rear) or the ego's (front) speed."""
LC_CLOSING_HORIZON_S = 3.0
"""Plus what a faster follower (or a slower new leader) closes in this long."""
LC_STYLE_FACTOR = {"conservative": 1.5, "normal": 1.0, "aggressive": 0.7}
"""Multiplies the lane-change gaps (an instruction never drops them below the minimum)."""
HARD_BRAKE_MPS2 = 3.0
"""A leader braking harder than this is treated as coming to a standstill."""
STANDOFF_M = 10.0
"""Waiting to pass a standing vehicle in its lane, the ego stops this far behind it (from
much closer the swerve is out of a car's steering reach without reversing)."""
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
CLOSED_LOOKAHEAD_M = 400.0
"""A lane the user said is closed is left once the ego knows (it is on that lane of an
edge with a neighbour lane): the instruction is the only way to know beyond sensing."""


@dataclass(frozen=True)
class Intent:
    """What the rules take from the user's instruction (untrusted plain text).

    The instruction can only choose among options the rules offer anyway: the driving
    style (gaps, whether to overtake a slow leader, how early to change lanes) and lanes
    to avoid. Requests to break rules (ignore a light, a speed figure) are noted and
    ignored: signals, the speed limit and the configured pools are never changed."""

    style: str = "normal"
    """"conservative", "normal" or "aggressive"."""
    closed_sides: frozenset[str] = frozenset()
    """"right" / "left": the user says that lane (rightmost / leftmost) is closed ahead."""
    refused: tuple[str, ...] = ()
    """Parts of the instruction the rules will not follow (quoted in the reasoning)."""


def _mentions(pattern: re.Pattern[str], text: str) -> bool:
    """``pattern`` occurs in ``text`` without a negation just before it."""
    for m in pattern.finditer(text):
        if not _NEGATION.search(text[:m.start()]):
            return True
    return False


def parse_instruction(text: Optional[str]) -> Intent:
    """The user's instruction as an :class:`Intent` (keyword rules, an APPROXIMATION of
    language understanding: no LLM here). Conservative wording wins over aggressive
    wording when both occur (the safer reading)."""
    if not text:
        return Intent()
    conservative = _mentions(CONSERVATIVE_WORDS, text)
    aggressive = _mentions(AGGRESSIVE_WORDS, text)
    style = "conservative" if conservative else "aggressive" if aggressive else "normal"
    sides = {m.group("side").lower() for m in CLOSED_LANE.finditer(text)}
    sides |= {m.group("side").lower() for m in CLOSED_LANE_REV.finditer(text)}
    refused = tuple(m.group(0)[:60] for m in UNSAFE_REQUEST.finditer(text))
    return Intent(style=style, closed_sides=frozenset(sides), refused=refused)


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
    ego_index: Optional[int] = None
    """The ego candidate chosen by the lane rule (None: the route candidate)."""

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
        intent = parse_instruction(request.instruction)
        careful = intent.style == "conservative"
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
        if intent.refused:
            plan.notes.append(
                "I do not follow the part(s) of the instruction that would break traffic "
                "rules or the speed limit (" + "; ".join(f"'{r}'" for r in intent.refused)
                + "); signals and limits still apply.")
        turn = self._left_turn_rule(scene, plan, accel, steer, safe_gap_s, previous_go,
                                    emergency, previous_stop)
        if turn == "none":
            turn = self._roundabout_rule(scene, plan, accel, safe_gap_s, previous_go,
                                         emergency, previous_stop)
        if turn == "none" and not emergency:
            # an emergency answer has no scenario encoding (the MPC gets the route
            # candidate), so a lane change cannot be chosen there: only the speed rules run
            self._lane_rule(scene, plan, accel, intent)
        if turn != "yield":
            self._path_rule(scene, plan, accel, emergency=emergency,
                            committed=turn == "commit")
        if turn == "none" and not plan.speed_set:
            self._headway_rule(scene, plan, accel)
        if not plan.speed_set:
            self._go(scene, plan, accel)
        if emergency:
            return {
                "reasoning": ("Emergency check. " + " ".join(plan.notes)).strip(),
                "action_guidance": _guidance(plan),
                "weight_adjustment": dict(plan.weights),
            }
        attention = list(plan.attention)
        ego_id = plan.ego_index if plan.ego_index is not None else scene.route_candidate_id
        encoding = {
            "ego_trajectory": ego_id,
            "attention": attention,
            "agent_trajectories": {
                aid: scene.agent(aid).closest_heading_id for aid in attention  # type: ignore
            },
        }
        ego_label = scene.ego_candidates[ego_id].label
        head = (
            f"I follow my route ({ego_label}) at {ego.v_mps:.1f} m/s."
            if ego_id == scene.route_candidate_id else
            f"I take '{ego_label}' (not the route candidate) at {ego.v_mps:.1f} m/s."
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
        # the clear time assumes the acceleration the rules ask for when the ego goes
        go_accel = max(_mid(accel[_accel_index(accel, cfg.turn_accel_mps2)]),
                       cfg.turn_accel_mps2)
        conflicts = []
        for view in scene.agents:
            c = self._oncoming_conflict(scene, view, man, yield_dirs, go_accel)
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
        # a queue behind a waiting ego: accept the gap a driver under that pressure takes
        # (the hysteresis margin, never less); every second waited holds them up too
        queued = _queued_behind(scene)
        margin = safe_gap_s - (cfg.go_hysteresis_s if previous_go or queued is not None
                               else 0.0)
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
            elif conflicts:
                # the gap was judged at the current speed: keep it (slowing down to the
                # turn speed first turned accepted gaps into missed ones); the MPC slows
                # for the curve itself
                plan.accel_index = _neutral(accel)
                plan.speed_set = True
                plan.notes.append("I keep my speed up to the junction.")
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

    def _roundabout_rule(
        self,
        scene: Scene,
        plan: _Plan,
        accel: tuple[tuple[float, float], ...],
        safe_gap_s: float,
        previous_go: bool,
        emergency: bool,
        previous_stop: bool,
    ) -> str:
        """Rule 10 (entering a roundabout): traffic on the ring has priority. For each
        agent on the ring upstream of the ring lane the ego enters (along the ring's lane
        links, at most ``RING_LOOKBACK_M``), its time to that lane's start (the merge
        point) at its speed against the ego's time until its rear has passed the merge
        point (accelerating at the go interval up to ``turn_speed_mps``). A gap shorter
        than ``safe_gap_s`` (hysteresis as the left turn) -> stop before the yield line,
        "yield"; too close to stop comfortably -> "commit"; else "go". "none" when the
        next junction on the route is not a roundabout entry. APPROXIMATION: the merge
        point is the end of the entry's junction lane, not where the two junction lanes
        meet inside the junction; ring traffic's intent (exit before the merge point or
        not) is unknown, so every ring agent upstream counts."""
        cfg = self.config
        obs = scene.obs
        man = next_maneuver(obs, scene.lanes, max_distance_m=cfg.junction_attention_m)
        if man is None:
            return "none"
        approach = scene.lanes.get(man.approach_lane_id)
        ring = scene.lanes.get(man.link.to_lane)
        if approach is None or approach.roundabout or ring is None or not ring.roundabout:
            return "none"
        ego = obs.ego
        half_len = 0.5 * ego.length_m
        via = scene.lanes.get(man.link.via_lane) if man.link.via_lane else None
        d_merge = man.dist_to_stop_line_m + (via.length_m if via is not None else 0.0)
        go_accel = max(_mid(accel[_accel_index(accel, cfg.turn_accel_mps2)]),
                       cfg.turn_accel_mps2)
        conflicts: list[Conflict] = []
        for view in scene.agents:
            ag = view.agent
            lane = scene.lanes.get(ag.lane_id or "")
            if lane is None or not lane.roundabout:
                continue
            d = _ring_distance_m(scene.lanes, lane, ag.lane_pos_m, ring.id, RING_LOOKBACK_M)
            if d is None:
                continue
            t_agent = max(d - 0.5 * ag.length_m - CLEAR_MARGIN_M, 0.0) / max(ag.v_mps, 0.5)
            t_clear = travel_time_s(d_merge + half_len + 0.5 * ag.width_m + CLEAR_MARGIN_M,
                                    v0_mps=ego.v_mps, accel_mps2=go_accel,
                                    vmax_mps=ring.speed_limit_mps)
            conflicts.append(Conflict(view, d_merge, t_agent, t_clear, 0.0))
        for c in conflicts:
            plan.attend(c.view, "on the roundabout, has priority at my entry")
        margin = safe_gap_s - (cfg.go_hysteresis_s if previous_go else 0.0)
        unsafe = [c for c in conflicts if c.gap_s < margin]
        if not unsafe:
            if conflicts:
                plan.notes.append(
                    f"I enter the roundabout; the gap in the ring traffic is "
                    f"{min(c.gap_s for c in conflicts):.1f} s beyond my clearing time "
                    f"(enough from {margin:.1f} s).")
            if man.inside_junction or man.dist_to_stop_line_m < half_len + _GO_ZONE_M:
                if conflicts:  # clear the merge point before the ring car arrives
                    plan.accel_index = _accel_index(accel, cfg.turn_accel_mps2)
                    plan.speed_set = True
            else:
                # approach slowly enough to stop at the yield line for ring traffic that
                # shows up later (ent* cars join the ring from the arm before mine); from
                # 12 m/s ten metres out the ego could only commit (rab seeds 19, 112).
                # Far out keep the speed while a comfortable slow-down after the next
                # decision is still possible (slowing from 70 m out cost seconds)
                v, v_turn = ego.v_mps, cfg.approach_turn_speed_mps
                d = man.dist_to_stop_line_m - half_len
                if v <= v_turn or d - v * cfg.replan_s <= \
                        (v * v - v_turn * v_turn) / (2.0 * cfg.commit_decel_mps2) + _GO_ZONE_M:
                    self._approach_turn(man, v, plan, accel)
            return "go"
        worst = min(unsafe, key=lambda c: (c.gap_s, c.view.id))
        v = ego.v_mps
        d_stop = man.dist_to_stop_line_m - half_len - cfg.stop_margin_m
        vmax_brake = max(-lo for lo, _ in accel) if previous_stop else cfg.commit_decel_mps2
        need = _required_decel(v, d_stop, cfg.moving_speed_mps)
        if man.inside_junction or need is None or need > vmax_brake:
            plan.accel_index = _accel_index(accel, cfg.turn_accel_mps2)
            plan.speed_set = True
            plan.weights["safety"] = "high"
            plan.notes.append(
                f"I am too close to stop before the roundabout's yield line with "
                f"{worst.view.id} coming; I enter briskly and keep a safe distance.")
            return "commit"
        plan.speed_set = True
        plan.weights.update(action="high", safety="high")
        reason = (f"I must give way to {worst.view.id} on the roundabout: it reaches my "
                  f"entry in {worst.t_agent_s:.1f} s, I would need {worst.t_clear_s:.1f} s "
                  f"to enter (gap {worst.gap_s:.1f} s, enough from {margin:.1f} s).")
        if not emergency and v >= cfg.moving_speed_mps and \
                d_stop - v * cfg.replan_s > v * v / (2.0 * cfg.commit_decel_mps2) + 5.0:
            plan.accel_index = _neutral(accel)  # far: stopping now would stop well short
            plan.notes.append(reason + f" I keep my speed for now and stop at the yield line "
                              f"({d_stop:.0f} m) if the gap stays too small.")
            return "yield"
        plan.accel_index = _stop_index(accel, v, d_stop, None, cfg.moving_speed_mps)
        plan.notes.append(reason + f" I stop at the yield line ({max(d_stop, 0.0):.0f} m) "
                          "and wait for a gap.")
        return "yield"

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
        self, scene: Scene, view: AgentView, man: Maneuver, yield_dirs: tuple[str, ...],
        go_accel_mps2: float,
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
        return Conflict(view, cr.ego_s_m, t_agent, t_clear, zone)

    def _lane_rule(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...],
        intent: Intent,
    ) -> str:
        """Rule 8: which lane of a multi-lane road to drive in (paper Fig. 5 / 7).

        Applies where the ego is offered neighbour-lane candidates (a normal lane of a
        multi-lane edge, no junction choice ahead within the lookahead). Reasons, in
        order: leave a lane the user said is closed, or one blocked by a stopped vehicle
        ahead; reach a lane that continues along the route before the edge ends (early
        when conservative); overtake a slow leader through a faster neighbour lane
        (never when conservative). A change needs a gap to the new leader and follower
        (``LC_*``, scaled by the style); without one the ego keeps its lane and, when the
        change is urgent, eases off so the gap behind a neighbour passes. Returns "keep",
        "change" or "wait" (a change is wanted but the gap is not there); "none" when the
        rule does not apply. Geometry: ego-frame offsets (straight-road APPROXIMATION)."""
        obs = scene.obs
        ego = obs.ego
        here = scene.lanes.get(ego.lane_id or "")
        if here is None or here.internal or not scene.ego_candidates:
            return "none"
        siblings = {ln.index: ln for ln in scene.lanes.values()
                    if ln.edge_id == here.edge_id and not ln.internal}
        if len(siblings) < 2:
            return "none"
        # offered candidates per lane they move to (the first lane of their chain)
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
        # the route candidate may jump several lanes: it counts for the lane it ends on
        route_c = scene.ego_candidates[scene.route_candidate_id]
        route_lane = next((lid for lid in route_c.lane_ids
                           if lid in scene.lanes and scene.lanes[lid].edge_id == here.edge_id),
                          None)
        if here.id not in by_lane or len(set(by_lane) | {route_lane or here.id}) < 2:
            return "none"  # only junction choices offered: the turn rules decide
        cfg = self.config
        left_hand = obs.map.left_hand_traffic
        n = max(siblings) + 1
        closed = set()
        for side in intent.closed_sides:
            outer = 0 if (side == "right") != left_hand else n - 1
            if outer in siblings:
                closed.add(siblings[outer].id)
        # the lanes that continue along the route (and how far this edge still goes)
        continuing = self._continuing_lanes(scene, here, siblings)
        dist_end_m = max(0.0, here.length_m - ego.lane_pos_m)
        ok_idx = sorted(ln.index for ln in continuing if ln.id not in closed) or \
            sorted(ln.index for ln in continuing)
        need = min((abs(i - here.index) for i in ok_idx), default=0)
        toward = None
        if need > 0:
            nearest = min(ok_idx, key=lambda i: (abs(i - here.index), i))
            toward = here.index + (1 if nearest > here.index else -1)

        def lane_state(lane_id: str) -> tuple[Optional[AgentView], Optional[AgentView]]:
            """(leader, follower) on ``lane_id``, by the ego-frame longitudinal offset."""
            lead: Optional[AgentView] = None
            follow: Optional[AgentView] = None
            for v in scene.agents:
                # along the lane (the ego itself may stand turned half-way into a swerve)
                if v.agent.lane_id != lane_id or abs(v.kin.heading_rel_rad) > _ALONG_RAD:
                    continue
                lon = v.kin.longitudinal_m
                if lon >= 0.0 and (lead is None or lon < lead.kin.longitudinal_m):
                    lead = v
                if lon < 0.0 and (follow is None or lon > follow.kin.longitudinal_m):
                    follow = v
            return lead, follow

        limit = here.speed_limit_mps
        lead_here, _ = lane_state(here.id)
        # a standing leader, or one braking hard towards a standstill close ahead (eoa
        # hazards brake at 8 m/s^2): take the free neighbour lane early, while there is
        # still room to steer round it
        stopping = lead_here is not None and (
            lead_here.agent.v_mps < cfg.moving_speed_mps
            or (lead_here.agent.a_mps2 < -HARD_BRAKE_MPS2
                and lead_here.kin.longitudinal_m <= SLOW_LEADER_RANGE_M))
        blocked = lead_here is not None and stopping \
            and lead_here.kin.longitudinal_m <= obs.agents.sensing_range_m \
            and not _queued_at_junction(scene, lead_here)
        slow = lead_here is not None and lead_here.kin.longitudinal_m <= SLOW_LEADER_RANGE_M \
            and lead_here.agent.v_mps < SLOW_LEADER_FRACTION * limit
        merge_m = need * LANE_MERGE_PER_CHANGE_M + LANE_MERGE_SLACK_M
        # towards the lane the route needs: at once (normal, conservative: measured on
        # lane seeds 100-124, merging late into the slower traffic cost more in gaps and
        # harsh braking than the fast lane saved in time), late only when aggressive
        urgent_merge = need > 0 and (intent.style != "aggressive"
                                     or dist_end_m < merge_m * LANE_MERGE_AGGRESSIVE)
        want: Optional[int] = None
        why = ""
        urgent = False
        if here.id in closed and dist_end_m <= CLOSED_LOOKAHEAD_M:
            open_nb = [i for i in (here.index - 1, here.index + 1)
                       if i in siblings and siblings[i].id not in closed]
            if open_nb:
                want = min(open_nb, key=lambda i: (abs(i - (toward or i)), i))
                why, urgent = "the user says my lane is closed ahead", True
        if want is None and blocked and lead_here is not None:
            open_nb = [i for i in (here.index - 1, here.index + 1)
                       if i in siblings and siblings[i].id not in closed]
            if open_nb:
                # prefer the side towards the route, else the overtaking side
                over = here.index - 1 if left_hand else here.index + 1
                want = min(open_nb, key=lambda i: (i != toward, i != over, i))
                why = f"{lead_here.id} stands in my lane {lead_here.kin.gap_m:.0f} m ahead"
                urgent = True
        if want is None and urgent_merge and toward is not None:
            step_c = by_lane.get(siblings[toward].id) if toward in siblings else None
            if step_c is None and route_lane is not None and route_lane != here.id:
                step_c = scene.route_candidate_id
            if step_c is not None and (intent.style != "aggressive"
                                       or dist_end_m < LANE_MERGE_FORCE_M):
                # the route candidate, as before rule 8 existed: the MPC merges along it
                # and its safety term keeps the gaps; SUMO drivers make room. A strict gap
                # test here found no gap in dense slow traffic (lane seed 119 missed its
                # exit), and a missed exit costs a 200 s timeout.
                for lid in scene.ego_candidates[step_c].lane_ids:
                    ln = scene.lanes.get(lid)
                    if ln is not None and ln.edge_id == here.edge_id:
                        for v in scene.agents:
                            if v.agent.lane_id == lid and abs(v.kin.longitudinal_m) < 40.0:
                                plan.attend(v, "in the lane I merge into")
                plan.ego_index = step_c
                plan.notes.append(
                    f"My route needs {need} lane change(s) within {dist_end_m:.0f} m; I "
                    "move towards that lane now and keep safe gaps.")
                return "change"
            want = toward
            why = f"my route needs {need} lane change(s) within {dist_end_m:.0f} m"
            urgent = dist_end_m < merge_m
        if want is None and slow and intent.style != "conservative" and lead_here is not None:
            gain = SLOW_LEADER_GAIN_MPS * (0.5 if intent.style == "aggressive" else 1.0)
            best: Optional[tuple[float, int]] = None
            for i in (here.index - 1, here.index + 1):
                nb = siblings.get(i)
                if nb is None or nb.id in closed:
                    continue
                # moving away from the route lanes only with road enough to come back
                need_after = min((abs(j - i) for j in ok_idx), default=0)
                if need_after > need and (
                        intent.style != "aggressive"
                        or dist_end_m < (need_after * LANE_MERGE_PER_CHANGE_M
                                         + LANE_MERGE_SLACK_M) * 2.0):
                    continue  # away from the lanes the route needs: aggressive only
                lead_nb, _ = lane_state(nb.id)
                v_nb = nb.speed_limit_mps if lead_nb is None or \
                    lead_nb.kin.longitudinal_m > SLOW_LEADER_RANGE_M else lead_nb.agent.v_mps
                if v_nb - lead_here.agent.v_mps >= gain and (best is None or v_nb > best[0]):
                    best = (v_nb, i)
            if best is not None:
                want = best[1]
                why = (f"{lead_here.id} ahead drives {lead_here.agent.v_mps:.1f} m/s, the "
                       f"{'left' if (best[1] > here.index) != left_hand else 'right'} lane "
                       "is faster, so I overtake")
        keep_id = by_lane[here.id]
        if lead_here is not None and lead_here.kin.longitudinal_m <= SLOW_LEADER_RANGE_M:
            plan.attend(lead_here, "leader in my lane")
        if want is None:
            plan.ego_index = keep_id
            return "keep"
        target = siblings[want]
        side = "left" if (want > here.index) != left_hand else "right"
        cand = by_lane.get(target.id)
        if cand is None and route_lane is not None:
            # only the route candidate goes that way (it may cross the lane to its end)
            rl = scene.lanes[route_lane]
            if (rl.index - here.index) * (want - here.index) > 0:
                cand = scene.route_candidate_id
        if cand is None:
            plan.ego_index = keep_id
            return "none"
        crossed = [siblings[i] for i in range(min(here.index, want), max(here.index, want) + 1)
                   if i != here.index and i in siblings]
        if cand == scene.route_candidate_id and route_lane is not None:
            ri = scene.lanes[route_lane].index
            crossed = [siblings[i] for i in range(min(here.index, ri), max(here.index, ri) + 1)
                       if i != here.index and i in siblings]
        style_f = LC_STYLE_FACTOR[intent.style]
        blocker: Optional[tuple[AgentView, str]] = None
        for ln in crossed:
            lead_nb, follow_nb = lane_state(ln.id)
            for v, where in ((lead_nb, "ahead"), (follow_nb, "behind")):
                if v is None:
                    continue
                plan.attend(v, f"in the {side} lane {where}")
                gap = v.kin.gap_m
                if where == "ahead":
                    closing = max(0.0, ego.v_mps - v.agent.v_mps)
                    need_gap = LC_MIN_GAP_M + style_f * (LC_HEADWAY_S * ego.v_mps
                                                         + LC_CLOSING_HORIZON_S * closing)
                else:
                    closing = max(0.0, v.agent.v_mps - ego.v_mps)
                    need_gap = LC_MIN_GAP_M + style_f * (LC_HEADWAY_S * v.agent.v_mps
                                                         + LC_CLOSING_HORIZON_S * closing)
                if v.kin.longitudinal_m > -0.5 * ego.length_m and \
                        v.kin.longitudinal_m < 0.5 * ego.length_m + v.agent.length_m:
                    gap = 0.0  # beside me
                if gap < need_gap and (blocker is None or gap < blocker[0].kin.gap_m):
                    blocker = (v, where)
        if blocker is None:
            plan.ego_index = cand
            plan.notes.append(f"{_sentence(why)}; the gap in the {side} lane is free, so I "
                              f"change to the {side} lane.")
            return "change"
        plan.ego_index = keep_id
        v, where = blocker
        plan.notes.append(f"{_sentence(why)}, but {v.id} {where} in the {side} lane leaves "
                          "no safe gap yet, so I keep my lane for now.")
        if blocked and lead_here is not None and not plan.speed_set:
            # wait far enough behind the standing vehicle to steer round it later (a car
            # cannot reverse, and from a few metres the swerve is out of its steering reach)
            d_stop = lead_here.kin.gap_m - STANDOFF_M
            if lead_here.agent.v_mps >= cfg.moving_speed_mps:  # braking: where it will stand
                d_stop += lead_here.agent.v_mps ** 2 / (
                    2.0 * max(-lead_here.agent.a_mps2, HARD_BRAKE_MPS2))
            if ego.v_mps < cfg.moving_speed_mps and d_stop > 8.0:
                plan.accel_index = _mildest_accel(accel)  # creep up to the stand-off point
            else:
                # a braking bias (a neutral one lets the MPC speed up to just behind it)
                plan.accel_index = _stop_index(accel, ego.v_mps, max(d_stop, 0.0), None,
                                               cfg.moving_speed_mps)
                plan.notes.append(f"I stop about {STANDOFF_M:.0f} m behind {lead_here.id} "
                                  "so I can still steer round it.")
            plan.speed_set = True
            plan.weights["action"] = "high"
            return "wait"
        if urgent and where == "ahead" and v.agent.v_mps < ego.v_mps + 1.0 \
                and not plan.speed_set:
            # let the car beside / ahead in the target lane draw ahead, then merge behind it
            plan.accel_index = _brake_index(accel, 1.0, False)
            plan.speed_set = True
        elif urgent and where == "behind" and not plan.speed_set and ego.v_mps < 0.8 * limit:
            # a faster car behind in the target lane: get ahead of it if I can
            plan.accel_index = _mildest_accel(accel)
            plan.speed_set = True
        return "wait"

    def _continuing_lanes(self, scene: Scene, here: Lane, siblings: dict[int, Lane]
                          ) -> list[Lane]:
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

    def _path_rule(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...], *,
        emergency: bool, committed: bool
    ) -> None:
        """Rule 4: brake for an agent in the ego's own path ahead (within the corridor of
        its route candidate) that it closes in on. Traffic that only passes near the
        path (an oncoming car in its own lane) is the turn rule's business."""
        cfg = self.config
        ego = scene.obs.ego
        path = _route_path(scene, plan.ego_index)
        changing = plan.ego_index is not None and \
            scene.ego_candidates[plan.ego_index].label.startswith("change to the")
        threats = []
        standoff: dict[str, float] = {}
        for v in scene.agents:
            k = v.kin
            if k.longitudinal_m <= 0.0:
                continue
            # a standing vehicle (a breakdown, not a queue) in my own lane: stop far enough
            # behind it to steer round it later (only the closing speed matters for TTC)
            # a standing vehicle (a breakdown, not a queue) in my own lane, or one braking
            # hard towards a standstill: stop far enough behind where it will stand to
            # steer round it later (the constant-velocity TTC sees a braking car late)
            stopping = v.agent.v_mps < cfg.moving_speed_mps or \
                v.agent.a_mps2 < -HARD_BRAKE_MPS2
            stand = not changing and stopping and abs(k.heading_rel_rad) < _ALONG_RAD and \
                not _queued_at_junction(scene, v) and not _other_lane(scene, v)
            if k.ttc_s is None and not stand:
                continue
            if path is not None:
                corridor = 0.5 * (ego.width_m + v.agent.width_m) + cfg.path_corridor_m
                if _distance_to_path(path, v.agent.x_m, v.agent.y_m) > corridor:
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
        if emergency and worst.kin.ttc_s is not None and worst.kin.ttc_s < cfg.commit_ttc_s:
            plan.accel_index = _strongest_brake(accel)
            plan.weights.update(tracking="low", action="high")
        else:
            plan.accel_index = _brake_index(accel, need * self.config.brake_margin_factor,
                                            False)
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

    def _headway_rule(
        self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...]
    ) -> None:
        """Behind a moving leader in the ego's lane keep a gap from which the ego can still
        brake (or steer round it) if the leader brakes as hard as a car can
        (``LEADER_BRAKE_MPS2``): the ego's stopping distance after a reaction time, minus
        the leader's, plus ``STANDOFF_M`` to steer round it; at least ``HEADWAY_S`` of
        time gap. The MPC follows at its own (1 s) headway; too close, the rules brake
        gently (the mildest braking interval) until the gap has opened, and hold the
        speed while it is only a little short."""
        ego = scene.obs.ego
        v = ego.v_mps
        if v < HEADWAY_MIN_SPEED_MPS:
            return
        changing = plan.ego_index is not None and \
            scene.ego_candidates[plan.ego_index].label.startswith("change to the")
        if changing:
            return  # the leader of the lane being left does not matter
        leader = _lane_leader(scene)
        if leader is None or leader.agent.v_mps < self.config.moving_speed_mps:
            return  # standing: the stand-off rules (path, go) handle it
        vl = leader.agent.v_mps
        want = max(HEADWAY_S * v, v * HEADWAY_REACTION_S + v * v / (2.0 * EGO_BRAKE_MPS2)
                   - vl * vl / (2.0 * LEADER_BRAKE_MPS2) + STANDOFF_M)
        gap = leader.kin.gap_m
        if gap >= want:
            return
        plan.attend(leader, "leader in my lane")
        plan.speed_set = True
        plan.weights["action"] = "high"
        if gap < HEADWAY_OPEN_FRACTION * want and v > vl - 1.0:
            plan.accel_index = _brake_index(accel, 0.5, False)
            plan.notes.append(
                f"{leader.id} drives {gap:.0f} m ahead in my lane at {vl:.1f} m/s; I drop "
                f"back to about {want:.0f} m so I can still brake or steer round it if it "
                "brakes hard.")
        else:
            plan.accel_index = _neutral(accel)
            plan.notes.append(
                f"I follow {leader.id} ({gap:.0f} m ahead) and keep about {want:.0f} m, "
                "enough to brake or steer round it if it brakes hard.")

    def _go(self, scene: Scene, plan: _Plan, accel: tuple[tuple[float, float], ...]) -> None:
        ego = scene.obs.ego
        lane = scene.lanes.get(ego.lane_id or "")
        limit = lane.speed_limit_mps if lane is not None else DEFAULT_VEHICLE.max_speed_mps
        changing = plan.ego_index is not None and \
            scene.ego_candidates[plan.ego_index].label.startswith("change to the")
        close = None if changing else self._close_leader_in_path(scene, plan)
        if close is not None:
            cfg = self.config
            standing = close.agent.v_mps < cfg.moving_speed_mps
            d_m = close.kin.gap_m - STANDOFF_M
            moving = ego.v_mps >= cfg.moving_speed_mps
            if standing and (d_m < 3.0 or (not moving and d_m < 8.0)):
                # close behind a standing vehicle: stay (an accelerating bias would push
                # the MPC into it, and from nearer the ego could not steer round it)
                plan.accel_index = _brake_index(accel, 0.0, True)
                plan.weights["action"] = "high"
                plan.notes.append(f"{close.id} stands {close.kin.gap_m:.0f} m ahead in my "
                                  "path, so I stay where I am.")
            elif standing and not moving:
                plan.accel_index = _mildest_accel(accel)  # creep nearer, slowly
                plan.notes.append(f"I creep up behind {close.id}, standing ahead.")
            elif standing:
                # a neutral bias lets the MPC speed up to just behind it: brake to stop
                # about STANDOFF_M short of it instead
                plan.accel_index = _stop_index(accel, ego.v_mps, d_m, None,
                                               cfg.moving_speed_mps)
                plan.weights["action"] = "high"
                plan.notes.append(f"{close.id} stands {close.kin.gap_m:.0f} m ahead in my "
                                  f"path; I stop about {STANDOFF_M:.0f} m short of it.")
            else:
                plan.accel_index = _neutral(accel)
                if not plan.notes:
                    plan.notes.append(f"I follow {close.id} ahead in my path.")
            return
        if ego.v_mps < 0.8 * limit:
            plan.accel_index = _mildest_accel(accel)
            if not plan.notes:
                plan.notes.append(
                    f"The way is clear; I speed up towards the {limit:.1f} m/s limit."
                )
        elif not plan.notes:
            plan.notes.append("The way is clear; I keep my speed.")

    def _close_leader_in_path(self, scene: Scene, plan: _Plan) -> Optional[AgentView]:
        """The nearest agent ahead within the corridor of the chosen path, closer than
        what the ego needs to follow it comfortably (two seconds, at least 15 m) and not
        faster than the ego: the MPC follows it on its own; speeding up would fight that."""
        ego = scene.obs.ego
        path = _route_path(scene, plan.ego_index)
        best: Optional[AgentView] = None
        for v in scene.agents:
            k = v.kin
            if k.longitudinal_m <= 0.0 or k.motion == "oncoming":
                continue
            standing = v.agent.v_mps < self.config.moving_speed_mps and \
                not _queued_at_junction(scene, v)
            reach_m = max(15.0, 2.0 * ego.v_mps, STANDOFF_M + 15.0 if standing else 0.0)
            if k.gap_m > reach_m or v.agent.v_mps > ego.v_mps + 1.0:
                continue
            if _other_lane(scene, v):
                continue  # e.g. a standing car the ego is steering round in the next lane
            if path is not None:
                corridor = 0.5 * (ego.width_m + v.agent.width_m) + self.config.path_corridor_m
                if _distance_to_path(path, v.agent.x_m, v.agent.y_m) > corridor:
                    continue
            if best is None or k.gap_m < best.kin.gap_m:
                best = v
        return best


# -- helpers --------------------------------------------------------------------------------
_QUEUE_ZONE_M = 40.0
_ALONG_RAD = 1.2
"""Agents heading within this of the ego count as driving along its road (wider than the
30 deg of "same direction": an ego stopped turned into a swerve still sees them)."""


def _other_lane(scene: Scene, view: AgentView) -> bool:
    """The agent is on another lane of the ego's edge (both lanes known)."""
    ego_lane = scene.lanes.get(scene.obs.ego.lane_id or "")
    lane = scene.lanes.get(view.agent.lane_id or "")
    return ego_lane is not None and lane is not None and lane.id != ego_lane.id \
        and lane.edge_id == ego_lane.edge_id


RING_LOOKBACK_M = 60.0
"""Ring traffic this far (along the ring) before the ego's merge point counts (rule 10)."""


def _ring_distance_m(lanes: dict[str, Lane], start: Lane, pos_m: float, goal_id: str,
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


def _lane_leader(scene: Scene) -> Optional[AgentView]:
    """The nearest vehicle ahead in the ego's own lane (same lane id; driving along)."""
    ego = scene.obs.ego
    best: Optional[AgentView] = None
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m <= 0.0 or abs(k.heading_rel_rad) > 0.5:
            continue
        same = v.agent.lane_id == ego.lane_id if (v.agent.lane_id and ego.lane_id) \
            else abs(k.lateral_m) < 1.2
        if same and abs(k.lateral_m) < 2.5 and (best is None or k.gap_m < best.kin.gap_m):
            best = v
    return best


_QUEUE_BEHIND_M = 12.0
"""A vehicle this close behind in the ego's lane, (nearly) stopped, is held up by it."""


def _queued_behind(scene: Scene) -> Optional[AgentView]:
    """A (nearly) stopped vehicle close behind a (nearly) stopped ego in its lane."""
    ego = scene.obs.ego
    if ego.v_mps > 2.0:
        return None
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m >= 0.0 or k.gap_m > _QUEUE_BEHIND_M or v.agent.v_mps > 2.0:
            continue
        if abs(k.heading_rel_rad) < _ALONG_RAD and abs(k.lateral_m) < 1.8:
            return v
    return None


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]


def _queued_at_junction(scene: Scene, view: AgentView) -> bool:
    """A stopped vehicle near the end of a lane that meets a light or a junction choice
    is (probably) waiting there, not broken down: the ego queues behind it instead of
    changing lanes around it."""
    lane = scene.lanes.get(view.agent.lane_id or "")
    if lane is None or lane.length_m - view.agent.lane_pos_m > _QUEUE_ZONE_M:
        return False
    signalized = any(sl.lane_id == lane.id and sl.signalized for sl in scene.obs.map.stop_lines)
    return signalized or len({lk.direction for lk in lane.successors}) >= 2


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


def _route_path(scene: Scene, ego_index: Optional[int] = None) -> Optional[np.ndarray]:
    """(n, 2) points of the chosen ego candidate (default: the route candidate; None
    without candidates)."""
    if not scene.ego_candidates:
        return None
    i = scene.route_candidate_id if ego_index is None else ego_index
    return scene.ego_candidates[i].sample(60)


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
