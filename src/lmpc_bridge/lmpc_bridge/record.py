"""Per-step episode record (JSON-able): what the metrics need, and enough to replay.

One :class:`StepRecord` per simulation step *after* the control of that step was
applied (so ``t_s`` of record k is ``k * dt``, k >= 1).
"""
from __future__ import annotations

from typing import Any, Optional

from pydantic import BaseModel, ConfigDict


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class NearbyVehicle(_Frozen):
    """Another participant within sensing range of the ego at one step."""

    id: str
    kind: str
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    v_max_mps: float
    """Its desired top speed: lane speed limit x its speedFactor (SUMO allowed speed),
    capped by its vType's maxSpeed."""
    a_mps2: float
    gap_m: float
    """Bumper-to-bumper distance between its box and the ego box (0 when they overlap)."""
    affected: bool = False
    """Follower of the ego or yielding to it (see docs/lmpc_bridge.md); used by ``ineff``."""
    affected_reason: str = ""
    at_red_light: bool = False
    """Its next traffic light within 30 m shows red / yellow: never counted by ``ineff``
    (paper: "vehicles stopped at red lights are excluded"), even when ``affected``."""
    length_m: Optional[float] = None
    """Its box length (for pictures / replay); None in records written before it existed."""
    width_m: Optional[float] = None
    """Its box width; None in records written before it existed."""


class StepRecord(_Frozen):
    step: int
    t_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    a_mps2: float
    steer_rad: float
    lane_id: Optional[str] = None
    route_index: int = 0
    dist_to_target_m: float = 0.0
    control_accel_mps2: Optional[float] = None
    """As received (None when missing / late / non-finite)."""
    control_steer_rad: Optional[float] = None
    applied_accel_mps2: float = 0.0
    applied_steer_rad: float = 0.0
    clamped: bool = False
    late: bool = False
    decision_id: Optional[str] = None
    control_mode: Optional[str] = None
    solve_time_ms: Optional[float] = None
    nearby: tuple[NearbyVehicle, ...] = ()
    collided_with: Optional[str] = None


class EpisodeRecord(_Frozen):
    family: str
    seed: int
    description: str = ""
    dt_s: float
    max_time_s: float
    target_center: tuple[float, float]
    target_radius_m: float
    outcome: str = "running"
    reached_at_s: Optional[float] = None
    collided_with: Optional[str] = None
    held_insertions: int = 0
    """Vehicles SUMO inserted onto the ego's body that the bridge took out again until
    their spot was clear (``lmpc_bridge.insertion``; one per hold)."""
    insertion_holds: tuple[str, ...] = ()
    """One line per hold and per release (time, vehicle, place)."""
    shadows: int = 0
    """How often the ego stood across two lanes and the bridge put its shadow (a standing
    vehicle SUMO's drivers see) on the second lane (``lmpc_bridge.shadow``)."""
    shadow_log: tuple[str, ...] = ()
    """One line per placement and removal of the shadow."""
    steps: tuple[StepRecord, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict of the record (``json.dumps`` it, or use ``model_dump_json()``)."""
        return self.model_dump(mode="json")
