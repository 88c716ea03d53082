"""The central coordinator with an LLM backend (issue 18 item 2): prompt, schema,
validation, log and replay, in-process on the ``narrow`` family (development seed 101,
where two egos on their own planners collide).

The "LLM" here is SIMULATED: a function answering the prompt's JSON schema with what the
fixed rule set decides (so the test needs no model and no network), or with an unsafe
answer (both directions proceed) to show that such an answer is refused and the egos
fall back to the distributed rule set.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from lmpc_llm_planner.backends.base import BackendError, BackendReply
from lmpc_llm_planner.coordination import CoordinatorCore, make_coordinator_backend
from lmpc_llm_planner.coordination.llm import (
    LlmCoordinator,
    ReplayCoordinator,
    coordinator_prompt,
    coordinator_schema,
    parse_verdicts,
    participants,
)
from lmpc_llm_planner.coordination.rules import resolve
from lmpc_msgs_py.coordination import ConflictView, EgoStatus
from lmpc_scripts import multi


def st(ego: str, via: str, entry_m: float, v: float = 5.0) -> EgoStatus:
    view = ConflictView(conflict_id="AB", kind="narrow", via=via, dist_to_entry_m=entry_m,
                        dist_to_exit_m=entry_m + 50.0, dist_to_hold_m=max(entry_m - 5.0, 0.0))
    return EgoStatus(stamp_s=1.0, seq=1, ego_id=ego, dist_to_target_m=200.0, v_mps=v,
                     intent="approach", conflict=view)


def answer(items: list[tuple[str, str, int]]) -> str:
    return json.dumps({"reasoning": "test", "verdicts": [
        {"ego_id": e, "command": c, "priority": p} for e, c, p in items]})


def test_a_valid_answer_gives_verdicts_and_matches_its_schema() -> None:
    egos = [st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)]
    text = answer([("ego_2", "proceed", 0), ("ego_1", "yield", 1)])
    schema = coordinator_schema(egos)
    item = schema["properties"]["verdicts"]["items"]["properties"]
    assert item["ego_id"]["enum"] == ["ego_1", "ego_2"] and item["priority"]["maximum"] == 1
    got = parse_verdicts(text, egos)
    assert [(v.ego_id, v.command, v.priority, v.conflict_id) for v in got] == [
        ("ego_1", "yield", 1, "AB"), ("ego_2", "proceed", 0, "AB")]
    prompt = coordinator_prompt(egos, 1.0)
    assert "ego_1" in prompt and "ego_2" in prompt and "AB_0" in prompt


@pytest.mark.parametrize("text, why", [
    ("not json", "not JSON"),
    (answer([("ego_1", "proceed", 0), ("ego_2", "proceed", 1)]), "both proceed"),
    (answer([("ego_1", "proceed", 0)]), "no verdict for ego_2"),
    (answer([("ego_1", "yield", 0), ("ego_3", "yield", 1)]), "not a car of this round"),
    (answer([("ego_1", "go", 0), ("ego_2", "yield", 1)]), "not proceed or yield"),
    (answer([("ego_1", "yield", 0), ("ego_1", "yield", 1)]), "two verdicts"),
])
def test_invalid_or_unsafe_answers_are_refused(text: str, why: str) -> None:
    egos = [st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)]
    with pytest.raises(ValueError, match=why):
        parse_verdicts(text, egos)


def test_a_committed_ego_is_never_told_to_yield() -> None:
    egos = [st("ego_1", "AB_0", 3.0, v=10.0), st("ego_2", "BA_0", 40.0)]  # ego_1 cannot stop
    got = {v.ego_id: v.command for v in parse_verdicts(
        answer([("ego_1", "yield", 1), ("ego_2", "yield", 0)]), egos)}
    assert got == {"ego_1": "proceed", "ego_2": "yield"}


class RulesLlm:
    """A SIMULATED LLM: answers with the fixed rule set's verdicts, as JSON text."""

    def __init__(self) -> None:
        self.memory: dict[str, str] = {}
        self.egos: list[EgoStatus] = []
        self.calls = 0

    def __call__(self, system: str, user: str, schema: dict[str, Any], deadline_s: float
                 ) -> BackendReply:
        self.calls += 1
        ids = schema["properties"]["verdicts"]["items"]["properties"]["ego_id"]["enum"]
        verdicts = resolve([s for s in self.egos if s.ego_id in ids], self.memory)
        text = answer([(v.ego_id, v.command, v.priority) for v in verdicts.values()])
        return BackendReply(text=text, latency_s=0.01)


