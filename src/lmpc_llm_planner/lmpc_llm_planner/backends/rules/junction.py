"""What the two junction rules (left turn, roundabout entry) share: the conflict with a
priority agent, the ego's time to clear a crossing, the slow approach to a turn, and
when a stop at the line may be put off to the next decision. The time estimates are
APPROXIMATIONS (constant agent speeds, straight agent paths), documented in route.py."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_llm_planner.route import Maneuver
from lmpc_llm_planner.scene import AgentView

from .intervals import accel_index, brake_index, mid, mildest_accel, neutral
from .plan import Plan, RuleInputs

CLEAR_MARGIN_M = 1.0
"""Added to the half length / width of a vehicle when it clears a crossing."""
GO_ZONE_M = 8.0
"""With a safe gap and the front this close to the stop line, the ego turns briskly
(accelerating) instead of holding its approach speed."""


@dataclass(frozen=True)
class Conflict:
    """An agent with priority whose path crosses the ego's (an oncoming car in a left
    turn, ring traffic at a roundabout entry)."""

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
    what: str = "oncoming"
    """How the agent comes: "oncoming" or "crossing" (a left turn's crossing traffic)."""

    @property
    def gap_s(self) -> float:
        return self.t_agent_s - self.t_clear_s


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


def _go_index(inp: RuleInputs) -> int:
    """The interval the ego goes with: the go interval (``turn_accel_mps2``), or the
    mildest accelerating one for the conservative style (a careful driver turns gently)."""
    if inp.intent.style == "conservative":
        return mildest_accel(inp.accel)
    return accel_index(inp.accel, inp.cfg.turn_accel_mps2)


def go_accel_mps2(inp: RuleInputs) -> float:
    """The acceleration a clear time assumes: what the rules ask for when the ego goes
    (``_go_index``; the conservative style's gentle go gives longer clear times, so it
    takes only the larger gaps)."""
    accel = mid(inp.accel[_go_index(inp)])
    if inp.intent.style == "conservative":
        return accel
    return max(accel, inp.cfg.turn_accel_mps2)


def stop_brake_limit_mps2(inp: RuleInputs) -> float:
    """The strongest braking a stop at a junction may need: a new stop must be comfortable
    (as the MPC's own yield rule: otherwise commit); a stop already under way may brake
    harder (else it would flip to "commit" half-way as the distance shrinks)."""
    if inp.previous_stop:
        return max(-lo for lo, _ in inp.accel)
    return inp.cfg.commit_decel_mps2


def stop_can_wait(inp: RuleInputs, v_mps: float, d_stop_m: float,
                  next_s: Optional[float] = None) -> bool:
    """Far from the line (and not an emergency): braking to a stop now would stop well short
    of it, and stopping after the next decision (``next_s``, default ``replan_s``) is still
    comfortable."""
    cfg = inp.cfg
    t_next = cfg.replan_s if next_s is None else next_s
    return not inp.emergency and v_mps >= cfg.moving_speed_mps and \
        d_stop_m - v_mps * t_next > v_mps * v_mps / (2.0 * cfg.commit_decel_mps2) + 5.0


def go_briskly(inp: RuleInputs, plan: Plan, *, committed: bool = False) -> None:
    """Accelerate through the junction with ``_go_index``'s interval; committed, always
    with the go interval (a committed ego clears briskly, whatever the style)."""
    plan.accel_index = accel_index(inp.accel, inp.cfg.turn_accel_mps2) if committed \
        else _go_index(inp)
    plan.speed_set = True


def commit(inp: RuleInputs, plan: Plan, note: str) -> str:
    """Too close (or too far in) to stop: clear the junction briskly, safety high."""
    go_briskly(inp, plan, committed=True)
    plan.weights["safety"] = "high"
    plan.notes.append(note)
    return "commit"


def approach_turn(inp: RuleInputs, plan: Plan, man: Maneuver, v_mps: float,
                  next_s: Optional[float] = None) -> None:
    """Rule 4: slow to ``approach_turn_speed_mps`` by the stop line (a driver about to turn does;
    it also leaves room to react to traffic not yet in sensing range). The next decision
    acts ``next_s`` later (default ``replan_s``)."""
    cfg = inp.cfg
    accel = inp.accel
    d = man.dist_to_stop_line_m - 0.5 * DEFAULT_VEHICLE.length_m
    v_turn = cfg.approach_turn_speed_mps
    if man.inside_junction or d <= 0.0:
        return
    if v_mps > v_turn + 0.5:
        need = (v_mps**2 - v_turn**2) / (2.0 * d)
        if need > 0.2:
            plan.accel_index = brake_index(accel, need * cfg.brake_margin_factor, False)
            plan.speed_set = True
            # At "normal" the MPC barely follows a bias (tracking the speed limit wins).
            plan.weights["action"] = "high"
            plan.notes.append(f"I slow down to {v_turn:.0f} m/s for the turn.")
            return
    # at about the turn speed, hold it: an accelerating bias lasts until the next
    # decision (``next_s``) and would arrive too fast to stop for a late gap
    t_next = cfg.replan_s if next_s is None else next_s
    if v_mps + mid(accel[mildest_accel(accel)]) * t_next >= v_turn + 1.0:
        plan.accel_index = neutral(accel)
        plan.speed_set = True
        plan.weights["action"] = "high"
        plan.notes.append(f"I keep about {v_turn:.0f} m/s for the turn.")
