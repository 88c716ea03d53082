"""``lmpc-oracle`` (scripts/method_oracle.py, docs/ORACLE.md): its options, its score, its
determinism, and that it does not do worse than the MPC baseline where a better option
is known."""
from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from lmpc_bridge.episode import Episode
from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision
from lmpc_llm_planner.planner import build_request
from lmpc_scripts import method_oracle as mo
from lmpc_scripts import methods


def _first_scene(tmp_path: Path, family: str, seed: int):
    sim = SumoSim(work_dir=tmp_path / "scenes")
    try:
        obs = sim.reset(family, seed)
    finally:
        sim.close()
    return obs, build_scene(obs, lookahead_m=60.0, max_agents=20)


def _options(scene, planner, **kw):
    cfg = planner.space
    return mo.decision_options(
        scene, accel_intervals=cfg.accel_intervals_mps2, steer_intervals=cfg.steer_intervals_rad,
        neutral_accel=cfg.neutral_accel_index, neutral_steer=cfg.neutral_steer_index, **kw)


def test_the_options_are_bounded_named_once_and_start_with_no_decision(tmp_path: Path) -> None:
    obs, scene = _first_scene(tmp_path, "usi", 100)
    planner = methods.make_planner("lmpc-rules")
    req = build_request(scene, config=planner.config, space=planner.space)
    rules = parse_decision(planner.backend.complete(req).text, request=req).wire
    opts = _options(scene, planner, rules=rules)
    names = [o.name for o in opts]
    assert names[:2] == ["none", "rules"] and opts[0].wire is None and opts[1].wire is rules
    assert len(set(names)) == len(names) <= 32
    n_accel = len(planner.space.accel_intervals_mps2)
    assert {f"route/a{a}" for a in range(n_accel)} <= set(names)
    used = {o.wire.scenario_encoding.ego_trajectory for o in opts[1:]}
    assert not used & set(scene.leaving_ids)
    # every option is a valid answer to the request the rules reasoner got
    for o in opts[1:]:
        assert parse_decision(o.wire.model_dump_json(), request=req).success, o.name
    assert [o.name for o in _options(scene, planner, rules=rules, max_options=3)] == names[:3]
    # the rules' attention and predictions, or the baseline's (every offered agent)
    base = _options(scene, planner, rules=rules)[2].wire.scenario_encoding
    assert base.attention == list(scene.agent_ids)
    ruled = _options(scene, planner, rules=rules, encoding="rules")[2].wire.scenario_encoding
    assert ruled.attention == rules.scenario_encoding.attention


def test_the_window_score_prices_time_distance_and_penalties_and_a_collision_is_inf() -> None:
    def steps(n, gap=100.0):
        near = (SimpleNamespace(v_max_mps=10.0, v_mps=10.0, affected=False, at_red_light=False,
                                a_mps2=0.0, gap_m=gap),)
        return [SimpleNamespace(t_s=1.0 + 0.1 * k, nearby=near) for k in range(1, n + 1)]

    kw = dict(start_s=1.0, route_speed=10.0, episode_steps=100.0)
    far = mo.window_score(steps(80), outcome="running", end_dist_m=50.0, **kw)
    near = mo.window_score(steps(80), outcome="running", end_dist_m=20.0, **kw)
    assert near < far and far - near == pytest.approx(1.5 * 3.0)
    reached = mo.window_score(steps(40), outcome="reached", end_dist_m=0.0, **kw)
    assert reached == pytest.approx(1.5 * 4.0)
    close = mo.window_score(steps(80, gap=5.0), outcome="running", end_dist_m=20.0, **kw)
    assert close == pytest.approx(near + 80 * 20.0 * 5.0 / 100.0)
    assert math.isinf(mo.window_score(steps(10), outcome="collision", end_dist_m=0.0, **kw))
    assert math.isinf(mo.window_score(steps(10), outcome="off_route", end_dist_m=0.0, **kw))


