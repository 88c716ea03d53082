"""The coordination of one multi-ego episode (issue 18): modes ``none|distributed|central``.

``Coordination`` is what the in-process multi-ego loop (``lmpc_bridge.multi_episode``)
calls each step, before the egos' controllers and planners:

- ``none``: the egos are independent (each its own planner and MPC; nothing exchanged);
- ``distributed``: every ego builds its :class:`EgoStatus`, the statuses go to every
  other ego (through the codec, as on a shared topic), and each ego resolves the conflict
  with the fixed rule set (``coordination.rules``) and its own memory; no central node;
- ``central``: the statuses go to a :class:`CoordinatorCore` whose directives (one per
  ego in a conflict, every ``period_s``, valid ``ttl_s``) the egos follow; a silent
  coordinator lets the directives run out and each ego is on its own planner again.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Optional

from lmpc_msgs_py.codec import decode, encode
from lmpc_msgs_py.coordination import EgoStatus
from lmpc_msgs_py.messages import Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.coordination.coordinator import CoordinatorCore
from lmpc_llm_planner.coordination.ego import Command, EgoCoordination
from lmpc_llm_planner.coordination.rules import resolve

MODES = ("none", "distributed", "central")
DISTRIBUTED_TTL_S = 0.5
"""A distributed verdict is renewed every step; it lapses this long after the last."""


class Coordination:
    """See the module docstring."""

    def __init__(self, mode: str, ego_ids: Iterable[str], space: DecisionSpace, *,
                 coordinator: Optional[CoordinatorCore] = None) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown coordination mode {mode!r}; choose from "
                             f"{', '.join(MODES)}")
        if mode == "central" and coordinator is None:
            raise ValueError("coordination 'central' needs a coordinator")
        self.mode = mode
        self.egos = {eid: EgoCoordination(eid, space) for eid in ego_ids}
        self.coordinator = coordinator if mode == "central" else None
        self._memories: dict[str, dict[str, str]] = {eid: {} for eid in self.egos}
        self.statuses_sent = 0
        self.yield_steps: dict[str, int] = {eid: 0 for eid in self.egos}

    def prepare(self, now_s: float, obs: dict[str, Observation]) -> dict[str, Observation]:
        """The observations the running egos (``obs``'s keys) act on this step."""
        if self.mode == "none":
            return obs
        statuses = [decode(encode(self.egos[eid].status(o)), EgoStatus,
                           topic="/coordination/status") for eid, o in sorted(obs.items())]
        self.statuses_sent += len(statuses)
        if self.mode == "distributed":
            for eid in obs:
                v = resolve(statuses, self._memories[eid]).get(eid)
                self.egos[eid].follow(None if v is None else Command(
                    command=v.command, conflict_id=v.conflict_id, speed_band=None,
                    deadline_s=now_s + DISTRIBUTED_TTL_S, source="distributed",
                    directive_id=f"dist-{eid}-{v.command}"))
        else:
            assert self.coordinator is not None
            for d in self.coordinator.on_statuses(statuses, now_s):
                self.egos[d.ego_id].follow(Command(
                    command=d.command, conflict_id=d.conflict_id, speed_band=d.speed_band,
                    deadline_s=d.deadline_s, source=d.source, directive_id=d.directive_id))
        out = {}
        for eid, o in obs.items():
            cmd = self.egos[eid].in_force(now_s)
            if cmd is not None and cmd.command == "yield":
                self.yield_steps[eid] += 1
            out[eid] = self.egos[eid].apply(o)
        return out

    def shape(self, ego_id: str, decision: Optional[Decision],
              obs: Observation) -> Optional[Decision]:
        """The ego's new decision with its command's speed band taken in."""
        if self.mode == "none":
            return decision
        return self.egos[ego_id].shape(decision, obs)

    def stats(self) -> dict[str, int]:
        c = self.coordinator
        return {"statuses": self.statuses_sent,
                "directives": 0 if c is None else c.issued,
                "directives_refused": 0 if c is None else c.refused,
                "hold_steps": sum(e.holds for e in self.egos.values()),
                "shaped_decisions": sum(e.shaped for e in self.egos.values())}
