"""Shared ROS plumbing of the LanguageMPC nodes (this module is about ROS, so it imports rclpy).

- :class:`LmpcNode`: a node with JSON-on-``std_msgs/String`` publishers and
  subscriptions that validate every payload through the schemas, refuse
  duplicates / backwards sequence numbers, count every drop and log each kind
  of drop once per throttle period, naming topic, field and reason.
- :func:`run_node`: the Jazzy ``main()`` pattern (STYLE.md 11); a node started by
  ``run_graph.py`` also ends when that supervisor dies (:mod:`lmpc_msgs_py.supervision`).
- :meth:`LmpcNode.exit_if_bridge_gone`: a planner or MPC whose bridge has left the graph
  for good ends its process instead of waiting forever (docs/RELIABILITY_TESTS.md).
"""
from __future__ import annotations

import json
import signal
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Generic, Optional, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import String

from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.codec import DecodeError, decode, encode
from lmpc_msgs_py.discovery import stay_local
from lmpc_msgs_py.freshness import SequenceGate, StaleMessage
from lmpc_msgs_py.messages import LmpcMessage
from lmpc_msgs_py.profiling import StageTimes
from lmpc_msgs_py.scheduling import apply_priority_from_env, executor_from_env
from lmpc_msgs_py.supervision import follow_supervisor

M = TypeVar("M", bound=LmpcMessage)

LOG_THROTTLE_S = 5.0
BRIDGE_GONE_EXIT_S = 10.0
"""Default wall seconds a planner / MPC waits, once its ``/clock`` watchdog fired and no
node publishes ``/clock`` any more, before it ends its process (parameter
``bridge_gone_exit_s``; 0 = wait forever). Long enough for a bridge restarted by hand."""

EVENTS_SPIN_TIMEOUT_S = 0.5
"""The EventsExecutor is spun by ``spin_once`` with this timeout, never by its ``spin()``."""


class JsonPublisher(Generic[M]):
    """Publishes schema messages as JSON text on a ``std_msgs/String`` topic."""

    def __init__(self, node: Node, cls: type[M], name: str, qos: QoSProfile,
                 times: Optional[StageTimes] = None) -> None:
        self.cls = cls
        self.topic = name
        self._pub = node.create_publisher(String, name, qos)
        self._times = times or StageTimes()
        self._encode_key, self._publish_key = f"encode {name}", f"publish {name}"

    def publish(self, msg: M) -> None:
        if not isinstance(msg, self.cls):
            raise TypeError(f"{self.topic} carries {self.cls.__name__}, not {type(msg).__name__}")
        t0 = time.perf_counter()
        data = String(data=encode(msg))
        t1 = time.perf_counter()
        self._pub.publish(data)
        self._times.add(self._encode_key, (t1 - t0) * 1e3)
        self._times.add(self._publish_key, (time.perf_counter() - t1) * 1e3)

    def subscription_count(self) -> int:
        return self._pub.get_subscription_count()


