"""Multi-vehicle joint control in-process (issue 18) on the ``narrow`` family.

Development seeds only (100-124): on seed 101 two egos on their own planners collide in
the one-lane section, on seed 107 they deadlock (measured, docs/MULTI.md); the
coordinated modes must let both through there.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from graphkit import REPO

from lmpc_bridge.multi_episode import EgoWiring, run_multi_episode
from lmpc_bridge.multi_sim import MultiSumoSim
from lmpc_bridge.sim import SimError
from lmpc_llm_planner.coordination import CoordinatorCore, RulesCoordinator, SilentCoordinator
from lmpc_msgs_py.observation import Observation
from lmpc_scripts import multi


def _clean(result) -> None:
    assert result.ego_collisions == 0 and result.other_collisions == 0, result
    assert not result.deadlock, result
    assert result.all_reached, [(e.ego_id, e.outcome, e.detail) for e in result.egos]


@pytest.mark.parametrize("mode", ["distributed", "central"])
@pytest.mark.parametrize("seed", [101, 107])
def test_coordination_lets_both_egos_through(mode: str, seed: int, tmp_path: Path) -> None:
    result, row = multi.run_one("narrow", seed, "lmpc-rules", mode, tmp_path)
    _clean(result)
    assert row["hold_steps"] > 0  # somebody waited at the hold point
    if mode == "central":
        assert row["directives"] > 0 and row["directives_refused"] == 0


def test_a_silent_coordinator_falls_back_without_collision(tmp_path: Path) -> None:
    result, row = multi.run_one("narrow", 101, "lmpc-rules", "central", tmp_path,
                                coordinator=CoordinatorCore(SilentCoordinator()))
    _clean(result)
    assert row["directives"] == 0 and row["silent_steps"] > 0


class _SilentAfter(RulesCoordinator):
    """Answers like the rules backend until ``t_s``, then nothing (a crashed node)."""

    def __init__(self, t_s: float) -> None:
        super().__init__()
        self.t_s = t_s

    def verdicts(self, statuses, now_s):
        return super().verdicts(statuses, now_s) if now_s < self.t_s else []


def test_a_coordinator_going_silent_midway_leaves_no_collision(tmp_path: Path) -> None:
    result, row = multi.run_one("narrow", 107, "lmpc-rules", "central", tmp_path,
                                coordinator=CoordinatorCore(_SilentAfter(4.0)))
    _clean(result)
    assert row["directives"] > 0 and row["silent_steps"] > 0


class _Blind:
    """The MPC with every other vehicle removed from its observation."""

    def __init__(self, inner) -> None:
        self.inner = inner

    def compute(self, obs: Observation):
        agents = obs.agents.model_copy(update={"agents": ()})
        return self.inner.compute(Observation(map=obs.map, ego=obs.ego, agents=agents,
                                              signals=obs.signals))

    def on_decision(self, decision):
        return self.inner.on_decision(decision)


def test_two_blind_egos_collide_head_on_and_the_check_sees_it(tmp_path: Path) -> None:
    egos, _ = multi.wire("mpc", ["ego_1", "ego_2"], "none")
    blind = {eid: EgoWiring(controller=_Blind(w.controller)) for eid, w in egos.items()}
    result = run_multi_episode(MultiSumoSim(work_dir=tmp_path), family="narrow", seed=101,
                               egos=blind, max_time_s=60.0)
    assert result.ego_collisions == 1
    assert {e.collided_with for e in result.egos} == {"ego_1", "ego_2"}


def test_multi_sim_observations_and_refusals(tmp_path: Path) -> None:
    sim = MultiSumoSim(work_dir=tmp_path)
    with pytest.raises(SimError, match="one ego"):
        sim.reset("usi", 100)
    obs = sim.reset("narrow", 100)
    try:
        assert sorted(obs) == ["ego_1", "ego_2"]
        for eid, other in (("ego_1", "ego_2"), ("ego_2", "ego_1")):
            seen = {a.id: a for a in obs[eid].agents.agents}
            if other in seen:  # within sensing range: the bridge's exact pose
                pose = sim.egos[other].pose
                assert (seen[other].x_m, seen[other].y_m) == pytest.approx(
                    (pose.x_m, pose.y_m))
        assert obs["ego_1"].map.ego_route[0].startswith("WA")
        assert obs["ego_2"].map.ego_route[0].startswith("EB")
        with pytest.raises(SimError, match="unknown ego"):
            sim.observe("ego_3")
    finally:
        from lmpc_bridge import sumo_rng

        stale = {"default": -1}  # what an earlier simulation of the process left
        sumo_rng._COUNTS_AT_CLOSE = stale
        sim.close()
    # closing noted this simulation's generator counts (or None: unknown, so a following
    # single-ego branching run restarts to find them) instead of leaving stale ones
    assert sumo_rng.counts_at_close() is not stale


@pytest.mark.parametrize("extra,message", [
    (["--methods", "lmpc-openai"], "multi-ego families run mpc, lmpc-rules only"),
    (["--coordination", "none,chaos"], "--coordination ['chaos']"),
])
def test_benchmark_refuses_what_multi_ego_families_cannot_run(
        extra: list[str], message: str, tmp_path: Path) -> None:
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"),
                          "--families", "narrow", "--seeds", "100", "--out", str(tmp_path),
                          *extra], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert message in out.stderr
