"""Deciding for the moment a decision takes effect (issue 23; docs/lmpc_llm_planner.md,
"Deciding for the take-effect time").

A decision is computed from an observation at ``t`` and takes effect at ``t + latency``
(an LLM: ~2.5 s; DESIGN §2). Judged on the picture at ``t``, a gap, a "can I still stop
before the line", a lane change are judgements about a world that has moved on by
the time the MPC executes them (usi seed 3 at 2.5 s: a "yield" decided 35 m before the
junction braked the ego hard at the junction entry, 2.5 s later). So the planner
predicts the observation forward by the latency it expects and decides on that
picture, as a driver looks ahead by their reaction time.

The prediction is an APPROXIMATION, the same kind the MPC makes:

- the ego moves along its route at its current acceleration (stopping, never reversing),
  keeping its lateral offset from the route line (a car in the next lane stays there);
- every agent moves along its closest-heading lane candidate at its current speed (a
  standing agent stays put; no reactions);
- a signal link whose ``time_to_switch_s`` falls within the lookahead is never predicted
  more permissive: green -> yellow, yellow -> red, red stays red until a fresh picture
  shows it green; links the ego will have passed are dropped;
- stamps are the observation's: the decision's stamp (and hence its take-effect time)
  does not change.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
from lmpc_mpc.prediction import forecast
from lmpc_mpc.reference import _Polyline, lane_at, route_path, route_progress
from lmpc_mpc.stop_line import stop_distance_m

from lmpc_msgs_py.messages import Agent, EgoState, LinkSignal, MapSnapshot
from lmpc_msgs_py.observation import Observation

STEP_S = 0.1
"""Time step of the agents' forecast (the simulation's)."""
ON_ROUTE_LANE_M = 1.0
"""An ego this close to its route line is taken to be on the route's lane."""
OFF_ROUTE_M = 2.5
OFF_ROUTE_RAD = math.radians(25.0)
"""An ego farther from its route line, or turned farther from it, is extrapolated along
its own heading instead (it is not following the route line: a dodge, a stop mid-turn);
within ``OFF_ROUTE_M`` it keeps its offset (a car in the next lane stays there)."""
LEADER_GAP_M = 2.0
"""A predicted ego stays this far (bumper to bumper) behind a predicted leader."""
_NEXT_STATE = {"G": "y", "g": "y", "y": "r", "u": "r"}
"""What a switching link becomes (never more permissive; red stays red)."""


def travel_m(v_mps: float, a_mps2: float, dt_s: float) -> tuple[float, float]:
    """(distance, end speed) at constant acceleration over ``dt_s``, stopping at rest."""
    v = max(0.0, v_mps)
    if a_mps2 < 0.0 and v + a_mps2 * dt_s <= 0.0:
        return v * v / (-2.0 * a_mps2), 0.0
    return v * dt_s + 0.5 * a_mps2 * dt_s * dt_s, v + a_mps2 * dt_s


def _lane_pos(map_: MapSnapshot, lane_id: Optional[str], x_m: float, y_m: float) -> float:
    for lane in map_.lanes:
        if lane.id == lane_id:
            return min(max(_Polyline.of(lane.centerline).project(x_m, y_m)[0], 0.0), 1.0e5)
    return 0.0


def predict_ego(map_: MapSnapshot, ego: EgoState, dt_s: float, *,
                stop_within_m: Optional[float] = None) -> tuple[EgoState, float]:
    """The ego ``dt_s`` ahead (see the module docstring) and the distance it travelled, at
    its current acceleration, stopping within ``stop_within_m`` (a red light's stop line,
    a leader) if it would pass it."""
    dist, v_end = travel_m(ego.v_mps, ego.a_mps2, dt_s)
    dist = max(dist, 0.0)
    if stop_within_m is not None and dist > stop_within_m:
        dist, v_end = max(0.0, stop_within_m), 0.0
    route = route_path(map_)
    s0 = route_progress(map_, ego) if route is not None else None
    if route is None or s0 is None or dist <= 1e-6:
        return ego.model_copy(update={"v_mps": v_end}), dist
    line = route.line
    p0 = line.at(s0)[0]
    _, _, heading0 = line.project(float(p0[0]), float(p0[1]))
    # signed lateral offset of the ego from the route line (left positive)
    offset = -math.sin(heading0) * (ego.x_m - p0[0]) + math.cos(heading0) * (ego.y_m - p0[1])
    if abs(offset) > OFF_ROUTE_M or \
            abs(math.remainder(ego.yaw_rad - heading0, 2.0 * math.pi)) > OFF_ROUTE_RAD:
        # off its route line (dodging, turned in a junction): straight on along its heading
        x = ego.x_m + dist * math.cos(ego.yaw_rad)
        y = ego.y_m + dist * math.sin(ego.yaw_rad)
        lane = lane_at(map_, x_m=x, y_m=y, yaw_rad=ego.yaw_rad, lane_id=None)
        lane_id = lane.id if lane is not None else ego.lane_id
        return ego.model_copy(update={
            "x_m": x, "y_m": y, "v_mps": v_end, "lane_id": lane_id,
            "lane_pos_m": _lane_pos(map_, lane_id, x, y),
            "dist_to_target_m": max(0.0, ego.dist_to_target_m - dist)}), dist
    s1 = s0 + dist
    p1 = line.at(s1)[0]
    ahead = line.at(s1 + 1.0)[0]
    yaw = math.atan2(ahead[1] - p1[1], ahead[0] - p1[0])
    x = float(p1[0] - math.sin(yaw) * offset)
    y = float(p1[1] + math.cos(yaw) * offset)
    j = route.lane_at(s1)
    if abs(offset) < ON_ROUTE_LANE_M:
        # on its route lane: inside a junction the best-fitting internal lane may be
        # another one (the straight one where the route turns)
        lane_id: Optional[str] = route.lane_ids[j]
    else:
        lane = lane_at(map_, x_m=x, y_m=y, yaw_rad=yaw, lane_id=None)
        lane_id = lane.id if lane is not None else ego.lane_id
    route_index = ego.route_index
    for lid in route.lane_ids[j::-1]:
        if lid in map_.ego_route:
            route_index = max(route_index, map_.ego_route.index(lid))
            break
    return ego.model_copy(update={
        "x_m": x, "y_m": y, "yaw_rad": yaw, "v_mps": v_end, "lane_id": lane_id,
        "lane_pos_m": _lane_pos(map_, lane_id, x, y), "route_index": route_index,
        "dist_to_target_m": max(0.0, ego.dist_to_target_m - dist)}), dist


