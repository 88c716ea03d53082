"""Assemble an :class:`Observation` from the separately arriving topics (no ROS).

The bridge publishes ego state, agents and signals with the same stamp per step;
DDS delivers them in any order. The node asks :meth:`ObservationAssembler.complete`
for the ego state it holds; after a short wall wait it uses :meth:`newest` instead
(the newest agents / signals, or empty ones stamped like the ego when none came).
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Optional

from lmpc_msgs_py.messages import AgentArray, EgoState, MapSnapshot, SignalStates
from lmpc_msgs_py.observation import Observation
from lmpc_mpc.reference import index_map

KEEP_STAMPS = 20
STAMP_EPS_S = 1e-6


def _key(stamp_s: float) -> int:
    return int(round(stamp_s / STAMP_EPS_S))


class ObservationAssembler:
    """Buffers the latest map and the last few agents / signals messages by stamp."""

    def __init__(self) -> None:
        self.map: Optional[MapSnapshot] = None
        self._agents: "OrderedDict[int, AgentArray]" = OrderedDict()
        self._signals: "OrderedDict[int, SignalStates]" = OrderedDict()
        self.incomplete_used = 0
        """Observations built without matching agents / signals (counted for diagnostics)."""

    def on_map(self, msg: MapSnapshot) -> None:
        if self.map is None or msg.version >= self.map.version or msg.stamp_s < self.map.stamp_s:
            self.map = msg
            index_map(msg)  # the map lookups now, not in the first decision (city: ~10 ms)

    def on_agents(self, msg: AgentArray) -> None:
        self._agents[_key(msg.stamp_s)] = msg
        while len(self._agents) > KEEP_STAMPS:
            self._agents.popitem(last=False)

    def on_signals(self, msg: SignalStates) -> None:
        self._signals[_key(msg.stamp_s)] = msg
        while len(self._signals) > KEEP_STAMPS:
            self._signals.popitem(last=False)

    def complete(self, ego: EgoState) -> Optional[Observation]:
        """The observation of ``ego``'s stamp when map, agents and signals are all here."""
        k = _key(ego.stamp_s)
        if self.map is None or k not in self._agents or k not in self._signals:
            return None
        return Observation(map=self.map, ego=ego, agents=self._agents[k],
                           signals=self._signals[k])

    def newest(self, ego: EgoState) -> Optional[Observation]:
        """Best effort after the wait: newest agents / signals not after ``ego``'s stamp."""
        if self.map is None:
            return None
        full = self.complete(ego)
        if full is not None:
            return full
        self.incomplete_used += 1
        k = _key(ego.stamp_s)
        agents = next((a for s, a in reversed(self._agents.items()) if s <= k), None)
        signals = next((g for s, g in reversed(self._signals.items()) if s <= k), None)
        return Observation(
            map=self.map,
            ego=ego,
            agents=agents or AgentArray(stamp_s=ego.stamp_s, seq=ego.seq),
            signals=signals or SignalStates(stamp_s=ego.stamp_s, seq=ego.seq),
        )
