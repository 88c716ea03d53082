"""``usi-multi``: 2-4 egos meet at the unsignalized intersection (issue 18).

The network is the ``usi`` family's (``usi._write_plain_net``: a four-way priority
junction ``C``, major road W-E with 1-2 lanes per direction, minor road N-S with one).
Each ego comes from its own arm (seeded permutation) and turns left, goes straight or
turns right (seeded); left turns leave from the leftmost lane, the others from lane 0;
target: 40 m into its exit edge.

- Start: every ego's nominal arrival time at the stop line (at its start speed, 6-11 m/s)
  lies within 2 s of a common time of 5-8 s; its start is 25-130 m before the stop line.
- Interaction check: every ego has another ego whose movement conflicts with its own
  (their paths cross, or they end on the same road) and whose nominal arrival is less
  than ``MEET_S`` apart, so without coordination they meet in the junction. Conflicts
  come from the arms' order around the junction (right-hand traffic: each arm's way in
  lies right of its way out; two movements cross when their end points interleave).
- Background traffic by seed: none (about half the seeds) or one car following one of
  the egos 20-35 m behind it at its speed.

As ``narrow``: a normal :class:`Scene` for ``ego_1`` (single-ego runs work too) and
``params["egos"]`` (JSON, ``lmpc_bridge.multi_scene``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lmpc_bridge.scenarios.base import Scene, TargetSpec, register_family, run_netconvert
from lmpc_bridge.scenarios.common import (
    driver_vtype,
    read_net,
    select_candidate,
    target_on_lanes,
    vehicle_line,
    write_routes,
)
from lmpc_bridge.scenarios.usi import SPEED_LIMIT_MPS, _write_plain_net

ARMS = ("E", "N", "W", "S")
"""Counter-clockwise around the junction (angles 0, 90, 180, 270 degrees)."""
TURNS = {"right": 1, "straight": 2, "left": 3}
"""Arm offset (counter-clockwise) of the exit for each turn."""
MEET_S = 2.0
TARGET_INTO_EXIT_M = 40.0
TARGET_RADIUS_M = 5.0
MIN_DIST_M, MAX_DIST_M = 25.0, 130.0


@dataclass(frozen=True)
class UsiMultiParams:
    major_lanes: int
    arms: tuple[int, ...]
    """Index into ``ARMS`` of each ego's arm (ego_1 first)."""
    turns: tuple[str, ...]
    arrival_s: tuple[float, ...]
    speed_mps: tuple[float, ...]
    follower: int
    """0: no background car; k: one car behind ego_k."""
    follower_gap_m: float
    aggressiveness: float

    def exit_arm(self, k: int) -> int:
        return (self.arms[k] + TURNS[self.turns[k]]) % 4

    def dist_m(self, k: int) -> float:
        return self.arrival_s[k] * self.speed_mps[k]


def _sample(rng: np.random.Generator) -> UsiMultiParams:
    n = int(rng.choice([2, 3, 4]))
    arms = tuple(int(a) for a in rng.permutation(4)[:n])
    turns = tuple(str(rng.choice(list(TURNS))) for _ in range(n))
    common = float(rng.uniform(5.0, 8.0))
    arrival = tuple(common + float(rng.uniform(-2.0, 2.0)) for _ in range(n))
    speed = tuple(float(rng.uniform(6.0, 11.0)) for _ in range(n))
    return UsiMultiParams(
        major_lanes=int(rng.integers(1, 3)), arms=arms, turns=turns, arrival_s=arrival,
        speed_mps=speed, follower=int(rng.choice([0] * n + list(range(1, n + 1)))),
        follower_gap_m=float(rng.uniform(20.0, 35.0)),
        aggressiveness=float(rng.uniform(0.0, 1.0)))


def _ends(arm_in: int, arm_out: int) -> tuple[float, float]:
    """Angles (degrees) of a movement's way in and way out on the junction's rim."""
    return (arm_in * 90.0 + 10.0) % 360.0, (arm_out * 90.0 - 10.0) % 360.0


