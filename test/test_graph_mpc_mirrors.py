"""The MPC's visual mirrors as a stock ROS tool sees them: nav_msgs/Path for the reference
and the predicted horizon, visualization_msgs/MarkerArray for the ego's three reference
candidates and the agents' predictions (usi seed 0, rules planner, sync clock)."""
from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from graphkit import RUN_GRAPH

pytestmark = pytest.mark.graph

PATHS = ("/lmpc/mpc/reference", "/lmpc/mpc/predicted")
MARKERS = ("/lmpc/mpc/candidates", "/lmpc/mpc/agent_predictions")


def _stamp_s(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def test_mpc_paths_and_markers(tmp_path: Path, domain_id: int) -> None:
    rclpy = pytest.importorskip("rclpy")
    from nav_msgs.msg import Odometry, Path as PathMsg
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from visualization_msgs.msg import Marker, MarkerArray

    keep_all = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                          reliability=ReliabilityPolicy.RELIABLE)
    rclpy.init()
    node = rclpy.create_node("mirror_test_observer")
    got: dict[str, list[Any]] = {name: [] for name in PATHS + MARKERS}
    egos: list[Any] = []
    for name in PATHS:
        node.create_subscription(PathMsg, name, got[name].append, keep_all)
    for name in MARKERS:
        node.create_subscription(MarkerArray, name, got[name].append, keep_all)
    # the ego from its Odometry mirror: a subscriber of /lmpc/ego_state would count as
    # one of the participants the bridge waits for before step 0
    node.create_subscription(Odometry, "/lmpc/ego/odom", egos.append, keep_all)
    seen: dict[str, list[str]] = {}
    # the observer joins first (LOCALHOST discovery: docs/ARCHITECTURE.md)
    graph = subprocess.Popen(
        [sys.executable, str(RUN_GRAPH), "--scenario", "usi", "--seed", "0", "--planner", "rules",
         "--clock", "sync", "--quiet", "--run-dir", str(tmp_path / "run"),
         "--domain-id", str(domain_id)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while graph.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            for name, types in node.get_topic_names_and_types():
                seen[name] = types
        for _ in range(40):  # drain what is still queued
            rclpy.spin_once(node, timeout_sec=0.02)
        out = graph.communicate(timeout=60)[0]
    finally:
        if graph.poll() is None:
            graph.kill()
        node.destroy_node()
        rclpy.try_shutdown()

    assert graph.returncode == 0, out[-3000:]
    for name in PATHS:
        assert seen.get(name) == ["nav_msgs/msg/Path"], (name, seen.get(name))
    for name in MARKERS:
        assert seen.get(name) == ["visualization_msgs/msg/MarkerArray"], (name, seen.get(name))
    assert egos
    ego_at = sorted((_stamp_s(e.header), e.pose.pose.position.x, e.pose.pose.position.y)
                    for e in egos)

    def near_ego(t_s: float, x: float, y: float, within_m: float) -> bool:
        # the ego within 0.3 s of the stamp (DDS does not order the topics)
        return any(abs(t - t_s) <= 0.3 + 1e-6 and math.hypot(x - ex, y - ey) <= within_m
                   for t, ex, ey in ego_at)

    for name in PATHS:
        msgs = got[name]
        assert len(msgs) > 20, (name, len(msgs))
        assert all(m.header.frame_id == "map" for m in msgs)
        full = [m for m in msgs if m.poses]
        assert len(full) > 0.8 * len(msgs)
        for m in full[::10]:
            p = m.poses[0].pose.position
            assert math.isfinite(p.x) and math.isfinite(p.y)
            assert near_ego(_stamp_s(m.header), p.x, p.y, 3.0), (name, p.x, p.y)

    cand = got["/lmpc/mpc/candidates"]
    assert len(cand) > 20
    counts = []
    for arr in cand:
        assert arr.markers and arr.markers[0].action == Marker.DELETEALL
        lines = arr.markers[1:]
        assert all(m.header.frame_id == "map" and m.type == Marker.LINE_STRIP for m in lines)
        counts.append(len(lines))
        if not lines:
            continue
        assert 1 <= len(lines) <= 3
        # exactly one highlighted (the widest) candidate
        widths = sorted(m.scale.x for m in lines)
        assert widths[-1] > 0.0 and (len(widths) == 1 or widths[-2] < widths[-1])
        t_s = _stamp_s(lines[0].header)
        for m in lines:
            pts = [(q.x, q.y) for q in m.points]
            assert len(pts) >= 2 and all(math.isfinite(a) and math.isfinite(b) for a, b in pts)
            # a candidate starts at the ego and stays within the lookahead
            assert near_ego(t_s, *pts[0], 1.0), pts[0]
            assert all(near_ego(t_s, a, b, 70.0) for a, b in pts[::10])
    # up to three candidates; on usi seed 0 the ego's approach lane has two connections
    # (straight and left), and in the junction its internal lane gives one
    assert max(counts) >= 2 and min(c for c in counts if c) >= 1, counts

    preds = got["/lmpc/mpc/agent_predictions"]
    assert len(preds) > 20
    spaces = set()
    for arr in preds:
        assert arr.markers[0].action == Marker.DELETEALL
        for m in arr.markers[1:]:
            assert m.header.frame_id == "map" and m.ns in ("attended", "unattended")
            spaces.add(m.ns)
            assert len(m.points) >= 2
            assert all(math.isfinite(q.x) and math.isfinite(q.y) for q in m.points)
    assert "attended" in spaces  # the baseline attends every agent in sensing range
