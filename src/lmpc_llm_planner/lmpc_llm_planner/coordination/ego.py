"""One ego's side of the coordination (issue 18): its status, and its command taken in.

``EgoCoordination`` sits between the ego's observation and its planner / MPC:

- ``status(obs)``: the :class:`EgoStatus` it reports (route position, speed, intent, the
  shared conflict ahead -- narrow section, junction or merge -- as :class:`ConflictView`,
  its current decision in a few words);
- ``follow(command)``: the command in force (``yield`` / ``proceed``, a speed band, until
  a deadline in sim time; from a :class:`Directive` in ``central`` mode, from its own
  rule set in ``distributed`` mode). After the deadline the ego is on its own planner;
- ``apply(obs)``: the observation its planner and MPC act on. The **rules** backend's
  way to take ``yield``: a virtual standing obstacle at the hold point (``hold_<lane>``),
  which the rules' headway rule and the MPC's leader limit both stop behind; not added
  once the ego cannot stop before the hold point any more (committed);
- ``shape(decision, obs)``: the speed band as a bias: a new decision whose acceleration
  interval would leave the band is moved to the interval that brings the speed back
  into it (mildest braking above the band, neutral inside it).

An LLM planner also reads the command as prompt text (``Command.text()`` into
``PlannerCore.on_command``: in-process ``Coordination.command_text``, in the ROS graph
``CoordinationWiring.command_text``; docs/MULTI.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from lmpc_msgs_py.coordination import EgoStatus, SpeedBand
from lmpc_msgs_py.messages import AgentArray, Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace, midpoint, neutral_index

from lmpc_llm_planner.coordination.conflicts import (
    Section,
    conflict_view,
    hold_agent,
    route_starts_m,
    shared_sections,
)
from lmpc_llm_planner.coordination.rules import committed


@dataclass(frozen=True)
class Command:
    command: str
    conflict_id: str
    speed_band: Optional[SpeedBand]
    deadline_s: float
    source: str
    directive_id: str

    def text(self) -> str:
        """The command in words (an LLM planner's prompt carries it: ``on_command``)."""
        band = "" if self.speed_band is None else (
            f", speed {self.speed_band.min_mps:.0f}-{self.speed_band.max_mps:.0f} m/s")
        return f"{self.command} at {self.conflict_id}{band} until t={self.deadline_s:.1f} s"


class EgoCoordination:
    """See the module docstring."""

    def __init__(self, ego_id: str, space: DecisionSpace) -> None:
        self.ego_id = ego_id
        self.space = space
        self.command: Optional[Command] = None
        self.last_decision: Optional[Decision] = None
        self._map_key: Optional[int] = None
        self._sections: tuple[Section, ...] = ()
        self._starts: tuple[float, ...] = ()
        self._seq = 0
        self.holds = 0
        """Steps with the hold obstacle in the observation."""
        self.shaped = 0
        """Decisions the speed band changed."""

    def _geometry(self, obs: Observation) -> None:
        if self._map_key != id(obs.map):
            self._map_key = id(obs.map)
            self._sections = shared_sections(obs.map)
            self._starts = route_starts_m(obs.map)

    def _ahead(self, obs: Observation) -> tuple[Optional[Section], object]:
        self._geometry(obs)
        for sec in self._sections:
            view = conflict_view(obs, sec, self._starts)
            if view is not None:
                return sec, view
        return None, None

    def in_force(self, now_s: float) -> Optional[Command]:
        c = self.command
        return c if c is not None and now_s < c.deadline_s - 1e-9 else None

    def status(self, obs: Observation, *, done: bool = False) -> EgoStatus:
        _, view = self._ahead(obs)
        cmd = self.in_force(obs.stamp_s)
        if done:
            intent = "done"
        elif view is None:
            intent = "cruise"
        elif view.dist_to_exit_m <= 0.0:  # type: ignore[attr-defined]
            intent = "through"
        elif view.inside:  # type: ignore[attr-defined]
            intent = "pass"
        elif cmd is not None and cmd.command == "yield":
            intent = "wait"
        else:
            intent = "approach"
        d = self.last_decision
        summary = "" if d is None else (
            f"{d.source} {d.mode}: accel interval {d.accel_interval}"
            + (f", attends {', '.join(d.attention[:3])}" if d.attention else ""))[:200]
        self._seq += 1
        return EgoStatus(
            stamp_s=obs.stamp_s, seq=self._seq, ego_id=self.ego_id,
            route_index=obs.ego.route_index, dist_to_target_m=obs.ego.dist_to_target_m,
            v_mps=obs.ego.v_mps, intent=intent,
            conflict=None if done else view,  # type: ignore[arg-type]
            decision_summary=summary, directive_id=None if cmd is None else cmd.directive_id)

    def follow(self, command: Optional[Command]) -> None:
        self.command = command

    def apply(self, obs: Observation) -> Observation:
        cmd = self.in_force(obs.stamp_s)
        if cmd is None or cmd.command != "yield":
            return obs
        sec, view = self._ahead(obs)
        if sec is None or sec.conflict_id != cmd.conflict_id \
                or view.dist_to_exit_m <= 0.0:  # type: ignore[attr-defined]
            return obs
        status = EgoStatus(stamp_s=obs.stamp_s, seq=0, ego_id=self.ego_id,
                           dist_to_target_m=obs.ego.dist_to_target_m, v_mps=obs.ego.v_mps,
                           intent="approach", conflict=view)  # type: ignore[arg-type]
        if committed(status):
            return obs  # it can no longer stop before the hold point: it goes through
        hold = hold_agent(obs, sec, self._starts)
        self.holds += 1
        a = obs.agents
        agents = AgentArray(stamp_s=a.stamp_s, seq=a.seq, sensing_range_m=a.sensing_range_m,
                            agents=tuple(sorted((*a.agents, hold), key=lambda g: g.id)))
        return Observation(map=obs.map, ego=obs.ego, agents=agents, signals=obs.signals)

    def shape(self, decision: Optional[Decision], obs: Observation) -> Optional[Decision]:
        if decision is None:
            return None
        cmd = self.in_force(obs.stamp_s)
        band = None if cmd is None else cmd.speed_band
        if band is not None:
            decision = self._into_band(decision, band, obs.ego.v_mps)
        self.last_decision = decision
        return decision

    def _into_band(self, decision: Decision, band: SpeedBand, v_mps: float) -> Decision:
        pool = self.space.accel_intervals_mps2
        mids = [midpoint(iv) for iv in pool]
        now = mids[decision.accel_interval]
        if v_mps > band.max_mps + 0.5 and now >= 0.0:
            braking = [i for i, m in enumerate(mids) if m < 0.0]
            if not braking:
                return decision
            want = max(braking, key=lambda i: (mids[i], -i))  # the mildest braking
        elif v_mps >= band.max_mps - 0.5 and now > 0.0:
            want = neutral_index(pool)
        elif v_mps < band.min_mps - 0.5 and now < 0.0:
            want = neutral_index(pool)
        else:
            return decision
        self.shaped += 1
        return decision.model_copy(update={
            "accel_interval": want,
            "reasoning": (decision.reasoning + f" [coordination: speed band "
                          f"{band.min_mps:.0f}-{band.max_mps:.0f} m/s]")[:8000]})