class Watching(LlmCoordinator):
    """Lets the simulated LLM see the statuses the prompt was made from."""

    def verdicts(self, statuses, now_s):
        self.ask.egos = participants(statuses)  # type: ignore[attr-defined]
        return super().verdicts(statuses, now_s)


def _row(result: Any) -> list[tuple]:
    return [(e.ego_id, e.outcome, round(e.metrics.time_s, 3), round(e.metrics.overall_cost, 4))
            for e in result.egos]


def test_an_llm_coordinator_lets_both_through_and_its_log_replays(tmp_path: Path) -> None:
    log = tmp_path / "coordinator.jsonl"
    llm = RulesLlm()
    backend = Watching(llm, "llm:simulated", log_path=log)
    result, row = multi.run_one("narrow", 101, "lmpc-rules", "central", tmp_path / "a",
                                coordinator=CoordinatorCore(backend))
    assert result.ego_collisions == 0 and result.other_collisions == 0 and result.all_reached
    assert row["directives"] > 0 and row["directives_refused"] == 0
    assert llm.calls > 0 and not backend.errors
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(records) == llm.calls and all(r["source"] == "llm:simulated" for r in records)

    replay = ReplayCoordinator(log)
    again, row2 = multi.run_one("narrow", 101, "lmpc-rules", "central", tmp_path / "b",
                                coordinator=CoordinatorCore(replay))
    assert replay.misses == 0 and replay.name == "llm:simulated"
    assert _row(again) == _row(result) and row2["directives"] == row["directives"]


def test_an_unsafe_llm_is_refused_and_the_egos_fall_back(tmp_path: Path) -> None:
    def reckless(system: str, user: str, schema: dict[str, Any], deadline_s: float
                 ) -> BackendReply:
        ids = schema["properties"]["verdicts"]["items"]["properties"]["ego_id"]["enum"]
        return BackendReply(text=answer([(e, "proceed", k) for k, e in enumerate(ids)]),
                            latency_s=0.01)

    backend = LlmCoordinator(reckless, "llm:reckless")
    result, row = multi.run_one("narrow", 101, "lmpc-rules", "central", tmp_path,
                                coordinator=CoordinatorCore(backend))
    assert result.ego_collisions == 0 and result.other_collisions == 0 and result.all_reached
    assert backend.errors["invalid"] > 0 and "both proceed" in backend.last_error
    assert row["silent_steps"] > 0  # the distributed rule set took over


