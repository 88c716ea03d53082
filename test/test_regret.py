"""scripts/regret.py (docs/ORACLE.md, "Regret"): the regret of the oracle's own decisions
is 0, and a two-scene lmpc-rules run gives one sane row per decision."""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import tempfile
from pathlib import Path

import pytest

from lmpc_bridge.evaluation.rows import write_rows
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import benchmark, methods, regret
from lmpc_scripts import method_oracle as mo

SMALL = mo.OracleConfig(lookahead_s=3.0, max_options=8)
"""A smaller search than the default, to keep the tests short (the regret uses the same)."""
SMALLER = mo.OracleConfig(lookahead_s=2.0, max_options=5)


def test_the_regret_of_the_oracles_own_decisions_is_zero(tmp_path: Path) -> None:
    log = tmp_path / "usi-100-lmpc-oracle.jsonl"

    def build(spec):  # the oracle with the small search, its decision log kept
        return mo.build(dataclasses.replace(spec, log_path=log), oracle=SMALL)

    methods.prepare()
    sim = SumoSim(work_dir=tmp_path / "scenes")
    try:
        row = {"method": "lmpc-oracle", "family": "usi", "seed": 100, "outcome": "-",
               "time_s": "", "overall_cost": ""}
        rows, scene = regret.regret_of_scene(tmp_path, row, sim=sim, oracle=SMALL,
                                             build=build, max_time_s=12.0)
    finally:
        sim.close()
    chosen = [json.loads(line) for line in log.read_text().splitlines()]
    chosen = [r for r in chosen if r.get("kind") == "oracle"]
    assert len(rows) == len(chosen) >= 4
    assert [r["t_s"] for r in rows] == [round(c["stamp_s"], 3) for c in chosen]
    for r, c in zip(rows, chosen):
        # the chosen decision is recognised as the option the oracle chose (or one of the
        # same content), and no option of the same search beats it
        assert r["regret"] == 0.0 and r["parts"] == "", r
        assert c["scores"][c["chosen"]] == (None if math.isinf(r["chosen_score"])
                                            else round(r["chosen_score"], 6)), (r, c)
        assert c["scores"][r["chosen"]] == c["scores"][c["chosen"]], (r, c)
    assert scene["decisions"] == len(rows)


def test_the_rules_continuation_judges_the_rules_run_as_the_oracle_does(
        tmp_path: Path) -> None:
    """``--continuation rules``: after the chosen decision the rules reasoner decides on in
    the rollout, so at the first instant (both runs in the same state) the regret scores
    the rules planner's decision exactly as Table I's oracle (16 s + rules continuation,
    here a short window) scores its ``rules`` option; without the continuation the same
    decision held alone scores differently."""
    judge = mo.OracleConfig(lookahead_s=5.0, max_options=3, continuation="rules")
    log = tmp_path / "usi-100-lmpc-oracle.jsonl"

    def oracle(spec):
        return mo.build(dataclasses.replace(spec, log_path=log), oracle=judge)

    row = {"method": "lmpc-rules", "family": "usi", "seed": 100, "outcome": "-",
           "time_s": "", "overall_cost": ""}
    methods.prepare()
    sim = SumoSim(work_dir=tmp_path / "scenes")
    try:
        regret.regret_of_scene(tmp_path, dict(row, method="lmpc-oracle"), sim=sim,
                               oracle=judge, build=oracle, max_time_s=5.5)
        with_rules, _ = regret.regret_of_scene(tmp_path, row, sim=sim, oracle=judge,
                                               max_time_s=5.5)
        held, _ = regret.regret_of_scene(
            tmp_path, row, sim=sim, oracle=dataclasses.replace(judge, continuation="none"),
            max_time_s=5.5)
    finally:
        sim.close()
    first = next(json.loads(line) for line in log.read_text().splitlines()
                 if json.loads(line).get("kind") == "oracle")
    assert first["stamp_s"] == 0.0 and with_rules[0]["t_s"] == 0.0
    assert with_rules[0]["chosen"] == "rules", with_rules[0]
    assert math.isfinite(with_rules[0]["chosen_score"])
    assert round(with_rules[0]["chosen_score"], 6) == first["scores"]["rules"]
    assert held[0]["chosen"] == "rules"
    assert abs(held[0]["chosen_score"] - with_rules[0]["chosen_score"]) > 1e-6


