"""The decision vocabulary: what a ``Decision`` may choose, defined once for the graph.

A :class:`DecisionSpace` holds the acceleration and steer-angle intervals of the action
guidance (paper stage 2; the neutral band is the interval that contains 0) and the weight
pool of the weight adjustment (stage 3: three levels of four groups). It is loaded from
one YAML file (the packaged ``config/decision_space.yaml`` unless a node or script names
another) by both sides of the graph:

- the planner offers the intervals and levels to the LLM and sends **indices and level
  names** (``Decision.accel_interval``, ``steer_interval``, ``weights``), never numbers;
- the MPC alone turns them into numbers (:meth:`DecisionSpace.bias_for`,
  :meth:`DecisionSpace.weights_for`).

Each Decision carries :attr:`DecisionSpace.space_hash` of the space it was made in; the
MPC refuses a Decision whose hash is not its own (an index means another number in
another space). The hash covers the validated content only (not comments, key order or
number spelling).
"""
from __future__ import annotations

import hashlib
import json
from functools import cached_property
from pathlib import Path
from typing import Generic, Literal, Sequence, TypeVar

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, \
    model_validator

from lmpc_msgs_py.messages import WeightLevels
from lmpc_msgs_py.yamlfile import first_field_error, read_mapping

DEFAULT_SPACE_PATH = Path(__file__).resolve().parent / "config" / "decision_space.yaml"
"""The packaged decision space (the one the planner and the MPC use unless told)."""
SPACE_HASH_CHARS = 16
"""Hex characters of the sha256 kept as the space's hash (64 bits)."""

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class DecisionSpaceError(ValueError):
    """The decision-space file is missing, unreadable or invalid (names the field)."""


class TrackingWeights(BaseModel):
    """Diagonal ``W_x``, ``W_v``, ``W_theta`` of the tracking cost ``C_trk``."""

    model_config = _STRICT
    w_pos: float = Field(ge=0.0)
    """Weight on the squared x and y position error to the reference [1/m^2]."""
    w_v: float = Field(ge=0.0)
    """Weight on the squared speed error [1/(m/s)^2]."""
    w_yaw: float = Field(ge=0.0)
    """Weight on the squared (wrapped) yaw error [1/rad^2]."""
    w_steer: float = Field(ge=0.0)
    """Weight on the squared error to the reference's curvature steer angle [1/rad^2]."""


class ActionWeights(BaseModel):
    """Diagonal ``W_s`` of ``(A - A_hat)^T W_s (A - A_hat)``."""

    model_config = _STRICT
    w_accel: float = Field(ge=0.0)
    """Weight on the squared distance of the acceleration to its bias [1/(m/s^2)^2]."""
    w_steer: float = Field(ge=0.0)
    """Weight on the squared distance of the steer angle to its bias [1/rad^2]."""


class SmoothnessWeights(BaseModel):
    """Diagonal ``W_g`` (first difference) and ``W_l`` (second difference) of ``A``."""

    model_config = _STRICT
    w_g_accel: float = Field(ge=0.0)
    """Weight on the squared step-to-step change of the acceleration."""
    w_g_steer: float = Field(ge=0.0)
    """Weight on the squared step-to-step change of the steer angle."""
    w_l_accel: float = Field(ge=0.0)
    """Weight on the squared second difference of the acceleration."""
    w_l_steer: float = Field(ge=0.0)
    """Weight on the squared second difference of the steer angle."""


class SafetyWeights(BaseModel):
    """Scalar ``w_saf`` of ``C_saf = w_saf sum max(0, d_hat - d)^2``."""

    model_config = _STRICT
    w_saf: float = Field(ge=0.0)
    """Weight on the squared shortfall of the distance to each attended agent [1/m^2]."""


W = TypeVar("W", bound=BaseModel)


class LevelSet(BaseModel, Generic[W]):
    """The three levels of one weight group."""

    model_config = _STRICT
    low: W
    """Weights when the planner asks for less of this term."""
    normal: W
    """Weights of the baseline and of a decision that leaves the group alone."""
    high: W
    """Weights when the planner asks for more of this term."""

    def at(self, level: Literal["low", "normal", "high"]) -> W:
        """The weights of ``level``."""
        out: W = getattr(self, level)
        return out


class WeightPool(BaseModel):
    """The four groups of weights the planner chooses levels from (paper stage 3)."""

    model_config = _STRICT
    tracking: LevelSet[TrackingWeights]
    """Tracking group: position, speed, yaw / steer errors."""
    action: LevelSet[ActionWeights]
    """Action group: pull of the control towards the bias ``A_hat``."""
    smoothness: LevelSet[SmoothnessWeights]
    """Smoothness group: first and second differences of the control."""
    safety: LevelSet[SafetyWeights]
    """Safety group: one-sided distance penalty to attended agents."""


class ResolvedWeights(BaseModel):
    """The numbers of one choice of levels (what the MPC's cost receives)."""

    model_config = _STRICT
    tracking: TrackingWeights
    action: ActionWeights
    smoothness: SmoothnessWeights
    safety: SafetyWeights


Interval = tuple[float, float]


