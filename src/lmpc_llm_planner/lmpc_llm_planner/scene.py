"""What the planner knows about one observation, computed once and shared by the
prompt generator, the rules backend, the safety floor and the emergency check.

Plain Python + numpy, no ROS. Gap, closing speed and time to collision come from
:mod:`lmpc_mpc.closeness` (one definition, shared with the MPC's per-step safety
floor): a deliberate APPROXIMATION for decision making (constant velocities, box
supports along the line of sight); the MPC does the exact safety work.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping, Optional, Sequence

import numpy as np
from lmpc_mpc.closeness import closeness, wrap_rad
from lmpc_mpc.reference import (
    WRONG_WAY_RAD,
    Candidate,
    candidates_for_pose,
    closest_heading,
    heading_off_rad,
    route_candidate,
)

from lmpc_msgs_py.messages import Agent, Lane
from lmpc_msgs_py.observation import Observation

SAME_LANE_LATERAL_M = 1.8
"""|lateral offset| below which an agent counts as in the ego's lane (half a lane)."""
SIDE_LONGITUDINAL_M = 3.0
"""|longitudinal offset| below which an agent counts as beside the ego."""
ROUTE_CHANGE_PER_LANE_M = 60.0
"""Road kept per lane change still needed when the ego's lane does not lead on along
its route: beyond lookahead + this per change, staying in lane counts as the route."""
STRAIGHT_LINE_HORIZON_S = 5.0
"""Length (in time at the agent's speed) of the straight-line candidate of an off-map agent."""


@dataclass(frozen=True)
class Kinematics:
    """Ego-relative kinematics of one agent (no map, cheap enough for every observation)."""

    agent: Agent
    distance_m: float
    """Centre to centre."""
    gap_m: float
    """Approximate box-to-box gap (>= 0)."""
    longitudinal_m: float
    """Ahead of the ego (+) or behind (-), in the ego frame."""
    lateral_m: float
    """Left of the ego (+) or right (-), in the ego frame."""
    heading_rel_rad: float
    """Agent yaw minus ego yaw, wrapped."""
    closing_speed_mps: float
    """Rate at which the centre distance shrinks (negative: moving apart)."""
    ttc_s: Optional[float]
    """Time to collision when on a collision course (constant velocities), else None."""

    @property
    def relation(self) -> str:
        """Where the agent is, in words: ahead / behind / left / right / ahead-left ..."""
        lon, lat = self.longitudinal_m, self.lateral_m
        if abs(lat) < SAME_LANE_LATERAL_M:
            return "ahead" if lon >= 0.0 else "behind"
        side = "left" if lat > 0.0 else "right"
        if abs(lon) < SIDE_LONGITUDINAL_M:
            return side
        return f"{'ahead' if lon > 0.0 else 'behind'}-{side}"

    @property
    def motion(self) -> str:
        """Its heading relative to the ego, in words."""
        h = self.heading_rel_rad
        if abs(h) < math.radians(30):
            return "same direction"
        if abs(h) > math.radians(150):
            return "oncoming"
        return "crossing from the " + ("right" if h > 0.0 else "left")


def agent_kinematics(obs: Observation) -> tuple[Kinematics, ...]:
    """Kinematics of every observed agent, nearest first (ties by id: deterministic)."""
    ego = obs.ego
    ce, se = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
    out = []
    for ag in obs.agents.agents:
        c = closeness(ego, ag)
        dx, dy = ag.x_m - ego.x_m, ag.y_m - ego.y_m
        out.append(
            Kinematics(
                agent=ag,
                distance_m=c.distance_m,
                gap_m=c.gap_m,
                longitudinal_m=dx * ce + dy * se,
                lateral_m=-dx * se + dy * ce,
                heading_rel_rad=wrap_rad(ag.yaw_rad - ego.yaw_rad),
                closing_speed_mps=c.closing_speed_mps,
                ttc_s=c.ttc_s,
            )
        )
    out.sort(key=lambda k: (k.distance_m, k.agent.id))
    return tuple(out)


