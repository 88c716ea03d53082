"""usi training seed 10095, `lmpc-rules` with no instruction, in process: under a "go" the
MPC turned in early; when its crossing rule refused the go (`onc3` oncoming), the solver
failed three steps running and the shifted plan kept accelerating into the junction; the
fallback brake stopped the ego with its nose in the oncoming lane, and `onc3` hit it
(main at 4267af9: collision at 19.0 s). The shifted plan no longer accelerates once the
go is refused (docs/lmpc_mpc.md, "The ego's body, not its centre")."""
from __future__ import annotations

from pathlib import Path

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods


def test_the_ego_does_not_stop_with_its_nose_in_the_oncoming_lane(tmp_path: Path) -> None:
    wiring = methods.build(SceneSpec("lmpc-rules", "usi", 10095))
    result = run_episode(SumoSim(work_dir=tmp_path), family="usi", seed=10095,
                         controller=wiring.controller, planner=wiring.planner)
    assert result.outcome == "reached", (result.outcome, result.detail)
    # the mechanism: the crossing rule refused a go at some step
    assert wiring.controller.stats().go_refused > 0
