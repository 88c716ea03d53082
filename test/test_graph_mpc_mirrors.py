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

from graphkit import RUN_GRAPH, read_episode

pytestmark = pytest.mark.graph

PATHS = ("/lmpc/mpc/reference", "/lmpc/mpc/predicted")
MARKERS = ("/lmpc/mpc/candidates", "/lmpc/mpc/agent_predictions")


def _stamp_s(header: Any) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def test_mpc_paths_and_markers(tmp_path: Path, domain_id: int) -> None:
    rclpy = pytest.importorskip("rclpy")
    from nav_msgs.msg import Path as PathMsg
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from lmpc_msgs_py import qos as lmpc_qos
    from visualization_msgs.msg import Marker, MarkerArray

    keep_all = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                          reliability=ReliabilityPolicy.RELIABLE)
    rclpy.init()
    node = rclpy.create_node("mirror_test_observer")
    got: dict[str, list[Any]] = {name: [] for name in PATHS + MARKERS}
    mirror_subs = [node.create_subscription(PathMsg, name, got[name].append, keep_all)
                   for name in PATHS]
    mirror_subs += [node.create_subscription(MarkerArray, name, got[name].append, keep_all)
                    for name in MARKERS]
    seen: dict[str, list[str]] = {}
    # The observer joins first (LOCALHOST discovery: docs/ARCHITECTURE.md) and is one
    # more participant the bridge waits for before step 0 (--extra-subscribers 1): it
    # subscribes to the ego state once it has matched the MPC's four mirror publishers.
    graph = subprocess.Popen(
        [sys.executable, str(RUN_GRAPH), "--scenario", "usi", "--seed", "0", "--planner", "rules",
         "--clock", "sync", "--quiet", "--run-dir", str(tmp_path / "run"),
         "--domain-id", str(domain_id), "--extra-subscribers", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ego_sub = None
    try:
        deadline = time.monotonic() + 120
        while graph.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            if ego_sub is None and all(sub.get_publisher_count() >= 1 for sub in mirror_subs):
                ego_sub = node.create_subscription(String, "/lmpc/ego_state",
                                                   lambda _msg: None, lmpc_qos.STREAM)
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
    assert ego_sub is not None, "the MPC's mirror publishers never matched"
    for name in PATHS:
        assert seen.get(name) == ["nav_msgs/msg/Path"], (name, seen.get(name))
    for name in MARKERS:
        assert seen.get(name) == ["visualization_msgs/msg/MarkerArray"], (name, seen.get(name))
    # the ego from the bridge's per-step record (every step, whatever DDS delivered to
    # this observer: it is no participant the bridge waits for before step 0)
    ego_at = [(s["t_s"], s["x_m"], s["y_m"])
              for s in read_episode(tmp_path / "run")["record"]["steps"]]
    assert len(ego_at) > 20

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
