"""usi training seed 10005, `lmpc-rules` with no instruction, in process: the left turn met
``cross0``, a car of the crossing road that moved off its stop line together with the ego
(for SUMO an ego placed by ``moveToXY`` is no approaching foe until it is on the
junction's internal lane). SUMO stopped it in the junction; it restarted into the ego
passing in front of it at 14.7 s (main at b07b4c5). The left-turn rule now yields to a
crossing car starting into the junction (docs/lmpc_rules.md, "Per family")."""
from __future__ import annotations

from pathlib import Path

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods


def test_the_left_turn_waits_for_a_crossing_car_starting_with_it(tmp_path: Path) -> None:
    work = tmp_path
    log = work / "log.jsonl"
    wiring = methods.build(SceneSpec("lmpc-rules", "usi", 10005, log_path=log))
    result = run_episode(SumoSim(work_dir=work / "scenes"), family="usi", seed=10005,
                         controller=wiring.controller, planner=wiring.planner)
    assert result.outcome == "reached", (result.outcome, result.detail)
    # the mechanism: some decision yielded to the crossing car
    text = log.read_text()
    assert "must yield to crossing cross0" in text, \
        f"no decision yielded to cross0 in {len(text.splitlines())} decisions"
