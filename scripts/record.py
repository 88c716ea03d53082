#!/usr/bin/env python3
"""Record the graph's topics to a rosbag2 file (MCAP storage) with the `rosbags` library.

Subscribes to every topic under ``/lmpc`` (and ``/clock``, ``/diagnostics``) as soon as
it has publishers; takes the serialized CDR bytes as they come (``raw=True``),
so the bag holds exactly what went over DDS. ``ros2 bag info/play`` and Foxglove
read the result.

Nothing of step 0 is lost to discovery: with ``--expect TOPIC,...`` (run_graph.py
names the producers' topics: the MPC's control, the planner's decision and status)
the recorder subscribes to the ego state only once each of those topics has a
publisher matched with its subscription. A sync-clock bridge counts the recorder
among the ego-state subscribers it waits for before step 0 (``extra_subscribers``),
so step 0 starts only when the recorder hears every producer. Endpoint matching is
per pair of participants: the bridge seeing the MPC says nothing about the recorder
seeing it. Nor is it symmetric: the recorder's subscription can count the planner's
publisher as matched a moment before that publisher has matched the subscription, and a
volatile publisher sends a sample only to the readers it knows (a CI run lost step 0's
decision so, another the MPC's first predicted path). So a topic is subscribed only once
its publishers are known, with their durability as rosbag2 does: transient-local when
every publisher offers it (the project's publishers do, ``lmpc_qos.PRODUCED``), and then a
publisher's late match still delivers its last samples; volatile otherwise (a user's
volatile publisher is recorded too, without that guarantee; /clock is volatile, as
rclpy's time source subscribes it).

    record.py --out runs/usi-0/bag          (stop with Ctrl-C / SIGINT: the bag is closed cleanly)
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Optional, Sequence

from lmpc_msgs_py.discovery import stay_local

stay_local()

import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from lmpc_msgs_py import qos as lmpc_qos  # noqa: E402
from lmpc_msgs_py import topics  # noqa: E402
from lmpc_msgs_py.supervision import follow_supervisor  # noqa: E402

STRING = "std_msgs/msg/String"
KNOWN_TOPICS: dict[str, str] = {
    topics.CLOCK: "rosgraph_msgs/msg/Clock",
    topics.DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
    **{topics.topic(name): STRING for name in (
        topics.MAP, topics.EGO_STATE, topics.AGENTS, topics.SIGNALS, topics.EPISODE,
        topics.DECISION, topics.CONTROL, topics.INSTRUCTION, topics.PLANNER_STATUS)},
    topics.topic(topics.EGO_ODOM): "nav_msgs/msg/Odometry",
    topics.topic(topics.REFERENCE_PATH): "nav_msgs/msg/Path",
    topics.topic(topics.PREDICTED_PATH): "nav_msgs/msg/Path",
    topics.topic(topics.CANDIDATE_MARKERS): "visualization_msgs/msg/MarkerArray",
    topics.topic(topics.AGENT_PREDICTION_MARKERS): "visualization_msgs/msg/MarkerArray",
}
LATCHED_TOPICS = {topics.topic(name) for name in topics.LATCHED}
# Reliable and deep: a recorder busy writing must not lose samples to a short history.
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                        reliability=ReliabilityPolicy.RELIABLE)
# The same, asking for the publishers' kept samples (only when every publisher offers them:
# a transient-local subscription does not match a volatile publisher).
RECORD_DURABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)


def message_class(type_name: str) -> type:
    import importlib

    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


DISCOVER_PERIOD_S = 0.02
"""How often the recorder looks for new topics and publishers."""

EXPECT_TIMEOUT_S = 60.0
"""Wall seconds to wait for the expected producers before subscribing to the ego state
anyway (a producer that never comes: the bridge then reports who is missing)."""


class Recorder(Node):
    def __init__(self, out: Path, expect: Sequence[str] = ()) -> None:
        super().__init__("lmpc_recorder")
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        # metadata version 9: what rosbag2 of Jazzy writes (and reads)
        self.writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.subscriptions_by_topic: dict[str, Any] = {}
        self.ego_topic = topics.topic(topics.EGO_STATE)
        self.expect = list(expect)
        self.waiting_for_producers = bool(self.expect)
        self.expect_deadline = time.monotonic() + EXPECT_TIMEOUT_S
        # Fast while the graph comes up, so a topic is subscribed well before step 0.
        self.create_timer(DISCOVER_PERIOD_S, self._tick)
        self.get_logger().info(f"recording to {out}")

    def _tick(self) -> None:
        self._discover()
        if self.waiting_for_producers:
            self._check_expected()

    def _check_expected(self) -> None:
        missing = [t for t in self.expect if t not in self.subscriptions_by_topic
                   or self.subscriptions_by_topic[t].get_publisher_count() < 1]
        timed_out = time.monotonic() > self.expect_deadline
        if missing and not timed_out:
            return
        if missing:
            self.get_logger().warning(
                f"no publisher matched on {', '.join(missing)} after {EXPECT_TIMEOUT_S:.0f} s: "
                f"subscribing to {self.ego_topic} anyway")
        for name in missing:
            self._subscribe(name, KNOWN_TOPICS[name], durable=False)
        self.waiting_for_producers = False
        self._subscribe(self.ego_topic, KNOWN_TOPICS[self.ego_topic], durable=self._durable(
            self.get_publishers_info_by_topic(self.ego_topic)))
        self.get_logger().info(f"producers matched: subscribed to {self.ego_topic}")

    @staticmethod
    def _durable(offered: Sequence[Any]) -> bool:
        """Ask for kept samples only if every publisher offers them (rosbag2's rule)."""
        return bool(offered) and all(
            info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for info in offered)

    def _subscribe(self, name: str, type_name: str, durable: bool) -> None:
        if name in self.connections or type_name not in self.typestore.types:
            return
        qos = (lmpc_qos.LATCHED if name in LATCHED_TOPICS
               else RECORD_DURABLE_QOS if durable else RECORD_QOS)
        self.connections[name] = self.writer.add_connection(
            name, type_name, typestore=self.typestore)
        self.counts[name] = 0

        def on_raw(data: bytes, topic: str = name) -> None:
            self.writer.write(self.connections[topic], time.time_ns(), data)
            self.counts[topic] += 1

        self.subscriptions_by_topic[name] = self.create_subscription(
            message_class(type_name), name, on_raw, qos, raw=True)
        self.get_logger().info(f"{name}: subscribed" + (
            " (publishers keep their samples, asking for them)" if durable else ""))

    def _discover(self) -> None:
        """Subscribe every graph topic (the known ones and any under /lmpc) that has
        publishers, with their durability; the ego state only once the producers matched
        (the bridge's start signal)."""
        for name, types in self.get_topic_names_and_types():
            if name in self.connections or not types:
                continue
            if name == self.ego_topic and self.waiting_for_producers:
                continue
            if name not in KNOWN_TOPICS and not name.startswith(topics.ROOT):
                continue
            offered = self.get_publishers_info_by_topic(name)
            if offered:  # a topic only subscribed to has no QoS to go by yet
                self._subscribe(name, KNOWN_TOPICS.get(name, types[0]), self._durable(offered))

    def close(self) -> None:
        self.writer.close()
        total = sum(self.counts.values())
        self.get_logger().info(f"bag closed: {total} messages on {len(self.counts)} topics")


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="bag folder (must not exist)")
    ap.add_argument("--expect", default="",
                    help="comma-separated topics whose publishers must be matched before the "
                         "recorder subscribes to the ego state (the bridge's start signal)")
    args, ros_args = ap.parse_known_args(argv)
    expect = [t for t in args.expect.split(",") if t]
    unknown = sorted(set(expect) - set(KNOWN_TOPICS))
    if unknown:
        ap.error(f"--expect: not a recorded topic: {', '.join(unknown)}")
    follow_supervisor()  # started by run_graph.py: never outlive it
    rclpy.init(args=ros_args)
    node: Optional[Recorder] = None
    try:
        node = Recorder(args.out, expect)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
