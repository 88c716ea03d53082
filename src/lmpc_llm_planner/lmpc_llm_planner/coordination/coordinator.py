"""The central coordinator (issue 18; the paper's central LLM): statuses in, directives out.

``CoordinatorCore`` is backend-pluggable like ``PlannerCore``: every ``period_s`` of sim
time it hands the egos' latest statuses to its backend and turns the backend's verdicts
into :class:`Directive` messages (priority, ``yield`` / ``proceed``, a speed band and a
deadline ``ttl_s`` after the statuses' stamp). Each directive is encoded and decoded
through ``lmpc_msgs_py.codec`` as on the wire, and one naming an unknown ego is refused
and counted (``refused``), never delivered.

Backends (``make_coordinator_backend``):
- ``rules``: the fixed rule set of ``coordination.rules`` with a memory of which
  direction holds each conflict;
- ``openai`` / ``local``: an LLM asked with the egos' statuses, its JSON answer
  validated (an unsafe or invalid answer is a silent round); ``replay``: a recorded LLM
  coordination answered again from its log (``coordination.llm``). The extension point is
  the :class:`CoordinatorBackend` protocol: ``verdicts(statuses, now_s)``.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional, Protocol

from lmpc_msgs_py.codec import DecodeError, decode, encode
from lmpc_msgs_py.coordination import Directive, EgoStatus, SpeedBand

from lmpc_llm_planner.coordination.rules import Verdict, resolve

PERIOD_S = 1.0
TTL_S = 3.0
PROCEED_MAX_MPS = 10.0
"""Speed band of a ``proceed`` directive: through the one-lane section at most this."""
BACKENDS = ("rules", "openai", "local", "replay")


class CoordinatorBackend(Protocol):
    name: str

    def verdicts(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Verdict]: ...


class RulesCoordinator:
    """The ``rules`` backend (see the module docstring)."""

    name = "rules"

    def __init__(self) -> None:
        self.memory: dict[str, str] = {}

    def verdicts(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Verdict]:
        return sorted(resolve(statuses, self.memory).values(), key=lambda v: v.ego_id)


class SilentCoordinator:
    """A coordinator that answers nothing (a crashed or hung central node), for tests."""

    name = "rules"

    def verdicts(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Verdict]:
        return []


def make_coordinator_backend(name: str, *, planner_config: Any = None,
                             log_path: Optional[Path] = None,
                             replay_log: Optional[Path] = None) -> CoordinatorBackend:
    """The backend ``name``. ``openai`` / ``local`` take their endpoint / model settings
    from ``planner_config`` (a ``PlannerConfig``; default: the packaged one) and write
    their calls to ``log_path``; ``replay`` answers from ``replay_log`` (such a log)."""
    if name == "rules":
        return RulesCoordinator()
    if name not in BACKENDS:
        raise ValueError(f"unknown coordinator backend {name!r}; choose from "
                         f"{', '.join(BACKENDS)}")
    from lmpc_llm_planner.coordination import llm

    if name == "replay":
        if replay_log is None:
            raise ValueError("coordinator backend 'replay' needs the log of a recorded LLM "
                             "coordination (coordinator.jsonl)")
        return llm.ReplayCoordinator(replay_log)
    if planner_config is None:
        from lmpc_llm_planner.config import load_planner_config

        planner_config = load_planner_config()
    if name == "openai":
        return llm.openai_coordinator(planner_config.openai, log_path=log_path)
    return llm.local_coordinator(planner_config.local, log_path=log_path)


class CoordinatorCore:
    """Directives from statuses; see the module docstring."""

    def __init__(self, backend: CoordinatorBackend, *, period_s: float = PERIOD_S,
                 ttl_s: float = TTL_S, speed_limit_mps: float = PROCEED_MAX_MPS) -> None:
        self.backend = backend
        self.period_s, self.ttl_s = period_s, ttl_s
        self.proceed_max_mps = speed_limit_mps
        self._t_last: Optional[float] = None
        self._seq = 0
        self.issued = 0
        self.refused = 0
        self.refusals: list[str] = []
        self.last_round: list[Directive] = []
        """The directives of the newest round (empty: the backend said nothing)."""

    def due(self, now_s: float) -> bool:
        return self._t_last is None or now_s >= self._t_last + self.period_s - 1e-6

    def on_statuses(self, statuses: Sequence[EgoStatus], now_s: float) -> list[Directive]:
        """The directives of this round ([] when not due or the backend said nothing)."""
        if not self.due(now_s):
            return []
        self._t_last = now_s
        known = {st.ego_id for st in statuses}
        out: list[Directive] = []
        self.last_round = out
        for v in self.backend.verdicts(statuses, now_s):
            self._seq += 1
            band = SpeedBand(min_mps=0.0, max_mps=0.0) if v.command == "yield" else \
                SpeedBand(min_mps=0.0, max_mps=self.proceed_max_mps)
            try:
                d = Directive(stamp_s=now_s, seq=self._seq,
                              directive_id=f"coord-{self._seq}-{v.ego_id}", ego_id=v.ego_id,
                              conflict_id=v.conflict_id, priority=v.priority,
                              command=v.command,  # type: ignore[arg-type]
                              speed_band=band, deadline_s=now_s + self.ttl_s,
                              source=self.backend.name, reasoning=v.why)
                d = self.receive(encode(d), known)
            except (ValueError, DecodeError) as exc:
                self.refused += 1
                self.refusals.append(str(exc).splitlines()[0][:300])
                continue
            self.issued += 1
            out.append(d)
        return out

    def receive(self, text: str, known: set[str]) -> Directive:
        """Decode a directive as an ego's side would: out of schema or for an unknown ego
        raises (``DecodeError`` / ``ValueError`` with one line)."""
        d = decode(text, Directive, topic="/coordination/directive")
        if d.ego_id not in known:
            raise ValueError(f"dropped directive {d.directive_id}: unknown ego {d.ego_id!r}")
        return d
