"""ROS plumbing shared by the ``llm_planner`` and ``mock_llm`` nodes (imports rclpy).

Both take observations from the topics, hand them to a core object with
``on_observation(obs) -> Decision | None`` and publish, per ego state, the
decision (if any) THEN the ``PlannerStatus`` carrying that observation's stamp:
the sync barrier the bridge waits on (docs/ARCHITECTURE.md).
"""
from __future__ import annotations

import time
from typing import Any, Optional, Protocol

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from std_msgs.msg import String

from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import LmpcNode
from lmpc_msgs_py.freshness import is_stale
from lmpc_msgs_py.messages import (
    AgentArray,
    Decision,
    EgoState,
    MapSnapshot,
    PlannerStatus,
    SignalStates,
)
from lmpc_msgs_py.observation import Observation

from lmpc_llm_planner.assembler import ObservationAssembler
from lmpc_llm_planner.prompt import instruction_error

STALE_AFTER_S = 0.3
"""Ego state older than this vs /clock (sim time): no new decision (RELIABILITY.md)."""
ASSEMBLY_WAIT_S = 0.2
"""Wall time to wait for the agents / signals of an ego state's stamp (and, by default, for
the other inputs a subclass waits on, ``inputs_ready``)."""
CLOCK_WATCHDOG_S = 2.0
DIAGNOSTICS_PERIOD_S = 1.0
POLL_PERIOD_S = 0.02


class CoreLike(Protocol):
    def on_observation(self, obs: Observation) -> Optional[Decision]: ...
    def on_instruction(self, text: str) -> None: ...


