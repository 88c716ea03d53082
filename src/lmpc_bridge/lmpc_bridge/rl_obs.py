"""The learned planners' observation: one ``Observation`` as a fixed-size float32 vector
(docs/RL.md, "Observation"). Pure numpy: the benchmark's ``dqn`` / ``ppo`` / ``sac``
methods compute it without gymnasium; ``lmpc_bridge.gym_env`` is its Gymnasium face.

Layout (``EGO_FEATURES`` + ``AGENT_FEATURES`` x ``k_agents``), every entry scaled to
about [-1, 1] and clipped to [-``CLIP``, ``CLIP``]:

- ego: speed / 20 m/s, acceleration / 5 m/s^2, heading error to the route / pi, signed
  lateral offset to the route's centerline / 5 m (left positive), distance to the target
  / 300 m, 1 when the ego's lane is on its route, the next signal on the route as
  (red, yellow, green) flags (all 0: none ahead), the distance to its stop line / 100 m
  (1 when none);
- the nearest ``k_agents`` agents, nearest first, each: 1 (present), its position in the
  ego's frame (x ahead, y left) / 50 m, its speed / 20 m/s, sin and cos of its heading
  relative to the ego's, its speed along the ego's heading minus the ego's / 20 m/s;
  missing agents are all zeros.
"""
from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from lmpc_msgs_py.observation import Observation

EGO_FEATURES = 10
AGENT_FEATURES = 7
DEFAULT_K_AGENTS = 8
CLIP = 5.0

_RED = frozenset("rus")
_YELLOW = frozenset("y")


def obs_size(k_agents: int = DEFAULT_K_AGENTS) -> int:
    """Length of the vector for ``k_agents`` agents."""
    return EGO_FEATURES + AGENT_FEATURES * k_agents


class RouteFrame:
    """The route's centerline near the ego, from the latched map (rebuilt when the map's
    version or the ego's route index changes)."""

    def __init__(self) -> None:
        self._key: Optional[tuple[Any, ...]] = None
        self._lanes: dict[str, Any] = {}
        self._line: Optional[np.ndarray] = None

    def offset(self, obs: Observation) -> tuple[float, float]:
        """(heading error [rad], signed lateral offset [m], left positive) of the ego to
        the route's centerline from its current lane on; (0, 0) without a lane."""
        m, ego = obs.map, obs.ego
        key = (id(m), m.version, ego.route_index)
        if key != self._key:
            if self._key is None or self._key[:2] != key[:2]:
                self._lanes = {ln.id: ln for ln in m.lanes}
            pts: list[tuple[float, float]] = []
            start = max(ego.route_index - 1, 0)
            for lane_id in m.ego_route[start:ego.route_index + 4]:
                lane = self._lanes.get(lane_id)
                if lane is not None:
                    pts.extend(lane.centerline)
            self._line = np.asarray(pts, dtype=float) if len(pts) >= 2 else None
            self._key = key
        line = self._line
        if line is None:
            return 0.0, 0.0
        p = np.array([ego.x_m, ego.y_m])
        a, b = line[:-1], line[1:]
        d = b - a
        length2 = np.maximum((d * d).sum(axis=1), 1e-9)
        t = np.clip(((p - a) * d).sum(axis=1) / length2, 0.0, 1.0)
        closest = a + t[:, None] * d
        i = int(np.argmin(((closest - p) ** 2).sum(axis=1)))
        seg = d[i]
        heading = math.atan2(seg[1], seg[0])
        rel = p - closest[i]
        cross = seg[0] * rel[1] - seg[1] * rel[0]
        dist = float(np.hypot(*rel))
        lateral = math.copysign(dist, cross) if dist > 0.0 else 0.0
        return math.remainder(ego.yaw_rad - heading, 2.0 * math.pi), lateral


def observation_vector(obs: Observation, geometry: RouteFrame,
                       k_agents: int = DEFAULT_K_AGENTS) -> np.ndarray:
    """``obs`` as the float32 vector of the module docstring."""
    ego = obs.ego
    out = np.zeros(obs_size(k_agents), dtype=np.float32)
    heading_err, lateral = geometry.offset(obs)
    on_route = ego.lane_id is not None and ego.lane_id in obs.map.ego_route
    red = yellow = green = 0.0
    stop_m = 100.0
    ahead = [ln for ln in obs.signals.links if ln.distance_m >= 0.0]
    if ahead:
        nxt = min(ahead, key=lambda ln: ln.distance_m)
        state = nxt.state
        if state in _RED:
            red = 1.0
        elif state in _YELLOW:
            yellow = 1.0
        else:
            green = 1.0
        stop_m = min(nxt.distance_m, 100.0)
    out[:EGO_FEATURES] = (
        ego.v_mps / 20.0, ego.a_mps2 / 5.0, heading_err / math.pi, lateral / 5.0,
        ego.dist_to_target_m / 300.0, float(on_route), red, yellow, green, stop_m / 100.0)
    cos_e, sin_e = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
    agents = sorted(obs.agents.agents,
                    key=lambda ag: (ag.x_m - ego.x_m) ** 2 + (ag.y_m - ego.y_m) ** 2)
    for j, ag in enumerate(agents[:k_agents]):
        dx, dy = ag.x_m - ego.x_m, ag.y_m - ego.y_m
        rel_yaw = ag.yaw_rad - ego.yaw_rad
        along = ag.v_mps * math.cos(rel_yaw) - ego.v_mps
        base = EGO_FEATURES + AGENT_FEATURES * j
        out[base:base + AGENT_FEATURES] = (
            1.0, (cos_e * dx + sin_e * dy) / 50.0, (-sin_e * dx + cos_e * dy) / 50.0,
            ag.v_mps / 20.0, math.sin(rel_yaw), math.cos(rel_yaw), along / 20.0)
    np.clip(out, -CLIP, CLIP, out=out)
    return out
