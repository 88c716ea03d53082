"""usi training seed 10005, `lmpc-rules` with no instruction, in process: the left turn met
``cross0``, a car of the crossing road that moved off its stop line together with the ego
(for SUMO an ego placed by ``moveToXY`` is no approaching foe until it is on the
junction's internal lane). The two stood in the junction 0.1-0.2 m apart and the ego crept
into it at 14.7 s (main at b07b4c5). The left-turn rule now yields to a crossing car
starting into the junction (docs/lmpc_rules.md, "Rule 3")."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods


def test_the_left_turn_waits_for_a_crossing_car_starting_with_it() -> None:
    work = Path(tempfile.mkdtemp(prefix="lmpc-crossing-"))
    log = work / "log.jsonl"
    wiring = methods.build(SceneSpec("lmpc-rules", "usi", 10005, log_path=log))
    result = run_episode(SumoSim(work_dir=work / "scenes"), family="usi", seed=10005,
                         controller=wiring.controller, planner=wiring.planner)
    assert result.outcome == "reached", (result.outcome, result.detail)
    # the mechanism: some decision yielded to the crossing car
    text = log.read_text()
    assert "must yield to crossing cross0" in text, [
        json.loads(line).get("reason", "")[:120] for line in text.splitlines()[:40]]
