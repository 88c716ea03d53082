"""LanguageMPC message schemas, JSON codec, topic names and QoS profiles."""
from lmpc_msgs_py.codec import DecodeError, decode, encode
from lmpc_msgs_py.freshness import SequenceGate, StaleMessage, is_stale
from lmpc_msgs_py.messages import (
    ALL_MESSAGES,
    Agent,
    AgentArray,
    AgentPrediction,
    AgentSignals,
    BezierTrajectory,
    Control,
    Decision,
    EgoState,
    EpisodeMetrics,
    EpisodeStatus,
    HistoryPoint,
    Lane,
    LaneLink,
    LinkSignal,
    LmpcMessage,
    MapSnapshot,
    PlannerStatus,
    PosePoint,
    SignalStates,
    StopLine,
    TargetArea,
    WeightLevels,
)
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

__all__ = [
    "ALL_MESSAGES", "Agent", "AgentArray", "AgentPrediction", "AgentSignals",
    "BezierTrajectory", "Control", "Decision", "DecodeError", "EgoState", "EpisodeMetrics",
    "EpisodeStatus", "HistoryPoint", "Lane", "LaneLink", "LinkSignal", "LmpcMessage",
    "MapSnapshot", "Observation", "PlannerStatus", "PosePoint", "SequenceGate",
    "SignalStates", "StaleMessage", "StopLine", "TargetArea", "WeightLevels",
    "decode", "encode", "is_stale", "DEFAULT_VEHICLE", "VehicleParams",
]
