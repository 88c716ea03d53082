"""``coordinator`` node (issue 18; the paper's central LLM): a ROS wrapper around
:class:`~lmpc_llm_planner.coordination.coordinator.CoordinatorCore`.

Subscribes the shared ``/coordination/status`` (every ego's planner publishes its
``EgoStatus`` each step) and publishes ``Directive``s on ``/coordination/directive``.
A round runs on a **complete** set of statuses: the first stamp at which every ego of
the graph has sent one, except egos that reported and then fell silent for
``PEER_ACTIVE_S`` sim (through, or their planner died; an ego whose last status still
had a conflict ahead must also have been silent for ``QUIET_WALL_S`` wall: its statuses
may only be late, and a round without it would run on one side of the conflict), once
the core is due (every ``period_s`` of sim time), as the in-process coordinator does
with the statuses of one step. Parameters: ``ego_ids`` (the graph's egos, comma-separated;
a status from another ego is dropped and counted), ``backend`` (``rules``, ``openai``,
``local``, ``replay``: ``coordination/llm.py``), ``config_file`` (the planner YAML whose
``openai`` / ``local`` settings an LLM backend uses; '' = the packaged one), ``log_file``
(the LLM backend's JSON-lines call log; '' = none), ``replay_log`` (``replay``: such a
log), ``period_s``, ``ttl_s``, ``stats_file``. Diagnostics: rounds, directives issued /
refused, statuses dropped; with an LLM backend also its calls and silent rounds by cause
(``replay``: prompts the log did not have).

A coordinator that crashes or hangs sends nothing; the egos' planners notice the silence
(no directive for ``ttl_s``) and fall back (``coordination/link.py``).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType

from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import JsonPublisher, LmpcNode, run_node
from lmpc_msgs_py.coordination import Directive, EgoStatus

from lmpc_llm_planner.coordination.coordinator import (
    PERIOD_S,
    TTL_S,
    CoordinatorCore,
    make_coordinator_backend,
)
from lmpc_llm_planner.coordination.link import PEER_ACTIVE_S, _key
from lmpc_llm_planner.coordination.llm import LlmCoordinator, ReplayCoordinator

KEEP_STAMPS = 40
QUIET_WALL_S = 0.5
"""Wall seconds an ego still in a conflict must be silent before a round goes on without
it (its statuses may be late: seen once, a round at t=1.1 s on one of two egos whose
statuses came ~6 steps behind the other's)."""


class CoordinatorNode(LmpcNode):
    def __init__(self) -> None:
        super().__init__("coordinator")
        desc = ParameterDescriptor
        self.declare_profile_output()
        ids = str(self.declare_parameter("ego_ids", "", desc(
            description="the graph's egos, comma-separated")).value)
        self.known = frozenset(e for e in ids.split(",") if e)
        if not self.known:
            raise ValueError("coordinator: parameter ego_ids is empty")
        backend = str(self.declare_parameter("backend", "rules", desc(
            description="rules | openai | local | replay")).value)
        config_file = str(self.declare_parameter("config_file", "", desc(
            description="planner YAML with the LLM backend's settings ('' = packaged)")).value)
        log_file = str(self.declare_parameter("log_file", "", desc(
            description="JSON-lines log of the LLM backend's calls ('' = none)")).value)
        replay_log = str(self.declare_parameter("replay_log", "", desc(
            description="replay: the coordinator log to answer from")).value)
        period = float(self.declare_parameter("period_s", PERIOD_S).value)
        ttl = float(self.declare_parameter("ttl_s", TTL_S).value)
        self.declare_parameter("stats_file", "", desc(
            description="JSON file for the counters, written when the node ends"))
        planner_config = None
        if backend in ("openai", "local"):
            from lmpc_llm_planner.config import load_planner_config

            planner_config = load_planner_config(config_file or None)
        self.backend_name = backend
        self.core = CoordinatorCore(make_coordinator_backend(
            backend, planner_config=planner_config, log_path=Path(log_file) if log_file
            else None, replay_log=Path(replay_log) if replay_log else None),
            period_s=period, ttl_s=ttl)
        self._by_stamp: dict[int, dict[str, EgoStatus]] = {}
        self._newest: dict[str, int] = {}
        self._last: dict[str, tuple[float, bool]] = {}
        """Per ego: steady time of its newest status, and whether it had a conflict ahead."""
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._done: set[int] = set()
        self.rounds = 0
        self._pub: Optional[JsonPublisher[Directive]] = None
        self._sub = self.json_subscription(EgoStatus, topics.COORD_STATUS, self._on_status,
                                           shared=True)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._connect_timer = self.create_timer(0.05, self._connect, clock=steady)
        self.create_timer(1.0, self._diagnostics, clock=steady)
        self.get_logger().info(f"coordinator up: backend {backend}, period {period} s, ttl "
                               f"{ttl} s, egos {', '.join(sorted(self.known))}")

    def _connect(self) -> None:
        """Create the directive publisher once every ego's status publisher is matched:
        the bridge waits for it before step 0 (run_graph passes ``coordination``)."""
        if self._sub.get_publisher_count() < len(self.known):
            return
        self._pub = self.json_publisher(Directive, topics.COORD_DIRECTIVE)
        self._connect_timer.cancel()
        self.get_logger().info("connected: every ego's status publisher matched")

    def _on_status(self, st: EgoStatus) -> None:
        if st.ego_id not in self.known:
            self.count_drop(topics.COORD_STATUS, "ego_id", f"unknown ego {st.ego_id!r}")
            return
        k = _key(st.stamp_s)
        self._by_stamp.setdefault(k, {})[st.ego_id] = st
        if k >= self._newest.get(st.ego_id, k):
            self._newest[st.ego_id] = k
            self._last[st.ego_id] = (self._wall(), st.conflict is not None
                                     and st.intent not in ("done", "through"))
        for old in sorted(self._by_stamp)[:-KEEP_STAMPS]:
            del self._by_stamp[old]
            self._done.discard(old)
        if k in self._done:
            return
        # every ego of the graph takes part unless it reported and then fell silent
        # (through, or its planner died): a round never runs on one side of a conflict
        # because the other side's statuses do not arrive yet (the egos then fall back)
        active = {eid for eid in self.known if not self._gone(eid, k)}
        have = self._by_stamp[k]
        if not active <= set(have) or not self.core.due(st.stamp_s):
            return
        self._done.add(k)
        self.rounds += 1
        statuses = [have[eid] for eid in sorted(have)]
        with self.stage_times.stage("round (backend, directives)"):
            directives = self.core.on_statuses(statuses, st.stamp_s)
        for d in directives:
            if self._pub is not None:
                self._pub.publish(d)
        text = ", ".join(f"{d.ego_id} {d.command} p{d.priority}" for d in directives)
        self.get_logger().info(f"round t={st.stamp_s:.1f}s on {', '.join(sorted(have))}: "
                               f"{text or 'no directive'}")
        for line in self.core.refusals:
            self.log_event(f"refused:{line[:40]}", f"directive refused: {line}")
        self.core.refusals.clear()

    def _wall(self) -> float:
        return self._steady.now().nanoseconds * 1e-9

    def _gone(self, eid: str, k: int) -> bool:
        """``eid`` reported and then fell silent (see the module docstring)."""
        if eid not in self._newest or self._newest[eid] >= k - _key(PEER_ACTIVE_S):
            return False
        wall, in_conflict = self._last[eid]
        return not in_conflict or self._wall() - wall >= QUIET_WALL_S

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "backend": self.backend_name, "rounds": self.rounds,
            "directives_issued": self.core.issued, "directives_refused": self.core.refused,
            "statuses_dropped": self.counters.get("dropped_messages", 0)}
        b = self.core.backend
        if isinstance(b, LlmCoordinator):
            out.update(llm_source=b.name, llm_calls=b.calls, llm_errors=dict(b.errors),
                       llm_last_error=b.last_error)
        elif isinstance(b, ReplayCoordinator):
            out.update(llm_source=b.name, replay_misses=b.misses,
                       replay_stamp_matches=b.stamp_matches)
        return out

    def destroy_node(self) -> None:
        """Also write :meth:`stats` to ``stats_file`` (when set)."""
        path = str(self.get_parameter("stats_file").value)
        if path:
            try:
                Path(path).write_text(json.dumps(self.stats(), indent=1))
            except OSError as exc:
                self.get_logger().warning(f"could not write {path}: {exc}")
        super().destroy_node()

    def _diagnostics(self) -> None:
        self.publish_diagnostics(0, "ok", {
            "rounds": self.rounds, "directives_issued": self.core.issued,
            "directives_refused": self.core.refused, "egos": ",".join(sorted(self.known))})


def main(args: Optional[list[str]] = None) -> int:
    return run_node(CoordinatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
