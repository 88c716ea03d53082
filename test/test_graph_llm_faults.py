"""Every mock-LLM failure mode against the real planner process (RELIABILITY.md fault 6).

The planner runs its ``openai`` backend against graphkit.FakeLlmServer, an
OpenAI-compatible server on loopback that answers each call in a scripted failure
mode (delay past the deadline, hang, prose, fenced JSON, two objects, unknown action,
ghost vehicle, NaN, empty, then it dies). One sync-clock episode carries them all.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from graphkit import (
    FakeLlmServer,
    NodeSet,
    bridge_params,
    logs_with_tracebacks,
    read_episode,
    write_planner_config,
)

pytestmark = pytest.mark.graph

DEADLINE_S = 1.0
MAX_RETRIES = 1
FAULTY = ["delay", "hang", "garbage", "fenced", "two_objects", "unknown_action", "ghost",
          "nan", "empty"]
# each faulty mode twice (the re-ask fails too: a fallback), one recovery on the re-ask,
# then the server dies: every later call is refused
SCRIPT = ["valid"] + [m for mode in FAULTY for m in (mode, mode)] \
    + ["garbage", "valid", "valid", "crash"]
EXPECTED_KIND = {"delay": "timeout", "hang": "timeout", "crash": "transport",
                 "fenced": "fenced", "empty": "empty"}


def test_every_mock_llm_failure_mode_gives_fallbacks_and_the_planner_keeps_serving(
    tmp_path: Path, domain_id: int
) -> None:
    run_dir = tmp_path / "run"
    with FakeLlmServer(SCRIPT, delay_s=DEADLINE_S + 1.0, hang_s=30.0) as server:
        cfg = write_planner_config(
            tmp_path / "planner.yaml", backend="openai", deadline_s=DEADLINE_S,
            max_retries=MAX_RETRIES, period_s=1.0, openai={"base_url": server.base_url})
        with NodeSet(run_dir, domain_id) as g:
            g.start("bridge", bridge_params(run_dir, clock_mode="sync", wait_for_planner=True,
                                            scenario="usi", seed=0, max_time_s=40.0,
                                            planner_timeout_s=20.0))
            g.start("mpc", {"use_sim_time": True, "clock_mode": "sync"})
            g.start("planner", {"use_sim_time": True, "config_file": str(cfg),
                                "run_dir": str(run_dir)},
                    env={"LMPC_OPENAI_BASE_URL": server.base_url,
                         "LMPC_OPENAI_MODEL": "fake"})
            assert g.wait_exit("bridge", 240) == 0
            planner_alive = g.procs["planner"].alive()
            codes = g.stop_all()
        calls = list(server.calls)
    ep = read_episode(run_dir)
    records = [json.loads(line) for line in (run_dir / "decisions.jsonl").read_text().splitlines()]
    attempts = [a for r in records for a in r["attempts"]]
    print(f"{len(calls)} backend calls, {len(records)} decisions, "
          f"{sum(r['source'] == 'fallback' for r in records)} fallbacks")
    seen: dict[str, set] = {}
    for mode, att in zip(calls, attempts):
        seen.setdefault(mode, set()).add(att["error_kind"])
    print("mode -> planner error kind:", {m: sorted(k, key=str) for m, k in seen.items()})
    assert len(calls) >= len(SCRIPT) + 2, f"the episode ended before the script: {calls}"
    # the calls the planner logged are the calls the server saw, in order
    assert len(attempts) == len(calls)
    for mode, att in zip(calls, attempts):
        if mode == "valid":
            assert att["error_kind"] is None, att
        else:
            assert att["error_kind"] is not None, (mode, att)
            if mode in EXPECTED_KIND:
                assert att["error_kind"] == EXPECTED_KIND[mode], (mode, att)
    # bounded calls per cycle: one ask and at most MAX_RETRIES re-asks
    assert max(len(r["attempts"]) for r in records) <= MAX_RETRIES + 1
    for r in records:
        failed = all(a["error_kind"] is not None for a in r["attempts"])
        assert (r["source"] == "fallback") == failed, r
    kinds = {a["error_kind"] for a in attempts if a["error_kind"]}
    assert {"timeout", "transport", "fenced", "empty"} <= kinds, kinds
    # after the server died the planner still decided (fallbacks) every period
    after_crash = [r for r in records if any(a["error_kind"] == "transport"
                                             for a in r["attempts"])]
    assert len(after_crash) >= 2 and all(r["source"] == "fallback" for r in after_crash)
    assert planner_alive and codes["planner"] == 0, codes
    # The driving under this script of failures is not the subject: a decision's effect
    # time is its measured (wall) latency, so the trajectory depends on the machine's load.
    # Under CI load (2026-12-03) the ego once stood turned in the junction after a yield
    # and its re-entry went 5.2 m wide: off_route, the open mechanism 2 of issue 23. A
    # failed episode is allowed; a collision or a crashed node is not.
    assert ep["outcome"] in ("reached", "timeout", "off_route"), ep["detail"]
    assert ep["metrics"]["collisions"] == 0
    assert ep["fallbacks"] >= len(FAULTY)
    assert logs_with_tracebacks(run_dir) == {}