def test_regret_of_a_two_scene_rules_run(tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert benchmark.main(["--families", "usi,rab", "--seeds", "124", "--methods",
                           "lmpc-rules", "--workers", "1", "--out", str(run)]) == 0
    summary = regret.run(run, oracle=SMALLER, progress=False)
    out = run / "regret"
    for name in ("regret.csv", "summary.json", "regret.md", "regret.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    with (out / "regret.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["family"] for r in rows} == {"usi", "rab"}
    for sc in summary["scenes"]:
        mine = [r for r in rows if r["family"] == sc["family"]]
        assert len(mine) == sc["decisions"] > 0
        if sc["repeats_recorded_row"]:  # the re-run is the recorded run: one row a decision
            assert sc["same_instants"] and sc["decisions"] == sc["recorded_decisions"]
    rab = next(s for s in summary["scenes"] if s["family"] == "rab")
    assert rab["repeats_recorded_row"], rab
    for r in rows:
        chosen, best, reg = (float(r["chosen_score"]), float(r["best_score"]),
                             float(r["regret"]))
        assert reg >= 0.0 and best <= chosen, r
        if math.isfinite(chosen):
            assert abs(reg - (chosen - best)) < 1e-5, r
        assert (r["parts"] == "") == (reg == 0.0), r
        gains = {p: r[f"gain_{p}"] for p in regret.PARTS if r[f"gain_{p}"] != ""}
        if reg == 0.0 or not math.isfinite(reg):
            assert not gains, r
        elif r["chosen"] != "none" and set(r["parts"].split("+")) <= set(regret.PARTS):
            # a gain for each differing part; one part alone is the whole regret
            assert set(gains) == set(r["parts"].split("+")), r
            if len(gains) == 1:
                assert abs(float(next(iter(gains.values()))) - reg) < 1e-5, r
        assert int(r["options"]) <= SMALLER.max_options
    fam = summary["families"]["rab"]
    assert 0.0 <= fam["share_zero"] <= 1.0 and fam["decisions"] == rab["decisions"]
    assert fam["regret_median"] <= fam["regret_p90"]
    assert len(fam["worst"]) == min(10, fam["decisions"])
    assert set(fam["share_recovered_by_part"]) == set(regret.PARTS)
    assert all(v is None or 0.0 <= v <= 1.0 for v in fam["share_recovered_by_part"].values())
    assert [w["regret"] for w in fam["worst"]] == sorted((w["regret"] for w in fam["worst"]),
                                                         reverse=True)


@pytest.mark.xdist_group("ray")  # beside test_benchmark_ray's, which counts Ray processes
def test_ray_and_two_pool_workers_give_the_rows_of_one(tmp_path: Path, monkeypatch) -> None:
    """The executor and the number of workers change where the scenes run, not the files
    (every column but the wall times)."""
    pytest.importorskip("ray", reason="ray is not installed (the optional 'ray' extra)")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)  # a private local Ray, never a cluster
    run = tmp_path / "run"
    # two short scenes (19 decisions; usi,rab 101 had 46): the executors are the point
    assert benchmark.main(["--families", "si,usi", "--seeds", "101", "--methods",
                           "lmpc-rules", "--workers", "2", "--out", str(run)]) == 0

    def rows(out: Path) -> list[dict[str, str]]:
        with (out / "regret.csv").open() as fh:
            return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(fh)]

    one = regret.run(run, oracle=SMALLER, progress=False, out=tmp_path / "one")
    two = regret.run(run, oracle=SMALLER, progress=False, out=tmp_path / "two", workers=2)
    ray = regret.run(run, oracle=SMALLER, progress=False, out=tmp_path / "ray", workers=2,
                     executor="ray")
    assert rows(tmp_path / "one")
    assert rows(tmp_path / "one") == rows(tmp_path / "two") == rows(tmp_path / "ray")
    counts = [[sc["decisions"] for sc in x["scenes"]] for x in (one, two, ray)]
    assert counts[0] == counts[1] == counts[2], counts
    assert ray["executor"] == "ray" and ray["workers"] == 2 and not ray["interrupted"]
    # one scene on two workers: two parts, each re-running the scene and judging every
    # other instant, give the rows of one worker
    single = tmp_path / "single"
    (single / "decisions").mkdir(parents=True)
    with (run / "results.csv").open(newline="") as fh:
        write_rows(single / "results.csv",
                   [r for r in csv.DictReader(fh) if r["family"] == "usi"])
    for log in (run / "decisions").glob("usi-101-*"):
        shutil.copy(log, single / "decisions" / log.name)
    split = regret.run(single, oracle=SMALLER, progress=False, workers=2)
    assert [sc.get("parts") for sc in split["scenes"]] == [2]
    assert split["scenes"][0]["same_instants"] and split["scenes"][0]["repeats_recorded_row"]
    usi_rows = [r for r in rows(tmp_path / "one") if r["family"] == "usi"]
    assert len(usi_rows) > 2 and rows(single / "regret") == usi_rows