@dataclass(frozen=True)
class AgentView:
    """An agent as offered to the decision maker: kinematics plus its three candidates."""

    kin: Kinematics
    candidates: tuple[Candidate, ...]
    """Offered candidates; ``candidates[i].candidate_id == i``."""
    closest_heading_id: int
    """Index of the candidate closest to the agent's heading (baseline prediction)."""

    @property
    def agent(self) -> Agent:
        return self.kin.agent

    @property
    def id(self) -> str:
        return self.kin.agent.id


@dataclass(frozen=True)
class Scene:
    """One observation, analysed for decision making."""

    obs: Observation
    ego_candidates: tuple[Candidate, ...]
    """Offered ego candidates; ``ego_candidates[i].candidate_id == i``; at least one."""
    route_candidate_id: int
    """Index of the ego candidate that follows the route."""
    agents: tuple[AgentView, ...]
    """The agents offered in the prompt (nearest first, within sensing range, capped)."""
    all_kinematics: tuple[Kinematics, ...]
    """Every observed agent (the safety floor looks at all of them)."""
    lanes: Mapping[str, Lane]
    leaving_ids: frozenset[int] = frozenset()
    """Ego candidates that leave the route where it goes on (:func:`leaves_route`): never
    "the route", and the rules' lane choice does not take them (issue 21)."""

    def agent(self, agent_id: str) -> Optional[AgentView]:
        for view in self.agents:
            if view.id == agent_id:
                return view
        return None

    @property
    def agent_ids(self) -> tuple[str, ...]:
        return tuple(v.id for v in self.agents)

    def edge_lanes(self, lane: Lane) -> dict[int, Lane]:
        """The normal lanes of ``lane``'s edge by index (``lane`` among them); {} for a
        junction's internal lane."""
        if lane.internal:
            return {}
        return {ln.index: ln for ln in self.lanes.values()
                if ln.edge_id == lane.edge_id and not ln.internal}


def _renumber(cands: Sequence[Candidate]) -> tuple[Candidate, ...]:
    return tuple(
        c if c.candidate_id == i else replace(c, candidate_id=i) for i, c in enumerate(cands[:3])
    )


def _straight_line(agent: Agent) -> Candidate:
    # Off-map agents (pedestrians, a car off the network) get one straight-line
    # candidate along their heading (an approximation, said in the label).
    length = max(5.0, agent.v_mps * STRAIGHT_LINE_HORIZON_S)
    c, s = math.cos(agent.yaw_rad), math.sin(agent.yaw_rad)
    pts = tuple(
        (agent.x_m + f * length * c, agent.y_m + f * length * s) for f in (0.0, 0.5, 1.0)
    )
    return Candidate(
        candidate_id=0, control_points=pts, label="keep its current heading (off the lane map)",
        lane_ids=(),
    )


def agent_candidates(
    obs: Observation, agent: Agent, *, lookahead_m: float
) -> tuple[Candidate, ...]:
    """The (up to three) candidates of an agent, renumbered 0..n-1; never empty."""
    cands = candidates_for_pose(
        obs.map, x_m=agent.x_m, y_m=agent.y_m, yaw_rad=agent.yaw_rad, lane_id=agent.lane_id,
        lookahead_m=lookahead_m,
    )
    if not cands or min(heading_off_rad(c, agent.yaw_rad) for c in cands) > WRONG_WAY_RAD:
        # off the map, or against its lane's direction (a pedestrian on a crossing walks
        # either way): straight on along its heading
        return (_straight_line(agent),)
    return _renumber(cands)


def _mean_distance_m(a: Candidate, b: Candidate) -> float:
    pa, pb = a.sample(20), b.sample(20)
    return float(np.mean(np.hypot(pa[:, 0] - pb[:, 0], pa[:, 1] - pb[:, 1])))


