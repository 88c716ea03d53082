"""Oriented-box overlap (separating axes) and bumper-to-bumper gaps."""
from __future__ import annotations

import math

import pytest

from lmpc_bridge.geometry import OrientedBox, box_gap_m, boxes_overlap


def car(x: float, y: float, yaw: float = 0.0) -> OrientedBox:
    return OrientedBox(x, y, yaw, 4.0, 2.0)


def test_separated_and_overlapping_in_line() -> None:
    assert not boxes_overlap(car(0, 0), car(4.5, 0))
    assert boxes_overlap(car(0, 0), car(3.9, 0))
    assert box_gap_m(car(0, 0), car(4.5, 0)) == pytest.approx(0.5)
    assert box_gap_m(car(0, 0), car(3.9, 0)) == 0.0


def test_rotated_box_in_the_corner_gap() -> None:
    # A thin box at -45 degrees just beyond the corner (2, 1) of ``a``: the axis-aligned
    # bounding boxes overlap, the boxes do not (the separating axis is b's normal).
    a = car(0, 0)
    diag = (math.sqrt(0.5), math.sqrt(0.5))

    def thin_box(offset_m: float) -> OrientedBox:
        return OrientedBox(2.0 + offset_m * diag[0], 1.0 + offset_m * diag[1], -math.pi / 4,
                           4.0, 0.5)

    b = thin_box(0.6)
    xs = [p[0] for p in b.corners()]
    ys = [p[1] for p in b.corners()]
    assert min(xs) < 2.0 and min(ys) < 1.0  # AABBs overlap
    assert not boxes_overlap(a, b)
    assert box_gap_m(a, b) == pytest.approx(0.6 - 0.25)
    assert boxes_overlap(a, thin_box(0.2))


def test_symmetry_and_crossing() -> None:
    a, b = car(0, 0), car(0, 0, math.pi / 2)  # a cross: both centred at the origin
    assert boxes_overlap(a, b) and boxes_overlap(b, a)
    c, d = car(0, 0, 0.3), car(1.0, 5.0, -1.2)
    assert boxes_overlap(c, d) == boxes_overlap(d, c)
    assert box_gap_m(c, d) == pytest.approx(box_gap_m(d, c))


def test_side_by_side_gap() -> None:
    # parallel cars in neighbouring lanes 3.2 m apart: 1.2 m between their sides
    assert box_gap_m(car(0, 0), car(1.0, 3.2)) == pytest.approx(1.2)
    # diagonal corner-to-corner distance
    assert box_gap_m(car(0, 0), car(7.0, 6.0)) == pytest.approx(math.hypot(3.0, 4.0))