def test_swap_part_takes_one_part_of_the_donor() -> None:
    from lmpc_msgs_py.messages import AgentPrediction, BezierTrajectory, Decision, WeightLevels

    def traj(cid: int) -> BezierTrajectory:
        return BezierTrajectory(candidate_id=cid, control_points=((0.0, 0.0), (5.0, cid)),
                                label="x")

    common = dict(stamp_s=1.0, seq=1, source="rules", latency_s=0.0,
                  space_hash="0" * 16)
    a = Decision(decision_id="a", ego_trajectory=traj(0), accel_interval=2,
                 steer_interval=2, **common)
    b = Decision(decision_id="b", ego_trajectory=traj(1), accel_interval=4, steer_interval=1,
                 weights=WeightLevels(safety="high"), attention=("v1",),
                 agent_predictions=(AgentPrediction(agent_id="v1", trajectory=traj(2)),),
                 **common)
    s = regret.swap_part(a, b, "bias")
    assert (s.accel_interval, s.steer_interval) == (4, 1) and s.decision_id == "a"
    assert s.ego_trajectory == a.ego_trajectory and s.weights == a.weights
    s = regret.swap_part(a, b, "attention")
    assert s.attention == ("v1",) and s.agent_predictions == b.agent_predictions
    assert s.accel_interval == 2
    assert regret.swap_part(a, b, "reference").ego_trajectory.candidate_id == 1
    assert regret.swap_part(a, b, "weights").weights.safety == "high"


def test_a_folder_without_results_is_a_one_line_error(capsys) -> None:
    with tempfile.TemporaryDirectory() as d:
        assert regret.main([d]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("regret.py: ") and "results.csv" in err and "\n" not in err


def test_merging_regret_folders_gives_the_summary_of_one_run(tmp_path: Path, capsys) -> None:
    """``--merge``: a run split by family over two folders sums up as the whole run did
    (the committed usi / rab seeds 0-4 regret), and a scene in two folders is refused."""
    whole = Path(__file__).resolve().parents[1] / "docs/data/regret_rules_2026-12-04"
    rows = regret.read_regret_csv(whole / "regret.csv")
    summary = json.loads((whole / "summary.json").read_text())
    for fam in ("rab", "usi"):
        part = tmp_path / fam
        part.mkdir()
        regret.write_csv(part / "regret.csv", [r for r in rows if r["family"] == fam])
        scenes = [sc for sc in summary["scenes"] if sc["family"] == fam]
        (part / "summary.json").write_text(json.dumps(dict(summary, scenes=scenes)))
    assert regret.main(["--merge", str(tmp_path / "usi"), str(tmp_path / "rab"),
                        "--out", str(tmp_path / "both")]) == 0
    merged = json.loads((tmp_path / "both" / "summary.json").read_text())
    assert merged["families"] == summary["families"]
    assert merged["scenes"] == summary["scenes"]
    assert (tmp_path / "both" / "regret.csv").read_text() == (whole / "regret.csv").read_text()
    capsys.readouterr()
    assert regret.main(["--merge", str(tmp_path / "usi"), str(tmp_path / "usi"),
                        "--out", str(tmp_path / "twice")]) == 2
    assert "usi 0" in capsys.readouterr().err
    judged = json.loads((tmp_path / "rab" / "summary.json").read_text())
    (tmp_path / "rab" / "summary.json").write_text(json.dumps(dict(judged,
                                                                   continuation="rules")))
    assert regret.main(["--merge", str(tmp_path / "usi"), str(tmp_path / "rab"),
                        "--out", str(tmp_path / "mixed")]) == 2
    assert "continuation rules" in capsys.readouterr().err
