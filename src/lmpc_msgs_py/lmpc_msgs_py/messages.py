"""Message schemas of the LanguageMPC graph (DESIGN §3).

Every message is a strict, frozen pydantic model carried as JSON in a
``std_msgs/String``. Each carries a ``schema`` field ``"lmpc/<Name>@<version>"``;
receivers refuse unknown fields, wrong types, NaN / ±Inf and physically absurd
values (RELIABILITY.md). Units are in the field names.

Conventions (ROS REP 103 where it applies):
- positions are SUMO network coordinates in metres, x east, y north;
- ``yaw_rad`` is counter-clockwise from +x (east), in (-pi, pi];
- vehicle positions are the **centre of the bounding box** (SUMO reports the
  front bumper; the bridge converts);
- ``stamp_s`` is simulation time in seconds (the bridge's ``/clock``).
"""
from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

# --- physical bounds (refuse absurd values, RELIABILITY.md) -------------------------------
MAX_COORD_M = 1.0e6
MAX_SPEED_MPS = 70.0
MAX_ACCEL_MPS2 = 15.0
MAX_STEER_RAD = 1.0
MAX_VEHICLE_DIM_M = 30.0
MAX_LIST_LEN = 5000
MAX_ID_CHARS = 1024
"""Longest id (lane, edge, junction, traffic light, vehicle...) a message carries.

SUMO itself has no limit. netconvert's junction joining builds ids from the joined
ids: OSM city imports give internal lane ids of 170+ characters, and a test network
joined twice (test_bridge_limits.py) gives 191 (``:cluster_306484187_cluster_...``).
Every further join can multiply the length by up to four (``--max-join-ids`` 4), so
the bound sits ~5x above the longest seen; it still bounds a message (200 attended
agents x 1 KiB << the 1 MiB payload limit). Was 128 until issue 21. Scene files are
checked against it before anything starts (``lmpc_bridge.scenarios.limits``)."""
MAX_LANE_INDEX = 64
MAX_LANE_WIDTH_M = 20.0
MAX_LANE_LENGTH_M = 1.0e5

Coord = Annotated[float, Field(ge=-MAX_COORD_M, le=MAX_COORD_M)]
Yaw = Annotated[float, Field(ge=-2.0 * math.pi, le=2.0 * math.pi)]
Speed = Annotated[float, Field(ge=0.0, le=MAX_SPEED_MPS)]
Accel = Annotated[float, Field(ge=-MAX_ACCEL_MPS2, le=MAX_ACCEL_MPS2)]
Steer = Annotated[float, Field(ge=-MAX_STEER_RAD, le=MAX_STEER_RAD)]
Stamp = Annotated[float, Field(ge=0.0, le=1.0e7)]
Seq = Annotated[int, Field(ge=0)]
Dim = Annotated[float, Field(gt=0.0, le=MAX_VEHICLE_DIM_M)]
Point = tuple[Coord, Coord]
Ident = Annotated[str, Field(min_length=1, max_length=MAX_ID_CHARS)]


class LmpcMessage(BaseModel):
    """Base of every message: strict, frozen, no unknown fields, no NaN/Inf."""

    model_config = ConfigDict(
        extra="forbid",
        frozen=True,
        allow_inf_nan=False,
        strict=True,
        populate_by_name=True,
    )
    SCHEMA: ClassVar[str] = ""


class _Part(BaseModel):
    """Base of nested parts (no schema field of their own)."""

    model_config = LmpcMessage.model_config


def _schema_field(name: str) -> Any:
    return Field(default=name, alias="schema")


# --- map ---------------------------------------------------------------------------------
TurnDirection = Literal["s", "l", "r", "t", "L", "R", "invalid"]
"""SUMO link direction: straight, left, right, turnaround, partly left/right."""


class LaneLink(_Part):
    to_lane: Ident
    via_lane: Optional[Ident] = None
    """Internal junction lane that carries the connection (its shape is in ``lanes``)."""
    direction: TurnDirection
    signalized: bool = False
    tls_id: Optional[Ident] = None
    link_index: Optional[Annotated[int, Field(ge=0)]] = None


