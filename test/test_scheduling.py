"""The PM QoS wake-up latency request of ``run_graph.py --cpu-dma-latency`` (without the
kernel's device: a file stands in for it, the kernel reads the same 4 bytes)."""
from __future__ import annotations

import os
import struct
from pathlib import Path

import pytest

from lmpc_msgs_py.scheduling import CpuLatencyHold
from lmpc_scripts import run_graph


def test_the_request_is_written_and_held_until_closed(tmp_path: Path) -> None:
    dev = tmp_path / "cpu_dma_latency"
    dev.write_bytes(b"")
    hold = CpuLatencyHold(25, device=str(dev))
    assert hold.held and hold.state == f"held: wake-up latency <= 25 us ({dev})"
    assert struct.unpack("i", dev.read_bytes()) == (25,)
    fd = hold._fd
    assert fd is not None
    os.fstat(fd)  # open while held
    hold.close()
    assert not hold.held
    with pytest.raises(OSError):
        os.fstat(fd)
    hold.close()  # twice is harmless


def test_no_device_says_why_and_holds_nothing(tmp_path: Path) -> None:
    hold = CpuLatencyHold(0, device=str(tmp_path / "missing"))
    assert not hold.held
    assert hold.state is not None and hold.state.startswith("not held: cannot open")
    assert str(tmp_path / "missing") in hold.state
    assert CpuLatencyHold(None).state is None  # not asked: nothing said
    with pytest.raises(ValueError, match="-1"):
        CpuLatencyHold(-1, device=str(tmp_path / "missing"))


def test_run_graph_refuses_a_negative_latency(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        run_graph.parse_args(["--cpu-dma-latency", "-3"])
    assert exc.value.code == 2
    assert "--cpu-dma-latency" in capsys.readouterr().err
    assert run_graph.parse_args(["--cpu-dma-latency", "0"]).cpu_dma_latency == 0
    assert run_graph.parse_args([]).cpu_dma_latency is None


def test_the_planner_runs_one_priority_below_the_loop_and_never_with_the_llm() -> None:
    from lmpc_msgs_py.scheduling import node_priorities

    assert node_priorities(0, "rules") == {}
    assert node_priorities(20, "rules") == {"bridge": 20, "mpc": 20, "planner": 19,
                                            "mock_llm": 19}
    assert node_priorities(20, "local") == {"bridge": 20, "mpc": 20}
    assert node_priorities(1, "rules") == {"bridge": 1, "mpc": 1}  # no priority 0


def test_the_nodes_get_local_discovery_with_the_packaged_profile(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``run_graph.ros_env``: the nodes' environment keeps discovery on this machine with
    the packaged Fast DDS profile (``lmpc_msgs_py.discovery``), or the user's own settings."""
    from lmpc_msgs_py.discovery import LOCAL_PROFILE, PROFILE_ENVS, RANGE_ENV

    for key in (RANGE_ENV, *PROFILE_ENVS, "RMW_IMPLEMENTATION"):
        monkeypatch.delenv(key, raising=False)
    env = run_graph.ros_env(7)
    assert (env[RANGE_ENV], env["ROS_DOMAIN_ID"]) == ("LOCALHOST", "7")
    assert env[PROFILE_ENVS[0]] == str(LOCAL_PROFILE) and LOCAL_PROFILE.is_file()
    monkeypatch.setenv(RANGE_ENV, "SUBNET")
    env = run_graph.ros_env(7)
    assert env[RANGE_ENV] == "SUBNET" and PROFILE_ENVS[0] not in env
