#!/usr/bin/env python3
"""Inspect the LanguageMPC graph without the `ros2` command line (`lmpc-topics`).

    lmpc-topics list [--window-s 3]        topics, types and measured rates
    lmpc-topics echo /lmpc/decision [-n 1] payloads decoded and pretty-printed through the schemas
    lmpc-topics hz /lmpc/control           wall and sim-time rates of one topic
    lmpc-topics instruct "drive conservatively" [--ego-id ego_2]
                                           send an instruction to the running planner

JSON payloads on ``std_msgs/String`` topics are decoded with the schema their
``schema`` field names; anything that fails validation is shown with the reason.
On a full ROS 2 install the equivalents are ``ros2 topic list -t``,
``ros2 topic echo``, ``ros2 topic hz`` and ``ros2 topic pub --once`` (see the README).

``instruct`` checks the text as the planner will (a text it would refuse is refused here,
exit 2), waits for the planner's subscription to ``/lmpc/instruction`` (exit 1 when none
matches within ``--discovery-s``), publishes the text once (reliable, volatile: like
``ros2 topic pub --once``) and stays up ``--linger-s`` so the sample is delivered. The
planner acts on it from its next decision and logs "instruction received".
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from typing import Any, Callable, Optional, Sequence

from lmpc_msgs_py.discovery import stay_local

stay_local()

import rclpy  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402

from lmpc_msgs_py import ALL_MESSAGES, DecodeError, decode  # noqa: E402
from lmpc_msgs_py import qos as lmpc_qos  # noqa: E402
from lmpc_msgs_py import topics as lmpc_topics  # noqa: E402

SCHEMAS = {cls.SCHEMA: cls for cls in ALL_MESSAGES}


def message_class(type_name: str) -> type:
    """``std_msgs/msg/String`` -> the Python message class."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def decode_payload(msg: Any) -> tuple[Optional[dict[str, Any]], Optional[str]]:
    """Decode a ``std_msgs/String`` JSON payload through its schema: (data, error)."""
    text = getattr(msg, "data", None)
    if not isinstance(text, str):
        return None, None
    try:
        raw = json.loads(text)
    except ValueError:
        return None, None
    if not isinstance(raw, dict) or raw.get("schema") not in SCHEMAS:
        return None, None
    try:
        obj = decode(text, SCHEMAS[raw["schema"]])
    except DecodeError as exc:
        return raw, str(exc)
    return obj.model_dump(by_alias=True), None


def sim_stamp(msg: Any) -> Optional[float]:
    data, _ = decode_payload(msg)
    if data and "stamp_s" in data:
        return float(data["stamp_s"])
    clock = getattr(msg, "clock", None)
    if clock is not None:
        return clock.sec + clock.nanosec * 1e-9
    header = getattr(msg, "header", None)
    if header is not None:
        return header.stamp.sec + header.stamp.nanosec * 1e-9
    return None


def wait_for_topics(node: Node, timeout_s: float,
                    settle_s: float = 2.0) -> list[tuple[str, list[str]]]:
    """Topics once discovery has settled: the set unchanged for ``settle_s`` (at most
    ``timeout_s`` in all). A busy machine announces a participant's endpoints late:
    raise ``settle_s`` there."""
    deadline = time.monotonic() + timeout_s
    found: list[tuple[str, list[str]]] = []
    stable_since = time.monotonic()
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        now = node.get_topic_names_and_types()
        if now != found:
            found, stable_since = now, time.monotonic()
        elif found and time.monotonic() - stable_since > settle_s:
            break
    return found


class RateMeter:
    def __init__(self) -> None:
        self.wall: list[float] = []
        self.sim: list[float] = []

    def __call__(self, msg: Any) -> None:
        self.wall.append(time.monotonic())
        stamp = sim_stamp(msg)
        if stamp is not None:
            self.sim.append(stamp)

    @staticmethod
    def _rate(times: list[float]) -> Optional[float]:
        if len(times) < 2 or times[-1] <= times[0]:
            return None
        return (len(times) - 1) / (times[-1] - times[0])

    def rates(self) -> tuple[Optional[float], Optional[float]]:
        return self._rate(self.wall), self._rate(sorted(set(self.sim)))


def _qos_for(node: Node, topic: str) -> Any:
    """Latched for the map and episode topics (when every publisher keeps its last sample,
    else the subscription would match none); volatile for the streams, whose publishers
    also keep samples (``lmpc_qos.PRODUCED``) but whose history would distort a rate."""
    infos = node.get_publishers_info_by_topic(topic)
    if (infos and topic.rsplit("/", 1)[-1] in lmpc_topics.LATCHED
            and all(i.qos_profile.durability.name == "TRANSIENT_LOCAL" for i in infos)):
        return lmpc_qos.LATCHED
    if infos and all(i.qos_profile.reliability.name == "BEST_EFFORT" for i in infos):
        return qos_profile_sensor_data
    return lmpc_qos.STREAM


def spin_for(node: Node, seconds: float, stop: Callable[[], bool] = lambda: False) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not stop():
        rclpy.spin_once(node, timeout_sec=0.05)


