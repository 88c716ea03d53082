"""Scene questions several rules ask: who leads in the ego's lane, who queues behind it or
at a junction, whether an agent is on another lane of the ego's edge, and where the chosen
ego path runs. Geometry in the ego frame (``AgentView.kin``) or the map frame."""
from __future__ import annotations

from typing import Optional

import numpy as np

from lmpc_llm_planner.scene import AgentView, Scene

STANDOFF_M = 10.0
"""Waiting to pass a standing vehicle in its lane, the ego stops this far behind it (from
much closer the swerve is out of a car's steering reach without reversing)."""
HARD_BRAKE_MPS2 = 3.0
"""A leader braking harder than this is treated as coming to a standstill."""
ALONG_RAD = 1.2
"""Agents heading within this of the ego count as driving along its road (wider than the
30 deg of "same direction": an ego stopped turned into a swerve still sees them)."""
QUEUE_ZONE_M = 40.0
"""A stopped vehicle this close to the end of a lane with a light or a junction choice
counts as queued there (not broken down)."""
QUEUE_BEHIND_M = 12.0
"""A vehicle this close behind in the ego's lane, (nearly) stopped, is held up by it."""


def other_lane(scene: Scene, view: AgentView) -> bool:
    """The agent is on another lane of the ego's edge (both lanes known)."""
    ego_lane = scene.lanes.get(scene.obs.ego.lane_id or "")
    lane = scene.lanes.get(view.agent.lane_id or "")
    return ego_lane is not None and lane is not None and lane.id != ego_lane.id \
        and lane.edge_id == ego_lane.edge_id


def lane_leader(scene: Scene) -> Optional[AgentView]:
    """The nearest vehicle ahead in the ego's own lane (same lane id; driving along)."""
    ego = scene.obs.ego
    best: Optional[AgentView] = None
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m <= 0.0 or abs(k.heading_rel_rad) > 0.5:
            continue
        same = v.agent.lane_id == ego.lane_id if (v.agent.lane_id and ego.lane_id) \
            else abs(k.lateral_m) < 1.2
        if same and abs(k.lateral_m) < 2.5 and (best is None or k.gap_m < best.kin.gap_m):
            best = v
    return best


def queued_behind(scene: Scene) -> Optional[AgentView]:
    """A (nearly) stopped vehicle close behind a (nearly) stopped ego in its lane."""
    ego = scene.obs.ego
    if ego.v_mps > 2.0:
        return None
    for v in scene.agents:
        k = v.kin
        if k.longitudinal_m >= 0.0 or k.gap_m > QUEUE_BEHIND_M or v.agent.v_mps > 2.0:
            continue
        if abs(k.heading_rel_rad) < ALONG_RAD and abs(k.lateral_m) < 1.8:
            return v
    return None


def queued_at_junction(scene: Scene, view: AgentView) -> bool:
    """A stopped vehicle near the end of a lane that meets a light or a junction choice
    is (probably) waiting there, not broken down: the ego queues behind it instead of
    changing lanes around it."""
    lane = scene.lanes.get(view.agent.lane_id or "")
    if lane is None or lane.length_m - view.agent.lane_pos_m > QUEUE_ZONE_M:
        return False
    signalized = any(sl.lane_id == lane.id and sl.signalized for sl in scene.obs.map.stop_lines)
    return signalized or len({lk.direction for lk in lane.successors}) >= 2


def route_path(scene: Scene, ego_index: Optional[int] = None) -> Optional[np.ndarray]:
    """(n, 2) points of the chosen ego candidate (default: the route candidate; None
    without candidates)."""
    if not scene.ego_candidates:
        return None
    i = scene.route_candidate_id if ego_index is None else ego_index
    return scene.ego_candidates[i].sample(60)


def distance_to_path(path: np.ndarray, x_m: float, y_m: float) -> float:
    """Distance from (x, y) to the polyline ``path``."""
    a = path[:-1]
    d = np.diff(path, axis=0)
    len2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    t = np.clip(((x_m - a[:, 0]) * d[:, 0] + (y_m - a[:, 1]) * d[:, 1]) / len2, 0.0, 1.0)
    ex = x_m - a[:, 0] - t * d[:, 0]
    ey = y_m - a[:, 1] - t * d[:, 1]
    return float(np.sqrt(np.min(ex * ex + ey * ey)))