def movements_conflict(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Do the movements ``(arm in, arm out)`` ``a`` and ``b`` (distinct arms in) cross or
    end on the same road?"""
    if a[1] == b[1]:
        return True
    lo, hi = sorted(_ends(*a))
    inside = [lo < x < hi for x in _ends(*b)]
    return inside[0] != inside[1]


def _check(p: UsiMultiParams) -> str | None:
    n = len(p.arms)
    if any(not MIN_DIST_M <= p.dist_m(k) <= MAX_DIST_M for k in range(n)):
        return None
    pairs = []
    for k in range(n):
        mates = [j for j in range(n) if j != k
                 and movements_conflict((p.arms[k], p.exit_arm(k)), (p.arms[j], p.exit_arm(j)))
                 and abs(p.arrival_s[k] - p.arrival_s[j]) < MEET_S]
        if not mates:
            return None
        pairs += [f"ego_{k + 1}~ego_{j + 1}" for j in mates if j > k]
    return (f"every ego has a conflicting ego arriving less than {MEET_S:.0f} s apart "
            f"({', '.join(pairs)})")


def _lane(p: UsiMultiParams, k: int) -> int:
    major = ARMS[p.arms[k]] in ("E", "W")
    return p.major_lanes - 1 if major and p.turns[k] == "left" else 0


@register_family("usi-multi")
def generate_usi_multi(seed: int, scene_dir: Path) -> Scene:
    """Generate usi-multi scene ``seed`` (see the module docstring)."""
    cand = select_candidate("usi-multi", seed, sample=_sample, check=_check)
    p = cand.params
    nodes, edges = _write_plain_net(scene_dir, major_lanes=p.major_lanes)
    net_file = scene_dir / "usi.net.xml"
    run_netconvert(nodes_file=nodes, edges_file=edges, net_file=net_file)
    net = read_net(net_file)
    routes: dict[str, tuple[str, ...]] = {}
    egos = []
    for k in range(len(p.arms)):
        a, b = ARMS[p.arms[k]], ARMS[p.exit_arm(k)]
        rid = f"r_ego_{k + 1}"
        routes[rid] = (f"{a}2C", f"C2{b}")
        lane = _lane(p, k)
        approach = float(net.getLane(f"{a}2C_{lane}").getLength())
        exit_edge = net.getEdge(f"C2{b}")
        lanes = [ln.getID() for ln in exit_edge.getLanes()]
        target = target_on_lanes(net, lanes, pos_m=TARGET_INTO_EXIT_M,
                                 radius_m=TARGET_RADIUS_M)
        egos.append({"ego_id": f"ego_{k + 1}", "route_id": rid, "route_edges": routes[rid],
                     "depart_lane": lane, "depart_pos_m": round(approach - p.dist_m(k), 3),
                     "depart_speed_mps": round(p.speed_mps[k], 3), "turn": p.turns[k],
                     "target": {"edge_id": target.edge_id, "lane_ids": target.lane_ids,
                                "lane_pos_m": target.lane_pos_m, "center": target.center,
                                "radius_m": target.radius_m}})
    vehicles = []
    follower = p.follower
    if follower:
        ego = egos[follower - 1]
        pos = ego["depart_pos_m"] - p.follower_gap_m
        if pos >= 1.0:
            speed = p.speed_mps[follower - 1]
            vehicles.append((0.0, vehicle_line(
                "bg0", type_id="bg", route=ego["route_id"], depart_s=0.0,
                lane=ego["depart_lane"], pos_m=round(pos, 3), speed_mps=speed,
                speed_factor=round(speed / SPEED_LIMIT_MPS, 3))))
        else:
            follower = 0
    route_file = scene_dir / "usi_multi.rou.xml"
    write_routes(route_file, vtypes=[driver_vtype("bg", aggressiveness=p.aggressiveness)],
                 routes={"r_ego": routes["r_ego_1"], **routes}, vehicles=vehicles)
    first = egos[0]
    t = first["target"]
    moves = ", ".join(f"ego_{k + 1} {ARMS[p.arms[k]]}->{ARMS[p.exit_arm(k)]} ({p.turns[k]})"
                      for k in range(len(p.arms)))
    return Scene(
        family="usi-multi", seed=seed, net_file=net_file, route_file=route_file,
        additional_files=(), ego_route_edges=routes["r_ego_1"],
        ego_depart_lane=first["depart_lane"], ego_depart_pos_m=first["depart_pos_m"],
        ego_depart_speed_mps=first["depart_speed_mps"],
        target=TargetSpec(edge_id=t["edge_id"], lane_ids=tuple(t["lane_ids"]),
                          lane_pos_m=t["lane_pos_m"], center=t["center"],
                          radius_m=t["radius_m"]),
        description=(f"{len(egos)} egos at the unsignalized junction ({p.major_lanes} "
                     f"lane(s) per direction on the major road): {moves}"
                     + (f"; a car follows ego_{follower}." if follower else ".")),
        params={"candidate": cand.index, "major_lanes": p.major_lanes,
                "moves": moves, "arrival_s": " ".join(f"{a:.2f}" for a in p.arrival_s),
                "follower": follower, "follower_gap_m": round(p.follower_gap_m, 3),
                "aggressiveness": round(p.aggressiveness, 3),
                "n_egos": len(egos), "egos": json.dumps(egos)},
        interaction=cand.reason,
    )
