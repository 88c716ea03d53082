"""One ego's coordination in the ROS graph (issue 18): the planner node's side, no ROS.

In-process, :class:`~lmpc_llm_planner.coordination.session.Coordination` sees every ego's
status of a step at once. In the graph each ego's planner is its own process: it
publishes its :class:`EgoStatus` on the shared ``/coordination/status`` topic, receives
the others' (``on_status``) and, in ``central`` mode, the coordinator's directives
(``on_directive``). ``EgoLink`` does per step what ``Coordination.prepare`` does for one
ego, with the same pieces (``EgoCoordination``, ``rules.resolve``):

- ``distributed``: the rule set runs on the newest **complete** set of statuses, i.e. the
  newest stamp for which this ego holds its own status and one of every other ego that is
  still reporting (a peer silent for ``PEER_ACTIVE_S`` has left: through, or its planner
  died). Every ego therefore resolves on the same statuses (one step older than its own
  observation when a peer's status of this step is late), so they agree on who goes
  first. The planner node waits for the peers' statuses of its step (``waiting_for``, at
  most its assembly wait: 0.2 s wall, 2 s in a sync graph): in sync mode they usually
  come within milliseconds, so the egos resolve on the statuses of the same step, as
  in-process;
- ``central``: a directive for this ego is followed when it arrives; the coordinator is
  **silent** when no directive (to any ego) came for ``ttl_s`` of sim time (none yet: the
  first ``ttl_s`` of the episode count as not silent). An ego that then sees a conflict
  and has no command in force falls back to ``on_silence`` as in-process (``distributed``:
  the rule set on the peers' statuses), logged once, counted in ``silent_steps``.
- A directive naming an ego that is not one of the graph's (``ego_ids``) is refused and
  counted (``directives_refused``); one out of schema never gets here (the node's codec
  refuses it and counts it the same way).
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Optional

from lmpc_msgs_py.coordination import Directive, EgoStatus
from lmpc_msgs_py.messages import Agent, Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.coordination.coordinator import TTL_S
from lmpc_llm_planner.coordination.ego import Command, EgoCoordination
from lmpc_llm_planner.coordination.rules import resolve
from lmpc_llm_planner.coordination.session import DISTRIBUTED_TTL_S, MODES

PEER_ACTIVE_S = 0.5
"""A peer whose newest status is older than this (sim) no longer takes part."""
KEEP_STAMPS = 40


def _key(stamp_s: float) -> int:
    return int(round(stamp_s * 1000.0))


class EgoLink:
    """See the module docstring."""

    def __init__(self, ego_id: str, ego_ids: Iterable[str], mode: str, space: DecisionSpace,
                 *, ttl_s: float = TTL_S, on_silence: str = "distributed") -> None:
        if mode not in MODES:
            raise ValueError(f"unknown coordination mode {mode!r}; choose from "
                             f"{', '.join(MODES)}")
        if on_silence not in ("distributed", "none"):
            raise ValueError(f"on_silence {on_silence!r}: choose distributed or none")
        self.known = frozenset(ego_ids)
        if ego_id not in self.known:
            raise ValueError(f"ego {ego_id!r} is not one of the graph's egos "
                             f"({', '.join(sorted(self.known))})")
        self.ego_id = ego_id
        self.mode = mode
        self.ttl_s = ttl_s
        self.on_silence = on_silence
        self.ego = EgoCoordination(ego_id, space)
        self.memory: dict[str, str] = {}
        self._own: dict[int, EgoStatus] = {}
        self._peers: dict[str, dict[int, EgoStatus]] = {}
        self.last_directive_s: Optional[float] = None
        self.counters: dict[str, int] = {
            "statuses_received": 0, "statuses_refused": 0, "directives_received": 0,
            "directives_followed": 0, "directives_refused": 0, "silent_steps": 0}
        self.events: list[str] = []
        """Lines to log (the node drains it): the first silent step, refusals."""

    # -- inputs --------------------------------------------------------------------------
    def on_status(self, st: EgoStatus) -> None:
        if st.ego_id == self.ego_id:
            return
        if st.ego_id not in self.known:
            self.counters["statuses_refused"] += 1
            self.events.append(f"status from unknown ego {st.ego_id!r} ignored")
            return
        self.counters["statuses_received"] += 1
        store = self._peers.setdefault(st.ego_id, {})
        store[_key(st.stamp_s)] = st
        for k in sorted(store)[:-KEEP_STAMPS]:
            del store[k]

    def on_directive(self, d: Directive) -> Optional[str]:
        """Take a (schema-valid) directive; why it was refused, or None."""
        if d.ego_id not in self.known:
            self.counters["directives_refused"] += 1
            why = (f"refused directive {d.directive_id}: unknown ego {d.ego_id!r} (egos "
                   f"{', '.join(sorted(self.known))})")
            self.events.append(why)
            return why
        self.counters["directives_received"] += 1
        self.last_directive_s = max(self.last_directive_s or 0.0, d.stamp_s)
        if d.ego_id == self.ego_id and self.mode == "central":
            self.counters["directives_followed"] += 1
            self.ego.follow(Command(command=d.command, conflict_id=d.conflict_id,
                                    speed_band=d.speed_band, deadline_s=d.deadline_s,
                                    source=d.source, directive_id=d.directive_id))
        return None

    def refuse(self, reason: str) -> None:
        """A directive the codec refused (out of schema): counted like an unknown ego."""
        self.counters["directives_refused"] += 1
        self.events.append(f"refused directive: {reason}")

    # -- per step ------------------------------------------------------------------------
    def report(self, obs: Observation) -> Optional[EgoStatus]:
        """This step's status, once per stamp (None: already reported)."""
        k = _key(obs.stamp_s)
        if k in self._own:
            return None
        st = self.ego.status(obs)
        self._own[k] = st
        for old in sorted(self._own)[:-KEEP_STAMPS]:
            del self._own[old]
        return st

    def leave(self, stamp_s: float) -> Optional[EgoStatus]:
        """This ego's episode ended at ``stamp_s`` (reached, collided, ...): its last status,
        ``done`` and without a conflict, for the peers (None: it never reported)."""
        if not self._own:
            return None
        last = self._own[max(self._own)]
        st = last.model_copy(update={"stamp_s": stamp_s, "seq": last.seq + 1,
                                     "intent": "done", "conflict": None})
        self._own[_key(stamp_s)] = st
        return st

    def waiting_for(self, now: float) -> tuple[str, ...]:
        """``distributed``: the peers whose status of this stamp is still missing (active
        ones, and, during the first ``PEER_ACTIVE_S * 2`` of the episode, the ones not heard
        from yet); the node waits for them up to its assembly wait."""
        if self.mode != "distributed":
            return ()
        k = _key(now)
        out = []
        for eid in sorted(self.known - {self.ego_id}):
            store = self._peers.get(eid)
            if not store:
                if now < 2 * PEER_ACTIVE_S:
                    out.append(eid)
            elif eid in self._taking_part(now) and k not in store:
                out.append(eid)
        return tuple(out)

    def _taking_part(self, now: float) -> dict[str, dict[int, EgoStatus]]:
        """The peers whose status of a stamp the rule set needs: heard from within
        ``PEER_ACTIVE_S`` and not ``done`` (an ego whose episode ended says so once,
        ``leave``, and falls silent: waiting for it would cost the assembly wait on each
        step until it counts as silent; in-process it is simply gone)."""
        return {eid: store for eid, store in self._peers.items()
                if store and max(store) >= _key(now - PEER_ACTIVE_S)
                and store[max(store)].intent != "done"}

    def prepare(self, obs: Observation) -> tuple[Optional[EgoStatus], Observation]:
        """This step's status (to publish, None when ``report`` gave it already) and the
        observation the planner acts on."""
        now = obs.stamp_s
        new = self.report(obs)
        st = self._own[_key(now)]
        if self.mode == "distributed":
            self._distributed(now)
        elif self.mode == "central":
            last = self.last_directive_s
            silent = (last is None and now >= self.ttl_s - 1e-9) or \
                (last is not None and now - last >= self.ttl_s - 1e-9)
            if silent and self.ego.in_force(now) is None \
                    and st.intent in ("approach", "wait", "pass"):
                if not self.counters["silent_steps"]:
                    self.events.append(
                        f"{self.ego_id}: no directive in force at t={now:.1f} s (coordinator "
                        f"silent since t={last or 0.0:.1f} s?): falling back to "
                        f"{self.on_silence}")
                self.counters["silent_steps"] += 1
                if self.on_silence == "distributed":
                    self._distributed(now)
        return new, (self.ego.apply(obs) if self.mode != "none" else obs)

    def shape(self, decision: Optional[Decision], obs: Observation) -> Optional[Decision]:
        return decision if self.mode == "none" else self.ego.shape(decision, obs)

    def _distributed(self, now: float) -> None:
        statuses = self.complete_set(now)
        v = resolve(statuses, self.memory).get(self.ego_id)
        self.ego.follow(None if v is None else Command(
            command=v.command, conflict_id=v.conflict_id, speed_band=None,
            deadline_s=now + DISTRIBUTED_TTL_S, source="distributed",
            directive_id=f"dist-{self.ego_id}-{v.command}"))

    def complete_set(self, now: float) -> list[EgoStatus]:
        """The newest set of statuses with one stamp from this ego and every active peer
        (see the module docstring); without one, its own newest and each peer's newest."""
        active = {eid: store for eid, store in self._peers.items()
                  if store and max(store) >= _key(now - PEER_ACTIVE_S)}
        taking_part = self._taking_part(now)
        left = [store[max(store)] for eid, store in sorted(active.items())
                if eid not in taking_part]  # done (the rule set passes over it)
        for k in sorted(self._own, reverse=True):
            if all(k in store for store in taking_part.values()):
                return [self._own[k], *(taking_part[eid][k] for eid in sorted(taking_part)),
                        *left]
        own = self._own[max(self._own)]
        return [own, *(store[max(store)] for _, store in sorted(active.items()))]

    @staticmethod
    def holds(before: Observation, after: Observation) -> tuple[Agent, ...]:
        """The virtual obstacles ``prepare`` added (for the ego's MPC)."""
        if after is before:
            return ()
        ids = {a.id for a in before.agents.agents}
        return tuple(a for a in after.agents.agents if a.id not in ids)

    def stats(self) -> dict[str, int]:
        return {**self.counters, "hold_steps": self.ego.holds,
                "shaped_decisions": self.ego.shaped}
