"""Obstacles of the MPC problem: their safety-zone rows per stage and the per-stage slots.

Every attended agent (and a red-light stop line) becomes one :class:`Obstacle` over the
horizon. :func:`obstacle_rows` turns them into slot rows ``(ox, oy, gap, headway, rho,
on)`` per stage (the safety zone of ``solver``'s ``C_saf``); :func:`pack` keeps, per stage,
only the obstacles whose safety term can matter there, nearest first, and linearises each
stretched distance into a half-plane (the rows the compiled problem takes as parameters).
Moved out of :mod:`lmpc_mpc.solver` unchanged (2026-12-06); ``MpcSolver`` calls :func:`pack`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from lmpc_msgs_py.vehicle import VehicleParams
from lmpc_mpc.config import MpcConfig
from lmpc_mpc.model import NOBS

_RELEVANCE_MARGIN_M = 6.0
"""An obstacle farther than this beyond ``d_hat`` from every guess of the ego at a stage
is left out of that stage (its safety term is zero there; see ``pack``)."""
_RELEVANCE_SPEED_MPS = 3.0
"""Speed added to the guesses' speed when judging relevance (``d_hat`` grows with v)."""
_BEHIND_RHO = 2.5
"""Lateral stretch of the safety zone of an agent behind the ego (the side clearance is
``1 / _BEHIND_RHO`` as effective): with the plain ellipse a follower closing in made the
ego swerve off its lane while braking (usi seed 6); a car behind in the next lane
(3.2 m over) stays outside the zone."""
_SAME_WAY_COS = 0.5
"""A follower whose forecast moves within 60 degrees of the ego's heading goes "our way"
(see ``_trailing``)."""
_STANDING_M = 0.5
"""A forecast that moves less than this over the horizon is a standing agent."""


class MpcInputError(ValueError):
    """An MPC problem with inconsistent shapes or non-finite numbers."""


@dataclass(frozen=True)
class Obstacle:
    """One attended participant (or a virtual stop-line obstacle) over the horizon."""

    obstacle_id: str
    xy_m: np.ndarray
    """(N+1, 2) predicted box centres, row k at t = k dt."""
    length_m: float
    width_m: float
    virtual: bool = False
    """A red-light stop line: no headway, a small gap."""
    beside: bool = False
    """Its forecast stays laterally clear of the ego's reference path over the whole
    horizon (``MpcController._lead_limits``): it never enters the path, so no headway
    (a time gap belongs to a car the ego follows or meets on its path). Otherwise, in
    a tight turn out of a junction, a car standing at the stop line of the opposite lane
    of the road turned into sits nearly dead ahead in the frame of the turn's tangent,
    and its headway held the ego in the junction for good (issue 21)."""
    yaw_rad: Optional[float] = None
    """The agent's heading now (None: unknown, e.g. a virtual obstacle)."""
    junction: bool = False
    """The agent or the ego is on a junction's internal lane now: a slow agent's box
    corners are tested against the path (``crossing._body_on_path``)."""


def slots_for(config: MpcConfig, n_obstacles: int) -> int:
    """The smallest compiled size (``agent_slot_sizes``) that holds ``n_obstacles``."""
    for size in config.agent_slot_sizes:
        if size >= n_obstacles:
            return size
    return config.agent_slot_sizes[-1]