class DecisionNode(LmpcNode):
    """Observation in, decision + status out; subclasses provide the core."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.declare_parameter("ego_id", "")
        self.declare_bridge_gone_exit()
        self.declare_profile_output()
        self.ego_id = self.get_parameter("ego_id").value or None
        self.core: Optional[CoreLike] = None
        self.assembler = ObservationAssembler()
        self._pending: Optional[EgoState] = None
        self._pending_deadline = 0.0
        # sync multi-ego graphs wait longer for the peers' statuses (graph_multi.py): the
        # bridge waits for every planner, so a peer slowed by a loaded CPU is late, not gone
        self.assembly_wait_s = float(self.declare_parameter(
            "assembly_wait_s", ASSEMBLY_WAIT_S, ParameterDescriptor(
                description="wall s to wait for an ego state's other inputs")).value)
        if not self.assembly_wait_s > 0:
            raise ValueError(f"assembly_wait_s must be > 0, got {self.assembly_wait_s}")
        self._status_seq = 0
        self._last_decision_id: Optional[str] = None
        self._decisions = 0
        self._fallbacks = 0
        self._last_clock_ns: Optional[int] = None
        self._clock_changed_at = time.monotonic()
        self._clock_stalled = False
        self._decision_pub = self.json_publisher(Decision, topics.DECISION)
        self._status_pub = self.json_publisher(PlannerStatus, topics.PLANNER_STATUS)

    def start(self) -> None:
        """Subscribe and start the wall timers (call once the core exists)."""
        self.json_subscription(MapSnapshot, topics.MAP, self.assembler.on_map,
                               lmpc_qos.LATCHED, check_seq=False)
        self.json_subscription(EgoState, topics.EGO_STATE, self._on_ego)
        self.json_subscription(AgentArray, topics.AGENTS, self._on_agents)
        self.json_subscription(SignalStates, topics.SIGNALS, self._on_signals)
        self.create_subscription(String, self.topic(topics.INSTRUCTION), self._on_instruction,
                                 lmpc_qos.STREAM)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(POLL_PERIOD_S, self._poll, clock=steady)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._diagnostics, clock=steady)
        self.get_logger().info(
            f"{self.get_name()} ready: waiting for {self.topic(topics.MAP)} and "
            f"{self.topic(topics.EGO_STATE)}"
        )

    # -- inputs ---------------------------------------------------------------------------
    def _on_instruction(self, msg: String) -> None:
        text = msg.data if isinstance(msg.data, str) else ""
        refused = instruction_error(text)
        if refused:
            self.count_drop(self.topic(topics.INSTRUCTION), "data", refused)
            return
        if self.core is not None:
            self.core.on_instruction(text)
            self.get_logger().info(f"instruction received ({len(text)} characters)")

    def _on_agents(self, msg: AgentArray) -> None:
        self.assembler.on_agents(msg)
        self._try_pending(force=False)

    def _on_signals(self, msg: SignalStates) -> None:
        self.assembler.on_signals(msg)
        self._try_pending(force=False)

    def _on_ego(self, msg: EgoState) -> None:
        if self._pending is not None:
            self._try_pending(force=True)  # a newer step came: finish the older one first
        self._pending = msg
        self._pending_deadline = time.monotonic() + self.assembly_wait_s
        self._try_pending(force=False)

    def _poll(self) -> None:
        self._watchdog()
        if self._pending is not None and time.monotonic() >= self._pending_deadline:
            self._try_pending(force=True)

    def _try_pending(self, *, force: bool) -> None:
        ego = self._pending
        if ego is None:
            return
        obs = self.assembler.complete(ego)
        if obs is None and not force:
            return
        if obs is None:
            obs = self.assembler.newest(ego)
        if obs is not None and not self.inputs_ready(obs):
            if not force:
                return  # e.g. the peers' statuses of this step (multi-ego coordination)
            self.counters["assembly_wait_expired"] += 1
            self.log_event("assembly_wait", f"inputs of t={ego.stamp_s:.2f} s still missing "
                           f"after {self.assembly_wait_s:.1f} s wall: deciding without them")
        self._pending = None
        self._process(ego, obs)

    # -- one step -------------------------------------------------------------------------
    def _process(self, ego: EgoState, obs: Optional[Observation]) -> None:
        if obs is None:
            self.log_event("wait:map", f"waiting for {self.topic(topics.MAP)}: no decision yet",
                           level="info")
        elif self._is_stale(ego):
            self.counters["stale_ego_state"] += 1
            self.log_event("stale", f"ego state at t={ego.stamp_s:.2f} s is older than "
                           f"{STALE_AFTER_S} s vs /clock: no new decision")
        elif self.core is not None:
            obs = self.before_decide(obs)
            with self.stage_times.stage("decide (core, backend)"):
                decision = self._safe_decide(obs)
            decision = self.after_decide(decision, obs)
            if decision is not None:
                self._decision_pub.publish(decision)
                self._last_decision_id = decision.decision_id
                self._decisions += 1
                if decision.source == "fallback":
                    self._fallbacks += 1
        self._publish_status(ego.stamp_s)

    def inputs_ready(self, obs: Observation) -> bool:
        """Whether to decide on ``obs`` now (else wait, at most ``assembly_wait_s``)."""
        return True

    def before_decide(self, obs: Observation) -> Observation:
        """The observation the core decides on (the coordination's hook; as is here)."""
        return obs

    def after_decide(self, decision: Optional[Decision],
                     obs: Observation) -> Optional[Decision]:
        """The decision to publish (the coordination's hook; as is here)."""
        return decision

    def _safe_decide(self, obs: Observation) -> Optional[Decision]:
        # The core never raises on backend output; this guard keeps the barrier alive
        # even on a bug (counted and logged, the status still goes out).
        try:
            return self.core.on_observation(obs) if self.core is not None else None
        except Exception as exc:  # noqa: BLE001
            self.counters["core_errors"] += 1
            self.log_event("core_error", f"planner core failed: {type(exc).__name__}: {exc}",
                           level="error")
            return None

    def _publish_status(self, stamp_s: float) -> None:
        self._status_pub.publish(PlannerStatus(
            stamp_s=stamp_s, seq=self._status_seq, last_decision_id=self._last_decision_id,
            decisions=self._decisions, fallbacks=self._fallbacks,
            dropped_messages=self.counters["dropped_messages"],
        ))
        self._status_seq += 1

    def _uses_sim_time(self) -> bool:
        return bool(self.get_parameter("use_sim_time").value)

    def _is_stale(self, ego: EgoState) -> bool:
        if not self._uses_sim_time():
            return False
        now_ns = self.get_clock().now().nanoseconds
        if now_ns <= 0:
            return False  # no /clock yet: nothing to compare with
        return is_stale(ego.stamp_s, now_ns * 1e-9, STALE_AFTER_S)

    # -- health ---------------------------------------------------------------------------
    def _watchdog(self) -> None:
        if not self._uses_sim_time():
            return
        now_ns = self.get_clock().now().nanoseconds
        if now_ns != self._last_clock_ns:
            self._last_clock_ns = now_ns
            self._clock_changed_at = time.monotonic()
            if self._clock_stalled:
                self.get_logger().info("simulation advancing again")
            self._clock_stalled = False
            return
        if now_ns > 0 and not self._clock_stalled \
                and time.monotonic() - self._clock_changed_at > CLOCK_WATCHDOG_S:
            self._clock_stalled = True
            self.counters["clock_stalls"] += 1
            self.get_logger().warn(
                f"simulation not advancing: /clock unchanged for {CLOCK_WATCHDOG_S:.0f} s wall"
            )
        if self._clock_stalled:
            self.exit_if_bridge_gone(True)

    def core_counters(self) -> dict[str, Any]:
        return {}

    def _diagnostics(self) -> None:
        level, message = 0, "ok"
        if self.assembler.map is None:
            level, message = 1, "waiting for map"
        if self._clock_stalled:
            level, message = 1, "simulation not advancing"
        extra: dict[str, object] = {
            "decisions": self._decisions, "fallbacks": self._fallbacks,
            "last_decision_id": self._last_decision_id or "",
            "incomplete_observations": self.assembler.incomplete_used,
        }
        extra.update(self.core_counters())
        self.publish_diagnostics(level, message, extra)
