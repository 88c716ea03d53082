"""PlannerCore: cadence, emergency pre-evaluation, re-ask and fallback, log, ids."""
from __future__ import annotations

import dataclasses
import json
import math
import time

import pytest
from lmpc_mpc import synthetic as syn

from lmpc_llm_planner.backends.base import BackendReply, DecisionRequest
from lmpc_llm_planner.backends.replay import ReplayBackend
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import PlannerConfig
from lmpc_llm_planner.planner import PlannerCore, emergency_check


def cfg_with(base: PlannerConfig, **kw) -> PlannerConfig:
    return PlannerConfig.model_validate({**base.model_dump(), **kw})


class Recording:
    """Wraps a backend (or a list of canned replies) and records the requests."""

    name = "llm:fake"

    def __init__(self, replies=None, *, raise_exc: bool = False, sleep_s: float = 0.0):
        self.replies = list(replies or [])
        self.raise_exc = raise_exc
        self.sleep_s = sleep_s
        self.requests: list[DecisionRequest] = []
        self.rules = RulesBackend()

    def complete(self, request: DecisionRequest) -> BackendReply:
        self.requests.append(request)
        if self.sleep_s:
            time.sleep(self.sleep_s)
        if self.raise_exc:
            raise ConnectionError("connection refused")
        if self.replies:
            return BackendReply(text=self.replies.pop(0), latency_s=0.0)
        return self.rules.complete(request)


def run(core: PlannerCore, map_, obs_factory, *, t_end_s: float, agents_at=lambda t: ()):
    out = []
    for k in range(int(round(t_end_s / 0.1)) + 1):
        t = k * 0.1
        d = core.on_observation(obs_factory(map_, ego_v_mps=0.0, stamp_s=t, seq=k,
                                            agents=agents_at(t)))
        if d is not None:
            out.append(d)
    return out


def test_cadence_every_period(left_turn_map, obs_factory, planner_config, mpc_config):
    core = PlannerCore(planner_config, RulesBackend(), mpc_config)
    ds = run(core, left_turn_map, obs_factory, t_end_s=10.0)
    assert [round(d.stamp_s, 3) for d in ds] == [0.0, 2.5, 5.0, 7.5, 10.0]
    assert all(d.mode == "normal" and d.source == "rules" for d in ds)
    assert len({d.decision_id for d in ds}) == len(ds)
    assert ds[1].decision_id == "2500-2"
    assert core.counters.decisions == 5 and core.counters.fallbacks == 0


def head_on(t_s: float):
    # A car in the ego's lane coming head-on, 20 m ahead at 10 m/s (TTC ~ 1.6 s).
    return [syn.agent("wrongway", x_m=1.6, y_m=-20.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                      lane_id="S_in_0")]


def test_emergency_trips_early_and_is_rate_limited(left_turn_map, obs_factory,
                                                   planner_config, mpc_config):
    core = PlannerCore(planner_config, RulesBackend(), mpc_config)
    ds = run(core, left_turn_map, obs_factory, t_end_s=2.0,
             agents_at=lambda t: head_on(t) if t >= 1.0 - 1e-9 else ())
    stamps = [round(d.stamp_s, 3) for d in ds]
    assert stamps == [0.0, 1.0, 1.5, 2.0]  # normal at 0, emergencies every 0.5 s from 1.0
    assert [d.mode for d in ds] == ["normal", "emergency", "emergency", "emergency"]
    assert mpc_config.bias_for(ds[1].accel_interval, ds[1].steer_interval)[0] < 0.0
    assert "wrongway" in ds[1].attention
    assert core.counters.emergencies == 3


def test_emergency_check_ignores_parallel_traffic(left_turn_map, obs_factory, planner_config,
                                                  oncoming_factory):
    passing = oncoming_factory("car1", y_m=-30.0, v_mps=10.0)  # adjacent opposite lane
    obs = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=10.0, agents=[passing])
    assert not emergency_check(obs, planner_config).tripped
    obs2 = obs_factory(left_turn_map, ego_y_m=-40.0, ego_v_mps=10.0, agents=head_on(0.0))
    check = emergency_check(obs2, planner_config)
    assert check.tripped and check.agent_id == "wrongway" and check.ttc_s < 2.0


