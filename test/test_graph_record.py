"""`run_graph.py --record` writes every topic of the run as a rosbag2 (MCAP) bag."""
from __future__ import annotations

from pathlib import Path

import pytest

from graphkit import run_graph

pytestmark = pytest.mark.graph


def test_record_writes_a_readable_bag_of_every_topic(tmp_path: Path, domain_id: int) -> None:
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    typesys = pytest.importorskip("rosbags.typesys")
    from lmpc_msgs_py import ALL_MESSAGES, decode

    run = run_graph(tmp_path, domain_id, "--scenario", "usi", "--seed", "1", "--planner",
                    "rules", "--record", "--quiet")
    assert run.summary["outcome"] == "reached", run.output[-3000:]
    bag = Path(run.summary["bag"])
    assert (bag / "metadata.yaml").exists()
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    schemas = {cls.SCHEMA: cls for cls in ALL_MESSAGES}
    counts: dict[str, int] = {}
    ego_stamps: set[float] = set()
    with rosbag2.Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.msgtype == "std_msgs/msg/String" and conn.topic != "/lmpc/instruction":
                name = msg.data.split('"schema":"', 1)[1].split('"', 1)[0]
                obj = decode(msg.data, schemas[name], topic=conn.topic)  # every payload validates
                if conn.topic == "/lmpc/ego_state":
                    ego_stamps.add(obj.stamp_s)
    assert types["/lmpc/ego/odom"] == "nav_msgs/msg/Odometry"
    assert types["/clock"] == "rosgraph_msgs/msg/Clock"
    steps = run.episode["metrics"]["steps"]
    # One observation per step taken (step 0 is re-offered while discovery settles).
    assert len(ego_stamps) == steps
    assert counts["/lmpc/control"] >= steps
    assert counts["/lmpc/decision"] == run.summary["decisions"]
    assert counts["/lmpc/map"] == 1
    for topic in ("/lmpc/agents", "/lmpc/signals", "/lmpc/planner/status", "/lmpc/mpc/predicted"):
        assert counts.get(topic, 0) >= steps, topic
