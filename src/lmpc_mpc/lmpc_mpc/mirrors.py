"""Plain-Python content of the MPC's visual mirrors (no ROS): polylines with colours.

``mpc_node`` turns these into ``visualization_msgs/MarkerArray`` messages (frame
``map``, sim-time stamps):

- ``CANDIDATE_MARKERS``: the ego's (up to) three Bezier reference candidates of its
  current pose, the one in force highlighted (wider, green); the others grey;
- ``AGENT_PREDICTION_MARKERS``: every observed agent's predicted positions over the
  horizon; attended agents (those in the MPC problem) orange with their real
  forecast, unattended ones blue with a constant-velocity straight line (display
  only: an approximation, they are not predicted by the MPC at all); a close agent
  the MPC also keeps clear of along its own forecast (``<id>#own`` in the controller's
  ``agent_predictions``, see docs/lmpc_mpc.md) gets that second line in namespace
  ``hedged``, purple.

Topic names: ``lmpc_msgs_py.topics.CANDIDATE_MARKERS`` / ``AGENT_PREDICTION_MARKERS``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import Agent, EgoState, MapSnapshot
from lmpc_mpc.reference import ReferencePathError, bezier_points, candidates_for_pose

RGBA = tuple[float, float, float, float]
CHOSEN_RGBA: RGBA = (0.1, 0.9, 0.2, 1.0)
OTHER_CANDIDATE_RGBA: RGBA = (0.6, 0.6, 0.6, 0.8)
ATTENDED_RGBA: RGBA = (1.0, 0.55, 0.0, 1.0)
UNATTENDED_RGBA: RGBA = (0.2, 0.4, 1.0, 0.6)
HEDGED_RGBA: RGBA = (0.6, 0.2, 0.9, 1.0)
OWN_SUFFIX = "#own"
"""Key suffix of the MPC's own forecast of a hedged agent (``MpcController``)."""
_CURVE_POINTS = 40


@dataclass(frozen=True)
class MirrorLine:
    """One LINE_STRIP marker: namespace, id, (M, 2) points, colour, width."""

    ns: str
    marker_id: int
    points_m: np.ndarray
    rgba: RGBA
    width_m: float
    label: str = ""


def _chosen_index(curves: Sequence[np.ndarray], reference_path: Optional[np.ndarray],
                  reference_id: Optional[int]) -> Optional[int]:
    """The candidate in force: the decision's ``candidate_id`` if it names one, else
    the candidate closest (mean distance) to the reference path the MPC tracked (the
    baseline's route reference is built separately, so it is matched by shape)."""
    if reference_id is not None and 0 <= reference_id < len(curves):
        return reference_id
    if reference_path is None or len(reference_path) == 0 or not curves:
        return None
    ref = np.asarray(reference_path, dtype=float)[:, :2]
    best, best_d = None, math.inf
    for i, c in enumerate(curves):
        d = np.min(np.hypot(c[:, None, 0] - ref[None, :, 0], c[:, None, 1] - ref[None, :, 1]),
                   axis=1)
        if float(np.mean(d)) < best_d:
            best, best_d = i, float(np.mean(d))
    return best


def candidate_lines(map_: MapSnapshot, ego: EgoState, *, lookahead_m: float,
                    reference_path: Optional[np.ndarray] = None,
                    reference_id: Optional[int] = None) -> list[MirrorLine]:
    """The ego's reference candidates at its pose, the one in force highlighted."""
    try:
        cands = candidates_for_pose(map_, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                                    lane_id=ego.lane_id, lookahead_m=lookahead_m)
    except (ReferencePathError, ValueError):
        return []
    curves = [bezier_points(c.control_points, _CURVE_POINTS) for c in cands]
    chosen = _chosen_index(curves, reference_path, reference_id)
    out = []
    for i, (c, pts) in enumerate(zip(cands, curves)):
        hit = i == chosen
        out.append(MirrorLine("candidates", i, pts, CHOSEN_RGBA if hit else OTHER_CANDIDATE_RGBA,
                              0.5 if hit else 0.2, c.label))
    return out


def agent_lines(agents: Sequence[Agent], predictions: Mapping[str, np.ndarray], *,
                horizon: int, dt_s: float) -> list[MirrorLine]:
    """Predicted positions of every agent: attended ones (keys of ``predictions``,
    their (N+1, 2) forecasts) and the rest as constant-velocity lines (display only)."""
    out = []
    t = np.arange(horizon + 1) * dt_s
    for i, ag in enumerate(sorted(agents, key=lambda a: a.id)):
        pred = predictions.get(ag.id)
        if pred is not None:
            out.append(MirrorLine("attended", i, np.asarray(pred, dtype=float)[:, :2],
                                  ATTENDED_RGBA, 0.3, ag.id))
            own = predictions.get(ag.id + OWN_SUFFIX)
            if own is not None:
                out.append(MirrorLine("hedged", i, np.asarray(own, dtype=float)[:, :2],
                                      HEDGED_RGBA, 0.3, ag.id))
            continue
        line = np.column_stack([ag.x_m + ag.v_mps * math.cos(ag.yaw_rad) * t,
                                ag.y_m + ag.v_mps * math.sin(ag.yaw_rad) * t])
        out.append(MirrorLine("unattended", i, line, UNATTENDED_RGBA, 0.15, ag.id))
    return out
