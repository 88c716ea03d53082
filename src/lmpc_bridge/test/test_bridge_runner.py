"""run_episode closed loop with the stand-in controller (NOT the real MPC)."""
from __future__ import annotations

import math
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from lmpc_msgs_py.messages import BezierTrajectory, Control, Decision
from lmpc_msgs_py.observation import Observation

from lmpc_bridge.runner import RecordingPlanner, run_episode
from lmpc_bridge.sim import SumoSim

sys.path.insert(0, str(Path(__file__).parent))
from conftest import StandInController  # noqa: E402


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SumoSim]:
    s = SumoSim(work_dir=tmp_path_factory.mktemp("runner_scenes"))
    yield s
    s.close()


@pytest.mark.parametrize("seed", range(5))
def test_standin_reaches_target_on_usi(sim: SumoSim, seed: int) -> None:
    result = run_episode(sim, family="usi", seed=seed, controller=StandInController())
    assert result.outcome == "reached", result.detail
    m = result.metrics
    assert m.collisions == 0 and 5.0 < m.time_s < 200.0
    assert m.steps == len(result.record.steps) == round(m.time_s / 0.1)
    assert result.controller_errors == 0 and result.decisions == 0
    assert len(result.solve_times_ms) == m.steps
    last = result.record.steps[-1]
    tx, ty = result.record.target_center
    assert math.hypot(last.x_m - tx, last.y_m - ty) <= result.record.target_radius_m + 0.5
    # the scene counts: an oncoming car came within 30 m of the ego while it turned
    assert any(n.id.startswith("onc") and n.gap_m < 30.0
               for s in result.record.steps for n in s.nearby)
    assert m.overall_cost == pytest.approx(m.ineff + 1.5 * m.time_s + 15 * m.pen_acc
                                           + 20 * m.pen_dist)


class EveryNPlanner:
    """Emits a decision every ``n`` observations (the first one a fallback)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.calls = 0

    def on_observation(self, obs: Observation) -> Decision | None:
        self.calls += 1
        if (self.calls - 1) % self.n:
            return None
        return Decision(
            stamp_s=obs.stamp_s, seq=obs.ego.seq, decision_id=f"d{self.calls}",
            source="fallback" if self.calls == 1 else "rules", latency_s=0.0,
            ego_trajectory=BezierTrajectory(candidate_id=0, control_points=((0.0, 0.0),
                                                                            (1.0, 0.0))),
            accel_interval=0, steer_interval=0, space_hash="0123456789abcdef")


class FlakyController(StandInController):
    """Raises on every 10th call and returns NaN-free controls otherwise."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def compute(self, obs: Observation) -> Control:
        self.calls += 1
        if self.calls % 10 == 0:
            raise RuntimeError("solver exploded")
        return super().compute(obs)


def test_planner_decisions_and_controller_faults_are_counted(sim: SumoSim) -> None:
    planner = EveryNPlanner(25)
    ctl = FlakyController()
    kept: list[Decision] = []
    result = run_episode(sim, family="usi", seed=5, controller=ctl,
                         planner=RecordingPlanner(planner, kept), max_time_s=8.0)
    assert result.outcome in ("timeout", "reached")
    steps = len(result.record.steps)
    assert planner.calls == steps
    assert result.decisions == len(ctl.decisions) == math.ceil(steps / 25)
    assert result.fallbacks == 1
    # the recording wrapper kept exactly the decisions the controller was given
    assert [d.decision_id for d in kept] == [d.decision_id for d in ctl.decisions]
    assert len(kept) == result.decisions
    assert result.controller_errors == steps // 10
    assert result.metrics.late_controls == steps // 10
    late_steps = [s.step for s in result.record.steps if s.late]
    assert late_steps == [10 * k for k in range(1, steps // 10 + 1)]
    if result.outcome == "timeout":
        assert result.metrics.time_s == pytest.approx(8.0)