class Lane(_Part):
    id: Ident
    edge_id: Ident
    index: Annotated[int, Field(ge=0, le=MAX_LANE_INDEX)]
    centerline: tuple[Point, ...] = Field(min_length=2, max_length=MAX_LIST_LEN)
    width_m: Annotated[float, Field(gt=0.0, le=MAX_LANE_WIDTH_M)]
    speed_limit_mps: Speed
    length_m: Annotated[float, Field(ge=0.0, le=MAX_LANE_LENGTH_M)]
    internal: bool = False
    """True for a lane inside a junction (SUMO ``:junction_..`` lanes)."""
    successors: tuple[LaneLink, ...] = ()
    allowed: tuple[Annotated[str, Field(max_length=32)], ...] = Field(default=(), max_length=16)
    """Vehicle classes allowed on the lane (SUMO vClass names); empty = unknown."""
    left_lane: Optional[Ident] = None
    """Neighbour lane to the left on the same edge that shares a vehicle class."""
    right_lane: Optional[Ident] = None
    roundabout: bool = False
    """Lane of a roundabout ring (or inside one of its junctions)."""


class StopLine(_Part):
    lane_id: Ident
    position: Point
    """Where the lane meets the junction (end of its centerline)."""
    junction_id: Ident
    signalized: bool


class TargetArea(_Part):
    lane_ids: tuple[Ident, ...] = Field(min_length=1)
    center: Point
    radius_m: Annotated[float, Field(gt=0.0, le=1000.0)]


class MapSnapshot(LmpcMessage):
    SCHEMA: ClassVar[str] = "lmpc/MapSnapshot@1"
    schema_id: Literal["lmpc/MapSnapshot@1"] = _schema_field("lmpc/MapSnapshot@1")
    stamp_s: Stamp
    seq: Seq = 0
    version: Annotated[int, Field(ge=0)] = 0
    """Increments whenever the content changes (the topic is latched)."""
    lanes: tuple[Lane, ...] = Field(max_length=MAX_LIST_LEN)
    stop_lines: tuple[StopLine, ...] = ()
    ego_route: tuple[Ident, ...] = Field(min_length=1)
    """The ego's route as a lane sequence (internal junction lanes included)."""
    target: TargetArea
    left_hand_traffic: bool = False


# --- ego and agents ----------------------------------------------------------------------
class EgoState(LmpcMessage):
    SCHEMA: ClassVar[str] = "lmpc/EgoState@1"
    schema_id: Literal["lmpc/EgoState@1"] = _schema_field("lmpc/EgoState@1")
    stamp_s: Stamp
    seq: Seq
    x_m: Coord
    y_m: Coord
    yaw_rad: Yaw
    v_mps: Speed
    a_mps2: Accel
    steer_rad: Steer
    length_m: Dim = 4.5
    width_m: Dim = 1.8
    lane_id: Optional[Ident] = None
    lane_pos_m: Annotated[float, Field(ge=-1.0, le=1.0e5)] = 0.0
    route_index: Annotated[int, Field(ge=0)] = 0
    """Index of ``lane_id`` in ``MapSnapshot.ego_route`` (progress along the route)."""
    dist_to_target_m: Annotated[float, Field(ge=0.0, le=1.0e6)]
    required_decision_id: Optional[Ident] = None
    """Sync mode barrier: the newest decision the bridge has seen; the MPC must
    have received it before computing the control for this step."""


AgentKind = Literal["car", "truck", "bus", "motorcycle", "bicycle", "pedestrian"]


class AgentSignals(_Part):
    left: bool = False
    right: bool = False
    brake: bool = False


class HistoryPoint(_Part):
    t_s: Stamp
    x_m: Coord
    y_m: Coord
    v_mps: Speed


class Agent(_Part):
    id: Ident
    kind: AgentKind
    x_m: Coord
    y_m: Coord
    yaw_rad: Yaw
    v_mps: Speed
    a_mps2: Accel
    length_m: Dim
    width_m: Dim
    lane_id: Optional[Ident] = None
    lane_pos_m: Annotated[float, Field(ge=-1.0, le=1.0e5)] = 0.0
    signals: AgentSignals = AgentSignals()
    history: tuple[HistoryPoint, ...] = Field(default=(), max_length=100)


class AgentArray(LmpcMessage):
    SCHEMA: ClassVar[str] = "lmpc/AgentArray@1"
    schema_id: Literal["lmpc/AgentArray@1"] = _schema_field("lmpc/AgentArray@1")
    stamp_s: Stamp
    seq: Seq
    sensing_range_m: Annotated[float, Field(gt=0.0, le=1000.0)] = 80.0
    agents: tuple[Agent, ...] = Field(default=(), max_length=1000)


# --- signals -----------------------------------------------------------------------------
SignalState = Literal["r", "y", "g", "G", "s", "u", "o", "O", "off"]
"""SUMO link state letters: red, yellow, green (minor), green (major), stop,
red-yellow, off-blinking, off-no-signal; ``off`` for unsignalized."""


