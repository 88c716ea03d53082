"""The ``replay`` backend: record decisions through PlannerCore's log, replay them."""
from __future__ import annotations

import json
import math
import time

import pytest
from lmpc_mpc import synthetic as syn

from lmpc_llm_planner.backends import BackendError, make_backend
from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.backends.replay import ReplayBackend, load_replay_log
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import PlannerConfig, ReplayConfig
from lmpc_llm_planner.planner import PlannerCore

SLEEP_S = 0.06


class ScriptedLlm:
    """Stands in for an LLM: rules answers after ``SLEEP_S``, with scripted faults by call
    number (prose, a connection error) so re-asks and fallbacks are recorded too."""

    name = "llm:fake-7b"

    def __init__(self, faults: dict[int, str]) -> None:
        self.faults = faults
        self.calls = 0
        self.rules = RulesBackend()

    def complete(self, request: DecisionRequest) -> BackendReply:
        self.calls += 1
        time.sleep(SLEEP_S)
        fault = self.faults.get(self.calls)
        if fault == "prose":
            return BackendReply(text="Let me think about it.", latency_s=SLEEP_S,
                                tokens_in=900, tokens_out=7)
        if fault == "transport":
            return BackendReply(text=None, latency_s=SLEEP_S, error_kind="transport",
                                error="ConnectionResetError")
        reply = self.rules.complete(request)
        return BackendReply(text=reply.text, latency_s=SLEEP_S, tokens_in=1000 + self.calls,
                            tokens_out=80)


def cfg_with(base: PlannerConfig, **kw) -> PlannerConfig:
    return PlannerConfig.model_validate({**base.model_dump(), **kw})


def observations(map_, obs_factory, t_end_s: float = 5.0, offset_s: float = 0.0):
    """The scene every 0.1 s; ``offset_s`` shifts the stamps (the same situations)."""
    out = []
    for k in range(int(round(t_end_s / 0.1)) + 1):
        t = k * 0.1
        car = syn.agent("car1", x_m=-1.6, y_m=40.0 - 10.0 * t, yaw_rad=-math.pi / 2,
                        v_mps=10.0, lane_id="N_in_0")
        out.append(obs_factory(map_, ego_y_m=-40.0 + 6.0 * t, ego_v_mps=6.0,
                               stamp_s=round(t + offset_s, 3), seq=k, agents=[car]))
    return out


def drive(core: PlannerCore, obs_list, instruction=None):
    if instruction:
        core.on_instruction(instruction)
    return [d for d in (core.on_observation(o) for o in obs_list) if d is not None]


@pytest.fixture
def recorded(left_turn_map, obs_factory, planner_config, mpc_config, tmp_path):
    """A recorded run of 3 decisions: call 2 is prose (re-asked), calls 4 and 5 fail
    (fallback)."""
    log = tmp_path / "decisions.jsonl"
    obs_list = observations(left_turn_map, obs_factory)
    core = PlannerCore(planner_config, ScriptedLlm({2: "prose", 4: "transport",
                                                    5: "transport"}), mpc_config,
                       log_path=log)
    decisions = drive(core, obs_list)
    assert [d.source for d in decisions] == ["llm:fake-7b", "llm:fake-7b", "fallback"]
    return log, obs_list, decisions


def strip_latency(d):
    return d.model_dump(exclude={"latency_s"})


def test_sleep_mode_repeats_decisions_and_about_the_latency(recorded, planner_config,
                                                            mpc_config):
    log, obs_list, original = recorded
    cfg = cfg_with(planner_config, backend="replay",
                   replay={"log_path": str(log), "latency": "sleep"})
    backend = make_backend(cfg)
    assert isinstance(backend, ReplayBackend) and backend.name == "llm:fake-7b"
    core = PlannerCore(cfg, backend, mpc_config)
    replayed = drive(core, obs_list)
    assert [strip_latency(d) for d in replayed] == [strip_latency(d) for d in original]
    records = [json.loads(line) for line in log.read_text().splitlines()]
    for a, b, rec in zip(original, replayed, records, strict=True):
        # Each call slept its recorded time: at least their sum; about the recorded
        # latency (APPROXIMATE: scheduling and prompt building add milliseconds).
        assert b.latency_s >= sum(att["latency_s"] for att in rec["attempts"])
        assert b.latency_s == pytest.approx(a.latency_s, abs=0.25)
    assert core.counters.errors == {"prose": 1, "transport": 2}
    assert backend.hits == {"hash": 5}


def test_report_mode_answers_at_once_with_the_recorded_latency(recorded, planner_config,
                                                               mpc_config, monkeypatch):
    log, obs_list, original = recorded
    backend = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report"))

    def no_sleep(_s: float) -> None:
        raise AssertionError("report mode must not sleep")

    monkeypatch.setattr("lmpc_llm_planner.backends.replay.time.sleep", no_sleep)
    core = PlannerCore(planner_config, backend, mpc_config)
    replayed = drive(core, obs_list)
    # PlannerCore takes a reports_latency backend's latencies: the decisions are identical,
    # latency included (they take effect at the same sim time as the recorded ones).
    assert [d.model_dump() for d in replayed] == [d.model_dump() for d in original]
    assert all(d.latency_s >= SLEEP_S for d in replayed)


