"""``coordinator`` node (issue 18; the paper's central LLM): a ROS wrapper around
:class:`~lmpc_llm_planner.coordination.coordinator.CoordinatorCore`.

Subscribes the shared ``/coordination/status`` (every ego's planner publishes its
``EgoStatus`` each step) and publishes ``Directive``s on ``/coordination/directive``.
A round runs on a **complete** set of statuses: the first stamp at which every ego of
the graph has sent one, except egos that reported and then fell silent for
``PEER_ACTIVE_S`` sim (through, or their planner died), once
the core is due (every ``period_s`` of sim time), as the in-process coordinator does
with the statuses of one step. Parameters: ``ego_ids`` (the graph's egos, comma-separated;
a status from another ego is dropped and counted), ``backend`` (``rules``, or ``openai`` /
``local`` with the packaged planner settings and no call log; ``replay`` needs a log the
node cannot be given yet, and ``run_graph.py`` always starts ``rules``), ``period_s``,
``ttl_s``. Diagnostics: rounds, directives issued / refused, statuses dropped.

A coordinator that crashes or hangs sends nothing; the egos' planners notice the silence
(no directive for ``ttl_s``) and fall back (``coordination/link.py``).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

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

KEEP_STAMPS = 40


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
            description="rules (openai / local / replay: not implemented)")).value)
        period = float(self.declare_parameter("period_s", PERIOD_S).value)
        ttl = float(self.declare_parameter("ttl_s", TTL_S).value)
        self.declare_parameter("stats_file", "", desc(
            description="JSON file for the counters, written when the node ends"))
        self.core = CoordinatorCore(make_coordinator_backend(backend), period_s=period,
                                    ttl_s=ttl)
        self._by_stamp: dict[int, dict[str, EgoStatus]] = {}
        self._newest: dict[str, int] = {}
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
        self._newest[st.ego_id] = max(self._newest.get(st.ego_id, k), k)
        for old in sorted(self._by_stamp)[:-KEEP_STAMPS]:
            del self._by_stamp[old]
            self._done.discard(old)
        if k in self._done:
            return
        # every ego of the graph takes part unless it reported and then fell silent
        # (through, or its planner died): a round never runs on one side of a conflict
        # because the other side's statuses do not arrive yet (the egos then fall back)
        active = {eid for eid in self.known if eid not in self._newest
                  or self._newest[eid] >= k - _key(PEER_ACTIVE_S)}
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

    def stats(self) -> dict[str, int]:
        return {"rounds": self.rounds, "directives_issued": self.core.issued,
                "directives_refused": self.core.refused,
                "statuses_dropped": self.counters.get("dropped_messages", 0)}

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