def cmd_list(node: Node, args: argparse.Namespace) -> int:
    found = wait_for_topics(node, args.discovery_s, args.settle_s)
    meters: dict[str, RateMeter] = {}
    for name, types in found:
        meter = RateMeter()
        node.create_subscription(message_class(types[0]), name, meter, _qos_for(node, name))
        meters[name] = meter
    spin_for(node, args.window_s)
    print(f"{'topic':<28} {'type':<36} {'pubs':>4} {'wall Hz':>8} {'sim Hz':>7}")
    for name, types in sorted(found):
        wall, sim = meters[name].rates()
        pubs = node.count_publishers(name)
        wall_txt = "-" if wall is None else f"{wall:.1f}"
        sim_txt = "-" if sim is None else f"{sim:.2f}"
        print(f"{name:<28} {types[0]:<36} {pubs:>4} {wall_txt:>8} {sim_txt:>7}")
    return 0


def _topic_type(node: Node, topic: str, discovery_s: float) -> Optional[str]:
    deadline = time.monotonic() + discovery_s
    while time.monotonic() < deadline:
        for name, types in node.get_topic_names_and_types():
            if name == topic:
                return types[0]
        rclpy.spin_once(node, timeout_sec=0.1)
    return None


def cmd_echo(node: Node, args: argparse.Namespace) -> int:
    type_name = _topic_type(node, args.topic, args.discovery_s)
    if type_name is None:
        print(f"topic {args.topic} not found", file=sys.stderr)
        return 1
    count = [0]

    def show(msg: Any) -> None:
        data, error = decode_payload(msg)
        if error:
            print(f"# INVALID: {error}")
        if data is not None:
            print(json.dumps(data, indent=2))
        else:
            print(msg)
        print("---", flush=True)
        count[0] += 1

    node.create_subscription(message_class(type_name), args.topic, show,
                             _qos_for(node, args.topic))
    spin_for(node, args.timeout_s, stop=lambda: bool(args.count) and count[0] >= args.count)
    return 0 if count[0] else 1


def cmd_hz(node: Node, args: argparse.Namespace) -> int:
    type_name = _topic_type(node, args.topic, args.discovery_s)
    if type_name is None:
        print(f"topic {args.topic} not found", file=sys.stderr)
        return 1
    meter = RateMeter()
    node.create_subscription(message_class(type_name), args.topic, meter,
                             _qos_for(node, args.topic))
    spin_for(node, args.window_s)
    wall, sim = meter.rates()
    print(json.dumps({"topic": args.topic, "type": type_name, "messages": len(meter.wall),
                      "wall_hz": wall, "sim_hz": sim}))
    return 0


def cmd_instruct(node: Node, args: argparse.Namespace) -> int:
    from std_msgs.msg import String

    from lmpc_llm_planner.prompt import instruction_error

    refused = instruction_error(args.text)
    if refused:
        print(f"instruction refused: {refused}", file=sys.stderr)
        return 2
    topic = lmpc_topics.topic(lmpc_topics.INSTRUCTION, args.ego_id or None)
    pub = node.create_publisher(String, topic, lmpc_qos.STREAM)
    spin_for(node, args.discovery_s, stop=lambda: pub.get_subscription_count() > 0)
    readers = pub.get_subscription_count()
    if readers == 0:
        print(f"no planner subscribes to {topic} (waited {args.discovery_s:g} s): is the "
              f"graph running with this ROS_DOMAIN_ID"
              f"{'' if args.ego_id else ' (several egos: --ego-id)'}?", file=sys.stderr)
        return 1
    msg = String()
    msg.data = args.text
    pub.publish(msg)
    spin_for(node, args.linger_s)
    print(f"sent to {readers} subscriber(s) of {topic} ({len(args.text)} characters)")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--discovery-s", type=float, default=3.0, help="wait for discovery")
    ap.add_argument("--settle-s", type=float, default=2.0,
                    help="list: discovery has settled once the topic set is unchanged this long")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p_list = sub.add_parser("list", help="topics with types and measured rates")
    p_list.add_argument("--window-s", type=float, default=3.0)
    p_echo = sub.add_parser("echo", help="print a topic, JSON decoded through the schemas")
    p_echo.add_argument("topic")
    p_echo.add_argument("-n", "--count", type=int, default=0, help="stop after N messages")
    p_echo.add_argument("--timeout-s", type=float, default=3600.0)
    p_hz = sub.add_parser("hz", help="wall and sim-time rate of a topic")
    p_hz.add_argument("topic")
    p_hz.add_argument("--window-s", type=float, default=5.0)
    p_in = sub.add_parser("instruct", help="send an instruction (untrusted text) to the planner")
    p_in.add_argument("text")
    p_in.add_argument("--ego-id", default="", help="the ego's planner in a multi-ego graph")
    p_in.add_argument("--linger-s", type=float, default=1.0,
                      help="stay up this long after publishing (delivery)")
    args = ap.parse_args(argv)
    rclpy.init()
    node = rclpy.create_node("lmpc_topics")
    try:
        return {"list": cmd_list, "echo": cmd_echo, "hz": cmd_hz,
                "instruct": cmd_instruct}[args.cmd](node, args)
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
