"""The graph's topics as a separate ROS node sees them: names, types, payloads, rates."""
from __future__ import annotations

import json
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
    "/lmpc/mpc/candidates": "visualization_msgs/msg/MarkerArray",
    "/lmpc/mpc/agent_predictions": "visualization_msgs/msg/MarkerArray",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def test_topics_types_payloads_and_rates(tmp_path: Path, domain_id: int) -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_msgs.msg import String

    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from lmpc_msgs_py import Control, Decision, DecodeError, decode

    # Deep enough that nothing is lost while this process is busy (the graph runs faster
    # than real time in sync mode).
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                          reliability=ReliabilityPolicy.RELIABLE)

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

    node.create_subscription(String, "/lmpc/decision", collect("decision", Decision), keep_all)
    node.create_subscription(String, "/lmpc/control", collect("control", Control), keep_all)
    from nav_msgs.msg import Odometry

    odom: list[Odometry] = []
    # the bridge builds the odometry mirror only while someone subscribes (as the MPC's
    # RViz mirrors): this subscriber gets it
    node.create_subscription(Odometry, "/lmpc/ego/odom", odom.append, keep_all)
    seen: dict[str, list[str]] = {}
    lister: subprocess.Popen[str] | None = None
    instructor: subprocess.Popen[str] | None = None
    # The observer joins the domain first, so it sees every endpoint from the start.
    # Realtime clock: the graph lives long enough (~20 s) to be inspected while it runs.
    graph = subprocess.Popen(
        [sys.executable, str(RUN_GRAPH), "--scenario", "usi", "--seed", "0", "--planner", "rules",
         "--clock", "realtime", "--quiet", "--run-dir", str(tmp_path / "run"),
         "--domain-id", str(domain_id)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while graph.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            for name, types in node.get_topic_names_and_types():
                seen[name] = types
            if lister is None and len(received["control"]) > 20:
                # The inspection tool, run as a user would, while the graph is live.
                lister = subprocess.Popen(
                    [sys.executable, str(TOPICS), "--discovery-s", "12", "--settle-s", "5", "list",
                     "--window-s", "2"],
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            if instructor is None and len(received["decision"]) >= 2:
                # an instruction in the middle of the episode, sent as a user would
                instructor = subprocess.Popen(
                    [sys.executable, str(TOPICS), "--discovery-s", "12", "instruct",
                     "drive conservatively"],
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        out = graph.communicate(timeout=60)[0]
        listing = lister.communicate(timeout=60)[0] if lister is not None else ""
        sent = instructor.communicate(timeout=60)[0] if instructor is not None else ""
    finally:
        for proc in (graph, lister, instructor):
            if proc is not None and proc.poll() is None:
                proc.kill()
        node.destroy_node()
        rclpy.try_shutdown()

    assert graph.returncode == 0, out[-3000:]
    for name, type_name in EXPECTED_TYPES.items():
        assert seen.get(name) == [type_name], f"{name}: {seen.get(name)}"
        assert name in listing, f"lmpc-topics list misses {name}:\n{listing}"
    assert not invalid, invalid[:3]

    controls = received["control"]
    decisions = received["decision"]
    assert len(odom) > 50 and odom[-1].header.frame_id == "map", len(odom)
    span_s = controls[-1].stamp_s - controls[0].stamp_s
    assert span_s > 5.0
    control_hz = (len({c.stamp_s for c in controls}) - 1) / span_s
    assert 9.0 <= control_hz <= 11.0, control_hz
    # A decision at least every 2.5 s of sim time (~0.4 Hz), more often only on an
    # emergency. (The first decisions may come before this observer matched the planner.)
    stamps = sorted(d.stamp_s for d in decisions)
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    assert len(stamps) >= 3 and max(gaps) <= 2.5 + 1e-6, gaps
    decision_hz = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert 0.38 <= decision_hz <= 2.0, decision_hz
    assert all(d.source == "rules" for d in decisions)
    # the instruction: delivered, logged, and in force from a decision after it on
    assert instructor is not None and instructor.returncode == 0, sent
    assert "sent to 1 subscriber(s) of /lmpc/instruction" in sent, sent
    run_dir = tmp_path / "run"
    assert "instruction received (20 characters)" in (run_dir / "planner.log").read_text()
    logged = [json.loads(line) for line in
              (run_dir / "decisions.jsonl").read_text().splitlines()]
    told = [d["instruction"] for d in logged]
    assert told[0] is None and told[-1] == "drive conservatively", told
    k = told.index("drive conservatively")
    assert all(t is None for t in told[:k]), told
    assert all(t == "drive conservatively" for t in told[k:]), told
