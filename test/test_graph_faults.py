"""Fault tests on real node processes (RELIABILITY.md, "Faults the graph tests must show").

Each test starts the node processes itself (graphkit.NodeSet) so it can kill one of
them mid-episode, remap an input through scripts/fault_relay.py, or start a node
alone; every test also checks that no node died with a Python traceback.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest

from graphkit import (
    FAULT_RELAY,
    NodeSet,
    Probe,
    bridge_params,
    logs_with_tracebacks,
    next_domain_id,
    read_episode,
    write_mpc_config,
)

pytestmark = pytest.mark.graph

TTL_S = 5.0  # planner.yaml ttl_s
CLOCK_WATCHDOG_S = 2.0  # RELIABILITY.md: /clock stale after 2 s wall
WATCHDOG_SLACK_S = 1.5  # log polling, a loaded 2-core machine


def _sim(**planner: object) -> dict[str, object]:
    return {"use_sim_time": True, **planner}


def _finite_record(steps: list[dict]) -> None:
    for s in steps:
        for key in ("x_m", "y_m", "v_mps", "applied_accel_mps2", "applied_steer_rad"):
            assert math.isfinite(s[key]), f"non-finite {key} at t={s['t_s']}"


def test_planner_killed_mid_episode_mpc_goes_to_baseline(tmp_path: Path, domain_id: int) -> None:
    run_dir = tmp_path / "run"
    with NodeSet(run_dir, domain_id) as g:
        g.start("bridge", bridge_params(run_dir, scenario="usi", seed=0, max_time_s=60.0,
                                        clock_mode="sync", wait_for_planner=True,
                                        planner_timeout_s=3.0))
        g.start("mpc", _sim(clock_mode="sync"))
        g.start("planner", _sim(backend="rules", run_dir=str(run_dir)))
        g.wait_for_log("bridge", "progress t=5.0s", 90)
        g.kill("planner")
        assert g.wait_exit("bridge", 120) == 0
        g.stop_all()
    ep = read_episode(run_dir)
    decisions = [json.loads(line) for line in
                 (run_dir / "decisions.jsonl").read_text().splitlines()]
    assert decisions, "the planner made no decision before it was killed"
    expiry_s = max(d["stamp_s"] for d in decisions) + TTL_S
    steps = ep["record"]["steps"]
    before = [s for s in steps if s["t_s"] < 5.0]
    after = [s for s in steps if s["t_s"] >= expiry_s + 0.2]
    assert "decision" in {s["control_mode"] for s in before}
    assert len(after) >= 10, f"episode ended at {ep['sim_time_s']} s, before the TTL ran out"
    modes_after = {s["control_mode"] for s in after}
    assert modes_after <= {"baseline", None}, modes_after
    assert sum(s["control_mode"] == "baseline" for s in after) >= 0.9 * len(after)
    assert ep["outcome"] != "collision", ep["detail"]
    assert ep["metrics"]["collisions"] == 0
    bridge_log = (run_dir / "bridge.log").read_text()
    assert "the planner left the graph" in bridge_log or "missing after" in bridge_log
    _finite_record(steps)
    print(f"planner killed: last decision expired at t={expiry_s:.1f} s; modes after: "
          f"{sorted(modes_after, key=str)}; outcome {ep['outcome']} at {ep['sim_time_s']} s; "
          f"late controls {ep['late_controls']}")
    assert logs_with_tracebacks(run_dir) == {}


def test_mpc_killed_bridge_brakes_to_a_stop_and_goes_on(tmp_path: Path, domain_id: int) -> None:
    run_dir = tmp_path / "run"
    max_time_s = 16.0
    with NodeSet(run_dir, domain_id) as g:
        g.start("bridge", bridge_params(run_dir, scenario="usi", seed=0, max_time_s=max_time_s,
                                        clock_mode="sync"))
        g.start("mpc", _sim(clock_mode="sync"))
        g.wait_for_log("bridge", "progress t=5.0s", 90)
        g.kill("mpc")
        assert g.wait_exit("bridge", 60) == 0
        g.stop_all()
    ep = read_episode(run_dir)
    steps = ep["record"]["steps"]
    assert ep["outcome"] == "timeout", ep["detail"]  # the simulation went on to its limit
    assert steps[-1]["t_s"] >= max_time_s - 0.15
    served = [s for s in steps if s["control_mode"] is not None]
    assert served and served[0]["t_s"] < 1.0, "the MPC did not serve from the start"
    t_kill = served[-1]["t_s"] + 0.1
    assert t_kill >= 5.0
    after = [s for s in steps if s["t_s"] >= t_kill + 0.5]
    assert all(s["late"] and s["control_mode"] is None for s in after)
    v_kill = next(s["v_mps"] for s in steps if s["t_s"] >= t_kill)
    assert v_kill > 1.0, "the ego was not moving when the MPC died (nothing to show)"
    for prev, cur in zip(after, after[1:]):
        assert cur["v_mps"] <= prev["v_mps"] + 1e-6, f"speeding up at t={cur['t_s']}"
    for s in after:
        if s["v_mps"] > 0.05:
            assert -9.0 <= s["applied_accel_mps2"] < 0.0, s  # bounded braking
    assert after[-1]["v_mps"] < 0.05, "the ego did not come to a stop"
    t_stop = next(s["t_s"] for s in after if s["v_mps"] < 0.05)
    print(f"MPC killed at t~{t_kill:.1f} s at {v_kill:.1f} m/s: stopped at t={t_stop:.1f} s, "
          f"sim went on to {steps[-1]['t_s']:.1f} s, late controls {ep['late_controls']}")
    assert ep["metrics"]["collisions"] == 0
    _finite_record(steps)
    assert "the ego brakes" in (run_dir / "bridge.log").read_text() or ep["late_controls"] > 0
    assert logs_with_tracebacks(run_dir) == {}


def test_bridge_killed_planner_and_mpc_notice_and_stop_cleanly(
    tmp_path: Path, domain_id: int
) -> None:
    run_dir = tmp_path / "run"
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as probe:
        probe.listen("/lmpc/control")
        g.start("bridge", bridge_params(run_dir, scenario="usi", seed=0, max_time_s=60.0,
                                        startup_timeout_s=60.0))
        g.start("mpc", _sim(clock_mode="realtime"))
        g.start("planner", _sim(backend="rules", run_dir=str(run_dir)))
        g.wait_for_log("bridge", "progress t=5.0s", 90)
        t_kill = time.monotonic()
        g.kill("bridge")
        g.wait_exit("bridge", 10)
        noticed = {name: g.wait_for_log(name, "simulation not advancing", 10) - t_kill
                   for name in ("mpc", "planner")}
        controls_at_notice = len(probe.messages("/lmpc/control"))
        time.sleep(1.5)
        assert len(probe.messages("/lmpc/control")) == controls_at_notice, \
            "the MPC published a control after it saw the simulation stop"
        assert controls_at_notice > 0
        codes = {name: g.stop(name, timeout_s=10) for name in ("mpc", "planner")}
    print(f"bridge killed: noticed after {noticed} s wall")
    for name, dt in noticed.items():
        assert dt <= CLOCK_WATCHDOG_S + WATCHDOG_SLACK_S, f"{name} noticed after {dt:.2f} s"
    assert codes == {"mpc": 0, "planner": 0}, codes
    assert logs_with_tracebacks(run_dir) == {}


def test_nodes_started_without_inputs_wait_and_command_nothing(
    tmp_path: Path, domain_id: int
) -> None:
    from lmpc_msgs_py import EgoState, encode

    alone = tmp_path / "bridge_alone"
    run_dir = tmp_path / "run"
    other_domain = next_domain_id()
    if other_domain == domain_id:
        other_domain = next_domain_id()
    with NodeSet(run_dir, domain_id) as g, NodeSet(alone, other_domain) as b, \
            Probe(domain_id) as probe:
        for topic in ("/lmpc/control", "/lmpc/decision", "/lmpc/planner/status"):
            probe.listen(topic)
        # the bridge in a domain of its own: nobody to step for
        b.start("bridge", bridge_params(alone, clock_mode="sync", max_time_s=30.0))
        # MPC and planner without a bridge
        g.start("mpc", _sim(clock_mode="sync"))
        g.start("planner", _sim(backend="rules", run_dir=str(run_dir)))
        g.wait_for_log("planner", "ready: waiting for /lmpc/map and /lmpc/ego_state", 60)
        g.wait_for_log("mpc", "waiting for /lmpc/map and /lmpc/ego_state", 60)
        b.wait_for_log("bridge", "waiting for subscribers of /lmpc/ego_state", 60)
        probe.wait_until("the MPC's diagnostics",
                         lambda: probe.diag("/mpc_controller").get("mode") == "idle", 10)
        probe.wait_until("the MPC saying what it waits for", lambda: probe.diag_messages.get(
            "/mpc_controller", "") == "waiting for /lmpc/ego_state", 10)
        # an ego state but no map: both say they wait for the map and command nothing
        ego = EgoState(stamp_s=0.0, seq=3, x_m=0.0, y_m=0.0, yaw_rad=0.0, v_mps=5.0,
                       a_mps2=0.0, steer_rad=0.0, dist_to_target_m=100.0)
        probe.publish("/lmpc/ego_state", encode(ego))
        probe.wait_subscribers("/lmpc/ego_state", 2, 10)
        for seq in range(4, 8):
            probe.publish("/lmpc/ego_state", encode(ego.model_copy(update={"seq": seq})))
            time.sleep(0.2)
        g.wait_for_log("mpc", "waiting for the map on /lmpc/map", 10)
        g.wait_for_log("planner", "waiting for /lmpc/map: no decision yet", 10)
        time.sleep(1.0)
        assert probe.messages("/lmpc/control") == []
        assert probe.messages("/lmpc/decision") == []
        assert "waiting" in probe.diag_messages.get("/llm_planner", "")
        assert b.procs["bridge"].alive() and "starting the episode" not in \
            b.procs["bridge"].log()
        codes = g.stop_all()
        codes.update(b.stop_all())
    assert set(codes.values()) == {0}, codes
    assert logs_with_tracebacks(run_dir) == {} and logs_with_tracebacks(alone) == {}


def test_corrupting_relay_drops_are_counted_and_treated_as_stale(
    tmp_path: Path, domain_id: int
) -> None:
    run_dir = tmp_path / "run"
    # one link after the other: a broken ego_state link starves the control link
    modes = ("nan", "corrupt", "empty", "duplicate", "reorder", "delay=0.6", "drop")
    ctl_plan = "0:pass," + ",".join(f"{2 + 1.5 * i:g}:{m}" for i, m in enumerate(modes)) \
        + ",12.5:pass"
    ego_plan = "0:pass," + ",".join(f"{14 + 1.5 * i:g}:{m}" for i, m in enumerate(modes)) \
        + ",24.5:pass"
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as probe:
        g.start("bridge", bridge_params(run_dir, scenario="usi", seed=0, max_time_s=40.0,
                                        startup_timeout_s=60.0),
                remaps={"/lmpc/control": "/lmpc/control_relayed"})
        g.start("mpc", _sim(clock_mode="realtime"),
                remaps={"/lmpc/ego_state": "/lmpc/ego_state_relayed"})
        g.start_cmd("relay", [
            __import__("sys").executable, str(FAULT_RELAY),
            "--link", "/lmpc/control:/lmpc/control_relayed",
            "--link", "/lmpc/ego_state:/lmpc/ego_state_relayed",
            "--plan", ctl_plan, "--plan", ego_plan, "--report-period-s", "1.0"])
        assert g.wait_exit("bridge", 120) == 0
        mpc_diag = probe.diag("/mpc_controller")
        g.stop_all()
    ep = read_episode(run_dir)
    relay_log = (run_dir / "relay.log").read_text()
    counts = json.loads(relay_log.rsplit("relay counts: ", 1)[1].splitlines()[0])
    ctl, ego = counts["/lmpc/control"], counts["/lmpc/ego_state"]
    for mode in ("nan", "corrupt", "empty", "duplicate", "reorder", "delay", "drop"):
        assert ctl.get(mode, 0) > 0 and ego.get(mode, 0) > 0, (mode, counts)
    # every payload the relay broke is one drop: refused by schema (NaN, truncated,
    # empty), as a duplicate, or as going backwards (one per reordered pair)
    bridge_log = (run_dir / "bridge.log").read_text()
    assert "dropped message on /lmpc/control" in bridge_log
    min_drops = ctl["nan"] + ctl["corrupt"] + ctl["empty"] + ctl["duplicate"] \
        + ctl["reorder"] // 2 - 2
    assert ep["dropped_messages"] >= min_drops, (ep["dropped_messages"], ctl)
    ego_drops = int(mpc_diag.get("dropped:/lmpc/ego_state", "0"))
    assert ego_drops >= ego["nan"] + ego["corrupt"] + ego["empty"] - 2, (mpc_diag, ego)
    # as for a stale input: the ego brakes on the steps without a usable control
    steps = ep["record"]["steps"]
    assert ep["late_controls"] >= ctl["drop"] // 2, ep["late_controls"]
    assert any(s["late"] for s in steps)
    _finite_record(steps)
    print(f"relay: {counts}; bridge drops {ep['dropped_messages']}, MPC ego_state drops "
          f"{ego_drops}, late controls {ep['late_controls']}, MPC stale inputs "
          f"{mpc_diag.get('stale_inputs')}, outcome {ep['outcome']}")
    assert ep["metrics"]["collisions"] == 0
    assert logs_with_tracebacks(run_dir) == {}


@pytest.mark.parametrize("fault,overrides", [
    ("over_budget", {"time_budget_s": 0.0002, "enforce_time_budget": True}),
    ("unconverged", {"max_iterations": 1}),
])
def test_mpc_solver_failure_gives_fallback_control_never_nan(
    tmp_path: Path, domain_id: int, fault: str, overrides: dict
) -> None:
    run_dir = tmp_path / "run"
    mpc_yaml = write_mpc_config(tmp_path / "mpc.yaml", **overrides)
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as probe:
        probe.listen("/lmpc/control")
        # clock_mode '' = the config decides whether the wall-time budget is enforced
        g.start("mpc", _sim(clock_mode="", config_file=str(mpc_yaml)))
        # the 6 s sync run takes about a second: the probe must hear the MPC before it starts
        probe.wait_publishers("/lmpc/control", 1, 60)
        g.start("bridge", bridge_params(run_dir, clock_mode="sync", max_time_s=6.0))
        assert g.wait_exit("bridge", 90) == 0
        mpc_diag = probe.diag("/mpc_controller")
        controls = [json.loads(m.data) for _, m in probe.messages("/lmpc/control")]
        g.stop_all()
    ep = read_episode(run_dir)
    assert controls, "no control published"
    modes = {c["mode"] for c in controls}
    assert modes <= {"shifted", "brake"}, f"{fault}: a failed solve was published as {modes}"
    assert "brake" in modes
    for c in controls:
        assert math.isfinite(c["accel_mps2"]) and math.isfinite(c["steer_rad"])
        assert c["accel_mps2"] <= 0.0
    assert int(mpc_diag.get("solver_failures", "0")) > 0, mpc_diag
    steps = ep["record"]["steps"]
    _finite_record(steps)
    assert max(s["v_mps"] for s in steps[len(steps) // 2:]) <= steps[0]["v_mps"] + 0.05
    assert ep["metrics"]["collisions"] == 0
    assert logs_with_tracebacks(run_dir) == {}


def test_a_second_graph_on_the_domain_is_reported(tmp_path: Path, domain_id: int) -> None:
    """Two producers on a one-producer topic (two graphs sharing ROS_DOMAIN_ID): the node
    warns with the topic and counts it; one producer is not reported."""
    run_dir = tmp_path / "run"
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as first, \
            Probe(domain_id) as second:
        g.start("mpc", _sim(clock_mode="sync"))
        g.wait_for_log("mpc", "waiting for /lmpc/map and /lmpc/ego_state", 60)
        first.publish("/lmpc/ego_state", "not json")
        first.wait_subscribers("/lmpc/ego_state", 1, 20)
        first.wait_until("the MPC's diagnostics", lambda: first.diag(
            "/mpc_controller").get("crosstalk_topics") is not None, 10)
        time.sleep(2.2)  # two more diagnostics periods with the first producer matched
        assert first.diag("/mpc_controller")["crosstalk_topics"] == "0"
        assert "publishers on" not in g.procs["mpc"].log()
        second.publish("/lmpc/ego_state", "not json either")
        second.wait_subscribers("/lmpc/ego_state", 1, 20)
        g.wait_for_log("mpc", "2 publishers on /lmpc/ego_state", 10)
        first.wait_until("crosstalk counted", lambda: first.diag(
            "/mpc_controller").get("crosstalk_topics") == "1", 5)
        codes = g.stop_all()
    assert set(codes.values()) == {0}, codes
    assert logs_with_tracebacks(run_dir) == {}
