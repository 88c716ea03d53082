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
from typing import Any

import pytest

from lmpc_msgs_py.messages import Control, Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_bridge.geometry import OrientedBox, boxes_overlap


class StandInController:
    """Pure pursuit + rule-based speed and lane choice on the ego route (test helper).

    Speed: cruise, slower near the first junction and in curves (lateral
    acceleration limit), a gap to whoever is ahead in the ego's lane, a stop at a
    red / yellow light, and gap acceptance before entering the first junction
    unless the ego's link is a protected green (``G``). Lanes: the route may
    start on another lane of the first edge than the ego's (``lane``); and a lane
    blocked by a stopped obstacle away from junctions is avoided through a free
    neighbour lane (``eoa``, ``construction``). Lane changes wait for a gap in
    the target lane (front and rear) and move the pure-pursuit target sideways
    at a bounded lateral speed. Not the MPC; no prediction beyond constant speed.
    """

    def __init__(self, *, cruise_mps: float = 11.0, turn_mps: float = 6.0,
                 accept_gap_s: float = 6.0, lat_accel_mps2: float = 2.0) -> None:
        self._cruise = cruise_mps
        self._turn = turn_mps
        self._accept_gap_s = accept_gap_s
        self._lat_acc = lat_accel_mps2
        self._path: list[tuple[float, float]] = []
        self._s: list[float] = []
        self._kappa: list[float] = []
        self._junction_start_s = math.inf
        self._junction_end_s = math.inf
        self._first_lane_end_s = math.inf
        self._junction_center = (0.0, 0.0)
        self._junction_turns = False
        self._lane_width = 3.2
        self._offset = 0.0          # current lateral offset of the pursuit target (left +)
        self._offset_goal = 0.0     # lane centre offset being changed to
        self._avoid: str | None = None  # id of the obstacle being avoided
        self._avoid_offset = 0.0
        self._initialised = False
        self.decisions: list[Decision] = []

    def on_decision(self, decision: Decision) -> None:
        self.decisions.append(decision)

    # --- path ----------------------------------------------------------------------------
    def _build_path(self, obs: Observation) -> None:
        lanes = {lane.id: lane for lane in obs.map.lanes}
        pts: list[tuple[float, float]] = []
        run: list[str] = []
        run_start = math.inf
        for i, lane_id in enumerate(obs.map.ego_route):
            lane = lanes[lane_id]
            if lane.internal and (not run or run[-1] == obs.map.ego_route[i - 1]):
                if not run:
                    run_start = self._arc(pts)
                run.append(lane_id)
            for p in lane.centerline:
                if not pts or math.dist(pts[-1], p) > 0.05:
                    pts.append(p)
            if i == 0:
                self._first_lane_end_s = self._arc(pts)
                self._lane_width = lane.width_m
        self._path = pts
        self._s = [0.0]
        for a, b in zip(pts, pts[1:]):
            self._s.append(self._s[-1] + math.dist(a, b))
        heads = [math.atan2(b[1] - a[1], b[0] - a[0]) for a, b in zip(pts, pts[1:])]
        self._kappa = [0.0] * len(pts)
        for i in range(1, len(pts) - 1):
            # curvature over a window of about 4 m (polyline corners are not curves)
            j = i
            while j < len(pts) - 1 and self._s[j] - self._s[i] < 4.0:
                j += 1
            dh = math.atan2(math.sin(heads[min(j, len(heads) - 1)] - heads[i - 1]),
                            math.cos(heads[min(j, len(heads) - 1)] - heads[i - 1]))
            self._kappa[i] = abs(dh) / max(self._s[j] - self._s[i - 1], 1.0)
        if run:
            self._junction_start_s = run_start
            self._junction_end_s = run_start + sum(lanes[lid].length_m for lid in run)
            jp = [p for lid in run for p in lanes[lid].centerline]
            self._junction_center = (sum(p[0] for p in jp) / len(jp),
                                     sum(p[1] for p in jp) / len(jp))
            turn = self._heading_at(self._junction_end_s + 0.5) \
                - self._heading_at(max(self._junction_start_s - 0.5, 0.0))
            self._junction_turns = abs(math.atan2(math.sin(turn), math.cos(turn))) \
                > math.radians(20.0)

    @staticmethod
    def _arc(pts: list[tuple[float, float]]) -> float:
        return sum(math.dist(a, b) for a, b in zip(pts, pts[1:]))

    def _project(self, x: float, y: float) -> tuple[float, float]:
        """(arc length, unsigned lateral distance) of a point on the path."""
        s, lat = self._project_signed(x, y)
        return s, abs(lat)

    def _project_signed(self, x: float, y: float) -> tuple[float, float]:
        """(arc length, signed lateral offset, left +) of a point on the path."""
        best = (0.0, math.inf, 0.0)
        for i, (a, b) in enumerate(zip(self._path, self._path[1:])):
            dx, dy = b[0] - a[0], b[1] - a[1]
            seg = math.hypot(dx, dy)
            u = max(0.0, min(1.0, ((x - a[0]) * dx + (y - a[1]) * dy) / (seg * seg)))
            ex, ey = x - a[0] - u * dx, y - a[1] - u * dy
            d = math.hypot(ex, ey)
            if d < best[1]:
                side = 1.0 if dx * ey - dy * ex >= 0.0 else -1.0
                best = (self._s[i] + u * seg, d, side * d)
        return best[0], best[2]

    def _index_at(self, s: float) -> int:
        for i in range(len(self._s) - 1):
            if self._s[i + 1] >= s:
                return i
        return len(self._s) - 2

    def _point_at(self, s: float, offset: float = 0.0) -> tuple[float, float]:
        i = self._index_at(s)
        a, b = self._path[i], self._path[i + 1]
        seg = max(self._s[i + 1] - self._s[i], 1e-9)
        u = min(max((s - self._s[i]) / seg, 0.0), 1.0) if s <= self._s[-1] else 1.0
        nx, ny = -(b[1] - a[1]) / seg, (b[0] - a[0]) / seg
        return (a[0] + u * (b[0] - a[0]) + offset * nx, a[1] + u * (b[1] - a[1]) + offset * ny)

    def _heading_at(self, s: float) -> float:
        i = self._index_at(s)
        a, b = self._path[i], self._path[i + 1]
        return math.atan2(b[1] - a[1], b[0] - a[0])

    # --- rules -----------------------------------------------------------------------------
    def must_wait(self, obs: Observation, s_front: float) -> bool:
        if s_front > self._junction_start_s + 1.0 or math.isinf(self._junction_start_s):
            return False  # committed (inside the junction, clear it), or no junction
        cx, cy = self._junction_center
        s_c = s_front - obs.ego.length_m / 2.0
        entry_heading = self._heading_at(self._junction_start_s)
        for agent in obs.agents.agents:
            if agent.v_mps < 0.5:
                continue
            s_a, lat = self._project(agent.x_m, agent.y_m)
            if lat < 2.0 and s_a < s_c:
                continue  # behind us on our own path
            rel = math.atan2(math.sin(agent.yaw_rad - entry_heading),
                             math.cos(agent.yaw_rad - entry_heading))
            if abs(rel) < math.radians(30.0) and agent.kind != "pedestrian":
                continue  # moving our way (a parallel lane, a leader): no conflict
            dx, dy = cx - agent.x_m, cy - agent.y_m
            dist = math.hypot(dx, dy)
            closing = agent.v_mps * (math.cos(agent.yaw_rad) * dx + math.sin(agent.yaw_rad) * dy) \
                / max(dist, 1e-6)
            if dist < 12.0:
                return True  # somebody is crossing the junction right now
            if closing > 0.5 and dist / closing < self._accept_gap_s:
                return True
        return False

    def _lane_free(self, obs: Observation, s_c: float, offset: float) -> bool:
        v = obs.ego.v_mps
        for agent in obs.agents.agents:
            s_a, lat = self._project_signed(agent.x_m, agent.y_m)
            if abs(lat - offset) > 0.5 * self._lane_width + 0.6:
                continue
            gap = abs(s_a - s_c) - (agent.length_m + obs.ego.length_m) / 2.0
            if s_a >= s_c:
                need = 4.0 + 0.3 * v + 2.0 * max(v - agent.v_mps, 0.0)
            elif agent.v_mps < 1.0:
                continue  # standing behind us: it waits for us (SUMO drivers do)
            else:
                need = 5.0 + 0.5 * agent.v_mps + 2.5 * max(agent.v_mps - v, 0.0)
            if gap < need:
                return False
        return True

    def _neighbour_offsets(self, obs: Observation) -> list[float]:
        """Offsets (left +) of drivable neighbour lanes of the ego's lane, left first."""
        lanes = {lane.id: lane for lane in obs.map.lanes}
        mine = lanes.get(obs.ego.lane_id or "")
        if mine is None or mine.internal:
            return []
        out = []
        for lane in obs.map.lanes:
            if lane.edge_id == mine.edge_id and abs(lane.index - mine.index) == 1 \
                    and lane.width_m > 2.5:  # a 2 m lane is a sidewalk (no vClass in Lane)
                out.append((lane.index - mine.index) * self._lane_width)
        return sorted(out, reverse=True)

    def _update_lane(self, obs: Observation, s_c: float, lat_c: float) -> None:
        ego = obs.ego
        lane_now = round(lat_c / self._lane_width) * self._lane_width
        # 1. a stopped obstacle in our lane, away from junctions: go round it
        if self._avoid is None and s_c < self._first_lane_end_s - 10.0:
            for agent in obs.agents.agents:
                s_a, lat = self._project_signed(agent.x_m, agent.y_m)
                near_junction = (self._junction_start_s - 35.0 < s_a
                                 < self._junction_end_s + 5.0)
                if (agent.v_mps < 5.0 and abs(lat - lane_now) < 1.5 and 0.0 < s_a - s_c < 60.0
                        and not near_junction):
                    sides = self._neighbour_offsets(obs)
                    if sides:
                        self._avoid, self._avoid_offset = agent.id, lane_now + sides[0]
                    break
        if self._avoid is not None:
            agent = next((a for a in obs.agents.agents if a.id == self._avoid), None)
            if agent is None or self._project_signed(agent.x_m, agent.y_m)[0] < s_c - 8.0 \
                    - agent.length_m:
                self._avoid = None  # passed (or out of sight): back to the route lane
        goal = self._avoid_offset if self._avoid is not None else 0.0
        # 2. a lane change whose gap closes (a car comes up fast behind) is broken off
        #    while the ego is still mostly in its old lane
        changing = abs(self._offset_goal - self._offset) > 0.05
        origin = self._offset_goal - math.copysign(self._lane_width, self._offset_goal - lat_c)
        if changing and abs(lat_c - origin) < 0.8 \
                and not self._lane_free(obs, s_c, self._offset_goal):
            self._offset_goal = lane_now
        # 3. one lane at a time towards the goal, only into a free gap
        if abs(self._offset_goal - self._offset) < 0.05 and abs(goal - self._offset_goal) > 0.1:
            step = math.copysign(self._lane_width, goal - self._offset_goal)
            candidate = self._offset_goal + step
            if abs(candidate - goal) > abs(step):
                candidate = goal
            if self._lane_free(obs, s_c, candidate):
                self._offset_goal = candidate
        rate = 0.9 * 0.1  # lateral metres per step
        self._offset += max(-rate, min(rate, self._offset_goal - self._offset))
        del ego

    def compute(self, obs: Observation) -> Control:
        if not self._path:
            self._build_path(obs)
        ego = obs.ego
        v = ego.v_mps
        s_c, lat_c = self._project_signed(ego.x_m, ego.y_m)
        if not self._initialised:
            self._initialised = True
            self._offset = self._offset_goal = round(lat_c / self._lane_width) * self._lane_width
        s_front = s_c + ego.length_m / 2.0
        self._update_lane(obs, s_c, lat_c)
        # pure pursuit from the rear axle
        lr, wb = DEFAULT_VEHICLE.lr_m, DEFAULT_VEHICLE.wheelbase_m
        rx, ry = ego.x_m - lr * math.cos(ego.yaw_rad), ego.y_m - lr * math.sin(ego.yaw_rad)
        look = max(5.0 if v > 2.0 else 3.5, 0.9 * v)  # shorter at a crawl: turn out tighter
        tx, ty = self._point_at(s_c + look, self._offset)
        alpha = math.atan2(ty - ry, tx - rx) - ego.yaw_rad
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
        steer = math.atan2(2.0 * wb * math.sin(alpha), math.hypot(tx - rx, ty - ry))
        # speed rule
        to_junction = self._junction_start_s - s_front
        v_des = self._cruise
        in_zone = (-2.0 < to_junction < 25.0
                   or self._junction_start_s <= s_front <= self._junction_end_s)
        if in_zone and self._junction_turns:
            v_des = self._turn
        for i in range(self._index_at(s_c), len(self._s)):  # curves ahead (lat accel)
            ahead = self._s[i] - s_c
            if ahead > 60.0:
                break
            if self._kappa[i] > 1e-3:
                v_curve = math.sqrt(self._lat_acc / self._kappa[i])
                v_des = min(v_des, math.sqrt(v_curve ** 2 + 2.0 * 2.0 * max(ahead, 0.0)))
        accel = 0.8 * (v_des - v)

        def stop_at(dist_m: float) -> None:
            nonlocal accel
            accel = min(accel, -6.0 if dist_m < 0.3 else -v * v / (2.0 * dist_m) - 0.3)

        if self.must_wait(obs, s_front) and not self._protected_green(obs):
            stop_at(to_junction - 1.0)
        light = self._light_ahead(obs)
        if light is not None:
            state, dist = light
            if state in "ru" or (state == "y" and v * v / (2.0 * 4.0) < dist - 1.0):
                if dist < v * v / (2.0 * 2.5) + 8.0:
                    stop_at(dist - 1.5)
        pending = abs(self._offset) > 0.2 and self._avoid is None
        if pending and s_front > self._first_lane_end_s - 80.0:
            stop_at(self._first_lane_end_s - 12.0 - s_front)  # not on the route lane yet
        for agent in obs.agents.agents:  # keep a gap to whoever is ahead in our lane(s)
            s_a, lat = self._project_signed(agent.x_m, agent.y_m)
            # in our lane: where the ego is now, or the lane it is moving into
            in_lane = abs(lat - lat_c) < 2.1 or abs(lat - self._offset_goal) < 1.9
            gap = s_a - s_c - (agent.length_m + ego.length_m) / 2.0
            if in_lane and 0.0 < s_a - s_c < 60.0:
                # stay well back from a standing obstacle: room to steer round it
                margin = 7.0 if (agent.v_mps < 0.5 and abs(lat - lat_c) < 1.0) else 2.0
                safe = margin + 1.0 + 1.5 * v
                if agent.id == self._avoid and abs(self._offset_goal - lat) > 2.0:
                    # steering round it now: creep on (<= 2 m/s) while the box swept
                    # along the current steering arc over the next 1.5 m stays clear of it
                    full = math.copysign(0.6, self._offset_goal - lat)
                    for trial in (steer, full):
                        if self._arc_clear(ego, trial, agent, 1.5 + v):
                            steer = trial  # full lock if only that clears it
                            accel = min(accel, 0.8 * (2.0 - v) if gap < 6.0 else accel)
                            break
                    else:
                        trial = None
                    if trial is not None:
                        continue
                if gap < safe:
                    accel = min(accel, -v * v / (2.0 * max(gap - margin, 0.3)) - 0.5)
        accel = max(min(accel, 2.5), -6.0)
        return Control(stamp_s=obs.stamp_s, seq=obs.ego.seq, accel_mps2=accel,
                       steer_rad=max(min(steer, 0.6), -0.6), mode="baseline",
                       solver_status="standin", solve_time_ms=0.0)

    @staticmethod
    def _arc_clear(ego: Any, steer: float, agent: Any, dist_m: float) -> bool:
        """The ego box, moved ``dist_m`` along the arc of ``steer``, clears ``agent`` (+0.3 m)."""
        wb = DEFAULT_VEHICLE.wheelbase_m
        other = OrientedBox(agent.x_m, agent.y_m, agent.yaw_rad, agent.length_m + 0.6,
                            agent.width_m + 0.6)
        x, y, yaw = ego.x_m, ego.y_m, ego.yaw_rad
        n = max(int(dist_m / 0.5), 1)
        for _ in range(n):
            step = dist_m / n
            yaw_mid = yaw + 0.5 * step * math.tan(steer) / wb
            x, y = x + step * math.cos(yaw_mid), y + step * math.sin(yaw_mid)
            yaw += step * math.tan(steer) / wb
            if boxes_overlap(OrientedBox(x, y, yaw, ego.length_m, ego.width_m), other):
                return False
        return True

    @staticmethod
    def _light_ahead(obs: Observation) -> tuple[str, float] | None:
        links = sorted(obs.signals.links, key=lambda link: link.distance_m)
        return (links[0].state, links[0].distance_m) if links else None

    @staticmethod
    def _protected_green(obs: Observation) -> bool:
        links = sorted(obs.signals.links, key=lambda link: link.distance_m)
        return bool(links) and links[0].state == "G"


@pytest.fixture
def standin_controller() -> StandInController:
    return StandInController()


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("bridge_scenes")
