"""Where the MPC stops for a signal (red, or a yellow it can still stop for comfortably):
one rule for the controller and the planner's lookahead.

Kept apart from :mod:`lmpc_mpc.controller` (moved from there unchanged) so that the
planner's process, which needs only this rule, does not load the solver and CasADi with
it (~60 ms of its start-up).
"""
from __future__ import annotations

from typing import Optional

from lmpc_msgs_py.observation import Observation

STOP_STATES = ("r", "y", "u")
"""Signal states the MPC stops for (``u``: red-yellow)."""
STOP_MARGIN_M = 1.0
"""The box front stops this far before a red light's stop line."""
COMFORT_DECEL_MPS2 = 3.0
"""A yellow light is run through when stopping would need more than this."""


def stop_distance_m(obs: Observation, *, length_m: float) -> Optional[float]:
    """How far the ego's box centre may still go before the next signal link when the MPC
    stops it there (red, or yellow it can still stop for comfortably), or None."""
    links = sorted(obs.signals.links, key=lambda lk: lk.distance_m)
    if not links:
        return None
    nxt = links[0]
    if nxt.state not in STOP_STATES:
        return None
    v = obs.ego.v_mps
    if nxt.state == "y" and nxt.distance_m < v * v / (2.0 * COMFORT_DECEL_MPS2):
        return None  # too close to stop comfortably on yellow: go on
    return max(0.0, nxt.distance_m - 0.5 * length_m - STOP_MARGIN_M)
