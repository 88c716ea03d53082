"""A recorded run replays: its bag's observations and decisions, fed to MpcController
in-process, reproduce the controls the MPC node published (RELIABILITY.md: "A run
records its topics so any failure can be replayed").

Replay rule (docs/RELIABILITY_TESTS.md): before the control for an ego state with
stamp t, every recorded decision with ``stamp_s <= t`` is given to the controller (a
decision takes effect at ``stamp_s + max(latency_s, dt)`` > t at the earliest, so
whether the node had received the decision of stamp t itself cannot matter; the
sync barrier guarantees the older ones); ``now_s`` is the ego stamp (sync clock).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from graphkit import run_graph

pytestmark = pytest.mark.graph

ACCEL_TOL_MPS2 = 1e-3
STEER_TOL_RAD = 1e-4


def read_bag(bag: Path) -> list[tuple[str, Any]]:
    """(topic, decoded schema message) of every JSON topic, in receive order."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from lmpc_msgs_py import ALL_MESSAGES, decode

    store = get_typestore(Stores.ROS2_JAZZY)
    schemas = {cls.SCHEMA: cls for cls in ALL_MESSAGES}
    out = []
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            if conn.msgtype != "std_msgs/msg/String" or conn.topic == "/lmpc/instruction":
                continue
            text = store.deserialize_cdr(raw, conn.msgtype).data
            name = text.split('"schema":"', 1)[1].split('"', 1)[0]
            out.append((conn.topic, decode(text, schemas[name], topic=conn.topic)))
    return out


def replay_controls(messages: list[tuple[str, Any]]) -> list[Any]:
    """The controls MpcController computes for the recorded ego states, in order."""
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController
    from lmpc_msgs_py import AgentArray, SignalStates
    from lmpc_msgs_py.observation import Observation

    maps = [m for t, m in messages if t == "/lmpc/map"]
    assert maps, "no map in the bag"
    agents = {m.stamp_s: m for t, m in messages if t == "/lmpc/agents"}
    signals = {m.stamp_s: m for t, m in messages if t == "/lmpc/signals"}
    decisions = sorted((m for t, m in messages if t == "/lmpc/decision"),
                       key=lambda d: (d.stamp_s, d.seq))
    egos = [m for t, m in messages if t == "/lmpc/ego_state"]
    # the node runs with clock_mode sync: the wall-time budget is counted, not enforced
    controller = MpcController(load_mpc_config(None), realtime=False)
    out = []
    given = 0
    for ego in egos:
        while given < len(decisions) and decisions[given].stamp_s <= ego.stamp_s + 1e-9:
            controller.on_decision(decisions[given])
            given += 1
        obs = Observation(
            map=maps[-1], ego=ego,
            agents=agents.get(ego.stamp_s) or AgentArray(stamp_s=ego.stamp_s, seq=0),
            signals=signals.get(ego.stamp_s) or SignalStates(stamp_s=ego.stamp_s, seq=0))
        out.append(controller.compute(obs, now_s=ego.stamp_s if ego.stamp_s > 0 else None))
    return out


def test_a_recorded_run_replays_its_controls_in_process(tmp_path: Path, domain_id: int) -> None:
    pytest.importorskip("rosbags.rosbag2")
    run = run_graph(tmp_path, domain_id, "--scenario", "usi", "--seed", "1", "--planner",
                    "rules", "--record", "--quiet", "--max-time-s", "25")
    assert run.summary["outcome"] in ("reached", "timeout"), run.output[-3000:]
    messages = read_bag(Path(run.summary["bag"]))
    recorded = [m for t, m in messages if t == "/lmpc/control"]
    replayed = replay_controls(messages)
    assert len(recorded) == len(replayed) >= 100, (len(recorded), len(replayed))
    decided = sum(c.mode == "decision" for c in recorded)
    assert decided >= len(recorded) // 2, "too few decision-mode controls to show anything"
    worst_a = worst_s = 0.0
    for rec, rep in zip(recorded, replayed):
        assert rep.stamp_s == rec.stamp_s
        assert rep.mode == rec.mode, (rec.stamp_s, rec.mode, rep.mode)
        assert rep.decision_id == rec.decision_id, rec.stamp_s
        worst_a = max(worst_a, abs(rep.accel_mps2 - rec.accel_mps2))
        worst_s = max(worst_s, abs(rep.steer_rad - rec.steer_rad))
    print(f"replayed {len(replayed)} controls ({decided} in decision mode): max |d accel| "
          f"{worst_a:.2e} m/s^2, max |d steer| {worst_s:.2e} rad")
    assert worst_a <= ACCEL_TOL_MPS2 and worst_s <= STEER_TOL_RAD, (worst_a, worst_s)
