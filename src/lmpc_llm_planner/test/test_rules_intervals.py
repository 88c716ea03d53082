"""The rules' interval helpers (backends/rules/intervals.py) on a hand-made pool."""
from __future__ import annotations

import pytest

from lmpc_llm_planner.backends.rules.intervals import (
    accel_index, brake_index, mid, mildest_accel, neutral, required_decel, stop_index,
    strongest_brake,
)

POOL = ((-6.0, -4.0), (-4.0, -2.0), (-2.0, -0.5), (-0.5, 0.5), (0.5, 1.5), (1.5, 3.0))
"""Midpoints -5, -3, -1.25, 0, 1, 2.25."""


def test_neutral_is_the_interval_holding_zero_else_the_nearest_midpoint():
    assert neutral(POOL) == 3
    assert neutral(((1.0, 2.0), (-3.0, -1.0))) == 0  # midpoints 1.5 and -2
    assert neutral(((-3.0, -1.0), (1.0, 2.0))) == 1


def test_strongest_brake_and_mildest_accel():
    assert strongest_brake(POOL) == 0
    assert mildest_accel(POOL) == 4
    assert mildest_accel(POOL[:4]) == neutral(POOL[:4])  # no accelerating interval


@pytest.mark.parametrize("want, index", [(1.0, 4), (2.0, 5), (5.0, 5), (0.1, 4)])
def test_accel_index_is_the_mildest_reaching_the_wanted_acceleration(want, index):
    assert accel_index(POOL, want) == index


@pytest.mark.parametrize("need, index", [(0.5, 2), (1.25, 2), (2.0, 1), (4.0, 0), (9.0, 0)])
def test_brake_index_is_the_mildest_braking_enough(need, index):
    assert brake_index(POOL, need, False) == index


def test_brake_index_hold_is_the_mildest_braking_interval():
    assert brake_index(POOL, 9.0, True) == 2
    assert brake_index(POOL[3:], 1.0, False) == neutral(POOL[3:])  # nothing brakes


def test_stop_index_stops_nearest_the_point_without_passing_the_limit():
    # from 10 m/s the midpoints stop in 40 m (-1.25), 16.7 m (-3) and 10 m (-5)
    assert stop_index(POOL, 10.0, 20.0, None, 0.5) == 1
    assert stop_index(POOL, 10.0, 30.0, None, 0.5) == 1      # 40 m would pass 31 m
    assert stop_index(POOL, 10.0, 30.0, 45.0, 0.5) == 2      # the limit allows 40 m
    assert stop_index(POOL, 10.0, 5.0, None, 0.5) == 0       # nothing fits: the strongest
    assert stop_index(POOL, 0.2, 5.0, None, 0.5) == 2        # stopped: hold (mildest)


def test_required_decel():
    assert required_decel(10.0, 25.0, 0.5) == pytest.approx(2.0)
    assert required_decel(0.2, 0.0, 0.5) == 0.0   # standing: nothing needed
    assert required_decel(10.0, 0.05, 0.5) is None  # moving with no distance left
    assert mid((-2.0, -0.5)) == -1.25
