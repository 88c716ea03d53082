"""Multi-vehicle joint control (issue 18): what an ego reports and what it is told.

Like every message of ``lmpc_msgs_py.messages``: strict, frozen pydantic models carried as
JSON, each with its ``schema`` field; ``codec.decode`` refuses unknown fields, wrong types,
NaN / ±Inf, out-of-range values and an ego id that is not ``ego_<k>`` with one clear line
naming the field.

- :class:`EgoStatus`: an ego's planner reports its local status (paper, "Multi-vehicle
  Joint Control": "each distributed LLM shares its local status with the central LLM"):
  where it is on its route, its speed, its intent, the shared conflict it sees ahead and
  a summary of its current decision.
- :class:`Directive`: the coordinator's command to one ego: its priority in the conflict,
  ``yield`` (hold before the conflict's entry) or ``proceed``, a target speed band and a
  deadline in sim time after which the ego goes back to its own planner.
"""
from __future__ import annotations

from typing import Annotated, ClassVar, Literal, Optional

from pydantic import Field, ValidationInfo, field_validator

from lmpc_msgs_py.messages import (
    Ident,
    LmpcMessage,
    Seq,
    Speed,
    Stamp,
    _Part,
    _schema_field,
)

EGO_ID_PATTERN = r"^ego_[1-9][0-9]{0,2}$"
"""Ids of the controlled vehicles of a multi-ego scene: ``ego_1`` ... ``ego_999``."""
EgoId = Annotated[str, Field(pattern=EGO_ID_PATTERN)]
Dist = Annotated[float, Field(ge=0.0, le=1.0e6)]

Intent = Literal["cruise", "approach", "wait", "pass", "through", "done"]
"""What the ego is doing about the conflict ahead: ``cruise`` (none ahead), ``approach``
(one ahead, not in it), ``wait`` (holding before it), ``pass`` (inside it), ``through``
(left it behind), ``done`` (reached its target)."""
ConflictKind = Literal["narrow", "junction", "merge"]
Command = Literal["yield", "proceed"]


class ConflictView(_Part):
    """A shared conflict ahead as one ego sees it (distances along its own route)."""

    conflict_id: Ident
    """The same for every ego that meets it (e.g. the narrow section's edge pair)."""
    kind: ConflictKind
    via: Ident
    """The conflict's lane the ego takes (its direction through a narrow section)."""
    dist_to_entry_m: Dist
    """0 once the ego's front is at or past the entry."""
    dist_to_exit_m: Dist
    """0 once the ego's rear has left the conflict."""
    dist_to_hold_m: Dist = 0.0
    """To where it waits when it yields (before the junction that leads into the
    conflict); 0 once past it."""
    inside: bool = False
    oncoming: tuple[Ident, ...] = Field(default=(), max_length=100)
    """Vehicles the ego sees in the conflict or about to enter it against its direction."""
    inbound: tuple[Ident, ...] = Field(default=(), max_length=100)
    """Vehicles the ego sees in the conflict or about to enter it in ITS direction (e.g.
    a car following it): the other direction must let them through too."""

    @field_validator("dist_to_exit_m")
    @classmethod
    def _exit_after_entry(cls, value: float, info: ValidationInfo) -> float:
        entry = info.data.get("dist_to_entry_m")
        if entry is not None and value < entry:
            raise ValueError(f"{value} is before dist_to_entry_m {entry}")
        return value


class EgoStatus(LmpcMessage):
    """One ego's local status for the coordinator (and the other egos, ``distributed``)."""

    SCHEMA: ClassVar[str] = "lmpc/EgoStatus@1"
    schema_id: Literal["lmpc/EgoStatus@1"] = _schema_field("lmpc/EgoStatus@1")
    stamp_s: Stamp
    seq: Seq
    ego_id: EgoId
    route_index: Annotated[int, Field(ge=0)] = 0
    dist_to_target_m: Dist
    v_mps: Speed
    intent: Intent
    conflict: Optional[ConflictView] = Field(default=None, validate_default=True)
    """The shared conflict ahead (None: none within the status's look-ahead)."""
    decision_summary: str = Field(default="", max_length=200)
    """The decision in force in a few words (source, speed interval, attention)."""
    directive_id: Optional[Ident] = None
    """The directive the ego follows now (None: its own planner alone)."""

    @field_validator("conflict")
    @classmethod
    def _intent_matches_conflict(cls, value: Optional[ConflictView],
                                 info: ValidationInfo) -> Optional[ConflictView]:
        intent = info.data.get("intent")
        if value is None and intent in ("approach", "wait", "pass"):
            raise ValueError(f"missing, intent {intent!r} needs a conflict")
        return value


class SpeedBand(_Part):
    min_mps: Speed = 0.0
    max_mps: Speed

    @field_validator("max_mps")
    @classmethod
    def _ordered(cls, value: float, info: ValidationInfo) -> float:
        low = info.data.get("min_mps")
        if low is not None and value < low:
            raise ValueError(f"{value} is below min_mps {low}")
        return value


class Directive(LmpcMessage):
    """The coordinator's command to one ego (see the module docstring)."""

    SCHEMA: ClassVar[str] = "lmpc/Directive@1"
    schema_id: Literal["lmpc/Directive@1"] = _schema_field("lmpc/Directive@1")
    stamp_s: Stamp
    """Sim time of the statuses the directive was made from."""
    seq: Seq
    directive_id: Ident
    ego_id: EgoId
    conflict_id: Ident
    priority: Annotated[int, Field(ge=0, le=999)]
    """0 = first through the conflict."""
    command: Command
    speed_band: SpeedBand
    deadline_s: Stamp
    """Sim time after which the ego stops following it (a silent coordinator)."""
    source: Annotated[str, Field(pattern=r"^(rules|distributed|replay|llm:[\w.:/\-]{1,96})$")]
    reasoning: str = Field(default="", max_length=2000)

    @field_validator("deadline_s")
    @classmethod
    def _deadline_after_stamp(cls, value: float, info: ValidationInfo) -> float:
        stamp = info.data.get("stamp_s")
        if stamp is not None and value <= stamp:
            raise ValueError(f"{value} is not after stamp_s {stamp}")
        return value


COORDINATION_MESSAGES: tuple[type[LmpcMessage], ...] = (EgoStatus, Directive)
