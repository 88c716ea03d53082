"""Geometry of the pictures (numpy only): lane surfaces, oriented boxes, points along a
lane, junction outlines from the SUMO net file, and the windows a picture shows."""
from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Iterable, Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import Lane, MapSnapshot
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge.record import NearbyVehicle
from lmpc_bridge.render.runs import RenderError


# Typical box sizes (length, width) in metres per kind, for records without sizes
# (SUMO default vTypes: passenger 5.0 x 1.8, truck 7.1 x 2.4, bus 12 x 2.5, ...).
_DEFAULT_SIZE_M = {
    "car": (5.0, 1.8), "truck": (7.1, 2.4), "bus": (12.0, 2.5), "motorcycle": (2.2, 0.9),
    "bicycle": (1.6, 0.65), "pedestrian": (0.5, 0.5),
}


def offset_polyline(points: Sequence[tuple[float, float]], offset_m: float) -> np.ndarray:
    """The polyline shifted ``offset_m`` to its left (negative: right), mitred joints.

    The mitre length is capped at twice the offset so sharp kinks do not spike.
    """
    pts = np.asarray(points, dtype=float)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    keep = np.concatenate(([True], lengths > 1e-9))
    pts = pts[keep]
    if len(pts) < 2:
        return pts
    seg = np.diff(pts, axis=0)
    seg /= np.hypot(seg[:, 0], seg[:, 1])[:, None]
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # left normals
    vertex_normals = np.empty_like(pts)
    vertex_normals[0], vertex_normals[-1] = normals[0], normals[-1]
    if len(pts) > 2:
        mid = normals[:-1] + normals[1:]
        norm = np.hypot(mid[:, 0], mid[:, 1])[:, None]
        mid = np.where(norm > 1e-9, mid / np.maximum(norm, 1e-9), normals[:-1])
        cos_half = np.sum(mid * normals[:-1], axis=1)[:, None]
        vertex_normals[1:-1] = mid / np.maximum(cos_half, 0.5)
    return pts + offset_m * vertex_normals


def lane_polygon(lane: Lane) -> np.ndarray:
    """The lane's surface: centerline +- half its width."""
    half = lane.width_m / 2.0
    left = offset_polyline(lane.centerline, half)
    right = offset_polyline(lane.centerline, -half)
    return np.concatenate([left, right[::-1]])


def box_corners(x_m: float, y_m: float, yaw_rad: float, length_m: float,
                width_m: float) -> np.ndarray:
    """The four corners of an oriented box centred at (x, y)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    hl, hw = length_m / 2.0, width_m / 2.0
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.array([x_m, y_m])


def agent_size_m(vehicle: NearbyVehicle) -> tuple[float, float]:
    """Recorded (length, width), or a typical size of its kind for older records."""
    if vehicle.length_m and vehicle.width_m:
        return vehicle.length_m, vehicle.width_m
    return _DEFAULT_SIZE_M.get(vehicle.kind, _DEFAULT_SIZE_M["car"])


def point_along(lane: Lane, distance_m: float) -> tuple[float, float, float]:
    """(x, y, heading) at ``distance_m`` along the lane centerline (clamped to its ends)."""
    pts = np.asarray(lane.centerline, dtype=float)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    remaining = min(max(distance_m, 0.0), float(lengths.sum()))
    for (x0, y0), (dx, dy), length in zip(pts[:-1], seg, lengths):
        if length <= 1e-9:
            continue
        if remaining <= length:
            f = remaining / length
            return float(x0 + f * dx), float(y0 + f * dy), math.atan2(dy, dx)
        remaining -= length
    dx, dy = seg[-1]
    return float(pts[-1, 0]), float(pts[-1, 1]), math.atan2(dy, dx)


def junction_outlines(net_file: Optional[Path]) -> list[np.ndarray]:
    """Junction polygons from the SUMO net file (empty when it is missing / unreadable)."""
    if net_file is None or not Path(net_file).is_file():
        return []
    stat = Path(net_file).stat()
    return list(_junction_outlines(str(net_file), stat.st_mtime_ns, stat.st_size))


@functools.lru_cache(maxsize=8)
def _junction_outlines(net_file: str, mtime_ns: int, size: int) -> tuple[np.ndarray, ...]:
    """Cached per file version: a run picture draws the map several times."""
    del mtime_ns, size  # cache key only
    import sumolib

    try:
        net = sumolib.net.readNet(str(net_file), withInternal=True)
    except Exception:  # noqa: BLE001 - the outline is decoration; lanes still get drawn
        return ()
    out = []
    for node in net.getNodes():
        shape = node.getShape()
        if shape and len(shape) >= 3 and node.getType() != "dead_end":
            out.append(np.asarray([(p[0], p[1]) for p in shape], dtype=float))
    return tuple(out)


def nose(corners: np.ndarray) -> np.ndarray:
    """Triangle marking the front of a box (corners 0 and 3 are the front ones)."""
    front_mid = (corners[0] + corners[3]) / 2.0
    centre = corners.mean(axis=0)
    back = front_mid + (centre - front_mid) * 0.5
    side = (corners[0] - corners[3]) * 0.35
    return np.array([front_mid, back + side, back - side])


def ego_start_pose(snapshot: MapSnapshot, depart_pos_m: float,
                   vehicle: VehicleParams = DEFAULT_VEHICLE) -> tuple[float, float, float]:
    """Ego box centre and heading at departure (``depart_pos_m`` is the front bumper)."""
    lanes = {lane.id: lane for lane in snapshot.lanes}
    if not snapshot.ego_route or snapshot.ego_route[0] not in lanes:
        raise RenderError("the map has no ego route: cannot place the ego start")
    return point_along(lanes[snapshot.ego_route[0]], depart_pos_m - vehicle.length_m / 2.0)


def bounds(points: Iterable[Sequence[float]], pad_m: float) -> tuple[float, ...]:
    """(x0, x1, y0, y1) of ``points`` padded by ``pad_m``."""
    arr = np.asarray(list(points), dtype=float)
    lo, hi = arr.min(axis=0) - pad_m, arr.max(axis=0) + pad_m
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def map_points(snapshot: MapSnapshot) -> list[tuple[float, float]]:
    """Every centerline point of the map."""
    return [p for lane in snapshot.lanes for p in lane.centerline]


def scene_window(snapshot: MapSnapshot, ego_xy: tuple[float, float], *,
                 pad_m: Optional[float]) -> tuple[float, ...]:
    """Map bounds, or (``pad_m`` given) the ego start, the route's junctions and the
    target padded by ``pad_m`` and clipped to the map: the arms are long, the
    interaction happens near the route."""
    full = bounds(map_points(snapshot), 5.0)
    if pad_m is None:
        return full
    lanes = {lane.id: lane for lane in snapshot.lanes}
    pts = [ego_xy, tuple(snapshot.target.center)]
    pts += [p for lane_id in snapshot.ego_route if lane_id in lanes and lanes[lane_id].internal
            for p in lanes[lane_id].centerline]
    x0, x1, y0, y1 = bounds(pts, pad_m)
    return max(x0, full[0]), min(x1, full[1]), max(y0, full[2]), min(y1, full[3])