def test_transport_error_retries_once_then_falls_back(left_turn_map, obs_factory,
                                                      planner_config, mpc_config, tmp_path):
    backend = Recording(raise_exc=True)
    log = tmp_path / "decisions.jsonl"
    core = PlannerCore(planner_config, backend, mpc_config, log_path=log)
    agents = [syn.agent("car1", x_m=-1.6, y_m=30.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                        lane_id="N_in_0")]
    d = core.on_observation(obs_factory(left_turn_map, agents=agents))
    assert len(backend.requests) == 2  # one call plus one re-ask
    assert d.source == "fallback"
    assert d.attention == ("car1",)  # baseline: every agent in range
    assert d.accel_interval == mpc_config.neutral_accel_index
    assert set(d.weights.model_dump().values()) == {"normal"}
    c = core.counters
    assert (c.fallbacks, c.retries, c.errors["transport"], c.backend_calls) == (1, 1, 2, 2)
    rec = json.loads(log.read_text().splitlines()[-1])
    assert rec["source"] == "fallback" and rec["error_kind"] == "transport"
    assert len(rec["attempts"]) == 2 and rec["attempts"][0]["prompt_sha256"]


def test_invalid_output_is_re_asked_with_the_error(left_turn_map, obs_factory,
                                                   planner_config, mpc_config):
    backend = Recording(["Sure, let me think about this junction..."])
    core = PlannerCore(planner_config, backend, mpc_config)
    d = core.on_observation(obs_factory(left_turn_map))
    assert d.source == "llm:fake"
    assert backend.requests[0].retry_error is None
    assert "prose" in backend.requests[1].retry_error
    assert "refused" in backend.requests[1].prompt
    assert core.counters.errors["prose"] == 1 and core.counters.fallbacks == 0


@pytest.mark.parametrize("bad", ["", "```json\n{}\n```", '{"reasoning": "x"}',
                                 '{"a": 1}{"b": 2}', "null", "[1, 2]", '{"reasoning": NaN}'])
def test_never_raises_on_garbage(left_turn_map, obs_factory, planner_config, mpc_config, bad):
    core = PlannerCore(planner_config, Recording([bad, bad]), mpc_config)
    d = core.on_observation(obs_factory(left_turn_map))
    assert d.source == "fallback"
    assert sum(core.counters.errors.values()) == 2


def test_timeout_discards_late_reply(left_turn_map, obs_factory, planner_config, mpc_config):
    cfg = cfg_with(planner_config, deadline_s=0.05, max_retries=0)
    # the call hangs 3 s: returning well before that shows the core did not wait for it,
    # with a margin that holds on a loaded machine (0.25 s of a 0.3 s call did not, load 13)
    core = PlannerCore(cfg, Recording(sleep_s=3.0), mpc_config)
    t0 = time.perf_counter()
    d = core.on_observation(obs_factory(left_turn_map))
    assert time.perf_counter() - t0 < 1.5  # did not wait for the hung call
    assert d.source == "fallback" and core.counters.errors["timeout"] == 1


def test_latency_measured_or_fixed(left_turn_map, obs_factory, planner_config, mpc_config):
    measured = PlannerCore(planner_config, Recording(sleep_s=0.05), mpc_config)
    d = measured.on_observation(obs_factory(left_turn_map))
    assert 0.05 <= d.latency_s < 2.0
    fixed = PlannerCore(cfg_with(planner_config, fixed_latency_s=1.7), RulesBackend(), mpc_config)
    d2 = fixed.on_observation(obs_factory(left_turn_map))
    assert d2.latency_s == 1.7 and d2.tokens_in > 100 and d2.tokens_out > 10


