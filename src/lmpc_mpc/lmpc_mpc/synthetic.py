"""Hand-made maps and observations for unit tests and the solver benchmark.

These are *synthetic*: simple geometry written by hand (no SUMO), in the same
schemas the bridge publishes, so tests of the reference, the solver and the
controller need no simulator.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import (
    Agent,
    AgentArray,
    EgoState,
    Lane,
    LaneLink,
    MapSnapshot,
    SignalStates,
    StopLine,
    TargetArea,
)
from lmpc_msgs_py.observation import Observation

LANE_W_M = 3.2


_Pts = tuple[tuple[float, float], ...]


def _line(x0: float, y0: float, x1: float, y1: float, n: int = 2) -> _Pts:
    xs, ys = np.linspace(x0, x1, n), np.linspace(y0, y1, n)
    return tuple((float(x), float(y)) for x, y in zip(xs, ys))


def _arc(cx: float, cy: float, r: float, a0_rad: float, a1_rad: float,
         n: int = 16) -> tuple[tuple[float, float], ...]:
    a = np.linspace(a0_rad, a1_rad, n)
    return tuple((float(cx + r * math.cos(t)), float(cy + r * math.sin(t))) for t in a)


def _lane(lid: str, pts: tuple[tuple[float, float], ...], *, index: int = 0,
          speed_mps: float = 13.89, internal: bool = False,
          successors: Sequence[LaneLink] = ()) -> Lane:
    arr = np.asarray(pts)
    length = float(np.sum(np.hypot(*np.diff(arr, axis=0).T)))
    edge = lid.rsplit("_", 1)[0]
    return Lane(id=lid, edge_id=edge, index=index, centerline=pts, width_m=LANE_W_M,
                speed_limit_mps=speed_mps, length_m=length, internal=internal,
                successors=tuple(successors))


def straight_road(*, length_m: float = 300.0, speed_mps: float = 13.89) -> MapSnapshot:
    """Two eastbound lanes (``E0_0`` right at y=-4.8, ``E0_1`` left at y=-1.6) and one
    westbound lane ``-E0_0`` at y=+1.6; the ego route is ``E0_0``."""
    lanes = (
        _lane("E0_0", _line(0.0, -4.8, length_m, -4.8), index=0, speed_mps=speed_mps),
        _lane("E0_1", _line(0.0, -1.6, length_m, -1.6), index=1, speed_mps=speed_mps),
        _lane("-E0_0", _line(length_m, 1.6, 0.0, 1.6), index=0, speed_mps=speed_mps),
    )
    return MapSnapshot(stamp_s=0.0, lanes=lanes, ego_route=("E0_0",),
                       target=TargetArea(lane_ids=("E0_0",), center=(length_m - 10.0, -4.8),
                                         radius_m=10.0))


def four_way_junction(*, arm_m: float = 100.0, speed_mps: float = 13.89,
                      ego_turn: str = "l") -> MapSnapshot:
    """An unsignalized 4-way junction at the origin, one lane per direction, junction
    box +-8 m. Ego comes from the south (``S_in_0``, northbound at x=+1.6) and turns
    left (``ego_turn="l"``) to ``W_out_0``, goes straight (``"s"``) or right (``"r"``).
    The oncoming lane ``N_in_0`` (southbound at x=-1.6) goes straight to ``S_out_0``
    or turns right into ``W_out_0``."""
    h = 1.6
    b = 8.0
    internal = (
        _lane(":J_0_0", _line(h, -b, h, b), internal=True,
              successors=[LaneLink(to_lane="N_out_0", direction="s")]),
        _lane(":J_1_0", _arc(-b, -b, b + h, 0.0, math.pi / 2.0), internal=True,
              successors=[LaneLink(to_lane="W_out_0", direction="l")]),
        _lane(":J_2_0", _arc(b, -b, b - h, math.pi, math.pi / 2.0), internal=True,
              successors=[LaneLink(to_lane="E_out_0", direction="r")]),
        _lane(":J_3_0", _line(-h, b, -h, -b), internal=True,
              successors=[LaneLink(to_lane="S_out_0", direction="s")]),
        _lane(":J_4_0", _arc(-b, b, b - h, 0.0, -math.pi / 2.0), internal=True,
              successors=[LaneLink(to_lane="W_out_0", direction="r")]),
    )
    lanes = (
        _lane("S_in_0", _line(h, -arm_m, h, -b), speed_mps=speed_mps, successors=[
            LaneLink(to_lane="N_out_0", via_lane=":J_0_0", direction="s"),
            LaneLink(to_lane="W_out_0", via_lane=":J_1_0", direction="l"),
            LaneLink(to_lane="E_out_0", via_lane=":J_2_0", direction="r"),
        ]),
        _lane("N_in_0", _line(-h, arm_m, -h, b), speed_mps=speed_mps, successors=[
            LaneLink(to_lane="S_out_0", via_lane=":J_3_0", direction="s"),
            LaneLink(to_lane="W_out_0", via_lane=":J_4_0", direction="r"),
        ]),
        _lane("N_out_0", _line(h, b, h, arm_m), speed_mps=speed_mps),
        _lane("S_out_0", _line(-h, -b, -h, -arm_m), speed_mps=speed_mps),
        _lane("W_out_0", _line(-b, h, -arm_m, h), speed_mps=speed_mps),
        _lane("E_out_0", _line(b, -h, arm_m, -h), speed_mps=speed_mps),
    ) + internal
    via = {"l": (":J_1_0", "W_out_0"), "s": (":J_0_0", "N_out_0"), "r": (":J_2_0", "E_out_0")}
    v_lane, out = via[ego_turn]
    end = {"W_out_0": (-arm_m + 10, h), "N_out_0": (h, arm_m - 10),
           "E_out_0": (arm_m - 10, -h)}[out]
    return MapSnapshot(
        stamp_s=0.0, lanes=lanes,
        stop_lines=(StopLine(lane_id="S_in_0", position=(h, -b), junction_id="J",
                             signalized=False),
                    StopLine(lane_id="N_in_0", position=(-h, b), junction_id="J",
                             signalized=False)),
        ego_route=("S_in_0", v_lane, out),
        target=TargetArea(lane_ids=(out,), center=end, radius_m=10.0))


def roundabout_entry(*, arm_m: float = 100.0, ring_m: float = 60.0,
                     ring_speed_mps: float = 8.33) -> MapSnapshot:
    """A roundabout entry, straightened: the ego comes from the south (``S_in_0``,
    northbound at x=+1.6, yield line at y=-8) and turns right into the ring lane
    ``R1_0`` (eastbound at y=-1.6); ring traffic comes along ``R0_0`` (eastbound at
    y=-1.6, from x=-8-``ring_m``) and goes straight on into ``R1_0``. Ring lanes and
    the junction lanes onto the ring are flagged ``roundabout``."""
    h, b = 1.6, 8.0
    ring: dict[str, Any] = dict(speed_mps=ring_speed_mps)
    lanes = tuple(ln.model_copy(update={"roundabout": True}) for ln in (
        _lane(":J_0_0", _arc(b, -b, b - h, math.pi, math.pi / 2.0), internal=True,
              successors=[LaneLink(to_lane="R1_0", direction="r")], **ring),
        _lane(":J_1_0", _line(-b, -h, b, -h), internal=True,
              successors=[LaneLink(to_lane="R1_0", direction="s")], **ring),
        _lane("R0_0", _line(-b - ring_m, -h, -b, -h), **ring, successors=[
            LaneLink(to_lane="R1_0", via_lane=":J_1_0", direction="s")]),
        _lane("R1_0", _line(b, -h, b + ring_m, -h), **ring),
    )) + (
        _lane("S_in_0", _line(h, -arm_m, h, -b), successors=[
            LaneLink(to_lane="R1_0", via_lane=":J_0_0", direction="r")]),
    )
    return MapSnapshot(
        stamp_s=0.0, lanes=lanes,
        stop_lines=(StopLine(lane_id="S_in_0", position=(h, -b), junction_id="J",
                             signalized=False),),
        ego_route=("S_in_0", ":J_0_0", "R1_0"),
        target=TargetArea(lane_ids=("R1_0",), center=(b + ring_m - 10.0, -h), radius_m=5.0))


def arc_road(*, radius_m: float = 30.0, speed_mps: float = 10.0) -> MapSnapshot:
    """A single lane ``A_0`` on a counter-clockwise half circle (a roundabout-like
    arc) around (0, radius), starting at the origin heading east, then ``B_0`` west."""
    arc = _arc(0.0, radius_m, radius_m, -math.pi / 2.0, math.pi / 2.0, n=40)
    lanes = (
        _lane("A_0", arc, speed_mps=speed_mps,
              successors=[LaneLink(to_lane="B_0", direction="s")]),
        _lane("B_0", _line(0.0, 2 * radius_m, -100.0, 2 * radius_m), speed_mps=speed_mps),
    )
    return MapSnapshot(stamp_s=0.0, lanes=lanes, ego_route=("A_0", "B_0"),
                       target=TargetArea(lane_ids=("B_0",), center=(-90.0, 2 * radius_m),
                                         radius_m=10.0))


def ego_state(*, x_m: float, y_m: float, yaw_rad: float, v_mps: float = 0.0,
              stamp_s: float = 0.0, seq: int = 0, lane_id: Optional[str] = None,
              route_index: int = 0, a_mps2: float = 0.0, steer_rad: float = 0.0,
              required_decision_id: Optional[str] = None) -> EgoState:
    """An ego state with the given pose (box centre)."""
    return EgoState(stamp_s=stamp_s, seq=seq, x_m=x_m, y_m=y_m, yaw_rad=yaw_rad, v_mps=v_mps,
                    a_mps2=a_mps2, steer_rad=steer_rad, lane_id=lane_id,
                    route_index=route_index, dist_to_target_m=100.0,
                    required_decision_id=required_decision_id)


def agent(aid: str, *, x_m: float, y_m: float, yaw_rad: float, v_mps: float = 0.0,
          lane_id: Optional[str] = None, length_m: float = 4.5,
          width_m: float = 1.8) -> Agent:
    """A car agent at the given pose."""
    return Agent(id=aid, kind="car", x_m=x_m, y_m=y_m, yaw_rad=yaw_rad, v_mps=v_mps,
                 a_mps2=0.0, length_m=length_m, width_m=width_m, lane_id=lane_id)


def observation(map_: MapSnapshot, ego: EgoState, agents: Sequence[Agent] = (), *,
                agents_stamp_s: Optional[float] = None,
                signals: Optional[SignalStates] = None) -> Observation:
    """Bundle an observation (agents / signals stamped like the ego unless told)."""
    t = ego.stamp_s if agents_stamp_s is None else agents_stamp_s
    return Observation(
        map=map_, ego=ego,
        agents=AgentArray(stamp_s=t, seq=ego.seq, agents=tuple(agents)),
        signals=signals if signals is not None else SignalStates(stamp_s=ego.stamp_s,
                                                                 seq=ego.seq))


def follow_lead_car(controller: Any, steps: int, dt_s: float
                    ) -> tuple[list[list[float]], list[list[float]]]:
    """Closed loop on :func:`straight_road`: the ego at 10 m/s, a car 30 m ahead at 6 m/s
    in the same lane, the plant the solver's own bicycle model. Returns the controls
    (accel, steer) and the plant states after each step (the MPC's golden scene)."""
    from lmpc_mpc.solver import simulate_bicycle  # the solver imports this module's peers

    m = straight_road()
    x = np.array([10.0, -4.8, 0.0, 10.0])
    controls, states = [], []
    for k in range(steps):
        t = k * dt_s
        lead = agent("lead", x_m=40.0 + 6.0 * t, y_m=-4.8, yaw_rad=0.0, v_mps=6.0,
                     lane_id="E0_0")
        ego = ego_state(x_m=float(x[0]), y_m=float(x[1]), yaw_rad=float(x[2]),
                        v_mps=float(x[3]), stamp_s=t, seq=k, lane_id="E0_0")
        ctl = controller.compute(observation(m, ego, [lead]))
        controls.append([ctl.accel_mps2, ctl.steer_rad])
        x = simulate_bicycle(x, np.array([[ctl.accel_mps2, ctl.steer_rad]]), dt_s=dt_s)[1]
        states.append([float(v) for v in x])
    return controls, states


def closed_loop(controller: Any, map_: MapSnapshot, x0: Sequence[float], steps: int,
                agents: Any = lambda t: (), *, lane_id: Optional[str] = None,
                before_step: Optional[Callable[[int], None]] = None
                ) -> list[tuple[float, np.ndarray, Any]]:
    """Drive ``controller`` on ``map_`` for ``steps`` control steps from the state ``x0``
    (x, y, yaw, v), each control applied to the MPC's own bicycle model
    (``solver.simulate_bicycle``); ``agents(t)``: the agents at time t; ``lane_id``: the
    ego state's lane; ``before_step(k)``: called before step k's control is computed
    (fault injection, reading the plan of step k - 1). Returns (t, state after the step,
    control) per step. The tests' closed loop."""
    from lmpc_mpc.solver import simulate_bicycle  # CasADi only where a loop is driven

    dt = controller.config.dt_s
    x = np.array(x0, dtype=float)
    log = []
    for k in range(steps):
        t = k * dt
        if before_step is not None:
            before_step(k)
        ego = ego_state(x_m=float(x[0]), y_m=float(x[1]),
                        yaw_rad=float(math.remainder(x[2], 2 * math.pi)), v_mps=float(x[3]),
                        stamp_s=t, seq=k, lane_id=lane_id)
        ctl = controller.compute(observation(map_, ego, agents(t)))
        x = simulate_bicycle(x, np.array([[ctl.accel_mps2, ctl.steer_rad]]), dt_s=dt)[1]
        log.append((t, x.copy(), ctl))
    return log