def obstacle_rows(obs: Sequence[Obstacle], ref: np.ndarray, yaw_ref: np.ndarray, *,
                  config: MpcConfig, vehicle: VehicleParams) -> Optional[np.ndarray]:
    """(n_obs, N+1, NOBS) slot rows (ox, oy, gap, headway, rho, on) of every obstacle
    at every stage, or None without obstacles. One vectorised pass."""
    n, cfg, veh = config.horizon, config, vehicle
    if not obs:
        return None
    n_o = len(obs)
    xy = np.empty((n_o, n + 1, 2))
    for i, ob in enumerate(obs):
        a = np.asarray(ob.xy_m, dtype=float)
        if a.shape != (n + 1, 2):
            raise MpcInputError(f"obstacle {ob.obstacle_id!r}: xy_m must be ({n + 1}, 2), "
                                f"got {a.shape}")
        xy[i] = a
    half_l = 0.5 * veh.length_m
    half_w = 0.5 * veh.width_m
    length = np.array([ob.length_m for ob in obs])[:, None]
    width = np.array([ob.width_m for ob in obs])[:, None]
    virtual = np.array([ob.virtual for ob in obs])[:, None]
    beside = np.array([ob.beside for ob in obs])[:, None]
    cos_r, sin_r = np.cos(yaw_ref), np.sin(yaw_ref)
    lon_ahead = (xy[:, :, 0] - ref[:, 0]) * cos_r + (xy[:, :, 1] - ref[:, 1]) * sin_r
    lat_clear = half_w + 0.5 * width + cfg.safety_lateral_gap_m
    ahead = lon_ahead > -half_l
    # behind the ego only near-overlap counts (a follower must not push us on); a
    # red-light stop line has no headway and a small gap
    gap_k = np.where(virtual, half_l + 1.0,
                     np.where(ahead, cfg.safety_gap_m + half_l + 0.5 * length,
                              half_l + 0.5 * length + 0.5))
    head = np.where(virtual | ~ahead | beside, 0.0, cfg.safety_headway_s)
    d_hat_ref = gap_k + head * ref[:, 3]
    rows = np.empty((n_o, n + 1, NOBS))
    rows[:, :, 0:2] = xy
    rows[:, :, 2] = gap_k
    rows[:, :, 3] = head
    # behind the ego the zone is wide (rho >= _BEHIND_RHO): a follower closing in can
    # only be answered along the road; a sideways escape off the lane is no answer
    rho = np.maximum(d_hat_ref / lat_clear, 1.0)
    rows[:, :, 4] = np.where(ahead | virtual, rho, np.maximum(rho, _BEHIND_RHO))
    # an agent behind the ego now (a follower) is its own driver's business while it
    # stays behind: its constant-speed forecast runs into a braking ego, and the term
    # then pushed the ego sideways off its lane (usi seed 1); once it is level or
    # ahead (overtaking) it counts again
    follower = (~ahead[:, :1]) & ~virtual
    # ... except a follower in the ego's lane going its way (a trailing car): its
    # constant-speed forecast "overtakes" a braking ego *through* it, and the term
    # then made the plan dodge that phantom sideways, up to 5 m into the oncoming
    # lane (usi seeds 8 and 17: the ego stopped half in the other lane, SUMO's
    # follower lost it as its leader and hit it; FATROP failed on the same problems
    # and braked by fallback). A real overtaker passes in another lane, outside
    # the narrow zone, so such an agent stays off over the whole horizon.
    rows[:, :, 5] = np.where(
        (follower & ~ahead) | _trailing(xy, ref, yaw_ref, follower, lat_clear),
        0.0, 1.0)
    return rows


def _trailing(xy: np.ndarray, ref: np.ndarray, yaw_ref: np.ndarray,
              follower: np.ndarray, lat_clear: np.ndarray) -> np.ndarray:
    """(n_obs, 1) followers in the ego's lane going its way: behind at stage 0,
    laterally inside the safety zone's half-width there, and forecast to move
    along the ego's heading (within 60 degrees; a standing one is included: its
    forecast never comes level anyway)."""
    c0, s0 = np.cos(yaw_ref[0]), np.sin(yaw_ref[0])
    dx0 = xy[:, 0, 0] - ref[0, 0]
    dy0 = xy[:, 0, 1] - ref[0, 1]
    lat0 = -s0 * dx0 + c0 * dy0
    move = xy[:, -1, :] - xy[:, 0, :]
    dist = np.hypot(move[:, 0], move[:, 1])
    along = (move[:, 0] * c0 + move[:, 1] * s0) / np.maximum(dist, 1e-9)
    same_way = (dist < _STANDING_M) | (along > _SAME_WAY_COS)
    return follower & (np.abs(lat0) < lat_clear[:, 0])[:, None] & same_way[:, None]


def _relevance(rows: np.ndarray, guesses: list[np.ndarray], yaw_ref: np.ndarray,
               max_speed_mps: float) -> np.ndarray:
    """(n_obs, N+1) how far (m) each obstacle's safety term is from switching on at
    each stage, for the nearest ego guess (reference / shifted previous plan):
    the stretched distance minus ``d_hat`` at a generous speed. Negative = active."""
    cos_r, sin_r = np.cos(yaw_ref), np.sin(yaw_ref)
    best = np.full(rows.shape[:2], np.inf)
    for g in guesses:
        dx = g[:, 0] - rows[:, :, 0]
        dy = g[:, 1] - rows[:, :, 1]
        lon = cos_r * dx + sin_r * dy
        lat = -sin_r * dx + cos_r * dy
        d = np.sqrt(lon ** 2 + (rows[:, :, 4] * lat) ** 2)
        v = np.minimum(g[:, 3] + _RELEVANCE_SPEED_MPS, max_speed_mps)
        best = np.minimum(best, d - (rows[:, :, 2] + rows[:, :, 3] * v))
    return best