def test_the_episode_score_is_the_o_c_the_episode_would_end_with() -> None:
    near = (SimpleNamespace(v_max_mps=10.0, v_mps=10.0, affected=False, at_red_light=False,
                            a_mps2=0.0, gap_m=5.0),)
    steps = [SimpleNamespace(t_s=10.0 + 0.1 * k, nearby=near) for k in range(1, 81)]
    kw = dict(start_s=10.0, route_speed=10.0, before_penalty=300.0, before_steps=100,
              dt_s=0.1)
    # 10 s before, 8 s in the window, 40 m to go at 10 m/s: 22 s, 220 steps
    score = mo.episode_score(steps, outcome="running", end_dist_m=40.0, **kw)
    assert score == pytest.approx((300.0 + 80 * 20.0 * 5.0) / 220.0 + 1.5 * 22.0)
    reached = mo.episode_score(steps[:40], outcome="reached", end_dist_m=0.0, **kw)
    assert reached == pytest.approx((300.0 + 40 * 100.0) / 140.0 + 1.5 * 14.0)
    assert math.isinf(mo.episode_score(steps, outcome="collision", end_dist_m=0.0, **kw))


def test_bad_oracle_settings_are_refused_in_one_line() -> None:
    with pytest.raises(ValueError, match="max_options"):
        mo.OracleConfig(max_options=0)
    with pytest.raises(ValueError, match="encoding"):
        mo.OracleConfig(encoding="llm")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="scoring"):
        mo.OracleConfig(scoring="best")  # type: ignore[arg-type]


def _oracle_run(tmp_path: Path, family: str, seed: int, config: mo.OracleConfig,
                max_time_s: float, tag: str):
    log = tmp_path / f"{tag}.jsonl"
    sim = SumoSim(work_dir=tmp_path / "scenes")
    wiring = mo.build(SceneSpec("lmpc-oracle", family, seed, log_path=log), config)
    try:
        result = run_episode(sim, family=family, seed=seed, controller=wiring.controller,
                             planner=wiring.planner, max_time_s=max_time_s)
    finally:
        sim.close()
    records = [json.loads(line) for line in log.read_text().splitlines()]
    for r in records:
        r.pop("wall_s", None)
    return result, records, wiring.planner


def test_the_oracle_is_deterministic_and_applies_the_best_scored_option(tmp_path: Path) -> None:
    config = mo.OracleConfig(lookahead_s=3.0, max_options=5)
    a, log_a, planner = _oracle_run(tmp_path, "usi", 100, config, 8.0, "a")
    b, log_b, _ = _oracle_run(tmp_path, "usi", 100, config, 8.0, "b")
    assert [s.model_dump(exclude={"solve_time_ms"}) for s in a.record.steps] == \
        [s.model_dump(exclude={"solve_time_ms"}) for s in b.record.steps]
    assert log_a == log_b and len(log_a) >= 3
    for rec in log_a:
        scores = {k: (math.inf if v is None else v) for k, v in rec["scores"].items()}
        assert len(scores) <= 5 and list(scores)[0] == "none"
        best = min(scores.values())
        # the chosen option is the first of the best-scored ones
        assert rec["chosen"] == next(k for k, v in scores.items() if v == best)
        assert ("decision" in rec) == (rec["chosen"] != "none")
    assert len(planner.wall_s) == len(log_a)


def test_a_rollout_leaves_the_episode_where_it_was(tmp_path: Path) -> None:
    """The oracle's rollouts branch the episode it is asked in: after its decision the
    episode goes on from the very state it was in (the baseline's next control)."""
    sim = SumoSim(work_dir=tmp_path / "scenes")
    plain = methods.build(SceneSpec("mpc", "usi", 100))
    oracle = mo.build(SceneSpec("lmpc-oracle", "usi", 100),
                      mo.OracleConfig(lookahead_s=2.0, max_options=3))
    try:
        ep = Episode(sim, family="usi", seed=100, controller=plain.controller)
        ep.start()
        ep.run(until_s=3.0)
        before = sim.record().steps
        ep.planner = oracle.planner
        oracle.planner.attach_episode(ep)
        obs = ep.begin_step()
        pending = ep.pending
        oracle.planner.on_observation(obs)
        assert ep.pending is not None and ep.pending[1] == pending[1]
        assert sim.record().steps == before and sim.time_s == pytest.approx(3.0)
    finally:
        sim.close()