class LmpcNode(Node):
    """Base node: validated JSON I/O, drop counters, throttled event logs, diagnostics."""

    def __init__(self, name: str, *, ego_id: Optional[str] = None, **kwargs: object) -> None:
        super().__init__(name, **kwargs)  # type: ignore[arg-type]
        self.ego_id = ego_id
        self.counters: Counter[str] = Counter()
        self.stage_times = StageTimes()
        """Per-stage wall times of this node (``lmpc_msgs_py.profiling``)."""
        self._last_log: dict[str, float] = {}
        self._inputs: dict[str, Any] = {}  # topic -> subscription of a single-producer topic
        self._diag_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self._bridge_gone_exit_s = 0.0
        self._bridge_gone_since: Optional[float] = None
        self._profile_file = ""

    # -- where the time went ---------------------------------------------------------------
    def declare_profile_output(self) -> None:
        """Declare ``profile_file``: where this node writes its stage times when it ends
        (JSON, ``lmpc_msgs_py.profiling``; '' = nowhere). ``run_graph.py`` sets it."""
        self._profile_file = str(self.declare_parameter(
            "profile_file", "", ParameterDescriptor(
                description="JSON file for this node's per-stage wall times, written when "
                            "the node ends ('' = none)")).value)

    def write_profile(self) -> None:
        if not self._profile_file:
            return
        try:
            Path(self._profile_file).write_text(json.dumps(
                {"node": self.get_name(), "stages_ms": self.stage_times.summary()}, indent=1))
        except OSError as exc:  # a lost profile must not turn a clean exit into a crash
            self.get_logger().warning(f"could not write {self._profile_file}: {exc}")

    def destroy_node(self) -> None:
        self.write_profile()
        super().destroy_node()

    # -- the bridge gone for good ----------------------------------------------------------
    def declare_bridge_gone_exit(self) -> None:
        """Declare ``bridge_gone_exit_s`` (for nodes that live on the bridge's clock)."""
        value = self.declare_parameter(
            "bridge_gone_exit_s", BRIDGE_GONE_EXIT_S, ParameterDescriptor(
                description="wall seconds to wait, after the /clock watchdog fired and while "
                            "no node publishes /clock, before this node exits (0 = never)",
                dynamic_typing=True),  # 10 and 10.0 both work on the command line
        ).value
        if not isinstance(value, (int, float)) or value < 0:
            raise ValueError(f"parameter bridge_gone_exit_s must be a number >= 0, "
                             f"got {value!r}")
        self._bridge_gone_exit_s = float(value)

    def exit_if_bridge_gone(self, clock_stalled: bool) -> bool:
        """Call from the ``/clock`` watchdog: True once the node has shut itself down.

        The bridge counts as gone for good when the clock is stalled (the watchdog fired)
        and nobody has published ``/clock`` for ``bridge_gone_exit_s`` wall seconds. A
        bridge that is alive but waits (a slow LLM in sync mode) still has its ``/clock``
        publisher, so the node keeps waiting for it. A bridge killed with SIGKILL leaves
        the graph only when DDS drops its participant (its lease, ~10-20 s)."""
        if self._bridge_gone_exit_s <= 0.0 or not clock_stalled \
                or self.count_publishers(topics.CLOCK) > 0:
            self._bridge_gone_since = None
            return False
        now = time.monotonic()
        if self._bridge_gone_since is None:
            self._bridge_gone_since = now
            self.get_logger().warning(
                f"no publisher on {topics.CLOCK}: the bridge has left the graph; exiting in "
                f"{self._bridge_gone_exit_s:.0f} s unless it comes back")
            return False
        if now - self._bridge_gone_since < self._bridge_gone_exit_s:
            return False
        self.get_logger().warning(
            f"the bridge has been gone for {self._bridge_gone_exit_s:.0f} s (no publisher on "
            f"{topics.CLOCK}): exiting")
        self.exit_code = 0
        rclpy.try_shutdown()
        return True

    # -- names and I/O -------------------------------------------------------------------
    def topic(self, name: str) -> str:
        return topics.topic(name, self.ego_id)

    def json_publisher(
        self, cls: type[M], name: str, qos: QoSProfile = lmpc_qos.PRODUCED, *,
        ego: Optional[str] = None,
    ) -> JsonPublisher[M]:
        """Publisher on ``name`` (of this node's ego, or of ``ego``: the multi-ego bridge)."""
        full = self.topic(name) if ego is None else topics.topic(name, ego)
        return JsonPublisher(self, cls, full, qos, self.stage_times)

    def json_subscription(
        self,
        cls: type[M],
        name: str,
        callback: Callable[[M], None],
        qos: QoSProfile = lmpc_qos.STREAM,
        *,
        check_seq: bool = True,
        ego: Optional[str] = None,
        shared: bool = False,
    ) -> Any:
        """Subscribe to ``name``; ``callback`` only ever sees valid, in-order messages.

        ``ego``: the topic of that ego (the multi-ego bridge), not this node's.
        ``shared``: a topic with one publisher per ego (``/coordination/status``): no
        sequence check across publishers, not in the single-producer check."""
        full = self.topic(name) if ego is None else topics.topic(name, ego)
        check_seq = check_seq and not shared
        gate = SequenceGate(full)
        decode_key = f"decode {full}"

        def on_raw(raw: String) -> None:
            t0 = time.perf_counter()
            try:
                msg = decode(raw.data, cls, topic=full)
                if check_seq:
                    gate.check(getattr(msg, "seq", 0))
            except (DecodeError, StaleMessage) as exc:
                self.count_drop(full, exc.field, exc.reason)
                return
            self.stage_times.add(decode_key, (time.perf_counter() - t0) * 1e3)
            callback(msg)

        sub = self.create_subscription(String, full, on_raw, qos)
        if not shared:
            self._inputs[full] = sub
        return sub

    # -- counters and throttled logs -----------------------------------------------------
    def count_drop(self, topic: str, field: str, reason: str) -> None:
        self.counters["dropped_messages"] += 1
        self.counters[f"dropped:{topic}"] += 1
        self.log_event(
            f"drop:{topic}:{field}",
            f"dropped message on {topic}: field '{field}': {reason} "
            f"(total drops on this topic: {self.counters[f'dropped:{topic}']})",
        )

    def log_event(self, key: str, text: str, *, level: str = "warn") -> None:
        """Log ``text`` at most once per :data:`LOG_THROTTLE_S` for the same ``key``."""
        now = time.monotonic()
        if now - self._last_log.get(key, -1e9) < LOG_THROTTLE_S:
            return
        self._last_log[key] = now
        # One call site per severity: rclpy remembers the severity of each call site and
        # raises ValueError ("Logger severity cannot be changed between calls") when the
        # same line logs at another level later (e.g. an info, then a warn event).
        logger = self.get_logger()
        if level == "info":
            logger.info(text)
        elif level == "error":
            logger.error(text)
        elif level == "debug":
            logger.debug(text)
        else:
            logger.warning(text)

    def check_single_producers(self) -> None:
        """Warn when a topic of the graph (one producer each) has several publishers.

        Two graphs on one ROS_DOMAIN_ID interleave their ego states, controls and decisions;
        the sequence gate then drops or re-syncs, and the run silently drives on someone
        else's data. Counted as ``crosstalk_topics`` and logged (throttled) with the topic."""
        shared = 0
        for topic, sub in self._inputs.items():
            n = sub.get_publisher_count()
            if n > 1:
                shared += 1
                self.log_event(
                    f"crosstalk:{topic}",
                    f"{n} publishers on {topic}, which has one producer per graph: another "
                    f"graph or tool shares ROS_DOMAIN_ID {self.context.get_domain_id()}? "
                    "Give each graph its own domain (run_graph.py --domain-id)")
        self.counters["crosstalk_topics"] = shared

    def publish_diagnostics(self, level: int, message: str, extra: dict[str, object]) -> None:
        self.check_single_producers()
        values = {**{k: v for k, v in self.counters.items()}, **extra}
        status = DiagnosticStatus(
            level=bytes([level]),
            name=self.get_fully_qualified_name(),
            message=message,
            hardware_id="languagempc",
            values=[KeyValue(key=str(k), value=str(v)) for k, v in sorted(values.items())],
        )
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(arr)