def test_the_backends_by_name(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown coordinator backend"):
        make_coordinator_backend("gpt")
    with pytest.raises(ValueError, match="needs the log"):
        make_coordinator_backend("replay")
    with pytest.raises(BackendError, match="holds no coordinator records"):
        (tmp_path / "empty.jsonl").write_text("not a record\n")
        make_coordinator_backend("replay", replay_log=tmp_path / "empty.jsonl")
    # the packaged openai settings point at api.openai.com, which needs a key
    import os

    saved = {k: os.environ.pop(k, None) for k in ("LMPC_OPENAI_API_KEY", "OPENAI_API_KEY",
                                                  "LMPC_OPENAI_BASE_URL")}
    try:
        with pytest.raises(BackendError, match="needs an API key"):
            make_coordinator_backend("openai")
    finally:
        os.environ.update({k: v for k, v in saved.items() if v is not None})


class PromptRecorder:
    """A SIMULATED LLM planner backend: the rules' answer; keeps every prompt."""

    name = "llm:recorder"
    reports_latency = False

    def __init__(self) -> None:
        from lmpc_llm_planner.backends.rules import RulesBackend

        self.rules = RulesBackend()
        self.prompts: list[str] = []

    def complete(self, request: Any) -> BackendReply:
        self.prompts.append(request.prompt)
        return self.rules.complete(request)


def test_an_llm_planner_reads_the_coordinators_command_in_its_prompt(tmp_path: Path) -> None:
    from lmpc_bridge.multi_episode import run_multi_episode
    from lmpc_bridge.multi_scene import ego_specs
    from lmpc_bridge.multi_sim import MultiSumoSim
    from lmpc_bridge.scenarios import build_scene
    from lmpc_llm_planner.config import load_planner_config
    from lmpc_llm_planner.planner import PlannerCore
    from lmpc_msgs_py.vocabulary import load_decision_space

    ids = [s.ego_id for s in ego_specs(build_scene("narrow", 101, work_dir=tmp_path))]
    egos, coordination = multi.wire("lmpc-rules", ids, "central")
    backends = {eid: PromptRecorder() for eid in ids}
    logs = {eid: tmp_path / f"{eid}.jsonl" for eid in ids}
    egos = {eid: dataclasses.replace(w, planner=PlannerCore(
        load_planner_config(), backends[eid], load_decision_space(), log_path=logs[eid]))
        for eid, w in egos.items()}
    result = run_multi_episode(MultiSumoSim(work_dir=tmp_path), family="narrow", seed=101,
                               egos=egos, coordination=coordination, max_time_s=120.0)
    assert result.ego_collisions == 0 and result.all_reached
    told = {eid: [p for p in b.prompts if "Coordinator's command" in p]
            for eid, b in backends.items()}
    assert any("yield at" in p for ps in told.values() for p in ps), "nobody was told to yield"
    assert any("proceed at" in p for ps in told.values() for p in ps)
    assert all(any("Coordinator's command" not in p for p in b.prompts)
               for b in backends.values())  # and without a command in force, no such line
    records = [json.loads(line) for eid in ids for line in logs[eid].read_text().splitlines()]
    assert {r["command"] is not None for r in records} == {True, False}


def test_replay_answers_a_changed_prompt_by_its_round_stamp(tmp_path: Path) -> None:
    """In the ROS graph a directive reaches its ego a step earlier or later from run to
    run, so a replayed round's statuses (and prompt) can differ from the recorded ones:
    ``hash_or_stamp`` answers with the round recorded at the same stamp on the same egos
    (validated against the statuses of now), ``hash`` stays silent."""
    log = tmp_path / "coordinator.jsonl"
    recorded = LlmCoordinator(lambda *a: BackendReply(text=answer(
        [("ego_1", "yield", 1), ("ego_2", "proceed", 0)]), latency_s=0.01), "llm:sim",
        log_path=log)
    egos = [st("ego_1", "AB_0", 60.0), st("ego_2", "BA_0", 40.0)]
    assert [v.command for v in recorded.verdicts(egos, 2.0)] == ["yield", "proceed"]
    moved = [st("ego_1", "AB_0", 58.0), st("ego_2", "BA_0", 41.0)]  # a step later
    by_stamp = ReplayCoordinator(log)
    assert [v.command for v in by_stamp.verdicts(moved, 2.0)] == ["yield", "proceed"]
    assert by_stamp.stamp_matches == 1 and by_stamp.misses == 0
    assert by_stamp.verdicts(moved, 3.0) == [] and by_stamp.misses == 1  # no round at 3 s
    strict = ReplayCoordinator(log, match="hash")
    assert strict.verdicts(moved, 2.0) == [] and strict.misses == 1
    assert [v.command for v in strict.verdicts(egos, 2.0)] == ["yield", "proceed"]
    # a recorded answer that is unsafe now is refused as any answer: silent
    committed_now = [st("ego_1", "AB_0", 2.0, v=10.0), st("ego_2", "BA_0", 41.0)]
    assert ReplayCoordinator(log).verdicts(committed_now, 2.0) == []
