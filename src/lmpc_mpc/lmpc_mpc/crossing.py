"""The MPC controller's crossing and stale-decision rules (moved out of
``lmpc_mpc.controller`` unchanged; docs/lmpc_mpc.md, "Stale decisions").

``CrossingRules`` is a mixin of ``MpcController``: its methods work on the controller's
own state (``_committed``, ``_yielded``, ``_leaders``, ``_beside``, ``_zone_tail``,
``_timing``, the stale record), so snapshots and restores of the controller cover them.

- ``_lead_limits``: per step, how far the reference may go: behind leaders, and before
  the conflict zone of a crossing / oncoming agent the ego yields to (the crossing
  rule: commit or yield, zones beyond the horizon, arriving agents);
- ``_reattend_stale`` / ``_note_stale`` / ``_held_by`` / ``_lane_change_kept``: the
  stale-decision check (``lmpc_mpc.stale``).
"""
from __future__ import annotations

import math
from typing import Mapping, Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import Agent, Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import VehicleParams
from lmpc_mpc.config import MpcConfig
from lmpc_mpc.mirrors import OWN_SUFFIX
from lmpc_mpc.prediction import forecast
from lmpc_mpc.reference import (
    REFERENCE_DS_M,
    _Polyline,
    braking_envelope,
    candidates_for_pose,
    closest_heading,
    lane_at,
)
from lmpc_mpc.solver import Obstacle
from lmpc_mpc.stale import StaleRecord, StaleVerdict, lane_change_gap, on_path, reach_m
from lmpc_mpc.stop_line import COMFORT_DECEL_MPS2 as _COMFORT_DECEL_MPS2

_STALE_LOG_DECISIONS = 256
"""The stale check's record is kept for this many decisions (the newest)."""
_BESIDE_STANDING_MPS = 0.5
"""An attended agent slower than this whose forecast stays laterally clear of the path
is flagged ``Obstacle.beside`` (no headway in its safety zone)."""
_BODY_SPEED_MPS = 2.0
"""An agent slower than this is on the path when a corner of its box is, not only when its
centre is (``_body_on_path``) - in a junction (``Obstacle.junction``), where cars stand at
angles to the ego's path. On a road the lanes keep standing cars parallel to it, and the
test stopped the ego passing a stopped car round it (eoa, development seeds at a 2.5 s
decision latency: 5 of 25 stood to the end)."""
_HEDGE_APART_M = 0.5
"""A close agent's own forecast is added beside the decision's prediction of it when the
two are farther apart than this at some step (see ``MpcController._problem``)."""
_HARD_DECEL_FRACTION = 0.8
"""A crossing the ego cannot clear before the agent arrives is yielded to while a stop
at this fraction of the maximum deceleration still ends before it (else: commit)."""
_ZONE_TAIL_STEPS = 30
"""A crossing agent still on the ego's path at the horizon's end: its conflict zone is
taken from its forecast this many steps further (``MpcController._lead_limits``)."""
_BRAKE_INTO_GAP = 1.0
"""The crossing rule's stops may end this fraction of ``safety_gap_m`` inside a conflict
zone's margin: "cannot stop before the zone" counts from the physical zone."""
_COMMIT_HOLD_S = 6.0
"""Once the ego commits to pass ahead of a crossing agent, it keeps that commitment this
long (sim time) while the agent stays a conflict, so it does not stop half-way."""
_HOLD_INTO_M = 1.0
"""A crossing the ego cannot clear before the agent arrives, and whose physical zone (the
safety gap braked into) a hard stop now overshoots by at most this, is yielded to by
stopping where the ego is, not committed to (``_lead_limits``) [m]."""
_HOLD_KEPT_INTO_M = 2.0
"""The same bound for an agent yielded to on the step before: the forecast zone's edge
jitters by +-0.5 m from step to step with the ego standing still, and at 1.0 m the ego
flickered between yield and commit and committed into the turn 2.6 s ahead of the
oncoming car (si 20 `lmpc-rules-enc` at latency 0: edge 0.86 -> 1.06 m past the stop,
then a collision). Not unbounded: an edge that jumps 4-6 m past a standing ego (a forecast
changing its lane) then held it deep in the junction, and it left its route on
restarting (usi 16 `mpc`) [m]."""
_HOLD_SPEED_MPS = 1.5
"""... and only while the ego creeps (at most this fast): a moving ego at the edge commits
as before (usi 121 at 5 s, usi 14 at 2.5 s: held inside the junction, it left its route
on restarting; the car it had committed in front of braked for it) [m/s]."""
_LANE_CHANGE_AHEAD_M = 25.0
"""A decision's curve that is in another lane this far ahead is a lane change."""