class LinkSignal(_Part):
    tls_id: Ident
    link_index: Annotated[int, Field(ge=0)]
    from_lane: Ident
    to_lane: Ident
    state: SignalState
    time_to_switch_s: Optional[Annotated[float, Field(ge=0.0, le=1.0e4)]] = None
    distance_m: Annotated[float, Field(ge=0.0, le=1.0e5)] = 0.0
    """Distance along the ego route from the ego to this link's stop line."""


class SignalStates(LmpcMessage):
    SCHEMA: ClassVar[str] = "lmpc/SignalStates@1"
    schema_id: Literal["lmpc/SignalStates@1"] = _schema_field("lmpc/SignalStates@1")
    stamp_s: Stamp
    seq: Seq
    links: tuple[LinkSignal, ...] = Field(default=(), max_length=MAX_LIST_LEN)


# --- decision ----------------------------------------------------------------------------
DecisionSource = Annotated[
    str, Field(pattern=r"^(rules|oracle|fallback|replay|mock|llm:[\w.:/\-]{1,96}"
                       r"|policy:[\w.\-]{1,32})$")]
"""Who made a decision; ``policy:<name>``: a learned planner (``dqn``, ``ppo``, ``sac``:
docs/RL.md) in place of the reasoner."""
DecisionMode = Literal["normal", "emergency"]
WeightLevel = Literal["low", "normal", "high"]


class BezierTrajectory(_Part):
    candidate_id: Annotated[int, Field(ge=0, le=2)]
    control_points: tuple[Point, ...] = Field(min_length=2, max_length=16)
    label: str = Field(default="", max_length=120)
    """Words for the prompt, e.g. ``"turn left at the junction"``."""


class AgentPrediction(_Part):
    agent_id: Ident
    trajectory: BezierTrajectory


class WeightLevels(_Part):
    tracking: WeightLevel = "normal"
    action: WeightLevel = "normal"
    smoothness: WeightLevel = "normal"
    safety: WeightLevel = "normal"


SpaceHash = Annotated[str, Field(pattern=r"^[0-9a-f]{16}$")]
"""``lmpc_msgs_py.vocabulary.DecisionSpace.space_hash``: 16 lower-case hex characters."""


class Decision(LmpcMessage):
    """The LLM's three-stage output after translation (DESIGN §3).

    It carries choices, not numbers: interval indices and weight levels of the decision
    space whose hash is ``space_hash`` (``lmpc_msgs_py.vocabulary``); the MPC turns them
    into the bias and the weights, and refuses a decision from another space.
    Version 2 (issue 15) dropped the numeric ``accel_bias_mps2`` / ``steer_bias_rad`` of
    version 1 and added ``space_hash``: a receiver of one version refuses the other by
    its schema name. Old decision logs still replay (``lmpc-replay`` answers from the
    recorded raw LLM text, not from the recorded Decision)."""

    SCHEMA: ClassVar[str] = "lmpc/Decision@2"
    schema_id: Literal["lmpc/Decision@2"] = _schema_field("lmpc/Decision@2")
    stamp_s: Stamp
    """Sim time of the observation the decision used."""
    seq: Seq
    decision_id: Ident
    source: DecisionSource
    mode: DecisionMode = "normal"
    latency_s: Annotated[float, Field(ge=0.0, le=600.0)]
    """Wall latency of the call (or the configured fixed value); the decision
    takes effect at ``stamp_s + max(latency_s, dt)``."""
    tokens_in: Annotated[int, Field(ge=0)] = 0
    tokens_out: Annotated[int, Field(ge=0)] = 0
    ttl_s: Annotated[float, Field(gt=0.0, le=60.0)] = 5.0
    # stage 1: scenario encoding
    ego_trajectory: BezierTrajectory
    agent_predictions: tuple[AgentPrediction, ...] = Field(default=(), max_length=200)
    attention: tuple[Ident, ...] = Field(default=(), max_length=200)
    # stage 2: action guidance (indices into the space's intervals; bias = midpoints)
    accel_interval: Annotated[int, Field(ge=0, le=31)]
    steer_interval: Annotated[int, Field(ge=0, le=31)]
    # stage 3: weight adjustment (levels of the space's weight pool)
    weights: WeightLevels = WeightLevels()
    space_hash: SpaceHash
    """Hash of the decision space the indices and levels refer to."""
    reasoning: str = Field(default="", max_length=8000)

    @model_validator(mode="after")
    def _predictions_match_attention(self) -> "Decision":
        attended = set(self.attention)
        if len(attended) != len(self.attention):
            raise ValueError("attention lists an agent twice")
        for pred in self.agent_predictions:
            if pred.agent_id not in attended:
                raise ValueError(f"prediction for agent {pred.agent_id!r} that is not attended")
        return self


