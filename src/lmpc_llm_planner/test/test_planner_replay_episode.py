"""A replayed run repeats an LLM run exactly: an in-process SUMO episode (usi seed 0) with
a simulated LLM whose calls report 1.7 s of latency (one answer is prose and re-asked),
then the same episode with ``replay`` (``latency: report``) from its decision log: the
same decisions (latency included, so each takes effect at the same sim time), the same
controls, the same metrics.

The "LLM" is SIMULATED: the rules reasoner's answer with a reported latency, so the test
needs no model and no network and runs at SUMO + MPC speed.
"""
from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from lmpc_mpc.config import load_mpc_config
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.backends.replay import ReplayBackend, load_replay_log
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import ReplayConfig, load_planner_config
from lmpc_llm_planner.planner import PlannerCore

LATENCY_S = 1.7
MAX_TIME_S = 15.0
runner = pytest.importorskip("lmpc_bridge.runner", reason="needs lmpc_bridge (SUMO)")
sim_mod = pytest.importorskip("lmpc_bridge.sim", reason="needs lmpc_bridge (SUMO)")


class SimulatedLlm:
    """Rules answers reported as taking ``LATENCY_S`` each; call 3 answers prose."""

    name = "llm:simulated"
    reports_latency = True

    def __init__(self) -> None:
        self.rules = RulesBackend()
        self.calls = 0

    def complete(self, request: DecisionRequest) -> BackendReply:
        self.calls += 1
        if self.calls == 3:
            return BackendReply(text="I would rather wait here.", latency_s=LATENCY_S)
        text = self.rules.complete(request).text
        return BackendReply(text=text, latency_s=LATENCY_S, tokens_in=900, tokens_out=120)


class Recorder:
    """Passes observations to the core and keeps its decisions."""

    def __init__(self, core: PlannerCore) -> None:
        self.core = core
        self.decisions: list[Any] = []

    def on_observation(self, obs: Any) -> Any:
        decision = self.core.on_observation(obs)
        if decision is not None:
            self.decisions.append(decision)
        return decision


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    s = sim_mod.SumoSim(work_dir=tmp_path_factory.mktemp("replay_episode"))
    yield s
    s.close()


def _episode(sim: Any, core: PlannerCore) -> tuple[Any, list[Any]]:
    from lmpc_mpc.controller import MpcController
    from lmpc_mpc.solver import MpcSolver

    config = load_mpc_config()
    solver = MpcSolver(config)  # fresh: no warm start carried over between the runs
    planner = Recorder(core)
    result = runner.run_episode(sim, family="usi", seed=0, planner=planner,
                                controller=MpcController(config, solver=solver),
                                max_time_s=MAX_TIME_S)
    return result, planner.decisions


def _controls(result: Any) -> list[tuple]:
    return [(s.step, s.decision_id, s.control_accel_mps2, s.control_steer_rad, s.x_m, s.y_m,
             s.v_mps, s.control_mode) for s in result.record.steps]


@pytest.mark.parametrize("instruction", [None, "drive aggressively"])
def test_replayed_run_repeats_the_llm_run_exactly(sim: Any, tmp_path: Path,
                                                  instruction: str | None) -> None:
    """Also with the user's instruction (issue 20 item 4): it is part of every prompt,
    so the replay, given the same text, finds every call by its hash."""
    log = tmp_path / "decisions.jsonl"
    cfg = load_planner_config()
    llm = PlannerCore(cfg, SimulatedLlm(), load_decision_space(), log_path=log)
    if instruction:
        llm.on_instruction(instruction)
    first, first_decisions = _episode(sim, llm)
    assert len(first_decisions) >= 4
    assert {d.latency_s for d in first_decisions} == {LATENCY_S, 2 * LATENCY_S}  # re-ask
    assert llm.counters.errors["prose"] == 1
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert records and {r.get("instruction") for r in records} == {instruction}

    replay_backend = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report"))
    replay = PlannerCore(cfg, replay_backend, load_decision_space())
    if instruction:
        replay.on_instruction(instruction)
    second, second_decisions = _episode(sim, replay)

    assert replay_backend.hits["miss"] == 0 and replay_backend.name == "llm:simulated"
    assert set(replay_backend.hits) == {"hash"}  # every prompt exactly as recorded
    assert [d.model_dump() for d in second_decisions] == [
        d.model_dump() for d in first_decisions]
    assert _controls(second) == _controls(first)
    assert second.outcome == first.outcome
    assert second.metrics == first.metrics
