"""What every rule reads (:class:`RuleInputs`) and writes (:class:`Plan`): the rules run in
order on one plan, each choosing intervals, weights, the ego candidate, attention and a
sentence of reasoning, and the backend turns the plan into the answer JSON."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from lmpc_mpc.reference import Candidate

from lmpc_llm_planner.config import RulesConfig
from lmpc_llm_planner.scene import AgentView, Scene

from .instruction import Intent
from .intervals import Intervals


@dataclass(frozen=True)
class RuleInputs:
    """One request as the rules see it (read-only)."""

    cfg: RulesConfig
    scene: Scene
    accel: Intervals
    """The request's acceleration interval pool (m/s^2)."""
    steer: Intervals
    """The request's steering interval pool (rad)."""
    intent: Intent
    safe_gap_s: float
    """``cfg.safe_gap_s``, longer when the user asked for careful driving."""
    previous_go: bool = False
    """The previous decision did not brake (the gap hysteresis applies)."""
    previous_stop: bool = False
    """The previous decision braked below the neutral interval (a stop under way)."""
    emergency: bool = False
    """An emergency request (no scenario encoding in the answer)."""
    ring_revisit_s: Optional[float] = None
    """Near a roundabout's yield line the rules ask to be asked again this soon
    (``RulesConfig.ring_revisit_s``; None: not here, the decision after this one comes
    ``replan_s`` later)."""
    ring_react_s: Optional[float] = None
    """With ``ring_revisit_s``: the sim time from this decision's observation until the
    next one acts (the revisit plus the expected latency), which the ring approach plans
    for instead of ``replan_s``."""


@dataclass
class Plan:
    attention: dict[str, str] = field(default_factory=dict)
    """id -> why (insertion order = the order of the reasoning)."""
    accel_index: int = 0
    steer_index: int = 0
    speed_set: bool = False
    """A rule chose the accel interval (the default "go" must not override it)."""
    hold_speed: Optional[str] = None
    """A rule found speeding up unsafe here (the reason, for the reasoning): the default
    "go" keeps the speed instead of speeding up; it may still slow down."""
    weights: dict[str, str] = field(
        default_factory=lambda: {
            "tracking": "normal", "action": "normal", "smoothness": "normal", "safety": "normal",
        }
    )
    notes: list[str] = field(default_factory=list)
    ego_index: Optional[int] = None
    """The ego candidate chosen by the lane rule (None: the route candidate)."""
    revisit_s: Optional[float] = None
    """Ask to be asked again this soon (``BackendReply.revisit_s``; None: at the period)."""

    def attend(self, view: AgentView, why: str) -> None:
        self.attention.setdefault(view.id, why)


def guidance(plan: Plan) -> dict[str, int]:
    """The answer's ``action_guidance`` object."""
    return {"accel_interval": plan.accel_index, "steer_interval": plan.steer_index}


def chosen_candidate(scene: Scene, plan: Plan) -> Candidate:
    """The ego candidate the plan follows (the lane rule's, else the route candidate)."""
    i = scene.route_candidate_id if plan.ego_index is None else plan.ego_index
    return scene.ego_candidates[i]


def changing_lanes(scene: Scene, plan: Plan) -> bool:
    """The lane rule chose a "change to the ... lane" candidate."""
    return plan.ego_index is not None and \
        scene.ego_candidates[plan.ego_index].label.startswith("change to the")


def sentence(text: str) -> str:
    return text[:1].upper() + text[1:]