# --- control -----------------------------------------------------------------------------
ControlMode = Literal["decision", "baseline", "shifted", "brake"]
"""``decision``: a valid decision is in force; ``baseline``: none (fixed weights,
all agents); ``shifted``: the solver failed, previous plan shifted; ``brake``:
bounded braking (solver failed repeatedly or inputs stale)."""


class PosePoint(_Part):
    x_m: Coord
    y_m: Coord
    yaw_rad: Yaw
    v_mps: Annotated[float, Field(ge=-5.0, le=MAX_SPEED_MPS)]


class Control(LmpcMessage):
    SCHEMA: ClassVar[str] = "lmpc/Control@1"
    schema_id: Literal["lmpc/Control@1"] = _schema_field("lmpc/Control@1")
    stamp_s: Stamp
    """Stamp of the ego state this control answers."""
    seq: Seq
    accel_mps2: Accel
    steer_rad: Steer
    mode: ControlMode
    solver_status: str = Field(max_length=200)
    solve_time_ms: Annotated[float, Field(ge=0.0, le=1.0e6)]
    decision_id: Optional[Ident] = None
    reference_id: Optional[Annotated[int, Field(ge=0, le=2)]] = None
    attended: tuple[Ident, ...] = Field(default=(), max_length=1000)
    predicted: tuple[PosePoint, ...] = Field(default=(), max_length=200)
    stale: tuple[Ident, ...] = Field(default=(), max_length=1000)
    """What the MPC's stale-decision check overrode on this step (``lmpc_mpc.stale``): the
    agents it re-attended with its own forecast or refused a "go" for, then ``go`` when
    it refused the decision's go bias (``lane_change``: its lane change, ``brake``: its
    braking on a roundabout with a car closing in from behind). Empty: the decision in
    force held (or none)."""


# --- episode -----------------------------------------------------------------------------
EpisodeOutcome = Literal["running", "reached", "collision", "timeout", "off_route", "error"]
"""``off_route`` (since ``EpisodeStatus@2``): the ego drove onto a road that is not on its
route (the bridge's ``route_watch``); a failure like ``timeout``."""


class EpisodeMetrics(_Part):
    time_s: Annotated[float, Field(ge=0.0)]
    ineff: Annotated[float, Field(ge=0.0)] = 0.0
    pen_acc: Annotated[float, Field(ge=0.0)] = 0.0
    pen_dist: Annotated[float, Field(ge=0.0)] = 0.0
    overall_cost: Annotated[float, Field(ge=0.0)] = 0.0
    collisions: Annotated[int, Field(ge=0)] = 0
    steps: Annotated[int, Field(ge=0)] = 0
    late_controls: Annotated[int, Field(ge=0)] = 0
    clamped_controls: Annotated[int, Field(ge=0)] = 0


class EpisodeStatus(LmpcMessage):
    """Version 2 added the outcome ``off_route``: a receiver of version 1 refuses a
    version-2 message by its schema name instead of failing on an unknown outcome."""

    SCHEMA: ClassVar[str] = "lmpc/EpisodeStatus@2"
    schema_id: Literal["lmpc/EpisodeStatus@2"] = _schema_field("lmpc/EpisodeStatus@2")
    stamp_s: Stamp
    seq: Seq
    scenario: Ident
    seed: Annotated[int, Field(ge=0)]
    outcome: EpisodeOutcome
    detail: str = Field(default="", max_length=1000)
    collided_with: Optional[Ident] = None
    metrics: EpisodeMetrics


# --- planner status (sync barrier and heartbeat) -----------------------------------------
class PlannerStatus(LmpcMessage):
    """Published by the planner after it processed an observation.

    In sync mode the bridge waits for the status of step *k* before it steps, so
    a decision requested at *k* is never overtaken by simulated time."""

    SCHEMA: ClassVar[str] = "lmpc/PlannerStatus@1"
    schema_id: Literal["lmpc/PlannerStatus@1"] = _schema_field("lmpc/PlannerStatus@1")
    stamp_s: Stamp
    """Stamp of the observation just processed."""
    seq: Seq
    last_decision_id: Optional[Ident] = None
    decisions: Annotated[int, Field(ge=0)] = 0
    fallbacks: Annotated[int, Field(ge=0)] = 0
    dropped_messages: Annotated[int, Field(ge=0)] = 0


ALL_MESSAGES: tuple[type[LmpcMessage], ...] = (
    MapSnapshot,
    EgoState,
    AgentArray,
    SignalStates,
    Decision,
    Control,
    EpisodeStatus,
    PlannerStatus,
)
