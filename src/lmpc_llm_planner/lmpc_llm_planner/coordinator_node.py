"""``coordinator`` node (issue 18; the paper's central LLM): a ROS wrapper around
:class:`~lmpc_llm_planner.coordination.coordinator.CoordinatorCore`.

Subscribes the shared ``/coordination/status`` (every ego's planner publishes its
``EgoStatus`` each step) and publishes ``Directive``s on ``/coordination/directive``.
A round runs on a **complete** set of statuses: the first stamp at which every ego
still reporting (a status within ``PEER_ACTIVE_S`` sim of that stamp) has sent one, once
the core is due (every ``period_s`` of sim time), as the in-process coordinator does
with the statuses of one step. Parameters: ``ego_ids`` (the graph's egos, comma-separated;
a status from another ego is dropped and counted), ``backend`` (``rules``; the LLM
backends are not implemented: ``make_coordinator_backend`` says so), ``period_s``,
``ttl_s``. Diagnostics: rounds, directives issued / refused, statuses dropped.

A coordinator that crashes or hangs sends nothing; the egos' planners notice the silence
(no directive for ``ttl_s``) and fall back (``coordination/link.py``).
"""
from __future__ import annotations

import sys
from typing import Optional

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType

from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import LmpcNode, run_node
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
        self.core = CoordinatorCore(make_coordinator_backend(backend), period_s=period,
                                    ttl_s=ttl)
        self._by_stamp: dict[int, dict[str, EgoStatus]] = {}
        self._newest: dict[str, int] = {}
        self._done: set[int] = set()
        self.rounds = 0
        self._pub = self.json_publisher(Directive, topics.COORD_DIRECTIVE)
        self.json_subscription(EgoStatus, topics.COORD_STATUS, self._on_status, shared=True)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0, self._diagnostics, clock=steady)
        self.get_logger().info(f"coordinator up: backend {backend}, period {period} s, ttl "
                               f"{ttl} s, egos {', '.join(sorted(self.known))}")

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
        active = {eid for eid, n in self._newest.items() if n >= k - _key(PEER_ACTIVE_S)}
        have = self._by_stamp[k]
        if not active <= set(have) or not self.core.due(st.stamp_s):
            return
        self._done.add(k)
        self.rounds += 1
        statuses = [have[eid] for eid in sorted(have)]
        with self.stage_times.stage("round (backend, directives)"):
            directives = self.core.on_statuses(statuses, st.stamp_s)
        for d in directives:
            self._pub.publish(d)
        for line in self.core.refusals:
            self.log_event(f"refused:{line[:40]}", f"directive refused: {line}")
        self.core.refusals.clear()

    def _diagnostics(self) -> None:
        self.publish_diagnostics(0, "ok", {
            "rounds": self.rounds, "directives_issued": self.core.issued,
            "directives_refused": self.core.refused, "egos": ",".join(sorted(self.known))})


def main(args: Optional[list[str]] = None) -> int:
    return run_node(CoordinatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
