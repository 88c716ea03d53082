"""The graph's topics as a separate ROS node sees them: names, types, payloads, rates."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from graphkit import RUN_GRAPH, TOPICS

pytestmark = pytest.mark.graph

EXPECTED_TYPES = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/lmpc/map": "std_msgs/msg/String",
    "/lmpc/ego_state": "std_msgs/msg/String",
    "/lmpc/agents": "std_msgs/msg/String",
    "/lmpc/signals": "std_msgs/msg/String",
    "/lmpc/episode": "std_msgs/msg/String",
    "/lmpc/decision": "std_msgs/msg/String",
    "/lmpc/control": "std_msgs/msg/String",
    "/lmpc/planner/status": "std_msgs/msg/String",
    "/lmpc/ego/odom": "nav_msgs/msg/Odometry",
    "/lmpc/mpc/reference": "nav_msgs/msg/Path",
    "/lmpc/mpc/predicted": "nav_msgs/msg/Path",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def test_topics_types_payloads_and_rates(tmp_path: Path, domain_id: int) -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_msgs.msg import String

    from lmpc_msgs_py import Control, Decision, DecodeError, decode
    from lmpc_msgs_py import qos as lmpc_qos

    # A long-enough episode: the planner decides every 2.5 s of sim time.
    graph = subprocess.Popen(
        [sys.executable, str(RUN_GRAPH), "--scenario", "usi", "--seed", "0", "--planner", "rules",
         "--clock", "sync", "--quiet", "--run-dir", str(tmp_path / "run"),
         "--domain-id", str(domain_id)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    rclpy.init()
    node = rclpy.create_node("graph_test_observer")
    received: dict[str, list[Any]] = {"decision": [], "control": []}
    invalid: list[str] = []

    def collect(kind: str, cls: type) -> Any:
        def on_msg(msg: String) -> None:
            try:
                received[kind].append(decode(msg.data, cls, topic=f"/lmpc/{kind}"))
            except DecodeError as exc:
                invalid.append(str(exc))
        return on_msg

    node.create_subscription(String, "/lmpc/decision", collect("decision", Decision),
                             lmpc_qos.STREAM)
    node.create_subscription(String, "/lmpc/control", collect("control", Control),
                             lmpc_qos.STREAM)
    seen: dict[str, list[str]] = {}
    listing = ""
    try:
        deadline = time.monotonic() + 120
        while graph.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            for name, types in node.get_topic_names_and_types():
                seen[name] = types
            if not listing and len(received["control"]) > 20:
                # The inspection tool, run as a user would, while the graph is live.
                listing = subprocess.run(
                    [sys.executable, str(TOPICS), "list", "--window-s", "1"],
                    capture_output=True, text=True, timeout=60,
                ).stdout
        out = graph.communicate(timeout=60)[0]
    finally:
        if graph.poll() is None:
            graph.kill()
        node.destroy_node()
        rclpy.try_shutdown()

    assert graph.returncode == 0, out[-3000:]
    for name, type_name in EXPECTED_TYPES.items():
        assert seen.get(name) == [type_name], f"{name}: {seen.get(name)}"
        assert name in listing, f"lmpc-topics list misses {name}:\n{listing}"
    assert not invalid, invalid[:3]

    controls = received["control"]
    decisions = received["decision"]
    span_s = controls[-1].stamp_s - controls[0].stamp_s
    assert span_s > 5.0
    control_hz = (len({c.stamp_s for c in controls}) - 1) / span_s
    assert 9.0 <= control_hz <= 11.0, control_hz
    normal = [d for d in decisions if d.mode == "normal"]
    decision_hz = (len(normal) - 1) / (normal[-1].stamp_s - normal[0].stamp_s)
    assert 0.3 <= decision_hz <= 0.5, decision_hz  # one every 2.5 s of sim time
    assert all(d.source == "rules" for d in decisions)
