"""Oriented boxes: overlap by the separating-axis theorem, and the gap between boxes.

Boxes are vehicle footprints: centre, yaw (rad, counter-clockwise from +x), length
along the heading and width across it. Pure Python (a few boxes per step).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

Vec = tuple[float, float]


@dataclass(frozen=True)
class OrientedBox:
    """A rectangle of ``length_m`` x ``width_m`` centred at (x_m, y_m), long side along yaw."""

    x_m: float
    y_m: float
    yaw_rad: float
    length_m: float
    width_m: float

    def corners(self) -> tuple[Vec, Vec, Vec, Vec]:
        """Corners counter-clockwise, starting front-left."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        hl, hw = self.length_m / 2.0, self.width_m / 2.0
        out = []
        for dl, dw in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)):
            out.append((self.x_m + dl * c - dw * s, self.y_m + dl * s + dw * c))
        return tuple(out)  # type: ignore[return-value]

    def axes(self) -> tuple[Vec, Vec]:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return (c, s), (-s, c)

    def bounding_radius_m(self) -> float:
        return 0.5 * math.hypot(self.length_m, self.width_m)


def _project(corners: tuple[Vec, ...], axis: Vec) -> tuple[float, float]:
    dots = [p[0] * axis[0] + p[1] * axis[1] for p in corners]
    return min(dots), max(dots)


def boxes_overlap(a: OrientedBox, b: OrientedBox) -> bool:
    """True if the two boxes intersect (touching edges count as overlap).

    Separating-axis theorem: two convex polygons are disjoint iff their
    projections are disjoint on one of the edge normals (two per rectangle).
    """
    reach = a.bounding_radius_m() + b.bounding_radius_m()
    if (a.x_m - b.x_m) ** 2 + (a.y_m - b.y_m) ** 2 > reach * reach:
        return False  # cheap reject: the circumscribed circles do not meet
    ca, cb = a.corners(), b.corners()
    for axis in (*a.axes(), *b.axes()):
        amin, amax = _project(ca, axis)
        bmin, bmax = _project(cb, axis)
        if amax < bmin or bmax < amin:
            return False
    return True


def _point_segment_dist(p: Vec, a: Vec, b: Vec) -> float:
    abx, aby = b[0] - a[0], b[1] - a[1]
    denom = abx * abx + aby * aby
    if denom == 0.0:
        t = 0.0
    else:
        t = max(0.0, min(1.0, ((p[0] - a[0]) * abx + (p[1] - a[1]) * aby) / denom))
    return math.hypot(p[0] - a[0] - t * abx, p[1] - a[1] - t * aby)


def box_gap_m(a: OrientedBox, b: OrientedBox) -> float:
    """Shortest distance between the two boxes (bumper to bumper); 0 if they overlap.

    For disjoint convex polygons the minimum distance is attained between a
    corner of one and an edge of the other.
    """
    if boxes_overlap(a, b):
        return 0.0
    ca, cb = a.corners(), b.corners()
    best = math.inf
    for corners_p, corners_e in ((ca, cb), (cb, ca)):
        for p in corners_p:
            for i in range(4):
                best = min(best, _point_segment_dist(p, corners_e[i], corners_e[(i + 1) % 4]))
    return best
