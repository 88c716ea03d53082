#!/usr/bin/env python3
"""A corrupting relay for fault tests: subscribes topic A, republishes to topic B, faulty.

Put it between two nodes by remapping the consumer's input (``--ros-args -r
/lmpc/control:=/lmpc/control_relayed``) and running::

    fault_relay.py --link /lmpc/control:/lmpc/control_relayed \\
        --plan "0:pass,4:nan,6:corrupt,8:drop,10:duplicate,12:reorder,14:delay=0.6,16:pass"

``--plan`` is a list of ``<wall seconds since the first message>:<mode>``; modes:

- ``pass``: forward unchanged;
- ``drop``: forward nothing;
- ``delay=S``: forward each message ``S`` wall seconds late (order kept);
- ``duplicate``: forward each message twice;
- ``reorder``: swap each pair of messages (hold one, send the next, then the held one);
- ``corrupt``: forward the first half of the JSON text (truncated, not JSON);
- ``nan``: forward the message with its first float field (other than ``stamp_s``) set
  to NaN (JSON text ``NaN``, which Python's json writes and strict parsers refuse);
- ``empty``: forward an empty string.

Several ``--link`` options relay several topics in one process (one DDS participant):
with one ``--plan`` they share it; with as many ``--plan`` options as links, link *i*
follows plan *i* (e.g. break one link after the other). The relay counts what it did
per input topic and mode and prints the counts (``relay counts: {...}``) every
``--report-period-s`` and when it stops (SIGINT/SIGTERM).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

from lmpc_msgs_py.discovery import stay_local

stay_local()

import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from rclpy._rclpy_pybind11 import RCLError  # noqa: E402
from rclpy.node import Node  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from lmpc_msgs_py import qos as lmpc_qos  # noqa: E402

MODES = ("pass", "drop", "delay", "duplicate", "reorder", "corrupt", "nan", "empty")


class PlanError(ValueError):
    """The ``--plan`` or ``--link`` text is malformed."""


@dataclass(frozen=True)
class Phase:
    from_s: float
    mode: str
    delay_s: float = 0.0


def parse_plan(text: str) -> list[Phase]:
    """``"0:pass,4:delay=0.5"`` -> phases sorted by start time."""
    phases = []
    for item in filter(None, (p.strip() for p in text.split(","))):
        try:
            start, mode = item.split(":", 1)
            arg = ""
            if "=" in mode:
                mode, arg = mode.split("=", 1)
            phase = Phase(float(start), mode.strip(), float(arg) if arg else 0.0)
        except ValueError:
            raise PlanError(f"plan item {item!r}: expected <seconds>:<mode>[=<arg>]") from None
        if phase.mode not in MODES:
            raise PlanError(f"plan item {item!r}: unknown mode {phase.mode!r} "
                            f"(one of {', '.join(MODES)})")
        if phase.mode == "delay" and phase.delay_s <= 0.0:
            raise PlanError(f"plan item {item!r}: delay needs a positive =<seconds>")
        phases.append(phase)
    if not phases:
        raise PlanError("empty plan")
    return sorted(phases, key=lambda p: p.from_s)


def inject_nan(text: str) -> str:
    """``text`` with its first float field (not ``stamp_s``) set to NaN; the text
    unchanged if it is not a JSON object with such a field."""
    try:
        obj = json.loads(text)
    except ValueError:
        return text
    if not isinstance(obj, dict):
        return text
    for key, value in obj.items():
        if isinstance(value, float) and key != "stamp_s":
            obj[key] = math.nan
            return json.dumps(obj, separators=(",", ":"))
    if "stamp_s" in obj:
        obj["stamp_s"] = math.nan
    return json.dumps(obj, separators=(",", ":"))


class FaultRelay(Node):
    """Relays each ``in -> out`` link through the current phase of the plan."""

    def __init__(self, links: list[tuple[str, str]], plans: list[list[Phase]],
                 report_period_s: float) -> None:
        super().__init__("lmpc_fault_relay")
        if len(plans) not in (1, len(links)):
            raise PlanError(f"{len(plans)} plans for {len(links)} links: give one plan, "
                            "or one per link")
        self.plans = {src: plans[i if len(plans) > 1 else 0]
                      for i, (src, _) in enumerate(links)}
        self.t0: Optional[float] = None
        self.counts: dict[str, dict[str, int]] = {src: {} for src, _ in links}
        """Per input topic: messages handled in each mode."""
        self._delayed: list[tuple[float, Any, str]] = []  # (due wall time, publisher, text)
        self._held: dict[str, Optional[str]] = {}
        self._pubs = {}
        for src, dst in links:
            # as the nodes publish: the MPC reads decisions transient local (DECISION_IN)
            pub = self.create_publisher(String, dst, lmpc_qos.PRODUCED)
            self._pubs[src] = pub
            self._held[src] = None
            self.create_subscription(
                String, src, lambda msg, s=src: self._on_msg(s, msg.data), lmpc_qos.STREAM)
        self.create_timer(0.005, self._flush)
        self.create_timer(report_period_s, self.report)
        self.get_logger().info(
            "relaying " + ", ".join(f"{s} -> {d}" for s, d in links)
            + " with plans " + "; ".join(
                src + " " + ",".join(f"{p.from_s:g}:{p.mode}" for p in plan)
                for src, plan in self.plans.items()))

    def phase(self, src: str) -> Phase:
        """The phase of ``src``'s plan now (the clock starts at the first message)."""
        now = time.monotonic()
        if self.t0 is None:
            self.t0 = now
        elapsed = now - self.t0
        plan = self.plans[src]
        current = plan[0]
        for p in plan:
            if p.from_s <= elapsed:
                current = p
        return current

    def _on_msg(self, src: str, text: str) -> None:
        p = self.phase(src)
        pub = self._pubs[src]
        counts = self.counts[src]
        counts[p.mode] = counts.get(p.mode, 0) + 1
        if p.mode != "reorder" and self._held[src] is not None:
            pub.publish(String(data=self._held[src]))  # a held message is never lost
            self._held[src] = None
        if p.mode == "pass":
            pub.publish(String(data=text))
        elif p.mode == "drop":
            return
        elif p.mode == "delay":
            self._delayed.append((time.monotonic() + p.delay_s, pub, text))
        elif p.mode == "duplicate":
            pub.publish(String(data=text))
            pub.publish(String(data=text))
        elif p.mode == "reorder":
            held = self._held[src]
            if held is None:
                self._held[src] = text
            else:
                pub.publish(String(data=text))
                pub.publish(String(data=held))
                self._held[src] = None
        elif p.mode == "corrupt":
            pub.publish(String(data=text[: max(1, len(text) // 2)]))
        elif p.mode == "nan":
            pub.publish(String(data=inject_nan(text)))
        elif p.mode == "empty":
            pub.publish(String(data=""))

    def _flush(self) -> None:
        now = time.monotonic()
        due = [d for d in self._delayed if d[0] <= now]
        if due:
            self._delayed = [d for d in self._delayed if d[0] > now]
            for _, pub, text in due:
                pub.publish(String(data=text))

    def report(self) -> None:
        print(f"relay counts: {json.dumps(self.counts, sort_keys=True)}", flush=True)


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--link", action="append", required=True, metavar="IN:OUT",
                    help="relay topic IN to topic OUT (repeatable)")
    ap.add_argument("--plan", action="append",
                    help="phases, see above (default 0:pass); one, or one per --link")
    ap.add_argument("--report-period-s", type=float, default=2.0)
    ap.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: env)")
    return ap.parse_args(argv)


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    try:
        plans = [parse_plan(text) for text in (args.plan or ["0:pass"])]
        links = []
        for link in args.link:
            src, sep, dst = link.partition(":")
            if not sep or not src.startswith("/") or not dst.startswith("/") or src == dst:
                raise PlanError(f"--link {link!r}: expected /in/topic:/out/topic")
            links.append((src, dst))
    except PlanError as exc:
        print(f"fault_relay: {exc}", file=sys.stderr)
        return 2
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    if len(plans) not in (1, len(links)):
        print(f"fault_relay: {len(plans)} plans for {len(links)} links", file=sys.stderr)
        return 2
    rclpy.init()
    relay = FaultRelay(links, plans, args.report_period_s)
    try:
        rclpy.spin(relay)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # the test's SIGTERM shut the context down while the executor built its wait set
        # ("the given context is not valid"): a clean shutdown, as in base_node.run_node
        if rclpy.ok():
            raise
    finally:
        relay.report()
        relay.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
