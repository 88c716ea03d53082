"""The stale-decision check of the MPC (issue 23; docs/lmpc_mpc.md, "Stale decisions").

A decision is computed from an observation ``latency`` (an LLM: ~2.5 s) before it takes
effect and stays in force until its successor does; the world moves on meanwhile. On
every step a decision is in force, the controller checks it against the *current*
state: its own forecast (closest-heading candidate, constant speed; a standing agent
stays put) of every observed agent within sensing range, whatever the decision
attends or predicts. This module holds the plain geometry of that check; the
controller (``MpcController._stale_check``) applies the verdicts:

- an agent whose own forecast enters the ego's path corridor ahead within the horizon
  ("near the ego's path or a conflict zone") and that the problem does not yet avoid
  along that forecast (the decision dropped it, or predicts it elsewhere) is added
  with the own forecast (re-attended);
- a lane change (the decision's curve leads into a neighbour lane of the ego's edge) is
  refused while an agent in that lane is beside the ego or would close the gap within
  ``LANE_CHANGE_S`` (``lane_change_gap``): the ego keeps its own lane for the rest of
  that decision (issue 23: lane changes executed late into a closed gap);
- a "go" (an acceleration bias above the neutral interval) is refused, i.e. the bias
  and the raised reference acceleration fall back to neutral, while the MPC's own
  crossing rule (``MpcController._lead_limits``, on its own forecasts) yields to some
  agent: the gap the decision relied on has closed.

- on a roundabout lane, with an agent coming onto the ego's path from behind, a braking
  bias (which brakes the reference to a stop) is not executed: made before the entry, it
  stopped the ego on the ring, where the car behind ran into it (rab 101 at 1.5 s, rab
  10034 at 5 s); the MPC's own crossing rule and leaders still brake for what is ahead;
- approaching a roundabout on a road, a ring agent whose own forecast leaves the ring is
  also kept clear of along the ring (``CrossingRules._ring_alternative``).

Elsewhere the check only adds caution: it never refuses a braking bias (it cannot know what
the decision brakes for; a version that refused a braking whose stop would land in a
moving vehicle's zone fixed usi 14 at 2.5 s but refused an emergency braking for a
pedestrian in si 20: docs/lmpc_mpc.md, "Stale decisions").

Everything else the decision chose (reference curve, weights, a braking bias, the
other agents' predictions) still applies. An APPROXIMATION like the rest of the MPC's
prediction: constant speeds along the lanes, no reaction of the agents.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

CORRIDOR_MARGIN_M = 0.5
"""An agent's forecast within half the summed widths + ``safety_lateral_gap_m`` + this
of the ego's path is on it (a little wider than the lead limits' test)."""


@dataclass(frozen=True)
class StaleVerdict:
    """What the check found on one step (empty: the decision holds)."""

    reattended: tuple[str, ...] = ()
    """Agents added with the MPC's own forecast (dropped or mispredicted by the decision)."""
    go_refused_for: tuple[str, ...] = ()
    """Agents the MPC's own crossing rule yields to while the decision says go."""
    lane_change_refused_for: tuple[str, ...] = ()
    """Agents in the target lane that closed the gap a decision's lane change relied on
    (``lane_change_gap``): the ego keeps its own lane."""

    brake_refused_for: tuple[str, ...] = ()
    """Agents closing in from behind while the ego is on a roundabout: the decision's
    braking (to a stop) was not executed there (``MpcController._problem``)."""

    @property
    def fired(self) -> bool:
        return bool(self.reattended or self.go_refused_for or self.lane_change_refused_for
                    or self.brake_refused_for)

    def labels(self) -> tuple[str, ...]:
        """For ``Control.stale``: the agents fallen back for, then ``go`` if the
        decision's go bias was refused, ``lane_change`` if its lane change was."""
        out = list(dict.fromkeys(self.reattended + self.go_refused_for
                                 + self.lane_change_refused_for + self.brake_refused_for))
        return tuple(out + (["go"] if self.go_refused_for else [])
                     + (["lane_change"] if self.lane_change_refused_for else [])
                     + (["brake"] if self.brake_refused_for else []))


LANE_CHANGE_S = 3.0
"""A lane change's gap must stay open this long (about its duration) at the current
speeds: a rear agent in the target lane may close in at its speed difference, a front
agent may fall back, by at most the room left beyond the safety gap."""


def lane_change_gap(dx_m: float, *, v_ego_mps: float, v_agent_mps: float,
                    need_m: float) -> bool:
    """Whether an agent in the target lane ``dx_m`` ahead (< 0: behind) of the ego along
    its heading leaves the gap open: box-to-box distance (centre distance minus
    ``need_m``, the half lengths plus the safety gap) stays >= 0 for ``LANE_CHANGE_S``."""
    closing = (v_agent_mps - v_ego_mps) if dx_m < 0.0 else (v_ego_mps - v_agent_mps)
    return abs(dx_m) - need_m - max(0.0, closing) * LANE_CHANGE_S >= 0.0


def reach_m(v0_mps: float, *, accel_mps2: float, horizon_s: float) -> float:
    """How far along its path the ego can get within the horizon (accelerating)."""
    return max(0.0, v0_mps) * horizon_s + 0.5 * max(0.0, accel_mps2) * horizon_s ** 2


def on_path(s_m: np.ndarray, d_m: np.ndarray, *, lateral_clear_m: float,
            reach_m: float, path_length_m: float) -> bool:
    """Whether a forecast (its projections ``s_m``, lateral offsets ``d_m`` on the ego's
    path, one per horizon step) enters the path corridor ahead of the ego and within
    what the ego can reach in the horizon."""
    inside = (d_m < lateral_clear_m + CORRIDOR_MARGIN_M) & (s_m > 0.0) \
        & (s_m < min(reach_m, path_length_m - 1e-6))
    return bool(np.any(inside))


@dataclass
class StaleRecord:
    """What the check did while one decision was in force (for the decision log)."""

    decision_id: str
    first_s: float
    last_s: float = 0.0
    steps: int = 0
    go_refused_steps: int = 0
    agents: list[str] = field(default_factory=list)

    def add(self, t_s: float, verdict: StaleVerdict) -> None:
        self.last_s = t_s
        self.steps += 1
        self.go_refused_steps += int(bool(verdict.go_refused_for))
        self.agents.extend(a for a in verdict.labels()
                           if a not in ("go", "lane_change", "brake") and a not in self.agents)

    def as_dict(self) -> dict[str, Any]:
        return {"decision_id": self.decision_id, "first_s": round(self.first_s, 3),
                "last_s": round(self.last_s, 3), "steps": self.steps,
                "go_refused_steps": self.go_refused_steps, "agents": list(self.agents)}