def test_chained_stages(left_turn_map, obs_factory, oncoming_factory, planner_config,
                        mpc_config):
    backend = Recording()
    chained = PlannerCore(cfg_with(planner_config, stages="chained"), backend, mpc_config)
    single = PlannerCore(planner_config, RulesBackend(), mpc_config)
    obs = obs_factory(left_turn_map, agents=[oncoming_factory("car1", y_m=30.0, v_mps=10.0)])
    a, b = chained.on_observation(obs), single.on_observation(obs)
    assert [r.stage for r in backend.requests] == [
        "scenario_encoding", "action_guidance", "weight_adjustment"]
    assert "scenario_encoding" in backend.requests[1].prior_stages
    keys = ("attention", "accel_interval", "steer_interval", "weights", "ego_trajectory")
    assert all(getattr(a, k) == getattr(b, k) for k in keys)


def test_instruction_goes_into_prompt_only(left_turn_map, obs_factory, planner_config,
                                           mpc_config):
    backend = Recording()
    core = PlannerCore(planner_config, backend, mpc_config)
    core.on_instruction("the right lane is closed ahead\x00\x1b[2J")
    core.on_observation(obs_factory(left_turn_map))
    prompt = backend.requests[0].prompt
    assert '"the right lane is closed ahead' in prompt
    assert "\x00" not in prompt and "\x1b" not in prompt


def test_time_going_backwards_restarts_schedule(left_turn_map, obs_factory, planner_config,
                                                mpc_config):
    core = PlannerCore(planner_config, RulesBackend(), mpc_config)
    assert core.on_observation(obs_factory(left_turn_map, stamp_s=5.0)) is not None
    assert core.on_observation(obs_factory(left_turn_map, stamp_s=5.1)) is None
    assert core.on_observation(obs_factory(left_turn_map, stamp_s=0.0)) is not None


def test_emergency_latency_is_honoured_separately(left_turn_map, obs_factory, planner_config,
                                                  mpc_config):
    """A simulated 2.5 s planner with the paper's short emergency path: normal decisions
    report 2.5 s, emergency ones 1.0 s, for the rules backend too (which reports 0
    otherwise); the TTL is raised so a decision outlives its successor's latency."""
    from lmpc_llm_planner.config import latency_overrides

    over = latency_overrides(2.5, 1.0, period_s=planner_config.period_s,
                             ttl_s=planner_config.ttl_s)
    assert over == {"fixed_latency_s": 2.5, "emergency_latency_s": 1.0}
    core = PlannerCore(cfg_with(planner_config, **over), RulesBackend(), mpc_config)
    ds = run(core, left_turn_map, obs_factory, t_end_s=2.0,
             agents_at=lambda t: head_on(t) if t >= 1.0 - 1e-9 else ())
    assert [(d.mode, d.latency_s) for d in ds] == [
        ("normal", 2.5), ("emergency", 1.0), ("emergency", 1.0), ("emergency", 1.0)]
    # without a simulated latency the rules reasoner is instant on both paths
    plain = run(PlannerCore(planner_config, RulesBackend(), mpc_config), left_turn_map,
                obs_factory, t_end_s=1.0, agents_at=lambda t: head_on(t) if t >= 1.0 - 1e-9
                else ())
    assert [(d.mode, d.latency_s) for d in plain] == [("normal", 0.0), ("emergency", 0.0)]
    # the emergency latency defaults to the paper's 1.5 s (or the normal one if shorter);
    # a 5 s latency keeps decisions in force until the next one takes effect
    assert latency_overrides(5.0, None, period_s=2.5, ttl_s=5.0) == {
        "fixed_latency_s": 5.0, "emergency_latency_s": 1.5, "ttl_s": 7.5}
    assert latency_overrides(1.0, None, period_s=2.5, ttl_s=5.0)["emergency_latency_s"] == 1.0
    with pytest.raises(ValueError, match="decision latency"):
        latency_overrides(-1.0, None, period_s=2.5, ttl_s=5.0)
    with pytest.raises(ValueError, match="expire before taking effect"):
        cfg_with(planner_config, fixed_latency_s=5.0)