RING_SUFFIX = "#ring"
"""Obstacle id suffix of a ring agent's forecast along the ring (``_ring_alternative``)."""


def _agent_of(obstacle_id: str) -> str:
    """The agent an obstacle id stands for (without an own / ring forecast suffix)."""
    return obstacle_id.removesuffix(OWN_SUFFIX).removesuffix(RING_SUFFIX)


def _time_to_m(dist_m: float, v_mps: float, accel_mps2: float) -> float:
    """Time to cover ``dist_m`` from ``v_mps`` accelerating at ``accel_mps2``."""
    v = max(0.0, v_mps)
    if dist_m <= 0.0:
        return 0.0
    if accel_mps2 <= 1e-9:
        return dist_m / v if v > 1e-9 else math.inf
    return (-v + math.sqrt(v * v + 2.0 * accel_mps2 * dist_m)) / accel_mps2


def _body_on_path(line: _Polyline, ob: Obstacle, clear_m: float) -> Optional[float]:
    """The arc length of the nearest corner of ``ob``'s box now (its first forecast
    position, its heading) that lies within ``clear_m`` of the path ahead of the ego; None
    if none does, or its heading is unknown.

    The "on the path" test measures an agent's centre against half the two widths; a car
    standing at an angle beside the path reaches it with a corner the test does not see
    (usi training 10032: the ego, steering at its limit in a left turn, swept its front
    corner into an oncoming car standing ~35 degrees to the path; docs/lmpc_mpc.md, "The
    ego's body, not its centre")."""
    if ob.yaw_rad is None:
        return None
    c, s = math.cos(ob.yaw_rad), math.sin(ob.yaw_rad)
    hl, hw = 0.5 * ob.length_m, 0.5 * ob.width_m
    x0, y0 = float(ob.xy_m[0, 0]), float(ob.xy_m[0, 1])
    corners = np.array([(x0 + dl * c - dw * s, y0 + dl * s + dw * c)
                        for dl, dw in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))])
    s_c, d_c = line.project_many(corners)
    hit = (d_c < clear_m) & (s_c > 0.0) & (s_c < line.length_m - 1e-6)
    return float(np.min(s_c[hit])) if np.any(hit) else None