def _lane_changes_needed(here: Lane, lanes: Mapping[str, Lane], next_edge: Optional[str]
                         ) -> int:
    """Lane changes from ``here`` to the nearest lane of its edge that connects to
    ``next_edge`` (0 when none does: nothing to gain by changing)."""
    best: Optional[int] = None
    for ln in lanes.values():
        if ln.edge_id != here.edge_id or ln.internal:
            continue
        if any(lk.to_lane in lanes and lanes[lk.to_lane].edge_id == next_edge
               for lk in ln.successors):
            d = abs(ln.index - here.index)
            best = d if best is None else min(best, d)
    return best or 0


def _route_edges_ahead(route_lanes: Sequence[str], lanes: Mapping[str, Lane],
                       here_edge: Optional[str]) -> list[str]:
    """The route's normal edges after the ego's edge, in order (all ahead when the ego's
    edge is not on the route, e.g. inside a junction)."""
    out: list[str] = []
    for lid in route_lanes:
        lane = lanes.get(lid)
        if lane is not None and not lane.internal and (not out or out[-1] != lane.edge_id):
            out.append(lane.edge_id)
    if here_edge in out:
        out = out[out.index(here_edge) + 1:]
    return out


def leaves_route(cand: Candidate, lanes: Mapping[str, Lane], route_ahead: Sequence[str],
                 here_edge: Optional[str]) -> bool:
    """True when ``cand`` drives onto a normal edge the route does not take next while the
    route goes on (``route_ahead``: the route's edges after the ego's, from
    ``_route_edges_ahead``). Beyond the route's last edge in the map anything goes."""
    k = 0
    for lid in cand.lane_ids:
        lane = lanes.get(lid)
        if lane is None or lane.internal or (k == 0 and lane.edge_id == here_edge):
            continue
        if k < len(route_ahead) and lane.edge_id == route_ahead[k]:
            k += 1
            continue
        if k >= len(route_ahead):
            return False
        if k > 0 and lane.edge_id == route_ahead[k - 1]:
            continue
        return True
    return False