def pack(obs: Sequence[Obstacle], ref: np.ndarray, yaw_ref: np.ndarray, *, config: MpcConfig,
         vehicle: VehicleParams, warm: Optional[np.ndarray]
         ) -> tuple[Optional[np.ndarray], int]:
    """Per stage, the obstacles whose safety term can matter, nearest first:
    (N+1, n_slots, NOBS) rows and the compiled slot count that holds them.

    The safety term of an obstacle is exactly zero while the ego keeps farther than
    ``d_hat`` from it, so an obstacle more than ``_RELEVANCE_MARGIN_M`` beyond that
    from every guess of the ego at that stage (the reference and the shifted
    previous plan) is left out of the stage. This is exact unless the solve moves
    the ego farther than the margin from both guesses within one step; the next
    step re-selects from the new plan. Slots are per stage, so the compiled size
    follows the most obstacles *near one stage*, not the number attended."""
    rows = obstacle_rows(obs, ref, yaw_ref, config=config, vehicle=vehicle)
    if rows is None:
        return None, config.agent_slot_sizes[0]
    guesses = [ref]
    if warm is not None:
        w = warm
        guesses.append(np.vstack([w[1:, :4], w[-1:, :4]]))
    rel = _relevance(rows, guesses, yaw_ref, vehicle.max_speed_mps)
    keep = (rel < _RELEVANCE_MARGIN_M) & (rows[:, :, 5] > 0.0)
    count = int(keep.sum(axis=0).max())
    n_slots = slots_for(config, count)
    if count == 0:
        return None, n_slots
    # nearest-to-active first in every stage, irrelevant ones sorted to the end
    order = np.argsort(np.where(keep, rel, np.inf), axis=0, kind="stable")[:n_slots]
    k_idx = np.arange(config.horizon + 1)[None, :]
    packed = rows[order, k_idx]  # (n_slots, N+1, NOBS)
    packed[..., 5] = np.take_along_axis(keep, order, axis=0)
    if len(order) < n_slots:
        pad = np.zeros((n_slots - len(order), config.horizon + 1, NOBS))
        pad[..., 4] = 1.0
        packed = np.concatenate([packed, pad], axis=0)
    packed[packed[..., 5] == 0.0, :5] = (0.0, 0.0, 0.0, 0.0, 1.0)
    # linearise at the reference point where it keeps clear of the obstacle (the
    # reference carries the yield / commit choice), else at the shifted previous
    # plan (which the last solve kept clear); without a plan, at the reference
    ref_rel = _relevance(packed, [ref], yaw_ref, vehicle.max_speed_mps)
    use_ref = (ref_rel >= 0.0)[..., None]
    plan = np.broadcast_to(guesses[-1][None, :, :2], packed.shape[:2] + (2,))
    at = np.where(use_ref, np.broadcast_to(ref[None, :, :2], plan.shape), plan)
    packed = halfplanes(packed, at, yaw_ref)
    return np.transpose(packed, (1, 0, 2)), n_slots


def halfplanes(packed: np.ndarray, at: np.ndarray, yaw_ref: np.ndarray) -> np.ndarray:
    """Rows (ox, oy, gap, headway, rho, on) -> (kx, ky, k0, gap, headway, on) with
    ``kx x + ky y + k0`` the stretched distance ``d_ik`` linearised at the point
    ``at`` (n_slots, N+1, 2) of stage k: its tangent plane, a lower bound of the
    convex ``d_ik``. So ``max(0, d_hat - d_lin)^2`` is convex in the ego position
    and never smaller than the exact term (an approximation: conservative away
    from the linearisation point). The exact term's Hessian is strongly indefinite
    near an obstacle: the IPM then needed up to its 60-iteration cap."""
    c, s = np.cos(yaw_ref), np.sin(yaw_ref)
    ox, oy, rho = packed[..., 0], packed[..., 1], packed[..., 4]
    dx = at[..., 0] - ox
    dy = at[..., 1] - oy
    lon = c * dx + s * dy
    lat_s = rho * (-s * dx + c * dy)
    dist = np.hypot(lon, lat_s)
    # on top of the obstacle the direction is undefined: take "behind it"
    tiny = dist < 1e-6
    a = np.where(tiny, -1.0, lon / np.where(tiny, 1.0, dist))
    b = np.where(tiny, 0.0, lat_s / np.where(tiny, 1.0, dist))
    out = np.empty_like(packed)
    out[..., 0] = a * c - b * rho * s
    out[..., 1] = a * s + b * rho * c
    out[..., 2] = -(out[..., 0] * ox + out[..., 1] * oy)
    out[..., 3] = packed[..., 2]
    out[..., 4] = packed[..., 3]
    out[..., 5] = packed[..., 5]
    return out
