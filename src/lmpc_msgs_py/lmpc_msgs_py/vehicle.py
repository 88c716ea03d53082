"""Ego vehicle parameters shared by the bridge (which integrates the ego) and the
MPC (which predicts it), so both use one model. Units in the names."""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class VehicleParams(BaseModel):
    """Kinematic bicycle of a mid-size car (reference point: box centre)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    length_m: float = Field(4.5, gt=0)
    width_m: float = Field(1.8, gt=0)
    wheelbase_m: float = Field(2.7, gt=0)
    """Distance between axles; the model's reference point is the box centre,
    with the rear axle ``lr_m`` behind it."""
    lr_m: float = Field(1.35, gt=0)
    """Centre of the box to rear axle (bicycle model slip angle uses lr / wheelbase)."""
    max_accel_mps2: float = Field(3.0, gt=0)
    max_decel_mps2: float = Field(6.0, gt=0)
    """Largest braking the controller may command (positive number)."""
    max_steer_rad: float = Field(0.6, gt=0)
    max_steer_rate_radps: float = Field(0.7, gt=0)
    max_speed_mps: float = Field(20.0, gt=0)
    safe_brake_mps2: float = Field(4.0, gt=0)
    """Bounded deceleration of every fallback brake (stale input, failed solver)."""


DEFAULT_VEHICLE = VehicleParams()
