"""A planner and an MPC with different decision-space files (issue 15): run_graph refuses
to start such a graph; nodes started by hand anyway meet an MPC that refuses every
Decision loudly (one error line naming both hashes and its file, counted on its
diagnostics), keeps its baseline behaviour and keeps serving; the episode runs on."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from graphkit import (
    REPO,
    NodeSet,
    Probe,
    bridge_params,
    logs_with_tracebacks,
    read_episode,
    run_graph,
)


def _other_space(folder: Path) -> Path:
    """The packaged decision space with one number changed (the strongest brake)."""
    from lmpc_msgs_py.vocabulary import DEFAULT_SPACE_PATH

    data = yaml.safe_load(DEFAULT_SPACE_PATH.read_text())
    data["accel_intervals_mps2"][0] = [-5.0, -4.0]
    path = folder / "other_space.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_run_graph_does_not_start_a_graph_of_two_decision_spaces(
    tmp_path: Path, domain_id: int
) -> None:
    from lmpc_msgs_py.vocabulary import load_decision_space

    other = _other_space(tmp_path)
    out = run_graph(tmp_path / "g", domain_id, "--planner", "rules", "--decision-space",
                    str(other), "--quiet", timeout_s=120)
    assert out.returncode == 3 and out.summary["outcome"] == "error", out.output[-2000:]
    detail = out.summary["detail"]
    assert "decision spaces differ" in detail and "no node started" in detail
    assert load_decision_space(other).space_hash in detail
    assert load_decision_space().space_hash in detail and str(other) in detail
    assert not list((tmp_path / "g" / "run").glob("*.log")), "a node was started"
    # the same file on both sides starts (checked without nodes: the pre-start test only)
    mpc = yaml.safe_load((REPO / "src/lmpc_mpc/lmpc_mpc/config/mpc.yaml").read_text())
    mpc["decision_space_file"] = str(other)
    (tmp_path / "mpc.yaml").write_text(yaml.safe_dump(mpc))
    from lmpc_scripts import run_graph as mod

    args = mod.parse_args(["--decision-space", str(other), "--mpc-config",
                           str(tmp_path / "mpc.yaml")])
    assert mod.decision_space_mismatch(args) is None
    assert mod.node_params(args, tmp_path)["planner"]["decision_space_file"] == str(other)


@pytest.mark.graph
def test_a_planner_of_another_decision_space_is_refused_by_the_mpc(
    tmp_path: Path, domain_id: int
) -> None:
    from lmpc_msgs_py.vocabulary import DEFAULT_SPACE_PATH, load_decision_space

    other = _other_space(tmp_path)
    planner_hash = load_decision_space(other).space_hash
    mpc_space = load_decision_space()
    assert planner_hash != mpc_space.space_hash
    run_dir = tmp_path / "run"
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as probe:
        probe.listen("/lmpc/control")
        g.start("mpc", {"use_sim_time": True, "clock_mode": "sync"})
        g.start("mock_llm", {"use_sim_time": True, "decision_space_file": str(other),
                             "script_file": str(REPO / "test" / "data" / "go.yaml")})
        probe.wait_publishers("/lmpc/control", 1, 60)
        g.start("bridge", bridge_params(run_dir, clock_mode="sync", max_time_s=6.0,
                                        wait_for_planner=True))
        assert g.wait_exit("bridge", 120) == 0
        probe.wait_until("the MPC's diagnostics count the refusals", lambda: int(
            probe.diag("/mpc_controller").get("refused_decisions", "0")) > 0, 10)
        diag = probe.diag("/mpc_controller")
        level_message = probe.diag_messages.get("/mpc_controller", "")
        controls = [json.loads(m.data) for _, m in probe.messages("/lmpc/control")]
        mpc_log = g.procs["mpc"].log()
        g.stop_all()
    refused = [line for line in mpc_log.splitlines() if "REFUSED decision" in line]
    assert refused, mpc_log[-3000:]
    assert planner_hash in refused[0] and mpc_space.space_hash in refused[0]
    assert str(DEFAULT_SPACE_PATH) in refused[0] and "[ERROR]" in refused[0]
    assert "decisions refused" in level_message
    assert int(diag["dropped:/lmpc/decision"]) >= 1
    modes = {c["mode"] for c in controls}
    assert controls and "decision" not in modes and "baseline" in modes, modes
    ep = read_episode(run_dir)
    assert ep["record"]["steps"], "the episode did not run"
    assert logs_with_tracebacks(run_dir) == {}


@pytest.mark.graph
def test_a_decision_published_before_the_mpc_matched_still_reaches_it(
    tmp_path: Path, domain_id: int
) -> None:
    """The planner and the MPC discover each other on their own; a decision the planner
    sent before its writer had matched the MPC's reader must still arrive (CI lost the
    first decision of an episode so, 2026-12-03). Here the decision is published before
    the MPC process even starts; the MPC must receive it (seen through its refusal: the
    decision names another space, which the MPC logs by id)."""
    from lmpc_msgs_py import qos as lmpc_qos
    from lmpc_msgs_py.codec import encode
    from lmpc_msgs_py.messages import BezierTrajectory, Decision

    cps = ((10.0, -4.8), (30.0, -4.8), (50.0, -4.8), (70.0, -4.8))
    decision = Decision(stamp_s=0.0, seq=1, decision_id="before-the-match", source="mock",
                        latency_s=0.0, ego_trajectory=BezierTrajectory(
                            candidate_id=0, control_points=cps),
                        accel_interval=0, steer_interval=2, space_hash="0" * 16)
    with NodeSet(tmp_path / "run", domain_id) as g, Probe(domain_id) as probe:
        # the planner's writer QoS (lmpc_qos.PRODUCED), published with no reader around
        probe.publish("/lmpc/decision", encode(decision),
                      lmpc_qos.PRODUCED)
        g.start("mpc", {"use_sim_time": True, "clock_mode": "sync"})
        g.wait_for_log("mpc", "REFUSED decision before-the-match", 30)
        g.stop_all()
    assert logs_with_tracebacks(tmp_path / "run") == {}


@pytest.mark.graph
def test_the_sync_barrier_gives_up_on_a_lost_decision_once(tmp_path: Path,
                                                           domain_id: int) -> None:
    """Ego states that name a decision the MPC never gets (lost, or its planner died
    after the status): the MPC waits for it once (``BARRIER_WAIT_S``), then computes
    every step's control without waiting again (it waited on every step before: 1 s of
    wall time per step until the planner's next decision)."""
    from lmpc_msgs_py import qos as lmpc_qos
    from lmpc_msgs_py.codec import encode
    from lmpc_mpc import synthetic as S

    road = S.straight_road()
    steps = 6
    with NodeSet(tmp_path / "run", domain_id) as g, Probe(domain_id) as probe:
        probe.listen("/lmpc/control")
        g.start("mpc", {"use_sim_time": False, "clock_mode": "sync"})
        probe.publish("/lmpc/map", encode(road), lmpc_qos.LATCHED)
        for topic in ("/lmpc/agents", "/lmpc/signals", "/lmpc/ego_state"):
            probe.publish(topic, "")  # creates the publisher (dropped and counted)
            probe.wait_subscribers(topic, 1, 60)
        for k in range(steps):
            ego = S.ego_state(x_m=20.0 + k, y_m=-4.8, yaw_rad=0.0, v_mps=8.0,
                              stamp_s=0.1 * k, seq=k, required_decision_id="never-sent")
            obs = S.observation(road, ego)
            probe.publish("/lmpc/agents", encode(obs.agents))
            probe.publish("/lmpc/signals", encode(obs.signals))
            probe.publish("/lmpc/ego_state", encode(ego))
            probe.wait_until(f"the control for step {k}", lambda n=k + 1: len(
                probe.messages("/lmpc/control")) >= n, 30)
        probe.wait_until("the MPC's diagnostics", lambda: int(
            probe.diag("/mpc_controller").get("barrier_timeouts", "-1")) >= 0, 10)
        timeouts = int(probe.diag("/mpc_controller")["barrier_timeouts"])
        g.stop_all()
    assert timeouts == 1, timeouts
    assert logs_with_tracebacks(tmp_path / "run") == {}
