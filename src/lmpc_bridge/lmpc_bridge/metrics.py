"""Scene metrics of DESIGN §6 computed from an episode's per-step record.

- ``collision``: any overlap of the ego box with another participant's box.
- ``fail``: the target area was not reached within ``max_time_s`` (200 s).
- ``time``: seconds to reach the target (the elapsed time if not reached).
- ``ineff``: mean over steps of the sum over *affected* vehicles (followers of
  the ego, vehicles yielding to it) that are not at a red / yellow light of
  ``max(0, v_max,i - v_i)`` (a vehicle above its own desired speed is not
  negatively inefficient).
- ``pen_acc``: mean over steps of the sum over vehicles with gap <= 30 m of
  ``max(0, a_0 - a_i)``, ``a_0 = -2 m/s²``.
- ``pen_dist``: mean over steps of the sum over vehicles of ``max(0, d_0 - d_i)``,
  ``d_0 = 10 m``, ``d_i`` the bumper-to-bumper gap between the boxes.
- ``O.C. = ineff + 1.5 time + 15 pen_acc + 20 pen_dist``.

"Steps" are the records of the episode (one per applied control). ``time_s`` is
given by the caller: the time the target was reached; 200 s (the limit) for a
failed episode; the elapsed time at the collision for a collision. Definitions,
the paper's ambiguities and our choices: docs/METRICS.md. Pure functions.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lmpc_msgs_py.messages import EpisodeMetrics

from lmpc_bridge.record import StepRecord

A0_MPS2 = -2.0
D0_M = 10.0
ACC_RADIUS_M = 30.0
W_TIME, W_ACC, W_DIST = 1.5, 15.0, 20.0


@dataclass(frozen=True)
class MetricWeights:
    a0_mps2: float = A0_MPS2
    d0_m: float = D0_M
    acc_radius_m: float = ACC_RADIUS_M
    w_time: float = W_TIME
    w_acc: float = W_ACC
    w_dist: float = W_DIST


def step_ineff(step: StepRecord) -> float:
    """Sum of ``max(0, v_max - v)`` over affected vehicles not held by a red / yellow light."""
    return sum(max(0.0, n.v_max_mps - n.v_mps) for n in step.nearby
               if n.affected and not n.at_red_light)


def step_pen_acc(step: StepRecord, weights: MetricWeights = MetricWeights()) -> float:
    return sum(max(0.0, weights.a0_mps2 - n.a_mps2) for n in step.nearby
               if n.gap_m <= weights.acc_radius_m)


def step_pen_dist(step: StepRecord, weights: MetricWeights = MetricWeights()) -> float:
    return sum(max(0.0, weights.d0_m - n.gap_m) for n in step.nearby)


def compute_metrics(steps: Sequence[StepRecord], *, time_s: float,
                    weights: MetricWeights = MetricWeights()) -> EpisodeMetrics:
    """Metrics over ``steps``; ``time_s`` is the time to target (or elapsed / limit)."""
    n = len(steps)
    late_controls = sum(1 for s in steps if s.late)
    if n == 0:
        return EpisodeMetrics(time_s=max(time_s, 0.0), late_controls=late_controls)
    ineff = sum(step_ineff(s) for s in steps) / n
    pen_acc = sum(step_pen_acc(s, weights) for s in steps) / n
    pen_dist = sum(step_pen_dist(s, weights) for s in steps) / n
    overall = ineff + weights.w_time * time_s + weights.w_acc * pen_acc + weights.w_dist * pen_dist
    return EpisodeMetrics(
        time_s=time_s, ineff=ineff, pen_acc=pen_acc, pen_dist=pen_dist, overall_cost=overall,
        collisions=sum(1 for s in steps if s.collided_with is not None),
        steps=n, late_controls=late_controls, clamped_controls=sum(1 for s in steps if s.clamped),
    )
