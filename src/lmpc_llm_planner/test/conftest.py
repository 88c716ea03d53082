"""Fixtures of the planner tests: a hand-made unsignalized 4-way junction (from
``lmpc_mpc.synthetic``: ego from the south turning left, oncoming lane from the north),
observations on it, and the packaged configs. No ROS, no SUMO."""
from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Callable, Optional, Sequence

import pytest
from lmpc_mpc import synthetic as syn

from lmpc_msgs_py.messages import Agent, MapSnapshot
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace, load_decision_space

from lmpc_llm_planner.config import PlannerConfig, load_planner_config

sys.path.insert(0, str(Path(__file__).parent))  # rules_kit.py, the rules tests' helpers

NORTH = math.pi / 2.0
SOUTH = -math.pi / 2.0
ARM_M = 100.0
BOX_M = 8.0


@pytest.fixture(scope="session")
def space() -> DecisionSpace:
    """The packaged decision space (intervals and weight pool) the planner offers."""
    return load_decision_space()


@pytest.fixture(scope="session")
def mpc_config(space: DecisionSpace) -> DecisionSpace:
    """The same space under the name the tests used while it lived in the MPC config."""
    return space


@pytest.fixture(scope="session")
def planner_config() -> PlannerConfig:
    return load_planner_config()


@pytest.fixture(scope="session")
def left_turn_map() -> MapSnapshot:
    return syn.four_way_junction(arm_m=ARM_M, ego_turn="l")


@pytest.fixture(scope="session")
def road() -> MapSnapshot:
    """The two-lane straight road of the lane / headway tests."""
    return syn.straight_road(length_m=400.0)


@pytest.fixture(scope="session")
def straight_map() -> MapSnapshot:
    return syn.four_way_junction(arm_m=ARM_M, ego_turn="s")


def oncoming(aid: str, *, y_m: float, v_mps: float) -> Agent:
    """A car on the oncoming lane N_in_0 (southbound at x = -1.6) at ``y_m``."""
    return syn.agent(aid, x_m=-1.6, y_m=y_m, yaw_rad=SOUTH, v_mps=v_mps, lane_id="N_in_0")


def make_obs(
    map_: MapSnapshot,
    *,
    ego_y_m: float = -40.0,
    ego_v_mps: float = 8.0,
    agents: Sequence[Agent] = (),
    stamp_s: float = 0.0,
    seq: int = 0,
    ego_x_m: float = 1.6,
    lane_id: Optional[str] = "S_in_0",
) -> Observation:
    """The ego northbound on S_in_0 (stop line at y = -8) at ``ego_y_m``."""
    ego = syn.ego_state(
        x_m=ego_x_m, y_m=ego_y_m, yaw_rad=NORTH, v_mps=ego_v_mps, stamp_s=stamp_s, seq=seq,
        lane_id=lane_id,
    ).model_copy(update={"lane_pos_m": ego_y_m + ARM_M})
    return syn.observation(map_, ego, agents)


@pytest.fixture
def obs_factory() -> Callable[..., Observation]:
    return make_obs


@pytest.fixture
def oncoming_factory() -> Callable[..., Agent]:
    return oncoming
