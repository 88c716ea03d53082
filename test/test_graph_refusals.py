"""Bad input sent as raw std_msgs/String to the running nodes is refused and counted
(RELIABILITY.md, "Inputs that must be refused, with the node still running").

One realtime-clock episode (``si`` seed 0, up to 60 s: the ego waits at a red light;
bridge, MPC, rules planner) carries every bad payload of every input topic. Realtime,
not sync: the paced payloads take ~12 s of wall time, and a sync episode runs ~10x
faster than real time (35 s sim ended before the decision payloads were sent). Each
subscriber's ``dropped:<topic>`` diagnostics counter must grow by exactly the number
sent, and the episode must still run to its end.
LLM-output refusals (prose, fenced JSON, ...) are in test_graph_llm_faults.py.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import pytest

from graphkit import NodeSet, Probe, bridge_params, logs_with_tracebacks, read_episode

pytestmark = pytest.mark.graph

BRIDGE, MPC, PLANNER = "/sumo_bridge", "/mpc_controller", "/llm_planner"
SUBSCRIBERS = {
    "/lmpc/control": (BRIDGE,),
    "/lmpc/planner/status": (BRIDGE,),
    "/lmpc/decision": (BRIDGE, MPC),
    "/lmpc/ego_state": (MPC, PLANNER),
    "/lmpc/agents": (MPC, PLANNER),
    "/lmpc/signals": (MPC, PLANNER),
}
# per topic: a float field to poison, and physically absurd values (field -> value)
NUMBER_FIELD = {"/lmpc/control": "accel_mps2", "/lmpc/planner/status": "stamp_s",
                "/lmpc/decision": "latency_s", "/lmpc/ego_state": "v_mps",
                "/lmpc/agents": "sensing_range_m", "/lmpc/signals": "stamp_s"}
ABSURD: dict[str, list[dict[str, Any]]] = {
    "/lmpc/control": [{"steer_rad": 3.0}, {"accel_mps2": 50.0}, {"accel_mps2": -50.0}],
    "/lmpc/ego_state": [{"v_mps": 200.0}, {"steer_rad": 3.0}, {"a_mps2": -50.0}],
    "/lmpc/decision": [{"latency_s": 1e4}, {"accel_interval": 99},
                       {"space_hash": "not a hash"}],
    "/lmpc/agents": [{"sensing_range_m": 1e6}],
    "/lmpc/signals": [{"stamp_s": -5.0}],
    "/lmpc/planner/status": [{"decisions": -1}],
}


def _with(obj: dict[str, Any], **changes: Any) -> str:
    out = dict(obj)
    out.update(changes)
    return json.dumps(out)


def _without(obj: dict[str, Any], key: str) -> str:
    return json.dumps({k: v for k, v in obj.items() if k != key})


def bad_payloads(topic: str, text: str) -> list[tuple[str, str]]:
    """(case name, payload) for every bad input of RELIABILITY.md, made from a real
    message ``text`` of ``topic``."""
    obj = json.loads(text)
    field = NUMBER_FIELD[topic]
    schema = obj["schema"]
    name, _, version = schema.partition("@")
    cases: list[tuple[str, str]] = [
        ("not JSON", "this is not JSON"),
        ("truncated JSON", text[: len(text) // 2]),
        ("empty string", ""),
        ("very large string", json.dumps({"schema": schema, "pad": "x" * (1 << 20)})),
        ("wrong schema name", _with(obj, schema="lmpc/Bogus@1")),
        ("wrong schema version", _with(obj, schema=f"{name}@{int(version) + 1}")),
        ("schema missing", _without(obj, "schema")),
        ("missing field", _without(obj, "stamp_s")),
        ("extra field", _with(obj, bogus=1)),
        ("wrong type", _with(obj, stamp_s="soon")),
        ("NaN", _with(obj, **{field: 0.5}).replace(f'"{field}": 0.5', f'"{field}": NaN')),
        ("+Infinity", _with(obj, **{field: 0.5}).replace(f'"{field}": 0.5',
                                                         f'"{field}": Infinity')),
        ("-Infinity", _with(obj, **{field: 0.5}).replace(f'"{field}": 0.5',
                                                         f'"{field}": -Infinity')),
        ("1e309", _with(obj, **{field: 0.5}).replace(f'"{field}": 0.5', f'"{field}": 1e309')),
        ("duplicate", text),
        ("seq backwards", _with(obj, seq=max(1, obj["seq"] - 3))),
    ]
    for i, change in enumerate(ABSURD[topic]):
        cases.append((f"absurd {i} {change}", _with(obj, **change)))
    return cases


def _wait_diag(probe: Probe, what: str, pred: Callable[[], bool]) -> None:
    probe.wait_until(what, pred, 15)


def test_every_bad_input_is_dropped_counted_and_the_nodes_keep_serving(
    tmp_path: Path, domain_id: int
) -> None:
    run_dir = tmp_path / "run"
    sent: dict[str, list[str]] = {}
    with NodeSet(run_dir, domain_id) as g, Probe(domain_id) as probe:
        for topic in SUBSCRIBERS:
            probe.listen(topic)
        g.start("bridge", bridge_params(run_dir, clock_mode="realtime", scenario="si",
                                        seed=0, max_time_s=60.0))
        g.start("mpc", {"use_sim_time": True, "clock_mode": "realtime"})
        g.start("planner", {"use_sim_time": True, "backend": "rules", "run_dir": str(run_dir)})

        def templates() -> dict[str, str]:
            out = {}
            for topic in SUBSCRIBERS:
                msgs = [m.data for _, m in probe.messages(topic)
                        if json.loads(m.data).get("seq", 0) >= 5]
                if msgs:
                    out[topic] = msgs[-1]
            return out

        probe.wait_until("a real message with seq >= 5 on every input topic",
                         lambda: len(templates()) == len(SUBSCRIBERS), 90)
        real = templates()
        for topic, subs in SUBSCRIBERS.items():
            probe.publish(topic, "")  # creates the publisher; counted as one more drop
            probe.wait_subscribers(topic, len(subs) + 0, 15)
        before = {(n, t): probe.diag_count(n, f"dropped:{t}")
                  for t, subs in SUBSCRIBERS.items() for n in subs}
        for topic, text in real.items():
            cases = bad_payloads(topic, text)
            sent[topic] = [c for c, _ in cases]
            for _, payload in cases:
                probe.publish(topic, payload)
                # subscriber queues are 10 deep and a node may be busy for a while
                # (a solve on a loaded machine): pace the payloads so none is lost
                time.sleep(0.1)
        # the planner refuses an over-long instruction (untrusted text)
        probe.publish("/lmpc/instruction", "drive " * 2000)
        probe.wait_subscribers("/lmpc/instruction", 1, 15)
        probe.publish("/lmpc/instruction", "drive " * 2000)
        # a stamp older than the staleness bound (0.3 s sim): a valid message, refused
        # by age, not by the decoder. seq 0 passes the order gate (a restarted bridge
        # starts at 0), so the real stream after it is still accepted.
        stale = json.loads(real["/lmpc/ego_state"])
        stale.update(seq=0, stamp_s=max(0.0, stale["stamp_s"] - 3.0))
        stale_before = (probe.diag_count(PLANNER, "stale_ego_state"),
                        probe.diag_count(MPC, "stale_inputs"))
        probe.publish("/lmpc/ego_state", json.dumps(stale))
        expected = {(n, t): before[(n, t)] + len(sent[t]) + 1
                    for t, subs in SUBSCRIBERS.items() for n in subs}
        # empty string sent once before 'before' was read may or may not be in it:
        # wait until each counter reached at least the cases sent
        for (node, topic), want in expected.items():
            _wait_diag(probe, f"{node} dropped:{topic} >= {want - 1}",
                       lambda n=node, t=topic, w=want: probe.diag_count(n, f"dropped:{t}")
                       >= w - 1)
        time.sleep(2.5)  # two more diagnostics periods: nothing else trickles in
        after = {(n, t): probe.diag_count(n, f"dropped:{t}")
                 for t, subs in SUBSCRIBERS.items() for n in subs}
        instr_drops = probe.diag_count(PLANNER, "dropped:/lmpc/instruction")
        stale_after = (probe.diag_count(PLANNER, "stale_ego_state"),
                       probe.diag_count(MPC, "stale_inputs"))
        assert g.wait_exit("bridge", 180) == 0
        planner_diag = probe.diag(PLANNER)
        codes = g.stop_all()
    report = {f"{n} {t}": after[(n, t)] - before[(n, t)] for (n, t) in after}
    print("drops per subscriber:", json.dumps(report, indent=1))
    for (node, topic), count in after.items():
        n_sent = len(sent[topic])
        delta = count - before[(node, topic)]
        # every bad payload once; the empty string that created the publisher may have
        # been counted before or after 'before' was read
        assert n_sent <= delta <= n_sent + 1, (node, topic, delta, n_sent, sent[topic])
    assert instr_drops >= 1
    assert stale_after[0] > stale_before[0], "planner did not refuse the stale ego state"
    assert stale_after[1] > stale_before[1], "MPC did not brake on the stale ego state"
    ep = read_episode(run_dir)
    # the nodes kept serving: the episode ran to its end on the real messages
    assert ep["outcome"] in ("reached", "timeout"), ep["detail"]
    assert ep["sim_time_s"] >= 30.0, "the episode stopped early"
    assert ep["metrics"]["collisions"] == 0
    assert int(planner_diag.get("decisions", "0")) >= 2
    assert set(codes.values()) <= {0}, codes
    assert logs_with_tracebacks(run_dir) == {}
