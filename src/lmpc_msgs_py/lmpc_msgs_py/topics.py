"""Topic names of the graph (DESIGN §2), in one place.

All names are relative to a namespace root: ``/lmpc`` for a single ego,
``/<ego_id>/lmpc`` for each ego of a multi-ego graph (issue 18; see :func:`topic`): the
per-ego processes run in the ROS namespace ``/<ego_id>`` and name their topics
``/<ego_id>/lmpc/...``. The coordination topics (``/coordination/...``) are shared by
all egos.
"""
from __future__ import annotations

ROOT = "/lmpc"

CLOCK = "/clock"
MAP = "map"
EGO_STATE = "ego_state"
AGENTS = "agents"
SIGNALS = "signals"
EPISODE = "episode"
DECISION = "decision"
CONTROL = "control"
INSTRUCTION = "instruction"
PLANNER_STATUS = "planner/status"
# typed mirrors for stock ROS tools
EGO_ODOM = "ego/odom"
REFERENCE_PATH = "mpc/reference"
PREDICTED_PATH = "mpc/predicted"
CANDIDATE_MARKERS = "mpc/candidates"
AGENT_PREDICTION_MARKERS = "mpc/agent_predictions"
AGENT_MARKERS = "agents/markers"
DIAGNOSTICS = "/diagnostics"
# multi-vehicle joint control (issue 18, docs/MULTI.md)
COORD_STATUS = "/coordination/status"
"""Every ego's planner publishes its ``EgoStatus`` here (shared, one publisher per ego)."""
COORD_DIRECTIVE = "/coordination/directive"
"""The coordinator's ``Directive``s to the egos (shared)."""
COORD_HOLD = "coordination/hold"
"""Per ego: the virtual obstacles its coordination puts in its MPC's observation
(``AgentArray``; empty when none)."""

LATCHED = (MAP, EPISODE)
"""The topics published latched (``lmpc_qos.LATCHED``): a late subscriber gets the last one."""


def topic(name: str, ego_id: str | None = None) -> str:
    """Full topic name; absolute names (``/clock``) pass through unchanged.

    ``topic("ego_state")`` is ``/lmpc/ego_state`` (single ego), ``topic("ego_state",
    "ego_2")`` is ``/ego_2/lmpc/ego_state`` (ego ``ego_2`` of a multi-ego graph)."""
    if name.startswith("/"):
        return name
    return f"/{ego_id}{ROOT}/{name}" if ego_id else f"{ROOT}/{name}"
