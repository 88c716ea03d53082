"""Discovery with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and more than four participants.

docs/ARCHITECTURE.md feared that Fast DDS announces only to participant ids 0-3 on
loopback, so a 5th / 6th process (a relay, a recorder, a test probe) might miss
others. This test starts eight participants, one process each and staggered so the
later ones get ids 4-7, and checks that every one sees every other one's publisher.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from graphkit import node_env

pytestmark = pytest.mark.graph

PARTICIPANT = r"""
import sys, time
import rclpy
from std_msgs.msg import String
i, n, wait_s = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node(f"discovery_probe_{i}")
pub = node.create_publisher(String, f"/lmpc_discovery/p{i}", 10)
subs = [node.create_subscription(String, f"/lmpc_discovery/p{j}", lambda m: None, 10)
        for j in range(n) if j != i]
def seen():
    return [j for j in range(n) if j != i and node.count_publishers(f"/lmpc_discovery/p{j}")]
t_end = time.monotonic() + wait_s
while time.monotonic() < t_end and len(seen()) < n - 1:
    rclpy.spin_once(node, timeout_sec=0.1)
print(f"SEEN {i} {len(seen())}", flush=True)
t_end = time.monotonic() + 3.0  # stay while the others count
while time.monotonic() < t_end:
    rclpy.spin_once(node, timeout_sec=0.1)
node.destroy_node()
rclpy.shutdown()
"""
N = 8


def test_eight_localhost_participants_all_discover_each_other(
    tmp_path: Path, domain_id: int
) -> None:
    env = node_env(domain_id, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    procs = []
    for i in range(N):
        procs.append(subprocess.Popen(
            [sys.executable, "-c", PARTICIPANT, str(i), str(N), str(20.0)], env=env,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
        # staggered: the later processes take participant ids 4..7
        try:
            procs[-1].wait(timeout=0.4)
        except subprocess.TimeoutExpired:
            pass
    outputs = [p.communicate(timeout=60)[0] for p in procs]
    seen = {}
    for out in outputs:
        for line in out.splitlines():
            if line.startswith("SEEN "):
                _, i, k = line.split()
                seen[int(i)] = int(k)
    print(f"participants seen (of {N - 1}): {seen}")
    assert seen == {i: N - 1 for i in range(N)}, (seen, [o[-500:] for o in outputs])