def _check_intervals(name: str, intervals: tuple[Interval, ...]) -> None:
    if len(intervals) < 2:
        raise ValueError(f"{name}: needs at least 2 intervals, got {len(intervals)}")
    if len(intervals) > 32:  # Decision.accel_interval / steer_interval are 0..31
        raise ValueError(f"{name}: at most 32 intervals, got {len(intervals)}")
    for i, (lo, hi) in enumerate(intervals):
        if not lo < hi:
            raise ValueError(f"{name}[{i}]: lower bound {lo} must be below upper bound {hi}")
        if i and lo < intervals[i - 1][1] - 1e-9:
            raise ValueError(f"{name}[{i}]: intervals must be sorted and not overlap")
    if not any(lo <= 0.0 <= hi for lo, hi in intervals):
        raise ValueError(f"{name}: no interval contains 0 (a neutral interval is required)")


def midpoint(interval: Interval) -> float:
    """The bias an interval stands for: its midpoint."""
    return 0.5 * (interval[0] + interval[1])


def neutral_index(intervals: Sequence[Interval]) -> int:
    """The neutral band: among the intervals containing 0 the one whose midpoint is
    nearest 0 (the lowest index on a tie); a pool without one (only a partial pool a rule
    looks at; a DecisionSpace always has one): the interval with the midpoint nearest 0."""
    containing = [i for i, (lo, hi) in enumerate(intervals) if lo <= 0.0 <= hi]
    pool = containing or list(range(len(intervals)))
    return min(pool, key=lambda i: (abs(midpoint(intervals[i])), i))


class DecisionSpace(BaseModel):
    """The action intervals and the weight pool a Decision chooses from (see module doc)."""

    model_config = _STRICT
    weight_pool: WeightPool
    """The levels of the four weight groups (the planner picks names, never numbers)."""
    accel_intervals_mps2: tuple[Interval, ...]
    """Acceleration intervals of the action guidance, sorted; midpoints are the bias [m/s^2]."""
    steer_intervals_rad: tuple[Interval, ...]
    """Steer-angle intervals of the action guidance, sorted; midpoints are the bias [rad]."""
    _source: str = PrivateAttr(default="<in memory>")

    @model_validator(mode="after")
    def _check(self) -> "DecisionSpace":
        _check_intervals("accel_intervals_mps2", self.accel_intervals_mps2)
        _check_intervals("steer_intervals_rad", self.steer_intervals_rad)
        return self

    @property
    def source(self) -> str:
        """The file the space was loaded from (``<in memory>`` if built in code)."""
        return self._source

    @cached_property
    def space_hash(self) -> str:
        """First :data:`SPACE_HASH_CHARS` hex characters of the sha256 of the canonical
        JSON of the content (sorted keys, no spaces): equal spaces, equal hashes."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:SPACE_HASH_CHARS]

    def describe(self) -> str:
        """``"<hash> (<file>)"``: how error messages name the space."""
        return f"{self.space_hash} ({self.source})"

    @cached_property
    def neutral_accel_index(self) -> int:
        """Index of the acceleration interval that contains 0 (the neutral band)."""
        return neutral_index(self.accel_intervals_mps2)

    @cached_property
    def neutral_steer_index(self) -> int:
        """Index of the steer interval that contains 0 (the neutral band)."""
        return neutral_index(self.steer_intervals_rad)

    @property
    def neutral_accel_band(self) -> Interval:
        """The neutral acceleration interval ``(lo, hi)`` [m/s^2]: a bias below ``lo``
        brakes, one above ``hi`` speeds up."""
        return self.accel_intervals_mps2[self.neutral_accel_index]

    def bias_for(self, accel_index: int, steer_index: int) -> tuple[float, float]:
        """Bias ``A_hat = (accel_mps2, steer_rad)``: midpoints of the chosen intervals.

        Raises :class:`IndexError` naming the list when an index is out of range.
        """
        if not 0 <= accel_index < len(self.accel_intervals_mps2):
            raise IndexError(
                f"accel_index {accel_index} out of range 0..{len(self.accel_intervals_mps2) - 1}"
            )
        if not 0 <= steer_index < len(self.steer_intervals_rad):
            raise IndexError(
                f"steer_index {steer_index} out of range 0..{len(self.steer_intervals_rad) - 1}"
            )
        return (midpoint(self.accel_intervals_mps2[accel_index]),
                midpoint(self.steer_intervals_rad[steer_index]))

    def weights_for(self, levels: WeightLevels | None = None) -> ResolvedWeights:
        """The numbers of the chosen levels (``None``: all "normal", the baseline)."""
        lv = levels if levels is not None else WeightLevels()
        pool = self.weight_pool
        return ResolvedWeights(
            tracking=pool.tracking.at(lv.tracking),
            action=pool.action.at(lv.action),
            smoothness=pool.smoothness.at(lv.smoothness),
            safety=pool.safety.at(lv.safety),
        )


def load_decision_space(path: str | Path | None = None) -> DecisionSpace:
    """Load and validate a decision space (``None`` or ``""``: the packaged default).

    Raises :class:`DecisionSpaceError` naming the file, the field and the reason.
    """
    file = Path(path) if path is not None and str(path) != "" else DEFAULT_SPACE_PATH
    data = read_mapping(file, what="decision space", error=DecisionSpaceError)
    try:
        space = DecisionSpace.model_validate(data)
    except ValidationError as exc:
        raise DecisionSpaceError(first_field_error("decision space", file, exc)) from None
    space._source = str(file)
    return space


def space_mismatch(space: DecisionSpace, decision_hash: str) -> str | None:
    """One line naming both hashes when ``decision_hash`` is not ``space``'s, else None."""
    if decision_hash == space.space_hash:
        return None
    return (f"decision made in decision space {decision_hash!r}, but this node's space is "
            f"{space.describe()}: the planner and the MPC must load the same decision-space "
            "file (planner parameter decision_space_file, MPC config decision_space_file)")
