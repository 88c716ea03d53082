"""Topic names of the graph (DESIGN §2), in one place.

All names are relative to a namespace root: ``/lmpc`` for a single ego,
``/lmpc/<ego_id>`` for several egos (see :func:`topic`).
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

LATCHED = (MAP, EPISODE)
"""The topics published latched (``lmpc_qos.LATCHED``): a late subscriber gets the last one."""


def topic(name: str, ego_id: str | None = None) -> str:
    """Full topic name; absolute names (``/clock``) pass through unchanged."""
    if name.startswith("/"):
        return name
    return f"{ROOT}/{ego_id}/{name}" if ego_id else f"{ROOT}/{name}"