class CrossingRules:
    """Mixin of ``MpcController`` (see the module docstring); the attributes below are the
    controller's."""

    config: MpcConfig
    vehicle: VehicleParams
    _counts: dict[str, int]
    _committed: dict[str, float]
    _yielded: list[str]
    _last_yield: tuple[float, frozenset[str]]
    _leaders: list[tuple[str, float]]
    _followers: list[str]
    _beside: set[int]
    _zone_tail: dict[str, np.ndarray]
    _timing: tuple
    _ego_v_mps: float
    _lane_change_refused: dict[str, tuple[str, ...]]
    _now_s: float
    stale: StaleVerdict
    stale_log: dict[str, StaleRecord]

    def _baseline_curve(self, obs: Observation, ag: Agent) -> tuple[tuple[float, float], ...]:
        raise NotImplementedError  # the controller's

    def _zone_forecast(self, name: str, ag: Agent, cps: Optional[Sequence[Sequence[float]]],
                       obs: Observation) -> np.ndarray:
        """The agent's forecast over the horizon (N+1 rows); the forecast of the next
        ``_ZONE_TAIL_STEPS`` steps beyond it is kept under ``name`` for the crossing rule
        (``_lead_limits``: where a conflict zone the horizon cuts off goes on)."""
        cfg = self.config
        n = cfg.horizon
        xy = forecast(ag, cps, map_=obs.map, horizon=n + _ZONE_TAIL_STEPS, dt_s=cfg.dt_s,
                      lookahead_m=cfg.lookahead_m).xy_m
        self._zone_tail[name] = xy[n + 1:]
        return xy[: n + 1]

    def _lead_limits(self, line: _Polyline, obstacles: list[Obstacle],
                     speeds_mps: list[float]) -> Optional[np.ndarray]:
        """Per step, the farthest the reference may go: behind every attended agent
        predicted on the path (gap + half-lengths + headway at the agent's speed).

        This keeps the time-parameterised reference from running through a car
        ahead, so tracking and the safety term do not fight (our choice; the
        paper leaves the reference's speed profile open)."""
        self._leaders = []
        self._followers = []
        self._beside = set()
        if not obstacles:
            return None
        cfg, veh = self.config, self.vehicle
        n = cfg.horizon
        limit = np.full(n + 1, np.inf)
        hold_steps = int(math.ceil(cfg.safety_headway_s / cfg.dt_s))
        # one vectorised projection of every predicted position onto the path
        s_all, d_all = line.project_many(np.concatenate([ob.xy_m for ob in obstacles]))
        s_all = s_all.reshape(len(obstacles), n + 1)
        d_all = d_all.reshape(len(obstacles), n + 1)
        crossing: list[tuple[str, float, float, int, int]] = []
        tails = self._zone_tails(line, obstacles)
        for i, (ob, v) in enumerate(zip(obstacles, speeds_mps)):
            lat_clear = 0.5 * (veh.width_m + ob.width_m) + cfg.safety_lateral_gap_m
            gap = cfg.safety_gap_m + 0.5 * (veh.length_m + ob.length_m)
            s_k = s_all[i]
            d_k = d_all[i]
            if v < _BODY_SPEED_MPS and ob.junction and not np.any((d_k < lat_clear)
                                                                  & (s_k > 0.0)):
                body = _body_on_path(line, ob, 0.5 * veh.width_m + cfg.safety_lateral_gap_m)
                if body is not None:
                    # a slow agent whose body reaches the path where its centre does not:
                    # on the path, standing where its nearest corner reaches it (half its
                    # length on, as the gaps count from centres): the ego stops short of it
                    s_k = np.full(n + 1, body + 0.5 * ob.length_m)
                    d_k = np.zeros(n + 1)
            on = (d_k < lat_clear) & (s_k > 0.0) & (s_k < line.length_m - 1e-6)
            if v < _BESIDE_STANDING_MPS and not np.any(d_k < lat_clear):
                self._beside.add(i)  # standing beside the path: no headway (``Obstacle.beside``)
            s_t, d_t = tails[i]
            on_t = (d_t < lat_clear) & (s_t > 0.0) & (s_t < line.length_m - 1e-6)
            if not np.any(on):
                if np.any(on_t) and v >= _BESIDE_STANDING_MPS:
                    # arriving on our path only beyond the horizon (an ARRIVING agent):
                    # its zone from the first step it is on our path, k_first > N
                    k0 = int(np.argmax(on_t))
                    run = on_t[k0:]
                    run_s = s_t[k0:][: int(np.argmin(run)) if not np.all(run) else len(run)]
                    crossing.append((ob.obstacle_id, float(np.min(run_s)) - gap,
                                     float(np.max(run_s)) + gap, n + 1 + k0, n))
                continue
            along = bool(np.all(np.diff(s_k[on]) >= -1e-6))
            if along and not on[0] and float(s_k[on][0]) < gap:
                # coming onto our path from behind, going our way (a follower closing
                # in): no conflict zone ahead to yield to. Taken as crossing, its zone
                # from behind the ego made every other zone start behind the ego ("never
                # stop in another's zone"), so the ego committed to all of them
                self._followers.append(_agent_of(ob.obstacle_id))
                continue
            if on[0] and along:
                # a vehicle ahead going our way: follow it at gap + headway
                limit[on] = np.minimum(limit[on], s_k[on] - gap - cfg.safety_headway_s * v)
                self._leaders.append((_agent_of(ob.obstacle_id),
                                      float(np.min(limit[on]))))
                continue
            # crossing or oncoming: its zone on our path and the last step it is there
            k_last = min(n, int(np.max(np.nonzero(on)[0])) + hold_steps)
            s_on = s_k[on]
            if on[-1] and len(on_t):
                # still on our path at the horizon's end: the zone goes on where the
                # horizon cuts it off. Without this, an oncoming car's zone (met in a left
                # turn) grew toward the ego by ~1 m a step as the car came into the
                # horizon: the zone entry the ego yielded to was ahead of the true one
                n_run = int(np.argmin(on_t)) if not np.all(on_t) else len(on_t)
                s_on = np.concatenate([s_on, s_t[:n_run]])
            crossing.append((ob.obstacle_id, float(np.min(s_on)) - gap,
                             float(np.max(s_on)) + gap, int(np.argmax(on)), k_last))
        v0 = self._ego_v_mps
        comfort_m = v0 ** 2 / (2.0 * _COMFORT_DECEL_MPS2)
        hard_m = v0 ** 2 / (2.0 * _HARD_DECEL_FRACTION * veh.max_decel_mps2)
        last_t, last_yielded = self._last_yield
        # the agents yielded to on the step before (not older: a step without obstacles
        # leaves ``_yielded`` as it was)
        kept = last_yielded if 0.0 < self._now_s - last_t <= 1.5 * cfg.dt_s else frozenset()
        self._yielded = []
        for oid, s_enter, s_exit, k_first, k_last in crossing:
            # never plan to stop inside another crossing agent's zone (blocking the
            # junction): stop before that zone instead (our rule, see docs)
            moved = True
            while moved:
                moved = False
                for other, lo, hi, _, _ in crossing:
                    if other != oid and lo < s_enter < hi:
                        s_enter, moved = lo, True
            # "cannot stop before it anyway" counts from the physical zone (the safety gap
            # in front of it may be braked into): an ego standing or creeping at the
            # zone's edge (where a yield had held it) otherwise found itself "unable to
            # stop" a few cm inside the gap and committed in front of the car it had
            # waited for
            into_gap = _BRAKE_INTO_GAP * cfg.safety_gap_m
            in_time = self._time_along(s_exit) <= k_first * cfg.dt_s
            stop_in_m = hard_m - (s_enter + into_gap)
            clears = stop_in_m > 0.0 or in_time
            since = self._committed.get(oid)
            if k_first <= n and not in_time and v0 <= _HOLD_SPEED_MPS and 0.0 < stop_in_m \
                    and stop_in_m <= (_HOLD_KEPT_INTO_M if _agent_of(oid) in kept
                                      else _HOLD_INTO_M):
                # at the zone's edge, slow (a hard stop ends at most _HOLD_INTO_M inside
                # it, _HOLD_KEPT_INTO_M if the agent was yielded to on the step before),
                # and unable to clear it before the agent arrives: stop here, do not
                # commit. "Cannot stop before it" sent an ego creeping at 1 m/s 0.5 m
                # inside an oncoming car's zone margin across the bike and the car it had
                # just waited for (si 110 at a 1.5 s latency, dev seeds)
                limit[: k_last + 1] = np.minimum(limit[: k_last + 1], s_enter)
                self._yielded.append(_agent_of(oid))
                self._committed.pop(oid, None)
                continue
            if k_first > n:
                # an ARRIVING agent (on our path only beyond the horizon): yielded to only
                # when the ego cannot clear its zone before it arrives and can still stop
                # comfortably before the physical zone. Otherwise the ego started into a
                # left turn (from a stop for pedestrians) that takes ~5 s to clear while an
                # oncoming car 5 s away was not yet in the horizon, then met it in the
                # zone (si 24 at latency 0)
                if s_enter + into_gap >= comfort_m and \
                        self._time_along(s_exit) > k_first * cfg.dt_s:
                    limit[:] = np.minimum(limit, s_enter)
                    self._yielded.append(_agent_of(oid))
                continue
            if since is not None and 0.0 <= self._now_s - since <= _COMMIT_HOLD_S and clears:
                # committed earlier: as the ego slows, the comfortable stopping distance
                # shrinks below s_enter; yielding then would stop it half-way, so hold on
                # (unless the ego would now still be in the zone when the agent gets
                # there and can stop before it: si 13 at 2.5 s, a bike)
                continue
            if s_enter < comfort_m and clears:
                # too close to stop comfortably, and either it clears the zone before the
                # agent arrives or it could not stop before the zone even braking hard:
                # commit (pass ahead of it). Otherwise (it would still be in the zone when
                # the agent gets there, and a hard stop still ends before it) yield,
                # braking hard: a bike reaching the crossing the ego was committed to
                # because it was a little too close to stop comfortably hit it (si 13 at
                # a 2.5 s decision latency)
                self._committed[oid] = self._now_s
                continue
            # stay out of the conflict zone until it has left (plus one headway)
            limit[: k_last + 1] = np.minimum(limit[: k_last + 1], s_enter)
            self._yielded.append(_agent_of(oid))
        self._last_yield = (self._now_s, frozenset(self._yielded))
        return None if not np.any(np.isfinite(limit)) else limit

    def _time_along(self, s_m: float) -> float:
        """When the ego gets ``s_m`` along this step's path: accelerating at
        ``reference_accel_mps2`` from its speed, but never faster than the path's curves
        allow (the reference's lateral-acceleration cap and braking envelope). A left turn
        judged at the approach speed (13 m/s) "cleared" an oncoming car's zone in 1.8 s;
        slowing for the turn it took ~4 s, and the ego turned in front of the car (usi 117
        at a 2.5 s latency, dev seeds)."""
        geometry, v_max, prof = self._timing
        if s_m <= 0.0:
            return 0.0
        if prof is None:
            cfg = self.config
            ds = REFERENCE_DS_M
            _, s, _, kappa, _ = geometry
            v_cap = np.minimum(v_max, np.sqrt(cfg.reference_lat_accel_mps2
                                              / np.maximum(np.abs(kappa), 1e-6)))
            v_b = braking_envelope(v_cap, dec_mps2=2.0 * cfg.reference_accel_mps2, ds_m=ds)
            acc2 = 2.0 * cfg.reference_accel_mps2 * ds
            v = min(max(self._ego_v_mps, 0.0), float(v_b[0]))
            t_cum = np.zeros(len(s))
            t = 0.0
            for i in range(1, len(s)):
                v_next = min(float(v_b[i]), math.sqrt(v * v + acc2))
                t += 2.0 * ds / (v + v_next) if v + v_next > 1e-9 else math.inf
                t_cum[i] = t
                v = v_next
            prof = (s, t_cum, v)
            self._timing = (geometry, v_max, prof)
        s, t_cum, v_end = prof
        if s_m <= s[-1]:
            return float(np.interp(s_m, s, t_cum))
        return float(t_cum[-1]) + _time_to_m(s_m - float(s[-1]), v_end,
                                             self.config.reference_accel_mps2)

    def _zone_tails(self, line: _Polyline, obstacles: list[Obstacle]
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per obstacle, the projections (s, d) on the path of its forecast beyond the
        horizon (``_zone_forecast``; empty for obstacles without one), in one go."""
        tails = [self._zone_tail.get(ob.obstacle_id) for ob in obstacles]
        sizes = [0 if t is None else len(t) for t in tails]
        empty = (np.zeros(0), np.zeros(0))
        if not any(sizes):
            return [empty] * len(obstacles)
        s, d = line.project_many(np.concatenate([t for t in tails if t is not None and len(t)]))
        out, at = [], 0
        for k in sizes:
            out.append((s[at:at + k], d[at:at + k]) if k else empty)
            at += k
        return out

    def _held_by(self, v_mps: float, accel_mps2: float) -> tuple[str, ...]:
        """Leaders (``_lead_limits``) that hold the reference back within the horizon: their
        limit is short of where the ego would get accelerating at ``accel_mps2``."""
        horizon_s = self.config.horizon * self.config.dt_s
        free = reach_m(v_mps, accel_mps2=accel_mps2, horizon_s=horizon_s)
        return tuple(oid for oid, lim in self._leaders if lim < free)

    def _reattend_stale(self, obs: Observation, line: _Polyline, in_problem: Sequence[Agent],
                        preds: Mapping[str, object], obstacles: list[Obstacle],
                        speeds: list[float]) -> tuple[str, ...]:
        """The stale-decision check's attention part (``lmpc_mpc.stale``): every agent in
        sensing range whose own forecast enters the ego's path corridor within reach in
        the horizon, and that the problem does not yet avoid along that forecast (the
        decision dropped it, or its prediction of it is more than ``_HEDGE_APART_M``
        away), is added with the own forecast (``<id>#own`` beside a prediction).
        Appends to ``obstacles`` / ``speeds``; returns the ids added."""
        cfg, veh, ego = self.config, self.vehicle, obs.ego
        n = cfg.horizon
        horizon_s = n * cfg.dt_s
        reach = reach_m(ego.v_mps, accel_mps2=veh.max_accel_mps2, horizon_s=horizon_s)
        reach += veh.length_m + cfg.safety_gap_m
        placed = {ob.obstacle_id: ob for ob in obstacles}
        added: list[str] = []
        in_ids = {a.id for a in in_problem}
        ego_lane = lane_at(obs.map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                           lane_id=ego.lane_id)
        entering = ego_lane is not None and not ego_lane.roundabout
        for ag in obs.agents.agents:
            dist = math.hypot(ag.x_m - ego.x_m, ag.y_m - ego.y_m)
            if dist > cfg.sensing_range_m or dist > reach + ag.v_mps * horizon_s + 10.0:
                continue  # cannot meet the ego's path within the horizon
            # only for an agent the decision does not attend (it dropped it, or had not
            # seen it): one it attends it predicts itself, as the reasoner's gap check does
            ring = self._ring_alternative(obs, ag) if entering and ag.id not in preds \
                else None
            alt = None if ring is None or ag.id + RING_SUFFIX in placed else \
                self._forecast_on_path(ag.id + RING_SUFFIX, ag, ring, obs, line, reach)
            if alt is not None:
                # the ego approaches on a road, the agent is on a ring: also kept clear
                # of along the ring (it may go on past the ego's entry)
                obstacles.append(Obstacle(ag.id + RING_SUFFIX, alt, ag.length_m, ag.width_m))
                speeds.append(ag.v_mps)
                added.append(ag.id)
            if ag.id in in_ids and (ag.id not in preds or ag.id + OWN_SUFFIX in placed):
                continue  # already avoided along the MPC's own forecast
            own = self._baseline_curve(obs, ag) if ag.v_mps >= 0.05 else None
            name = ag.id + OWN_SUFFIX if ag.id in placed else ag.id
            mine = self._forecast_on_path(name, ag, own, obs, line, reach)
            if mine is None:
                continue
            theirs = placed.get(ag.id)
            if theirs is not None and float(np.max(np.hypot(*(mine - theirs.xy_m).T))) \
                    <= _HEDGE_APART_M:
                continue  # the decision's prediction agrees with the own forecast
            obstacles.append(Obstacle(name, mine, ag.length_m, ag.width_m))
            speeds.append(ag.v_mps)
            added.append(ag.id)
        return tuple(added)

    def _forecast_on_path(self, name: str, ag: Agent,
                          curve: Optional[Sequence[Sequence[float]]],
                          obs: Observation, line: _Polyline, reach: float
                          ) -> Optional[np.ndarray]:
        """The agent's zone forecast along ``curve`` (``_zone_forecast``) if it enters the
        ego's path corridor within ``reach`` in the horizon, else None."""
        cfg = self.config
        fc = self._zone_forecast(name, ag, curve, obs)
        s_k, d_k = line.project_many(fc)
        lat = 0.5 * (self.vehicle.width_m + ag.width_m) + cfg.safety_lateral_gap_m
        on = on_path(s_k, d_k, lateral_clear_m=lat, reach_m=reach, path_length_m=line.length_m)
        return fc if on else None

    def _ring_alternative(self, obs: Observation, ag: Agent
                          ) -> Optional[tuple[tuple[float, float], ...]]:
        """For an agent on a roundabout ring whose own forecast (closest heading) leaves
        the ring at the next junction: its candidate staying on the ring, else None.

        Whether a ring car exits before the ego's entry or goes on past it is not known
        (no indicator); the closest heading chose the exit for ``circ0`` in rab 112 (dev,
        1.5 s) and the MPC, under a decision that had not seen the car, drove into the
        ring in front of it. The rules reasoner counts every ring agent upstream, so
        does this check (``_reattend_stale``)."""
        if ag.v_mps < 0.05:
            return None
        lane = lane_at(obs.map, x_m=ag.x_m, y_m=ag.y_m, yaw_rad=ag.yaw_rad, lane_id=ag.lane_id)
        if lane is None or not lane.roundabout:
            return None
        rb = {ln.id for ln in obs.map.lanes if ln.roundabout}
        cands = candidates_for_pose(obs.map, x_m=ag.x_m, y_m=ag.y_m, yaw_rad=ag.yaw_rad,
                                    lane_id=ag.lane_id, lookahead_m=self.config.lookahead_m)
        own = closest_heading(cands, ag.yaw_rad) if cands else None
        if own is None or all(lid in rb for lid in own.lane_ids):
            return None
        ring = [c for c in cands if c.lane_ids and all(lid in rb for lid in c.lane_ids)]
        return ring[0].control_points if ring else None

    def _note_stale(self, decision: Optional[Decision], verdict: StaleVerdict) -> None:
        """Count the stale check's verdict and keep it per decision for the log."""
        self.stale = verdict
        if decision is None or not verdict.fired:
            return
        self._counts["stale_steps"] += 1
        self._counts["stale_agent_steps"] += len(verdict.reattended)
        self._counts["go_refused"] += int(bool(verdict.go_refused_for))
        self._counts["brake_refused"] += int(bool(verdict.brake_refused_for))
        rec = self.stale_log.get(decision.decision_id)
        if rec is None:
            rec = self.stale_log[decision.decision_id] = StaleRecord(
                decision_id=decision.decision_id, first_s=self._now_s)
        rec.add(self._now_s, verdict)
        if len(self.stale_log) > _STALE_LOG_DECISIONS:
            del self.stale_log[next(iter(self.stale_log))]

    def _lane_change_kept(self, obs: Observation, decision: Decision, path: np.ndarray
                          ) -> Optional[tuple[np.ndarray, tuple[str, ...]]]:
        """The stale check's lane-change part (``lmpc_mpc.stale.lane_change_gap``): when
        the decision's ``path`` leads into a neighbour lane of the ego's edge and an
        agent in that lane is beside the ego or would close the gap, the ego's own-lane
        path and those agents (kept for the rest of the decision, so the ego does not
        swing back and forth); else None. Once the ego's centre is in the target lane
        its lane is the target lane: the change goes on."""
        ego, cfg, veh = obs.ego, self.config, self.vehicle
        own = lane_at(obs.map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                      lane_id=ego.lane_id)
        if own is None or own.internal:
            return None
        held = self._lane_change_refused.get(decision.decision_id)
        if held is None:
            seg = np.hypot(*np.diff(path, axis=0).T)
            at = int(np.searchsorted(np.cumsum(seg), _LANE_CHANGE_AHEAD_M))
            at = min(at, len(path) - 2)
            d = path[at + 1] - path[at]
            tgt = lane_at(obs.map, x_m=float(path[at + 1, 0]), y_m=float(path[at + 1, 1]),
                          yaw_rad=math.atan2(d[1], d[0]), lane_id=None)
            if tgt is None or tgt.internal or tgt.id == own.id or tgt.edge_id != own.edge_id \
                    or abs(tgt.index - own.index) != 1:
                return None  # no lane change on this edge
            hx, hy = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
            blockers = []
            for ag in obs.agents.agents:
                if ag.lane_id != tgt.id:
                    continue
                dx = (ag.x_m - ego.x_m) * hx + (ag.y_m - ego.y_m) * hy
                need = 0.5 * (veh.length_m + ag.length_m) + cfg.safety_gap_m
                if not lane_change_gap(dx, v_ego_mps=ego.v_mps, v_agent_mps=ag.v_mps,
                                       need_m=need):
                    blockers.append(ag.id)
            if not blockers:
                return None
            held = self._lane_change_refused[decision.decision_id] = tuple(blockers)
            if len(self._lane_change_refused) > _STALE_LOG_DECISIONS:
                del self._lane_change_refused[next(iter(self._lane_change_refused))]
        cands = candidates_for_pose(obs.map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                                    lane_id=own.id, lookahead_m=cfg.lookahead_m)
        keep = [c for c in cands if c.lane_ids and c.lane_ids[0] == own.id]
        cand = keep[0] if keep else closest_heading(cands, ego.yaw_rad)
        return cand.sample(200), held
