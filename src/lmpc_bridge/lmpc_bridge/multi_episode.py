"""In-process multi-ego episode (issue 18): N egos, each its own MPC and planner core.

Per step k, for the running egos: ``obs = sim.observe(ego)``; ``coordination.prepare``
(statuses exchanged, commands taken in: the observations the egos act on); per ego
``control = controller.compute(obs)``, ``decision = planner.on_observation(obs)`` shaped by
the coordination and handed to the controller; then ONE ``sim.step(controls)``. As in
``runner.run_episode`` a decision from observation k never changes control k, and
exceptions of a controller / planner are counted, the step taken with bounded braking /
without a decision. The planners, controllers and the coordination are injected (the
bridge imports neither the planner nor the MPC); ``scripts/multi.py`` wires them.

For pictures the result keeps, per ego, its single-ego :class:`EpisodeRecord` (pose, speed,
the vehicles it sensed, per step), its map, and an :class:`EgoMark` per step: the command
the coordination had in force for it (``yield`` / ``proceed``, from a directive or the
distributed rule) and whether it was holding (the hold obstacle in its observation). The
marks come from the coordination's optional ``marks()`` (``{ego_id: {command, source,
holding, intent}}`` for the step just prepared); without it, or in mode ``none``, no marks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional, Protocol

from lmpc_msgs_py.messages import Control, Decision, EpisodeMetrics, MapSnapshot
from lmpc_msgs_py.observation import Observation

from lmpc_bridge.multi_sim import MultiSumoSim
from lmpc_bridge.record import EpisodeRecord


class CoordinationLike(Protocol):
    def prepare(self, now_s: float, obs: dict[str, Observation]) -> dict[str, Observation]: ...

    def shape(self, ego_id: str, decision: Optional[Decision],
              obs: Observation) -> Optional[Decision]: ...


@dataclass(frozen=True)
class EgoWiring:
    controller: Any
    planner: Any = None


@dataclass(frozen=True)
class EgoMark:
    """What the coordination had one ego do at one step (for pictures)."""

    step: int
    """The ``StepRecord.step`` of the ego's record this mark belongs to."""
    command: Optional[str] = None
    """``yield`` / ``proceed`` in force, None without a command."""
    source: str = ""
    """Where the command came from (``central``, ``distributed``, a backend name)."""
    holding: bool = False
    """The hold obstacle was in the ego's observation (it was stopping before the section)."""
    intent: str = ""
    """The intent of the ego's status (``approach``, ``wait``, ``pass`` ...)."""

    @property
    def yielding(self) -> bool:
        return self.command == "yield"


@dataclass(frozen=True)
class EgoResult:
    ego_id: str
    outcome: str
    detail: str
    collided_with: Optional[str]
    metrics: EpisodeMetrics
    reached_at_s: Optional[float]
    decisions: int
    fallbacks: int
    controller_errors: int
    planner_errors: int


@dataclass(frozen=True)
class MultiResult:
    family: str
    seed: int
    egos: tuple[EgoResult, ...]
    deadlock: bool
    end_s: float
    stats: dict[str, int] = field(default_factory=dict)
    records: dict[str, EpisodeRecord] = field(default_factory=dict)
    """Per ego, its record (as a single-ego episode's), for pictures and replay."""
    maps: dict[str, MapSnapshot] = field(default_factory=dict)
    """Per ego, its map (its route and target on the scene's roads)."""
    marks: dict[str, tuple[EgoMark, ...]] = field(default_factory=dict)
    """Per ego, the coordination's marks by step (empty without coordination)."""
    warnings: tuple[str, ...] = ()
    """``MultiSumoSim.traffic_warnings``: vehicles of the scene SUMO refused at its start."""

    @property
    def ego_ids(self) -> frozenset[str]:
        return frozenset(e.ego_id for e in self.egos)

    @property
    def ego_collisions(self) -> int:
        """Collisions between two egos (each pair once)."""
        pairs = {tuple(sorted((e.ego_id, e.collided_with))) for e in self.egos
                 if e.outcome == "collision" and e.collided_with in self.ego_ids}
        return len(pairs)

    @property
    def other_collisions(self) -> int:
        """Egos that collided with a vehicle that is not an ego."""
        return sum(1 for e in self.egos
                   if e.outcome == "collision" and e.collided_with not in self.ego_ids)

    @property
    def all_reached(self) -> bool:
        return all(e.outcome == "reached" for e in self.egos)

    @property
    def clear_s(self) -> Optional[float]:
        """Time until every ego reached its target (None: one did not)."""
        if not self.all_reached:
            return None
        return max(e.reached_at_s or 0.0 for e in self.egos)

    @property
    def joint_oc(self) -> float:
        return sum(e.metrics.overall_cost for e in self.egos)


