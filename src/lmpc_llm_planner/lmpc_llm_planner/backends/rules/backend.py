"""The ``rules`` backend: builds the rule inputs from a request, runs the rule families in
order on one :class:`Plan` and answers the decision JSON an LLM would."""
from __future__ import annotations

import json
import time
from typing import Any, Optional

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.config import RulesConfig
from lmpc_llm_planner.scene import AgentView, Scene

from .emergency import emergency_answer, start_emergency
from .headway import headway_rule
from .instruction import parse_instruction
from .intervals import neutral
from .lane import lane_rule
from .left_turn import left_turn_rule
from .path import go_rule, path_rule
from .plan import Plan, RuleInputs, guidance
from .roundabout import roundabout_rule
from .situation import situation_rule


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
        answer, plan = self.reason(request)
        if request.stage != "all":
            answer = {"reasoning": answer["reasoning"], request.stage: answer[request.stage]}
        text = json.dumps(answer, separators=(",", ":"))
        return BackendReply(text=text, latency_s=time.perf_counter() - t0,
                            revisit_s=plan.revisit_s)

    # -- reasoning ------------------------------------------------------------------------
    def decide(self, request: DecisionRequest) -> dict[str, Any]:
        """The full answer object (all stages, or the emergency variant)."""
        return self.reason(request)[0]

    def reason(self, request: DecisionRequest) -> tuple[dict[str, Any], Plan]:
        """The full answer object and the plan behind it."""
        inp = rule_inputs(self.config, request)
        plan = start_plan(inp)
        run_rules(inp, plan)
        if inp.emergency:
            return emergency_answer(plan), plan
        return answer(inp.scene, plan), plan


def rule_inputs(cfg: RulesConfig, request: DecisionRequest) -> RuleInputs:
    """What the rules read from ``request``: the pools, the parsed instruction, the gap
    they accept and whether the previous decision went or braked."""
    accel = request.accel_intervals_mps2
    intent = parse_instruction(request.instruction)
    gap_factor = {"conservative": cfg.conservative_gap_factor,
                  "aggressive": cfg.aggressive_gap_factor}.get(intent.style, 1.0)
    lo_neutral = accel[neutral(accel)][0]
    prev = request.previous
    revisit, latency = cfg.ring_revisit_s, request.expected_latency_s
    # only a normal decision that comes back within the revisit (at most one in flight):
    # a slower one would act on a scene older than the revisit promises
    react = revisit + latency if revisit is not None and latency is not None \
        and latency <= revisit and request.mode == "normal" else None
    return RuleInputs(
        cfg=cfg, scene=request.scene, accel=accel, steer=request.steer_intervals_rad,
        intent=intent,
        safe_gap_s=cfg.safe_gap_s * gap_factor,
        previous_go=prev is not None and prev.accel_bias_mps2 >= 0.0,
        previous_stop=prev is not None and prev.accel_bias_mps2 < lo_neutral,
        emergency=request.mode == "emergency",
        ring_revisit_s=revisit if react is not None else None,
        ring_react_s=react,
    )


def start_plan(inp: RuleInputs) -> Plan:
    """A neutral plan with the style's and the mode's weights, the default attention
    (rules 1-2) and the note on refused parts of the instruction."""
    plan = Plan(accel_index=neutral(inp.accel), steer_index=neutral(inp.steer))
    if inp.intent.style == "conservative":
        plan.weights["safety"] = "high"
        plan.notes.append("The user asked for careful driving, so I keep larger gaps.")
    if inp.emergency:
        start_emergency(plan)
    attend_defaults(inp, plan)
    if inp.intent.refused:
        plan.notes.append(
            "I do not follow the part(s) of the instruction that would break traffic "
            "rules or the speed limit (" + "; ".join(f"'{r}'" for r in inp.intent.refused)
            + "); signals and limits still apply.")
    return plan


def run_rules(inp: RuleInputs, plan: Plan) -> str:
    """The rule families in order; returns the junction rules' verdict ("none", "go",
    "yield" or "commit")."""
    turn = left_turn_rule(inp, plan)
    if turn == "none":
        turn = roundabout_rule(inp, plan)
    if turn == "none" and not inp.emergency:
        # an emergency answer has no scenario encoding (the MPC gets the route
        # candidate), so a lane change cannot be chosen there: only the speed rules run
        lane_rule(inp, plan)
    if turn != "yield":
        path_rule(inp, plan, committed=turn == "commit")
    if turn == "none" and not plan.speed_set:
        headway_rule(inp, plan)
    if not plan.speed_set:
        go_rule(inp, plan)
    situation_rule(inp, plan)  # last: it only lowers the speed the others chose
    return turn


def attend_defaults(inp: RuleInputs, plan: Plan) -> None:
    """Rule 2: the leader in the ego's lane (within ``leader_range_m``) and every agent
    within ``nearby_attention_m``."""
    cfg = inp.cfg
    scene = inp.scene
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


def answer(scene: Scene, plan: Plan) -> dict[str, Any]:
    """The normal answer object: scenario encoding (rule 1: the route candidate unless
    the lane rule chose another), action guidance, weights and the reasoning."""
    ego = scene.obs.ego
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
        "action_guidance": guidance(plan),
        "weight_adjustment": dict(plan.weights),
    }
