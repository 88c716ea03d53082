"""The coordination of one multi-ego episode (issue 18): modes ``none|distributed|central``.

``Coordination`` is what the in-process multi-ego loop (``lmpc_bridge.multi_episode``)
calls each step, before the egos' controllers and planners:

- ``none``: the egos are independent (each its own planner and MPC; nothing exchanged);
- ``distributed``: every ego builds its :class:`EgoStatus`, the statuses go to every
  other ego (through the codec, as on a shared topic), and each ego resolves the conflict
  with the fixed rule set (``coordination.rules``) and its own memory; no central node;
- ``central``: the statuses go to a :class:`CoordinatorCore` whose directives (one per
  ego in a conflict, every ``period_s``, valid ``ttl_s``) the egos follow. When the
  coordinator goes silent (its newest round had no directive, or none to any ego for
  ``ttl_s``: crashed, hung), the directives run out and the ego falls back to ``on_silence``:
  ``distributed`` (default: the egos still exchange statuses and use the rule set among
  themselves) or ``none`` (its own planner alone; on development seed 101 of ``narrow``
  two egos on their own planners collide, so this is not the default). Steps on the
  fallback are counted (``silent_steps``) and the first one logged.
"""
from __future__ import annotations

import logging

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

_LOG = logging.getLogger(__name__)
MODES = ("none", "distributed", "central")
DISTRIBUTED_TTL_S = 0.5
"""A distributed verdict is renewed every step; it lapses this long after the last."""


class Coordination:
    """See the module docstring."""

    def __init__(self, mode: str, ego_ids: Iterable[str], space: DecisionSpace, *,
                 coordinator: Optional[CoordinatorCore] = None,
                 on_silence: str = "distributed") -> None:
        if mode not in MODES:
            raise ValueError(f"unknown coordination mode {mode!r}; choose from "
                             f"{', '.join(MODES)}")
        if mode == "central" and coordinator is None:
            raise ValueError("coordination 'central' needs a coordinator")
        if on_silence not in ("distributed", "none"):
            raise ValueError(f"on_silence {on_silence!r}: choose distributed or none")
        self.mode = mode
        self.on_silence = on_silence
        self.silent_steps = 0
        self._last_directive_s = 0.0
        """Sim time of the coordinator's last directive (to any ego); silent: none for
        the directives' ``ttl_s``."""
        self.egos = {eid: EgoCoordination(eid, space) for eid in ego_ids}
        self.coordinator = coordinator if mode == "central" else None
        self._memories: dict[str, dict[str, str]] = {eid: {} for eid in self.egos}
        self.statuses_sent = 0
        self.yield_steps: dict[str, int] = {eid: 0 for eid in self.egos}
        self._marks: dict[str, dict[str, object]] = {}

    def marks(self) -> dict[str, dict[str, object]]:
        """Per ego of the last ``prepare``: the command in force (``yield`` / ``proceed`` /
        None), its source, whether the hold obstacle was put in its observation, and the
        intent it reported (for pictures: ``lmpc_bridge.multi_episode.EgoMark``)."""
        return self._marks

    def prepare(self, now_s: float, obs: dict[str, Observation]) -> dict[str, Observation]:
        """The observations the running egos (``obs``'s keys) act on this step."""
        self._marks = {}
        if self.mode == "none":
            return obs
        statuses = [decode(encode(self.egos[eid].status(o)), EgoStatus,
                           topic="/coordination/status") for eid, o in sorted(obs.items())]
        self.statuses_sent += len(statuses)
        if self.mode == "distributed":
            for eid in obs:
                self._distributed(eid, statuses, now_s)
        else:
            assert self.coordinator is not None
            for d in self.coordinator.on_statuses(statuses, now_s):
                self._last_directive_s = now_s
                self.egos[d.ego_id].follow(Command(
                    command=d.command, conflict_id=d.conflict_id, speed_band=d.speed_band,
                    deadline_s=d.deadline_s, source=d.source, directive_id=d.directive_id))
            silent = not self.coordinator.last_round \
                or now_s - self._last_directive_s >= self.coordinator.ttl_s - 1e-9
            for eid in obs:
                st = next(s for s in statuses if s.ego_id == eid)
                if silent and self.egos[eid].in_force(now_s) is None \
                        and st.intent in ("approach", "wait", "pass"):
                    if not self.silent_steps:
                        _LOG.warning("%s: no directive in force at t=%.1f s (coordinator "
                                     "silent?): falling back to %s", eid, now_s,
                                     self.on_silence)
                    self.silent_steps += 1
                    if self.on_silence == "distributed":
                        self._distributed(eid, statuses, now_s)
        out = {}
        intents = {s.ego_id: s.intent for s in statuses}
        for eid, o in obs.items():
            ego = self.egos[eid]
            cmd = ego.in_force(now_s)
            if cmd is not None and cmd.command == "yield":
                self.yield_steps[eid] += 1
            holds = ego.holds
            out[eid] = ego.apply(o)
            self._marks[eid] = {"command": None if cmd is None else cmd.command,
                                "source": "" if cmd is None else cmd.source,
                                "holding": ego.holds > holds, "intent": intents.get(eid, "")}
        return out

    def _distributed(self, eid: str, statuses: list[EgoStatus], now_s: float) -> None:
        v = resolve(statuses, self._memories[eid]).get(eid)
        self.egos[eid].follow(None if v is None else Command(
            command=v.command, conflict_id=v.conflict_id, speed_band=None,
            deadline_s=now_s + DISTRIBUTED_TTL_S, source="distributed",
            directive_id=f"dist-{eid}-{v.command}"))

    def command_text(self, ego_id: str, now_s: float) -> Optional[str]:
        """The command in force for ``ego_id`` in words (``Command.text``; None: none): what
        an LLM planner's prompt carries (``PlannerCore.on_command``)."""
        cmd = self.egos[ego_id].in_force(now_s)
        return None if cmd is None else cmd.text()

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
                "silent_steps": self.silent_steps,
                "hold_steps": sum(e.holds for e in self.egos.values()),
                "shaped_decisions": sum(e.shaped for e in self.egos.values())}