def test_an_instruction_mid_episode_acts_from_the_next_decision_and_is_logged(
        left_turn_map, obs_factory, planner_config, mpc_config, tmp_path):
    """Issue 20 item 5: an instruction arriving at 3.0 s (between the 2.5 s and 5 s
    decisions) changes nothing before and shapes the 5 s decision (the rules' careful
    driving note and a larger safety weight); each decision's log record names the text
    in force."""
    log = tmp_path / "decisions.jsonl"
    core = PlannerCore(planner_config, RulesBackend(), mpc_config, log_path=log)
    plain = PlannerCore(planner_config, RulesBackend(), mpc_config)
    ds, ps = [], []
    for k in range(81):
        t = k * 0.1
        if k == 30:
            core.on_instruction("Please drive conservatively.")
        obs = obs_factory(left_turn_map, ego_v_mps=8.0, stamp_s=t, seq=k)
        for c, out in ((core, ds), (plain, ps)):
            d = c.on_observation(obs)
            if d is not None:
                out.append(d)
    assert [round(d.stamp_s, 3) for d in ds] == [0.0, 2.5, 5.0, 7.5]
    careful = "careful driving"
    assert [careful in d.reasoning for d in ds] == [False, False, True, True]
    assert [d.reasoning for d in ds[:2]] == [p.reasoning for p in ps[:2]]
    assert ds[2].weights != ps[2].weights  # the text changed the decision, not only words
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["instruction"] for r in records] == [
        None, None, "Please drive conservatively.", "Please drive conservatively."]


def test_cadence_config_sets_the_period_the_rules_replan_and_keeps_the_ttl_slack(
        tmp_path):
    """``--planning-period`` (issue 16 item 6): the period, the rules' assumed time to the
    next decision and a TTL keeping the file's slack over its period; other settings kept."""
    from lmpc_llm_planner.config import (
        PlannerConfigError, cadence_config, load_planner_config)

    slow = cadence_config(5.0)
    assert (slow["period_s"], slow["ttl_s"], slow["rules"]["replan_s"]) == (5.0, 7.5, 5.0)
    packaged = load_planner_config()
    assert slow["rules"]["safe_gap_s"] == packaged.rules.safe_gap_s
    fast = load_planner_config(overrides=cadence_config(1.0))
    assert (fast.period_s, fast.ttl_s, fast.rules.replan_s) == (1.0, 5.0, 1.0)
    own = tmp_path / "own.yaml"
    own.write_text("period_s: 2.0\nttl_s: 3.0\n")  # slack 1 s over its own period
    assert cadence_config(4.0, own)["ttl_s"] == 5.0
    for bad in (0.0, -1.0, 61.0):
        with pytest.raises(PlannerConfigError, match="planning period must be within"):
            cadence_config(bad)


def test_decide_for_effect_time_predicts_by_the_expected_latency(
        left_turn_map, obs_factory, planner_config, mpc_config):
    """``decide_for_effect_time`` (issue 23; off by default): the scene is the observation
    predicted by the latency the decision is expected to get - the declared one (normal /
    emergency), else the median of the last decisions'; off: 0."""
    off = PlannerCore(cfg_with(planner_config, fixed_latency_s=2.5), RulesBackend(), mpc_config)
    assert off.expected_latency_s("normal") == 0.0
    on = cfg_with(planner_config, decide_for_effect_time=True, fixed_latency_s=2.5,
                  emergency_latency_s=1.5)
    backend = Recording()
    core = PlannerCore(on, backend, mpc_config)
    assert (core.expected_latency_s("normal"), core.expected_latency_s("emergency")) == \
        (2.5, 1.5)
    obs = obs_factory(left_turn_map, ego_v_mps=8.0)
    core.on_observation(obs)
    seen = backend.requests[-1].scene.obs.ego
    # the ego seen by the backend is 2.5 s further along its route at 8 m/s (a = 0)
    assert math.hypot(seen.x_m - obs.ego.x_m, seen.y_m - obs.ego.y_m) == \
        pytest.approx(20.0, abs=0.5)
    assert seen.stamp_s == obs.ego.stamp_s
    measured = PlannerCore(cfg_with(planner_config, decide_for_effect_time=True),
                           Recording(sleep_s=0.02), mpc_config)
    assert measured.expected_latency_s("normal") == 0.0  # nothing measured yet
    measured.on_observation(obs)
    assert 0.02 <= measured.expected_latency_s("normal") < 2.0


