"""In-process episode runner (docs/ARCHITECTURE.md, "Logic objects"): no ROS, no MPC import.

Per step k: ``obs = sim.observe()``; ``control = controller.compute(obs)``;
``decision = planner.on_observation(obs)``; if any, ``controller.on_decision(decision)``;
``sim.step(control)``. A decision computed from observation k therefore can never
change control k (the controller applies the timing rule of ARCHITECTURE.md).
The planner and the controller are injected (Protocols below); ``scripts/`` wires
the concrete ones.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Protocol

from lmpc_msgs_py.messages import Control, Decision, EpisodeMetrics
from lmpc_msgs_py.observation import Observation

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


def _finite(control: Control) -> bool:
    return math.isfinite(control.accel_mps2) and math.isfinite(control.steer_rad)


def run_episode(sim: SumoSim, *, family: str, seed: int, controller: ControllerLike,
                planner: PlannerLike | None = None, max_time_s: float = 200.0) -> EpisodeResult:
    """Run one episode to its end (reached / collision / timeout / error).

    Exceptions of the controller or the planner do not end the episode: the
    step is taken with a missing control (bounded braking) or without a
    decision, and counted. SUMO errors end it with outcome ``error``.
    """
    obs = sim.reset(family, seed, max_time_s=max_time_s)
    decisions = fallbacks = controller_errors = planner_errors = 0
    solve_ms: list[float] = []
    wall_ms: list[float] = []
    last_decision_id: str | None = None
    while sim.outcome == "running":
        obs = sim.observe(required_decision_id=last_decision_id)
        control: Control | None
        started = time.perf_counter()
        try:
            control = controller.compute(obs)
            if not _finite(control):
                control, controller_errors = None, controller_errors + 1
        except Exception:  # noqa: BLE001 - a controller bug must not kill the benchmark
            control, controller_errors = None, controller_errors + 1
        wall_ms.append((time.perf_counter() - started) * 1000.0)
        if control is not None:
            solve_ms.append(control.solve_time_ms)
            if control.mode in ("brake", "shifted"):
                fallbacks += 1
        if planner is not None:
            try:
                decision = planner.on_observation(obs)
            except Exception:  # noqa: BLE001
                decision, planner_errors = None, planner_errors + 1
            if decision is not None:
                decisions += 1
                last_decision_id = decision.decision_id
                if decision.source == "fallback":
                    fallbacks += 1
                refusal = controller.on_decision(decision)
                if refusal is not None:
                    # in process the planner and the controller were built together: a
                    # refused decision is a wiring error, not a fault to ride out
                    raise RuntimeError(f"the controller refused a decision: {refusal}")
        sim.step(control)
    status = sim.status()
    return EpisodeResult(
        family=family, seed=seed, outcome=status.outcome, detail=status.detail,
        metrics=status.metrics, record=sim.record(), decisions=decisions, fallbacks=fallbacks,
        controller_errors=controller_errors, planner_errors=planner_errors,
        solve_times_ms=tuple(solve_ms), compute_wall_ms=tuple(wall_ms),
    )
