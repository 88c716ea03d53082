"""The emergency variant of the rules (rule 7).

An emergency request is answered by the same rules (a left turn that has committed keeps
going, one that waits keeps waiting; the answer never flaps to "keep my speed" while
stopped), with safety "high", no lane choice (the emergency answer has no scenario
encoding: the MPC gets the route candidate) and no stop put off to a later decision.
Only a threat in the ego's own path with a TTC under ``commit_ttc_s`` brakes at the
strongest interval."""
from __future__ import annotations

from typing import Any

from lmpc_llm_planner.scene import AgentView

from .intervals import strongest_brake
from .plan import Plan, RuleInputs, guidance


def start_emergency(plan: Plan) -> None:
    """Every emergency answer weighs safety high."""
    plan.weights["safety"] = "high"


def brakes_hard(inp: RuleInputs, worst: AgentView) -> bool:
    """An emergency with the path threat ``worst`` under ``commit_ttc_s`` to collision."""
    return inp.emergency and worst.kin.ttc_s is not None and \
        worst.kin.ttc_s < inp.cfg.commit_ttc_s


def brake_hard(inp: RuleInputs, plan: Plan) -> None:
    """The strongest braking interval, the bias over tracking."""
    plan.accel_index = strongest_brake(inp.accel)
    plan.weights.update(tracking="low", action="high")


def emergency_answer(plan: Plan) -> dict[str, Any]:
    """The emergency answer object (reasoning, action guidance, weights)."""
    return {
        "reasoning": ("Emergency check. " + " ".join(plan.notes)).strip(),
        "action_guidance": guidance(plan),
        "weight_adjustment": dict(plan.weights),
    }