def _finite(control: Control) -> bool:
    return math.isfinite(control.accel_mps2) and math.isfinite(control.steer_rad)


def run_multi_episode(sim: MultiSumoSim, *, family: str, seed: int,
                      egos: dict[str, EgoWiring], coordination: Optional[CoordinationLike] = None,
                      max_time_s: float = 200.0) -> MultiResult:
    """Run one multi-ego episode to its end (every ego reached / collided / timed out, or a
    deadlock); see the module docstring."""
    sim.reset(family, seed, max_time_s=max_time_s)
    if set(egos) != set(sim.egos):
        raise ValueError(f"wiring for {sorted(egos)} but the scene has {sorted(sim.egos)}")
    counts = {eid: {"decisions": 0, "fallbacks": 0, "controller_errors": 0,
                    "planner_errors": 0} for eid in egos}
    last_decision: dict[str, Optional[str]] = {eid: None for eid in egos}
    marks: dict[str, list[EgoMark]] = {eid: [] for eid in egos}
    marks_of = getattr(coordination, "marks", None)
    command_of = getattr(coordination, "command_text", None)
    while sim.running:
        running = sim.running_ids()
        obs = {eid: sim.observe(eid, required_decision_id=last_decision[eid])
               for eid in running}
        if coordination is not None:
            obs = coordination.prepare(sim.time_s, obs)
            step = int(round(sim.time_s / sim.dt_s)) + 1  # the record step this one makes
            for eid, m in (marks_of() if marks_of is not None else {}).items():
                marks[eid].append(EgoMark(step=step, command=m.get("command"),
                                          source=str(m.get("source", "")),
                                          holding=bool(m.get("holding", False)),
                                          intent=str(m.get("intent", ""))))
        controls: dict[str, Optional[Control]] = {}
        for eid in running:
            wiring, c = egos[eid], counts[eid]
            try:
                control: Optional[Control] = wiring.controller.compute(obs[eid])
                if control is not None and not _finite(control):
                    control = None
                    c["controller_errors"] += 1
            except Exception:  # noqa: BLE001 - a controller bug must not kill the benchmark
                control = None
                c["controller_errors"] += 1
            if control is not None and control.mode in ("brake", "shifted"):
                c["fallbacks"] += 1
            controls[eid] = control
            if wiring.planner is None:
                continue
            if command_of is not None and hasattr(wiring.planner, "on_command"):
                wiring.planner.on_command(command_of(eid, sim.time_s))  # LLM prompt text
            try:
                decision = wiring.planner.on_observation(obs[eid])
            except Exception:  # noqa: BLE001
                c["planner_errors"] += 1
                decision = None
            if coordination is not None:
                decision = coordination.shape(eid, decision, obs[eid])
            if decision is not None:
                c["decisions"] += 1
                last_decision[eid] = decision.decision_id
                if decision.source == "fallback":
                    c["fallbacks"] += 1
                refusal = wiring.controller.on_decision(decision)
                if refusal is not None:
                    raise RuntimeError(f"{eid}'s controller refused a decision: {refusal}")
        sim.step(controls)
    results = []
    for eid in sorted(egos):
        st, run = sim.status(eid), sim.egos[eid]
        results.append(EgoResult(ego_id=eid, outcome=st.outcome, detail=st.detail,
                                 collided_with=st.collided_with, metrics=st.metrics,
                                 reached_at_s=run.reached_at_s, **counts[eid]))
    stats = dict(getattr(coordination, "stats", lambda: {})())
    end_s = sim.time_s
    records = {eid: sim.record(eid) for eid in sorted(egos)}
    maps = {eid: sim.egos[eid].map for eid in sorted(egos)}
    sim.close()
    return MultiResult(family=family, seed=seed, egos=tuple(results), deadlock=sim.deadlock,
                       end_s=end_s, stats=stats, records=records, maps=maps,
                       marks={eid: tuple(m) for eid, m in marks.items()},
                       warnings=sim.traffic_warnings())