def test_every_request_carries_the_latency_the_planner_expects(
        left_turn_map, obs_factory, planner_config, mpc_config):
    """``DecisionRequest.expected_latency_s`` (the rules' fast ring approach needs a
    decision in force at once): the declared latency whether or not the planner decides
    for the effect time, the rules' own 0, None before an undeclared backend's first reply,
    then the median of its measured latencies."""
    obs = obs_factory(left_turn_map, ego_v_mps=8.0)
    for cfg, expected in ((planner_config, 0.0),
                          (cfg_with(planner_config, fixed_latency_s=2.5), 2.5)):
        backend = Recording()
        backend.reported_latency_s = 0.0  # a simulated reasoner declares its latency (rules)
        PlannerCore(cfg, backend, mpc_config).on_observation(obs)
        assert backend.requests[-1].expected_latency_s == expected
    measured = Recording(sleep_s=0.02)
    core = PlannerCore(planner_config, measured, mpc_config)
    core.on_observation(obs)
    assert measured.requests[-1].expected_latency_s is None  # an LLM's first decision
    core.on_observation(obs_factory(left_turn_map, ego_v_mps=8.0, stamp_s=2.5, seq=1))
    assert 0.02 <= measured.requests[-1].expected_latency_s < 2.0


class Revisiting:
    """The rules, asking to be asked again after 0.5 s while the sim time is below 2 s."""

    name = "rules"
    reported_latency_s = 0.0

    def __init__(self) -> None:
        self.rules = RulesBackend()

    def complete(self, request: DecisionRequest) -> BackendReply:
        reply = self.rules.complete(request)
        soon = request.scene.obs.stamp_s < 2.0 - 1e-9
        return dataclasses.replace(reply, revisit_s=0.5 if soon else None)


def test_a_backend_may_ask_to_be_asked_again_sooner_and_a_replay_repeats_it(
        left_turn_map, obs_factory, planner_config, mpc_config, tmp_path):
    """``BackendReply.revisit_s`` (the rules approaching a roundabout) shortens the time
    to the next request below ``period_s``; without it the period is back. The log keeps
    it, so a replayed run requests at the same instants with the same answers."""
    log = tmp_path / "decisions.jsonl"
    core = PlannerCore(planner_config, Revisiting(), mpc_config, log_path=log)
    ds = run(core, left_turn_map, obs_factory, t_end_s=7.0)
    stamps = [round(d.stamp_s, 3) for d in ds]
    assert stamps == [0.0, 0.5, 1.0, 1.5, 2.0, 4.5, 7.0]
    assert [json.loads(line)["attempts"][0]["revisit_s"] for line in log.read_text()
            .splitlines()] == [0.5, 0.5, 0.5, 0.5, None, None, None]
    replay_cfg = cfg_with(planner_config, backend="replay",
                          replay={"log_path": str(log), "latency": "report"})
    replayed = run(PlannerCore(replay_cfg, ReplayBackend.from_config(replay_cfg.replay),
                               mpc_config), left_turn_map, obs_factory, t_end_s=7.0)
    assert [d.model_dump(exclude={"source"}) for d in replayed] == \
        [d.model_dump(exclude={"source"}) for d in ds]
    # a fallback (no backend answer) goes back to the period
    core = PlannerCore(planner_config, Recording(["prose"] * 10), mpc_config)
    core._revisit_s = 0.5
    ds = run(core, left_turn_map, obs_factory, t_end_s=3.0)
    assert [round(d.stamp_s, 3) for d in ds] == [0.0, 2.5]
