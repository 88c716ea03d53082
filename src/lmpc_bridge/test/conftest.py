"""Fixtures of the lmpc_bridge tests: a tiny stand-in controller (NOT the real MPC).

The stand-in drives along the ego route by pure pursuit and picks its speed with
a simple rule: follow the route's speed, slow for the turn, keep a gap to
anybody ahead on the path, and before entering the junction wait while any
moving participant is approaching the junction within a few seconds
(gap acceptance). It exists only to exercise the simulation closed loop.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from lmpc_msgs_py.messages import Control, Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE


class StandInController:
    """Pure pursuit + gap-acceptance speed rule on the ego route (test helper)."""

    def __init__(self, *, cruise_mps: float = 11.0, turn_mps: float = 6.0,
                 accept_gap_s: float = 6.0) -> None:
        self._cruise = cruise_mps
        self._turn = turn_mps
        self._accept_gap_s = accept_gap_s
        self._path: list[tuple[float, float]] = []
        self._s: list[float] = []
        self._junction_start_s = 0.0
        self._junction_end_s = 0.0
        self._junction_center = (0.0, 0.0)
        self.decisions: list[Decision] = []

    def on_decision(self, decision: Decision) -> None:
        self.decisions.append(decision)

    def _build_path(self, obs: Observation) -> None:
        lanes = {lane.id: lane for lane in obs.map.lanes}
        pts: list[tuple[float, float]] = []
        junction_pts: list[tuple[float, float]] = []
        for i, lane_id in enumerate(obs.map.ego_route):
            lane = lanes[lane_id]
            for p in lane.centerline:
                if not pts or math.dist(pts[-1], p) > 0.05:
                    pts.append(p)
            if lane.internal:
                junction_pts.extend(lane.centerline)
            if i == 0:
                self._junction_start_s = self._arc(pts)
        self._path = pts
        self._s = [0.0]
        for a, b in zip(pts, pts[1:]):
            self._s.append(self._s[-1] + math.dist(a, b))
        start = self._junction_start_s
        internal_len = sum(lanes[lid].length_m for lid in obs.map.ego_route if lanes[lid].internal)
        self._junction_end_s = start + internal_len
        xs = [p[0] for p in junction_pts]
        ys = [p[1] for p in junction_pts]
        self._junction_center = (sum(xs) / len(xs), sum(ys) / len(ys))

    @staticmethod
    def _arc(pts: list[tuple[float, float]]) -> float:
        return sum(math.dist(a, b) for a, b in zip(pts, pts[1:]))

    def _project(self, x: float, y: float) -> tuple[float, float]:
        """(arc length, lateral distance) of a point on the path."""
        best = (0.0, math.inf)
        for i, (a, b) in enumerate(zip(self._path, self._path[1:])):
            dx, dy = b[0] - a[0], b[1] - a[1]
            seg = math.hypot(dx, dy)
            u = max(0.0, min(1.0, ((x - a[0]) * dx + (y - a[1]) * dy) / (seg * seg)))
            d = math.hypot(x - a[0] - u * dx, y - a[1] - u * dy)
            if d < best[1]:
                best = (self._s[i] + u * seg, d)
        return best

    def _point_at(self, s: float) -> tuple[float, float]:
        for i in range(len(self._s) - 1):
            if self._s[i + 1] >= s:
                a, b = self._path[i], self._path[i + 1]
                u = (s - self._s[i]) / max(self._s[i + 1] - self._s[i], 1e-9)
                return (a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1]))
        return self._path[-1]

    def must_wait(self, obs: Observation, s_front: float) -> bool:
        if s_front > self._junction_start_s + 1.0:
            return False  # committed: inside the junction, clear it
        cx, cy = self._junction_center
        for agent in obs.agents.agents:
            if agent.v_mps < 0.5:
                continue
            dx, dy = cx - agent.x_m, cy - agent.y_m
            dist = math.hypot(dx, dy)
            closing = agent.v_mps * (math.cos(agent.yaw_rad) * dx + math.sin(agent.yaw_rad) * dy) \
                / max(dist, 1e-6)
            if dist < 12.0:
                return True  # somebody is crossing the junction right now
            if closing > 0.5 and dist / closing < self._accept_gap_s:
                return True
        return False

    def compute(self, obs: Observation) -> Control:
        if not self._path:
            self._build_path(obs)
        ego = obs.ego
        v = ego.v_mps
        s_c, _ = self._project(ego.x_m, ego.y_m)
        s_front = s_c + ego.length_m / 2.0
        # pure pursuit from the rear axle
        lr, wb = DEFAULT_VEHICLE.lr_m, DEFAULT_VEHICLE.wheelbase_m
        rx, ry = ego.x_m - lr * math.cos(ego.yaw_rad), ego.y_m - lr * math.sin(ego.yaw_rad)
        look = max(5.0, 0.9 * v)
        tx, ty = self._point_at(s_c + look)
        alpha = math.atan2(ty - ry, tx - rx) - ego.yaw_rad
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
        steer = math.atan2(2.0 * wb * math.sin(alpha), math.hypot(tx - rx, ty - ry))
        # speed rule
        to_junction = self._junction_start_s - s_front
        v_des = self._cruise
        if -2.0 < to_junction < 25.0 or self._junction_start_s <= s_front <= self._junction_end_s:
            v_des = self._turn
        accel = 0.8 * (v_des - v)
        if self.must_wait(obs, s_front):
            d = to_junction - 1.0
            accel = min(accel, -6.0 if d < 0.3 else -v * v / (2.0 * d))
        for agent in obs.agents.agents:  # keep a gap to whoever is ahead on the path
            s_a, lat = self._project(agent.x_m, agent.y_m)
            gap = s_a - s_c - (agent.length_m + ego.length_m) / 2.0
            if lat < 2.5 and 0.0 < s_a - s_c < 60.0:
                safe = 3.0 + 1.5 * v
                if gap < safe:
                    accel = min(accel, -v * v / (2.0 * max(gap - 2.0, 0.3)) - 0.5)
        accel = max(min(accel, 2.5), -6.0)
        return Control(stamp_s=obs.stamp_s, seq=obs.ego.seq, accel_mps2=accel,
                       steer_rad=max(min(steer, 0.6), -0.6), mode="baseline",
                       solver_status="standin", solve_time_ms=0.0)


@pytest.fixture
def standin_controller() -> StandInController:
    return StandInController()


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("bridge_scenes")