def test_the_oracle_does_not_do_worse_than_mpc_where_a_better_option_is_known(
        tmp_path: Path) -> None:
    """usi seed 100 (development): the MPC alone waits for the oncoming cars and reaches
    the target at 13.6 s; speeding up through the gap (acceleration interval 5 early on)
    reaches it sooner. The oracle, 12 s lookahead, the first 8 options (none, rules, the
    route candidate with each acceleration interval), finds it."""
    sim = SumoSim(work_dir=tmp_path / "scenes")
    base = methods.build(SceneSpec("mpc", "usi", 100))
    try:
        mpc = run_episode(sim, family="usi", seed=100, controller=base.controller)
    finally:
        sim.close()
    oracle, log, _ = _oracle_run(tmp_path, "usi", 100,
                                 mo.OracleConfig(lookahead_s=12.0, max_options=8), 200.0, "o")
    assert mpc.outcome == oracle.outcome == "reached"
    assert oracle.metrics.overall_cost <= mpc.metrics.overall_cost
    assert oracle.metrics.time_s < mpc.metrics.time_s
    assert any(r["chosen"] != "none" for r in log)


def test_with_the_rules_continuation_the_rules_option_is_the_rules_planners_own_run(
        tmp_path: Path) -> None:
    """``continuation="rules"``: after an option the rules reasoner decides on in its
    rollout, so the ``rules`` option's rollout is exactly the ``lmpc-rules`` run over the
    window (eoa seed 100, development: the swerve round the stopped car takes several
    decisions), and ``none`` stays the MPC baseline."""
    config = mo.OracleConfig(lookahead_s=6.0, max_options=2, continuation="rules")
    sim = SumoSim(work_dir=tmp_path / "scenes")
    log = tmp_path / "o.jsonl"
    oracle = mo.build(SceneSpec("lmpc-oracle", "eoa", 100, log_path=log), config)
    try:
        ep = Episode(sim, family="eoa", seed=100, controller=oracle.controller,
                     planner=oracle.planner)
        ep.start()
        ep.ask(oracle.planner, ep.begin_step())
        scores = json.loads(log.read_text().splitlines()[0])["scores"]
        windows = {}
        for method in ("lmpc-rules", "mpc"):
            w = methods.build(SceneSpec(method, "eoa", 100))
            ep = Episode(sim, family="eoa", seed=100, controller=w.controller, planner=w.planner)
            ep.start()
            obs = ep.begin_step()
            pricing = mo.Pricing.at(ep, sim, obs, config)
            ep.end_step(None if w.planner is None else ep.ask(w.planner, obs))
            ep.run(until_s=config.lookahead_s)
            windows[method] = mo.window_score(
                sim.record().steps, outcome=sim.outcome, start_s=0.0,
                end_dist_m=sim.observe().ego.dist_to_target_m, route_speed=pricing.speed,
                episode_steps=pricing.episode_steps)
    finally:
        sim.close()
    assert scores["rules"] == pytest.approx(windows["lmpc-rules"], abs=1e-5)
    assert scores["none"] == pytest.approx(windows["mpc"], abs=1e-5)
    assert abs(scores["rules"] - scores["none"]) > 1.0  # the two policies differ here


def test_oracle_options_are_checked_by_name_and_value() -> None:
    cfg = mo.OracleConfig.from_options((("lookahead_s", "16"), ("continuation", "rules")))
    assert cfg.lookahead_s == 16.0 and cfg.continuation == "rules"
    with pytest.raises(ValueError, match="no option 'horizon'"):
        mo.OracleConfig.from_options((("horizon", 3),))
    with pytest.raises(ValueError, match="continuation"):
        mo.OracleConfig.from_options((("continuation", "llm"),))
    with pytest.raises(ValueError, match="lookahead_s"):
        mo.OracleConfig.from_options((("lookahead_s", "-1"),))


def test_the_benchmark_passes_the_oracle_options_and_refuses_them_without_the_oracle(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lmpc_scripts import benchmark

    with pytest.raises(SystemExit):
        benchmark.main(["--families", "usi", "--seeds", "100", "--methods", "mpc",
                        "--oracle-lookahead-s", "16", "--out", str(tmp_path / "a")])
    assert "need --methods lmpc-oracle" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        benchmark.main(["--families", "usi", "--seeds", "100", "--methods", "lmpc-oracle",
                        "--oracle-lookahead-s", "0", "--out", str(tmp_path / "b")])
    assert "lookahead_s must be > 0" in capsys.readouterr().err
    given = SimpleNamespace(oracle_lookahead_s=None, oracle_continuation="rules")
    assert benchmark.oracle_options(given) == (("continuation", "rules"),)
