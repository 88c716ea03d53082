"""Finite-horizon ADP: the MPC's model and cost in array code, and a policy network that
replaces the MPC solve by one forward pass (issue 17 item 3; docs/RL.md, "ADP").

Everything here is written once against an array module ``xp``: ``numpy`` at run time
(no JAX needed to drive, CI has none) and ``jax.numpy`` for training
(``scripts/train_adp.py`` differentiates :func:`objective` through :func:`rollout`).

- :func:`split_params` reads the solver's packed parameter vector (``MpcSolver._params``:
  x0 with the two previous controls, the weight slots of ``CostParams``, per stage the
  reference, curvature, acceleration bias and the linearised obstacle half-planes), so
  the policy sees exactly what the NLP sees;
- :func:`rollout` is the MPC's internal model (``model.midpoint_step`` of
  ``model.bicycle_function``), :func:`objective` the NLP's objective
  (``MpcSolver._nlp``: tracking, steer reference, action bias, smoothness and the
  safety term), equal to CasADi's to rounding (``test_adp.py``);
- :func:`features` is the policy's input, :func:`controls` maps its output to controls
  that satisfy the MPC's hard bounds (acceleration and steer boxes, the steer rate, and
  0 <= v <= v_max along the rollout), :class:`AdpPolicy` is the numpy network and
  :class:`AdpSolver` the ``MpcSolver`` stand-in the controller calls.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams
from lmpc_mpc.model import N_W, NOBS, NREF, NU, NX, CostParams

FEATURE_STRIDE = 2
"""The reference and obstacle features are taken at every this many stages (0, 2, .., N)."""
FEATURE_SLOTS = 3
"""Obstacle slots per feature stage (the solver packs them nearest-to-active first)."""
MARGIN_SCALE_M = 10.0
"""Obstacle margins enter the features clipped to +-this and divided by it."""


class Parts(NamedTuple):
    """The packed parameter vector by piece (leading batch axes allowed)."""

    x0: Any
    """(..., NX) x, y, yaw, v, a_{-1}, delta_{-1}, a_{-2}, delta_{-2}."""
    w: Any
    """(..., N_W) the ``CostParams`` slots."""
    ref: Any
    """(..., N+1, NREF) x, y, yaw (unwrapped near the ego's), v, curvature, accel bias."""
    obs: Any
    """(..., N+1, S, NOBS) kx, ky, k0, gap, headway, on."""


def n_slots_of(p_len: int, n: int) -> int:
    """The obstacle slots per stage of a packed vector of length ``p_len``."""
    per = (p_len - NX - N_W) / (n + 1)
    s = (per - NREF) / NOBS
    if per != int(per) or s != int(s) or s < 0:
        raise ValueError(f"a parameter vector of length {p_len} fits no horizon-{n} layout")
    return int(s)


def split_params(p: Any, n: int) -> Parts:
    """``MpcSolver._params``'s vector (shape (..., L)) by piece."""
    s = n_slots_of(p.shape[-1], n)
    lead = p.shape[:-1]
    stage = p[..., NX + N_W:].reshape(lead + (n + 1, NREF + NOBS * s))
    return Parts(p[..., :NX], p[..., NX:NX + N_W], stage[..., :NREF],
                 stage[..., NREF:].reshape(lead + (n + 1, s, NOBS)))


def _step(xp: Any, s: Any, u: Any, veh: VehicleParams, dt: float) -> Any:
    """One midpoint step of the kinematic bicycle, ``s`` (..., 4), ``u`` (..., 2)."""
    ratio = veh.lr_m / veh.wheelbase_m

    def f(q: Any) -> Any:
        beta = xp.arctan(ratio * xp.tan(u[..., 1]))
        return xp.stack([q[..., 3] * xp.cos(q[..., 2] + beta),
                         q[..., 3] * xp.sin(q[..., 2] + beta),
                         q[..., 3] / veh.lr_m * xp.sin(beta), u[..., 0]], axis=-1)

    k1 = f(s)
    return s + dt * f(s + 0.5 * dt * k1)


def rollout(xp: Any, x0: Any, us: Any, veh: VehicleParams, dt: float) -> Any:
    """States (..., N+1, 4) of the MPC's model from ``x0`` (..., >= 4) under ``us``
    (..., N, 2)."""
    s = x0[..., :4]
    if xp is not np:  # jax: one scanned step compiles in seconds, 30 unrolled in minutes
        from jax import lax

        def body(q: Any, u: Any) -> Any:
            q = _step(xp, q, u, veh, dt)
            return q, q

        _, seq = lax.scan(body, s, xp.moveaxis(us, -2, 0))
        return xp.concatenate([s[..., None, :], xp.moveaxis(seq, 0, -2)], axis=-2)
    out = [s]
    for k in range(us.shape[-2]):
        s = _step(xp, s, us[..., k, :], veh, dt)
        out.append(s)
    return xp.stack(out, axis=-2)


def objective(xp: Any, parts: Parts, us: Any, xs: Any, veh: VehicleParams,
              per_stage: bool = False) -> Any:
    """The NLP's objective for controls ``us`` (..., N, 2) and the states ``xs``
    (..., N+1, 4) they roll out to (``MpcSolver._nlp``, term by term). ``per_stage``:
    (..., N) the cost charged to each control step k (its control terms plus stage
    k+1's state terms) instead of the sum."""
    c = CostParams(*(parts.w[..., i] for i in range(N_W)))
    ref, obs = parts.ref, parts.obs
    x = xs[..., 1:, :]  # stages 1..N carry the state cost
    r = ref[..., 1:, :]
    cy, sy = xp.cos(r[..., 2]), xp.sin(r[..., 2])
    ex, ey = x[..., 0] - r[..., 0], x[..., 1] - r[..., 1]
    e_lon = cy * ex + sy * ey
    e_lat = -sy * ex + cy * ey
    e = c.w_pos[..., None] * (e_lon ** 2 + c.lateral_factor[..., None] * e_lat ** 2)
    e = e + c.w_v[..., None] * (x[..., 3] - r[..., 3]) ** 2
    e = e + c.w_yaw[..., None] * 2.0 * (1.0 - xp.cos(x[..., 2] - r[..., 2]))
    o = obs[..., 1:, :, :]
    dist = o[..., 0] * x[..., 0:1] + o[..., 1] * x[..., 1:2] + o[..., 2]
    short = xp.maximum(0.0, o[..., 3] + o[..., 4] * x[..., 3:4] - dist)
    e = e + c.w_saf[..., None] * xp.sum(o[..., 5] * short ** 2, axis=-1)
    # controls: the previous two ride in the state (x0[4:8], then the controls)
    a, d = us[..., 0], us[..., 1]
    a1 = xp.concatenate([parts.x0[..., 4:5], a[..., :-1]], axis=-1)
    d1 = xp.concatenate([parts.x0[..., 5:6], d[..., :-1]], axis=-1)
    a2 = xp.concatenate([parts.x0[..., 6:7], a1[..., :-1]], axis=-1)
    d2 = xp.concatenate([parts.x0[..., 7:8], d1[..., :-1]], axis=-1)
    d_ref = xp.arctan(veh.wheelbase_m * ref[..., 1:, 4])
    u = c.w_steer_ref[..., None] * (d - d_ref) ** 2
    u = u + c.w_bias_accel[..., None] * (a - ref[..., :-1, 5]) ** 2
    u = u + c.w_bias_steer[..., None] * (d - c.bias_steer_rad[..., None]) ** 2
    u = u + c.w_g_accel[..., None] * (a - a1) ** 2 + c.w_g_steer[..., None] * (d - d1) ** 2
    u = u + c.w_l_accel[..., None] * (a - 2 * a1 + a2) ** 2
    u = u + c.w_l_steer[..., None] * (d - 2 * d1 + d2) ** 2
    total = u + e
    return total if per_stage else xp.sum(total, axis=-1)


def controls(xp: Any, z: Any, x0: Any, veh: VehicleParams, dt: float) -> Any:
    """Network output ``z`` (..., N, 2) -> controls (..., N, 2) within the MPC's hard
    bounds: ``a = mid + half tanh(z_a)`` in [-max_decel, max_accel], then clipped so the
    speed stays in [0, max_speed] along the roll-out (the model's speed is v_k + a_k dt
    exactly); ``delta_k = clip(delta_{k-1} + rate dt tanh(z_delta), +-max_steer)``."""
    lo_a, hi_a = -veh.max_decel_mps2, veh.max_accel_mps2
    mid, half = 0.5 * (hi_a + lo_a), 0.5 * (hi_a - lo_a)
    rate = veh.max_steer_rate_radps * dt
    v = x0[..., 3]
    d = xp.clip(x0[..., 5], -veh.max_steer_rad, veh.max_steer_rad)

    def step(v: Any, d: Any, zk: Any) -> tuple[Any, Any, Any]:
        a = mid + half * xp.tanh(zk[..., 0])
        lo = xp.maximum(lo_a, -v / dt)
        hi = xp.maximum(xp.minimum(hi_a, (veh.max_speed_mps - v) / dt), lo)
        a = xp.minimum(xp.maximum(a, lo), hi)
        d = xp.clip(d + rate * xp.tanh(zk[..., 1]), -veh.max_steer_rad, veh.max_steer_rad)
        return v + a * dt, d, xp.stack([a, d], axis=-1)

    if xp is not np:  # jax: scanned (see rollout)
        from jax import lax

        def body(carry: Any, zk: Any) -> Any:
            v2, d2, u = step(carry[0], carry[1], zk)
            return (v2, d2), u

        _, seq = lax.scan(body, (v, d), xp.moveaxis(z, -2, 0))
        return xp.moveaxis(seq, 0, -2)
    out = []
    for k in range(z.shape[-2]):
        v, d, u = step(v, d, z[..., k, :])
        out.append(u)
    return xp.stack(out, axis=-2)


def features(parts: Parts, veh: VehicleParams = DEFAULT_VEHICLE) -> np.ndarray:
    """The policy's input (numpy, (..., F)), everything in the ego's frame at stage 0:

    - the ego: speed / 20 m/s, the two previous controls (accel / 5 m/s^2, steer / 0.5);
    - the reference at stages 0, 2, .., N: position (ahead, left) / 20 m, yaw relative to
      the ego (rad), speed / 20 m/s, curvature x 10 m, acceleration bias / 5 m/s^2;
    - per such stage, its first ``FEATURE_SLOTS`` obstacle slots (nearest-to-active
      first, as packed): the half-plane's normal in the ego frame, its margin
      ``kx x + ky y + k0 - gap - headway v`` at the stage's reference point and speed and
      at the ego's current position and speed (clipped to +-10 m, / 10 m), the headway,
      and on / off.
    The weights are not an input: the ``adp`` method replaces the baseline MPC, whose
    weights are always the "normal" level (a decision's other levels would need them)."""
    x0, ref, obs = parts.x0, parts.ref, parts.obs
    c, s = np.cos(x0[..., 2]), np.sin(x0[..., 2])
    ks = slice(0, None, FEATURE_STRIDE)
    r = ref[..., ks, :]
    dx = r[..., 0] - x0[..., 0:1]
    dy = r[..., 1] - x0[..., 1:2]
    fe = [x0[..., 3:4] / 20.0, x0[..., 4:5] / 5.0, x0[..., 5:6] / 0.5,
          x0[..., 6:7] / 5.0, x0[..., 7:8] / 0.5,
          (c[..., None] * dx + s[..., None] * dy) / 20.0,
          (-s[..., None] * dx + c[..., None] * dy) / 20.0,
          r[..., 2] - x0[..., 2:3], r[..., 3] / 20.0, r[..., 4] * 10.0, r[..., 5] / 5.0]
    o = obs[..., ks, :FEATURE_SLOTS, :]
    if o.shape[-2] < FEATURE_SLOTS:  # fewer slots packed: pad with "off"
        pad = np.zeros(o.shape[:-2] + (FEATURE_SLOTS - o.shape[-2], NOBS))
        o = np.concatenate([o, pad], axis=-2)
    on = o[..., 5]
    kx, ky, k0, gap, head = (o[..., i] for i in range(5))
    cc, ss = c[..., None, None], s[..., None, None]
    m_ref = (kx * r[..., 0:1] + ky * r[..., 1:2] + k0 - gap - head * r[..., 3:4])
    m_ego = (kx * x0[..., None, None, 0] + ky * x0[..., None, None, 1] + k0 - gap
             - head * x0[..., None, None, 3])
    lim = MARGIN_SCALE_M
    slot = np.stack([on * (cc * kx + ss * ky), on * (-ss * kx + cc * ky),
                     on * np.clip(m_ref, -lim, lim) / lim, on * np.clip(m_ego, -lim, lim) / lim,
                     on * head, on], axis=-1)
    fe.append(slot.reshape(slot.shape[:-3] + (-1,)))
    return np.concatenate(fe, axis=-1)


def n_features(n: int) -> int:
    k = len(range(0, n + 1, FEATURE_STRIDE))
    return 5 + 6 * k + 6 * FEATURE_SLOTS * k


# -- the network ------------------------------------------------------------------------------
def mlp(xp: Any, layers: Any, h: Any) -> Any:
    """Dense layers, tanh between them; the last one linear."""
    for i, (w, b) in enumerate(layers):
        h = h @ w + b
        if i < len(layers) - 1:
            h = xp.tanh(h)
    return h


@dataclass(frozen=True)
class AdpPolicy:
    """The trained network as numpy arrays (float64), with the input scaling it was
    trained with and its provenance."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    mean: np.ndarray
    std: np.ndarray
    meta: dict[str, Any]

    @property
    def horizon(self) -> int:
        return int(self.meta["horizon"])

    @property
    def dt_s(self) -> float:
        return float(self.meta["dt_s"])

    def plan(self, p: np.ndarray, veh: VehicleParams = DEFAULT_VEHICLE
             ) -> tuple[np.ndarray, np.ndarray]:
        """Controls (..., N, 2) and states (..., N+1, 4) for packed vectors ``p``."""
        parts = split_params(np.asarray(p, dtype=float), self.horizon)
        x = (features(parts, veh) - self.mean) / self.std
        z = mlp(np, self.layers, x).reshape(x.shape[:-1] + (self.horizon, NU))
        us = controls(np, z, parts.x0, veh, self.dt_s)
        return us, rollout(np, parts.x0, us, veh, self.dt_s)

    def save(self, path: Path) -> None:
        """Weights as float32 (half the file; the outputs move by ~1e-7 relative), the
        input scaling as float64, the provenance as JSON."""
        arrays: dict[str, Any] = {f"w{i}": w.astype(np.float32)
                                  for i, (w, _) in enumerate(self.layers)}
        arrays.update({f"b{i}": b.astype(np.float32) for i, (_, b) in enumerate(self.layers)})
        arrays.update(mean=self.mean, std=self.std, meta=np.array(json.dumps(self.meta)))
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:
            np.savez_compressed(fh, **arrays)


def load_adp(path: Path) -> AdpPolicy:
    """A network saved by ``AdpPolicy.save``; one-line errors for a missing or bad file."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"no ADP network {path}: train one (scripts/train_adp.py)")
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            n = sum(1 for k in data.files if k.startswith("w"))
            layers = tuple((data[f"w{i}"].astype(float), data[f"b{i}"].astype(float))
                           for i in range(n))
            mean, std = data["mean"].astype(float), data["std"].astype(float)
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not an ADP network ({exc})") from None
    if meta.get("kind") != "adp":
        raise ValueError(f"{path}: not an ADP network (kind {meta.get('kind')!r})")
    return AdpPolicy(layers, mean, std, meta)


# -- run time: the solver's stand-in ----------------------------------------------------------
def make_adp_solver(config: Any, policy: AdpPolicy,
                    vehicle: VehicleParams = DEFAULT_VEHICLE) -> Any:
    """An ``MpcSolver`` whose ``solve`` is the network's forward pass (see AdpSolver)."""
    from lmpc_mpc.solver import MpcSolver

    class AdpSolver(MpcSolver):
        """The controller's solver with the NLP replaced by ``policy``: the same
        parameter packing (``_params``: reference, obstacle selection and half-planes,
        with its own previous plan as the shifted guess), then one forward pass; the
        plan is accepted as the solver's would be (first control clipped to the
        bounds, warm state kept for the next packing). It never fails on finite input."""

        def warm_up(self) -> None:  # nothing to compile
            pass

        def solve(self, problem: Any) -> Any:
            from lmpc_mpc.solver import MpcInputError

            t0 = time.perf_counter()
            self._cpu0 = time.process_time()
            try:
                p, x0, n_slots = self._params(problem)
            except MpcInputError as exc:
                return self._fail(f"bad input: {exc}", t0, 0)
            us, xs = policy.plan(p, self.vehicle)
            elapsed = time.perf_counter() - t0
            if not (np.all(np.isfinite(us)) and np.all(np.isfinite(xs))):
                return self._fail("non-finite network output", t0, 0, elapsed)
            n = self.n
            stage = np.empty((n + 1, NX + NU))
            stage[:, :4] = xs
            prev = np.vstack([x0[4:6], us])
            prev2 = np.vstack([x0[6:8], x0[4:6], us[:-1]])
            stage[:, 4:6] = prev
            stage[:, 6:8] = prev2
            stage[:n, NX:] = us
            stage[n, NX:] = us[-1]
            return self._accept(stage, n_slots, "adp forward pass", t0, 0, elapsed)

    if policy.horizon != config.horizon or not math.isclose(policy.dt_s, config.dt_s):
        raise ValueError(f"ADP network is for horizon {policy.horizon}, dt {policy.dt_s}; "
                         f"the MPC config has {config.horizon}, {config.dt_s}")
    return AdpSolver(config, vehicle, solver="fatrop")