def test_report_mode_latencies_sum_to_the_recorded_one(recorded, planner_config, mpc_config):
    log, obs_list, original = recorded
    backend = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report"))
    assert backend.reports_latency
    core = PlannerCore(planner_config, backend, mpc_config)
    served = []
    real = backend.complete
    backend.complete = lambda req: served.append(real(req)) or served[-1]
    drive(core, obs_list)
    per_decision = [served[0:1], served[1:3], served[3:5]]  # calls: 1, prose + re-ask, 2 failed
    assert [sum(r.latency_s for r in calls) for calls in per_decision] == [
        d.latency_s for d in original]  # exactly, for a planner that takes reported latency


def test_replay_source_instead_of_recorded_one(recorded, planner_config, mpc_config):
    log, obs_list, original = recorded
    backend = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report",
                                                               keep_source=False))
    assert backend.name == "replay"
    replayed = drive(PlannerCore(planner_config, backend, mpc_config), obs_list)
    keys = ("decision_id", "attention", "accel_interval", "steer_interval", "weights",
            "ego_trajectory", "reasoning")
    for a, b in zip(original, replayed, strict=True):
        assert all(getattr(a, k) == getattr(b, k) for k in keys)
        assert b.source == ("fallback" if a.source == "fallback" else "replay")
    # The prompts quote the previous decision's source: after the first decision they
    # differ from the recorded ones and are matched by stamp.
    assert backend.hits == {"hash": 1, "stamp": 4}


def test_changed_prompt_matches_by_stamp_or_misses(recorded, planner_config, mpc_config):
    log, obs_list, original = recorded
    # An instruction changes every prompt: no hash matches any more.
    by_stamp = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report"))
    replayed = drive(PlannerCore(planner_config, by_stamp, mpc_config), obs_list,
                     instruction="please hurry")
    assert by_stamp.hits == {"stamp": 5}
    assert [d.accel_interval for d in replayed] == [d.accel_interval for d in original]
    hash_only = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report",
                                                                 match="hash"))
    core = PlannerCore(planner_config, hash_only, mpc_config)
    missed = drive(core, obs_list, instruction="please hurry")
    assert all(d.source == "fallback" for d in missed)
    assert core.counters.errors["transport"] == 2 * len(missed)
    reply = hash_only.complete(core_request(core, obs_list[0], instruction="please hurry"))
    assert reply.error_kind == "transport" and "no recorded answer for stamp 0.000" in reply.error


def test_shifted_stamps_match_within_the_window_only(recorded, left_turn_map, obs_factory,
                                                     planner_config, mpc_config):
    """The same situations 0.2 s later (in the ROS graph a request can move by a step or
    two): exact stamps miss them; a 0.5 s window answers each with the nearest call."""
    log, _, original = recorded
    shifted = observations(left_turn_map, obs_factory, offset_s=0.2)
    exact = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report"))
    missed = drive(PlannerCore(planner_config, exact, mpc_config), shifted,
                   instruction="please hurry")
    assert exact.hits["miss"] > 0 and all(d.source == "fallback" for d in missed)
    near = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report",
                                                            stamp_window_s=0.5))
    replayed = drive(PlannerCore(planner_config, near, mpc_config), shifted,
                     instruction="please hurry")
    assert near.hits == {"near": 5}
    assert [d.accel_interval for d in replayed] == [d.accel_interval for d in original]
    assert [d.source for d in replayed] == [d.source for d in original]


def core_request(core: PlannerCore, obs, **kw):
    from lmpc_llm_planner.planner import build_request
    from lmpc_llm_planner.scene import build_scene

    scene = build_scene(obs, lookahead_m=core.config.lookahead_m,
                        max_agents=core.config.max_agents_in_prompt)
    return build_request(scene, config=core.config, space=core.space, **kw)


def test_same_prompt_again_gets_the_same_answer(recorded, planner_config, mpc_config):
    log, obs_list, _ = recorded
    backend = ReplayBackend(load_replay_log(log), ReplayConfig(latency="report",
                                                               match="hash"))
    core = PlannerCore(planner_config, backend, mpc_config)
    req = core_request(core, obs_list[0])
    first, second = backend.complete(req), backend.complete(req)
    assert first.ok and first.text == second.text
    assert backend.hits == {"hash": 1, "repeat": 1}


def test_bad_logs_are_refused_with_a_clear_error(tmp_path, planner_config):
    with pytest.raises(BackendError, match="set replay.log_path"):
        make_backend(cfg_with(planner_config, backend="replay"))
    with pytest.raises(BackendError, match="cannot read decision log"):
        load_replay_log(tmp_path / "missing.jsonl")
    junk = tmp_path / "junk.jsonl"
    junk.write_text('not json\n{"stamp_s": 0, "mode": "normal", "error_kind": "scene"}\n')
    with pytest.raises(BackendError, match="no recorded backend call"):
        load_replay_log(junk)


def test_broken_lines_are_skipped(recorded):
    log, _, _ = recorded
    lines = log.read_text().splitlines()
    log.write_text("\n".join(["{broken", lines[1], "", json.dumps({"attempts": 3})]) + "\n")
    loaded = load_replay_log(log)
    assert loaded.skipped_lines == 3 and len(loaded.calls) == 2  # prose + its re-ask