def run_node(factory: Callable[[], Node], args: Optional[list[str]] = None) -> int:
    """Jazzy ``main()``: init, spin, shut down cleanly on Ctrl-C / external shutdown.

    Returns the exit code; a node may set ``node.exit_code`` and call
    ``rclpy.try_shutdown()`` to end the spin with that code.
    """
    follow_supervisor()  # before the slow parts: a dead launcher must not leave us behind
    stay_local()
    try:
        executor = executor_from_env()
    except ValueError as exc:
        print(exc, file=sys.stderr, flush=True)
        return 2
    priority = apply_priority_from_env()  # before rclpy.init: DDS threads inherit it
    rclpy.init(args=args if args is not None else sys.argv)
    node: Optional[Node] = None
    code = 0
    try:
        node = factory()
        if priority is not None:
            node.get_logger().info(f"scheduling: {priority}")
        node.get_logger().info(f"executor: {executor}")
        _spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # a signal (the supervisor's SIGINT / SIGTERM) shut the context down while the
        # executor was building its wait set: "the given context is not valid" - a clean
        # shutdown that lost a race inside rclpy, not a failure (seen once in CI)
        if rclpy.ok():
            raise
    finally:
        # A second Ctrl-C (or a supervisor's repeated SIGINT) while the node tears
        # down would raise KeyboardInterrupt inside rclpy's destroy calls and end the
        # process with a traceback; teardown takes well under a second, so ignore it.
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:
            pass  # not the main thread (an embedding program): keep its handlers
        if node is not None:
            code = int(getattr(node, "exit_code", 0))
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def _spin(node: Node, executor: str) -> None:
    """Spin ``node`` until rclpy shuts down, with the executor named (``EXECUTORS``)."""
    if executor == "single":
        rclpy.spin(node)
        return
    from rclpy.experimental import EventsExecutor

    events = EventsExecutor(context=node.context)
    events.add_node(node)
    # spin_once in a loop, not events.spin(): in the rclpy 7.1.6 wheels spin() ran at 100 %
    # CPU without ever firing the node's timers (the bridge never started) and did not
    # end on SIGTERM (2026-12-06); spin_once fires them and sleeps while idle
    while rclpy.ok(context=node.context):
        events.spin_once(timeout_sec=EVENTS_SPIN_TIMEOUT_S)