def predict_agent(map_: MapSnapshot, agent: Agent, dt_s: float, *,
                  lookahead_m: float) -> Agent:
    """The agent ``dt_s`` ahead along its closest-heading candidate at constant speed."""
    if agent.v_mps < 0.05:
        return agent
    steps = max(1, int(math.ceil(dt_s / STEP_S - 1e-9)))
    xy = forecast(agent, None, map_=map_, horizon=steps, dt_s=dt_s / steps,
                  lookahead_m=lookahead_m).xy_m
    d = xy[-1] - xy[-2]
    yaw = math.atan2(d[1], d[0]) if float(np.hypot(*d)) > 1e-6 else agent.yaw_rad
    x, y = float(xy[-1, 0]), float(xy[-1, 1])
    lane = lane_at(map_, x_m=x, y_m=y, yaw_rad=yaw, lane_id=None)
    lane_id = lane.id if lane is not None else None
    return agent.model_copy(update={"x_m": x, "y_m": y, "yaw_rad": yaw, "lane_id": lane_id,
                                    "lane_pos_m": _lane_pos(map_, lane_id, x, y)})


def predict_link(link: LinkSignal, dt_s: float, travel: float) -> Optional[LinkSignal]:
    """The link ``dt_s`` ahead, or None when the ego will have passed its stop line."""
    dist = link.distance_m - travel
    if dist < 0.0:
        return None
    update: dict[str, object] = {"distance_m": dist}
    if link.time_to_switch_s is not None:
        left = link.time_to_switch_s - dt_s
        if left <= 0.0:
            update["state"] = _NEXT_STATE.get(link.state, link.state)
            update["time_to_switch_s"] = None
        else:
            update["time_to_switch_s"] = left
    return link.model_copy(update=update)


def _leader_room_m(obs: Observation, predicted: tuple[Agent, ...]) -> Optional[float]:
    """How far the ego may travel along its route line before it would close up to the
    nearest agent predicted ahead of it on that line, going its way (bumper gap
    ``LEADER_GAP_M``), or None."""
    route = route_path(obs.map)
    s0 = route_progress(obs.map, obs.ego) if route is not None else None
    if route is None or s0 is None:
        return None
    room: Optional[float] = None
    for ag in predicted:
        s, dist, heading = route.line.project(ag.x_m, ag.y_m)
        if s <= s0 or dist > 0.5 * (obs.ego.width_m + ag.width_m) + 0.3 or \
                abs(math.remainder(ag.yaw_rad - heading, 2.0 * math.pi)) > math.pi / 4.0:
            continue
        free = s - s0 - 0.5 * (obs.ego.length_m + ag.length_m) - LEADER_GAP_M
        room = free if room is None else min(room, free)
    return None if room is None else max(0.0, room)


def predict_observation(obs: Observation, dt_s: float, *, lookahead_m: float) -> Observation:
    """``obs`` as predicted ``dt_s`` ahead (module docstring); ``obs`` itself for 0."""
    if dt_s <= 0.0:
        return obs
    agents = tuple(predict_agent(obs.map, a, dt_s, lookahead_m=lookahead_m)
                   for a in obs.agents.agents)
    stops = [m for m in (stop_distance_m(obs, length_m=obs.ego.length_m),
                         _leader_room_m(obs, agents)) if m is not None]
    ego, travel = predict_ego(obs.map, obs.ego, dt_s,
                              stop_within_m=min(stops) if stops else None)
    links = tuple(lk for lk in (predict_link(lk, dt_s, travel) for lk in obs.signals.links)
                  if lk is not None)
    return Observation(map=obs.map, ego=ego,
                       agents=obs.agents.model_copy(update={"agents": agents}),
                       signals=obs.signals.model_copy(update={"links": links}))