def ego_candidates(obs: Observation, *, lookahead_m: float) -> tuple[tuple[Candidate, ...], int]:
    """The ego's offered candidates and the index of the one following its route.

    When none of the nearest-lane candidates follows the route (no shared route lane
    ahead), or the best of them leaves the route where the route goes on
    (:func:`leaves_route`: near a junction the candidates are the connections of the
    ego's *current* lane, and on a short edge the route's turn may leave from another
    lane), the route candidate is appended (or replaces the last one when three are
    offered already), so the route is always offered.
    """
    ego = obs.ego
    cands = list(
        candidates_for_pose(
            obs.map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad, lane_id=ego.lane_id,
            lookahead_m=lookahead_m,
        )
    )
    # A candidate on no lane (the ego off the lane map) cannot be tracked as a manoeuvre.
    cands = [c for c in cands if c.lane_ids][:3]
    route_c = route_candidate(obs.map, ego, lookahead_m=lookahead_m)
    if not cands:
        return (replace(route_c, candidate_id=0),), 0
    ahead = obs.map.ego_route[ego.route_index:]
    route_set = set(ahead)
    lanes = {lane.id: lane for lane in obs.map.lanes}
    here = lanes.get(ego.lane_id or "")
    here_edge = here.edge_id if here is not None else None

    def edges(ids: Sequence[str]) -> set[str]:
        # normal (non-junction) edges other than the ego's own
        return {lanes[i].edge_id for i in ids
                if i in lanes and not lanes[i].internal and lanes[i].edge_id != here_edge}

    route_edges = edges(ahead)
    # the route's next normal edge after the ego's (None: the route ends on this edge)
    next_edge: Optional[str] = None
    seen_here = False
    for lid in ahead:
        lane = lanes.get(lid)
        if lane is None or lane.internal:
            continue
        if lane.edge_id == here_edge:
            seen_here = True
        elif seen_here or here_edge is None:
            next_edge = lane.edge_id
            break
    on_route_edge = seen_here
    continues = here is not None and on_route_edge and (
        next_edge is None
        or any(lk.to_lane in lanes and lanes[lk.to_lane].edge_id == next_edge
               for lk in here.successors))
    if here is not None and on_route_edge and not continues and not here.internal:
        # the route needs a lane change on this edge, but not yet: while the edge goes on
        # well beyond the lookahead, staying in lane still follows the route (the change
        # can come later, when there is a gap). Otherwise an emergency answer (which takes
        # the route candidate) would cut across lanes at once, gap or not.
        need = _lane_changes_needed(here, lanes, next_edge)
        remaining_m = here.length_m - ego.lane_pos_m
        continues = remaining_m > lookahead_m + ROUTE_CHANGE_PER_LANE_M * need
    # A candidate that leaves the route where the route goes on (a junction choice of the
    # wrong lane before a short edge's lane change, issue 21) never counts as the route,
    # however much of the route it shares first: then the route candidate is offered.
    ahead_edges = _route_edges_ahead(ahead, lanes, here_edge)
    stays = [not leaves_route(c, lanes, ahead_edges, here_edge) for c in cands]
    # Route edges reached beyond the current one decide; then staying in the ego's lane
    # when the route goes on from it: a parallel lane that leads to the route's next
    # edge follows the route as well as the route's own lane (the bridge treats
    # parallel lanes of a route edge as the same progress), so no lane change the route
    # does not need (e.g. back into the lane of a stopped car the ego has just swerved
    # round); then shared route lanes, then closeness to the route polyline.
    scores = [
        (
            stays[i],
            len(route_edges & edges(c.lane_ids)),
            continues and bool(c.lane_ids) and c.lane_ids[0] == ego.lane_id,
            len(route_set.intersection(c.lane_ids) - {ego.lane_id}),
            -_mean_distance_m(c, route_c),
        )
        for i, c in enumerate(cands)
    ]
    best = max(range(len(cands)), key=lambda i: (scores[i], -i))
    if not stays[best] or (scores[best][1] == 0 and not scores[best][2]
                           and scores[best][3] == 0 and -scores[best][4] > 2.0):
        # append while there is room (three offered at most): replacing the last one would
        # drop a neighbour-lane candidate the rules' lane choice needs (ego two lanes left
        # of its route lane: keep, change right, route)
        if len(cands) < 3:
            cands.append(route_c)
        else:
            cands[-1] = route_c
        best = len(cands) - 1
    return _renumber(cands), best


def build_scene(obs: Observation, *, lookahead_m: float, max_agents: int,
                candidates_from: Optional[Observation] = None) -> Scene:
    """Analyse ``obs``: ego candidates, route candidate, nearest agents with candidates.

    ``candidates_from``: build the ego's candidates from this observation's pose instead
    (the current one, when ``obs`` is predicted ahead: ``lmpc_llm_planner.lookahead``)."""
    kins = agent_kinematics(obs)
    in_range = [k for k in kins if k.distance_m <= obs.agents.sensing_range_m][:max_agents]
    views = []
    for k in in_range:
        cands = agent_candidates(obs, k.agent, lookahead_m=lookahead_m)
        best = closest_heading(list(cands), k.agent.yaw_rad)
        views.append(AgentView(kin=k, candidates=cands, closest_heading_id=best.candidate_id))
    pose = obs if candidates_from is None else candidates_from
    ego_c, route_id = ego_candidates(pose, lookahead_m=lookahead_m)
    lanes = {lane.id: lane for lane in obs.map.lanes}
    here = lanes.get(pose.ego.lane_id or "")
    here_edge = here.edge_id if here is not None else None
    ahead = _route_edges_ahead(pose.map.ego_route[pose.ego.route_index:], lanes, here_edge)
    leaving = frozenset(c.candidate_id for c in ego_c
                        if c.candidate_id != route_id
                        and leaves_route(c, lanes, ahead, here_edge))
    return Scene(
        obs=obs,
        ego_candidates=ego_c,
        route_candidate_id=route_id,
        agents=tuple(views),
        all_kinematics=kins,
        lanes=lanes,
        leaving_ids=leaving,
    )
