"""In-process episode runner (docs/ARCHITECTURE.md, "Logic objects"): no ROS, no MPC import.

Per step k: ``obs = sim.observe()``; ``control = controller.compute(obs)``;
``decision = planner.on_observation(obs)``; if any, ``controller.on_decision(decision)``;
``sim.step(control)``. A decision computed from observation k therefore can never
change control k (the controller applies the timing rule of ARCHITECTURE.md).
The planner and the controller are injected (Protocols below); ``scripts/`` wires
the concrete ones.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from lmpc_msgs_py.messages import Control, Decision, EpisodeMetrics
from lmpc_msgs_py.observation import Observation

from lmpc_bridge.episode import Episode
from lmpc_bridge.record import EpisodeRecord
from lmpc_bridge.sim import SumoSim


class PlannerLike(Protocol):
    def on_observation(self, obs: Observation) -> Decision | None: ...


class ControllerLike(Protocol):
    def on_decision(self, decision: Decision) -> str | None:
        """Store ``decision``; why it was refused (another decision space), or None."""
        ...

    def compute(self, obs: Observation) -> Control: ...


class RecordingPlanner:
    """A planner that keeps every decision the planner it wraps makes (in ``decisions``,
    or the list given), for the tools that look at them after the episode."""

    def __init__(self, inner: PlannerLike, decisions: list[Decision] | None = None) -> None:
        self.inner = inner
        self.decisions: list[Decision] = [] if decisions is None else decisions

    def on_observation(self, obs: Observation) -> Decision | None:
        decision = self.inner.on_observation(obs)
        if decision is not None:
            self.decisions.append(decision)
        return decision


@dataclass(frozen=True)
class EpisodeResult:
    """Outcome and metrics of one episode, with the record and the run's counters."""

    family: str
    seed: int
    outcome: str
    detail: str
    metrics: EpisodeMetrics
    record: EpisodeRecord
    decisions: int
    fallbacks: int
    """Decisions with source ``fallback`` plus controls in ``brake`` / ``shifted`` mode."""
    controller_errors: int
    """``compute`` raised or returned a non-finite control; the step braked instead."""
    planner_errors: int
    solve_times_ms: tuple[float, ...] = field(repr=False, default=())
    """``Control.solve_time_ms`` as reported by the controller, one per step."""
    compute_wall_ms: tuple[float, ...] = field(repr=False, default=())
    """Wall time of ``controller.compute`` measured here, one per step."""

    @property
    def success(self) -> bool:
        return self.outcome == "reached"


def run_episode(sim: SumoSim, *, family: str, seed: int, controller: ControllerLike,
                planner: PlannerLike | None = None, max_time_s: float = 200.0) -> EpisodeResult:
    """Run one episode to its end (reached / collision / timeout / error).

    Exceptions of the controller or the planner do not end the episode: the
    step is taken with a missing control (bounded braking) or without a
    decision, and counted. SUMO errors end it with outcome ``error``.
    """
    episode = Episode(sim, family=family, seed=seed, controller=controller, planner=planner,
                      max_time_s=max_time_s)
    episode.start()
    episode.run()
    return episode.result()
