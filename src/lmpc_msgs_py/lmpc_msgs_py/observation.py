"""The bundle of inputs the planner and the MPC work on, without ROS."""
from __future__ import annotations

from dataclasses import dataclass

from lmpc_msgs_py.messages import AgentArray, EgoState, MapSnapshot, SignalStates


@dataclass(frozen=True)
class Observation:
    """One step's view of the world: latched map plus the step's ego, agents, signals.

    The in-process benchmark builds it directly from the simulation; the nodes
    assemble it from the topics (all three stamps equal in sync mode).
    """

    map: MapSnapshot
    ego: EgoState
    agents: AgentArray
    signals: SignalStates

    @property
    def stamp_s(self) -> float:
        return self.ego.stamp_s
