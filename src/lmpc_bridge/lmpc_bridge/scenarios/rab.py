"""``rab``: one-lane roundabout, four arms; the ego enters at arm 0, leaves at a seeded arm.

Layout: ring nodes ``R0..R3`` on a circle of radius 18-26 m (seeded) around the
origin, at angles ``rot + 90 k + jitter`` (jitter +-12 deg, so the arms are not
symmetric and not axis-aligned); ring edges ``R<k>R<k+1>`` run counter-clockwise
(right-hand traffic) with arc shapes, 8.33 m/s. Arms ``A<k>`` 100 m out along
the same angles, edges ``A<k>in`` / ``A<k>out`` (one lane, 13.89 m/s).
netconvert ``--roundabouts.guess`` marks the ring as a roundabout (entering
traffic yields to circulating traffic).

The ego starts 40-70 m before its entry on ``A0in`` and leaves at arm 1, 2 or 3
(first, second or third exit). Circulating traffic: cars starting on the ring
arc before the ego's entry (``R3R0``) or entering from the other arms, the first
timed to pass the ego's entry within [-2, +3] s of its nominal arrival; plus
optional cars entering from arm 0 behind the ego.

Interaction check (build time, constant speeds): a circulating car passes the
ego's entry within [-3, +6] s of the ego's nominal arrival.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lmpc_bridge.scenarios.base import Scene, register_family, run_netconvert
from lmpc_bridge.scenarios.common import (
    LANE_WIDTH_M,
    arrival_window,
    driver_vtype,
    read_net,
    select_candidate,
    target_on_lanes,
    vehicle_line,
    write_plain_net,
    write_routes,
)

ARM_LENGTH_M = 100.0
RING_SPEED_MPS = 8.33
ARM_SPEED_MPS = 13.89
TARGET_INTO_EXIT_M = 35.0


@dataclass(frozen=True)
class RabParams:
    rot_deg: float
    jitter_deg: tuple[float, float, float, float]
    radius_m: float
    exit_arm: int
    ego_dist_m: float
    ego_speed_mps: float
    aggressiveness: float
    circulating: tuple[tuple[float, int, float], ...]
    """(arrival at the ego's entry s, exit arm, speed m/s) of cars on the ring arc R3->R0."""
    entering: tuple[tuple[int, float, int], ...]
    """(arm, arrival at its own entry s, exit arm) of cars entering from arms 1-3."""
    follower_gap_m: float | None

    @property
    def ego_arrival_s(self) -> float:
        return self.ego_dist_m / self.ego_speed_mps

    def angle_rad(self, k: int) -> float:
        return math.radians(self.rot_deg + 90.0 * k + self.jitter_deg[k])


def _sample(rng: np.random.Generator) -> RabParams:
    ego_dist = float(rng.uniform(40.0, 70.0))
    ego_speed = float(rng.uniform(7.0, 11.0))
    arrival = ego_dist / ego_speed
    circ = []
    t = arrival + float(rng.uniform(-2.0, 3.0))
    for _ in range(int(rng.integers(1, 4))):
        speed = round(float(rng.uniform(6.0, 8.0)), 3)
        circ.append((round(t, 3), int(rng.integers(0, 4)), speed))
        t += float(rng.uniform(2.5, 7.0))
    entering = tuple((int(rng.integers(1, 4)), round(float(rng.uniform(0.0, 15.0)), 3),
                      int(rng.integers(0, 4))) for _ in range(int(rng.integers(1, 4))))
    return RabParams(
        rot_deg=float(rng.uniform(0.0, 360.0)),
        jitter_deg=tuple(float(j) for j in rng.uniform(-12.0, 12.0, size=4)),  # type: ignore
        radius_m=float(rng.uniform(18.0, 26.0)), exit_arm=int(rng.integers(1, 4)),
        ego_dist_m=ego_dist, ego_speed_mps=ego_speed,
        aggressiveness=float(rng.uniform(0.0, 1.0)), circulating=tuple(circ), entering=entering,
        follower_gap_m=round(float(rng.uniform(20.0, 35.0)), 3) if rng.uniform() < 0.4 else None)


def _check(p: RabParams) -> str | None:
    hits = arrival_window([a for a, _, _ in p.circulating], p.ego_arrival_s, after_s=6.0)
    if not hits:
        return None
    return f"{len(hits)} circulating car(s) pass the ego's entry within [-3, +6] s of its arrival"


def _arc_shape(p: RabParams, a: int, b: int) -> str:
    a0, a1 = p.angle_rad(a), p.angle_rad(b)
    if a1 <= a0:
        a1 += 2.0 * math.pi
    n = max(int((a1 - a0) / math.radians(10.0)), 2)
    pts = [(p.radius_m * math.cos(a0 + (a1 - a0) * i / n),
            p.radius_m * math.sin(a0 + (a1 - a0) * i / n)) for i in range(n + 1)]
    return " ".join(f"{x:.3f},{y:.3f}" for x, y in pts)


def _ring_edges(start: int, end: int) -> list[str]:
    """Ring edges from ring node ``start`` counter-clockwise to ``end``."""
    out, k = [], start
    while True:
        out.append(f"R{k}R{(k + 1) % 4}")
        k = (k + 1) % 4
        if k == end:
            return out


@register_family("rab")
def generate_rab(seed: int, scene_dir: Path) -> Scene:
    """Generate rab scene ``seed`` (the seed-th candidate with a circulating conflict)."""
    cand = select_candidate("rab", seed, sample=_sample, check=_check)
    p = cand.params
    nodes, edges = [], []
    for k in range(4):
        ang = p.angle_rad(k)
        nodes.append({"id": f"R{k}", "x": round(p.radius_m * math.cos(ang), 3),
                      "y": round(p.radius_m * math.sin(ang), 3), "type": "priority"})
        r_out = p.radius_m + ARM_LENGTH_M
        nodes.append({"id": f"A{k}", "x": round(r_out * math.cos(ang), 3),
                      "y": round(r_out * math.sin(ang), 3), "type": "dead_end"})
        edges.append({"id": f"A{k}in", "from": f"A{k}", "to": f"R{k}", "numLanes": 1,
                      "speed": ARM_SPEED_MPS, "width": LANE_WIDTH_M, "priority": 1})
        edges.append({"id": f"A{k}out", "from": f"R{k}", "to": f"A{k}", "numLanes": 1,
                      "speed": ARM_SPEED_MPS, "width": LANE_WIDTH_M, "priority": 1})
        edges.append({"id": f"R{k}R{(k + 1) % 4}", "from": f"R{k}", "to": f"R{(k + 1) % 4}",
                      "numLanes": 1, "speed": RING_SPEED_MPS, "width": LANE_WIDTH_M + 0.8,
                      "priority": 2, "shape": _arc_shape(p, k, (k + 1) % 4)})
    nod, edg = write_plain_net(scene_dir, "rab", nodes=nodes, edges=edges)
    net_file = scene_dir / "rab.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net_file,
                   extra_args=("--roundabouts.guess", "true"))
    net = read_net(net_file)
    routes: dict[str, tuple[str, ...]] = {}
    for a in range(4):
        for b in range(4):
            if a != b:
                routes[f"r_{a}{b}"] = (f"A{a}in", *_ring_edges(a, b), f"A{b}out")
        routes[f"r_c{a}"] = ("R3R0", *(_ring_edges(0, a) if a != 0 else []), f"A{a}out")
    routes["r_ego"] = routes[f"r_0{p.exit_arm}"]
    vehicles: list[tuple[float, str]] = []
    arc_len = float(net.getEdge("R3R0").getLength())
    for i, (arrival, exit_arm, speed) in enumerate(p.circulating):
        dist = speed * max(arrival, 0.0)
        if dist <= arc_len - 2.0:
            depart, pos = 0.0, arc_len - max(dist, 2.0)
        else:
            depart, pos = (dist - (arc_len - 2.0)) / speed, 2.0
        vehicles.append((depart, vehicle_line(f"circ{i}", type_id="bg", route=f"r_c{exit_arm}",
                                              depart_s=round(depart, 2), lane=0, pos_m=pos,
                                              speed_mps=speed)))
    arm_len = float(net.getEdge("A1in").getLength())
    for i, (arm, arrival, exit_arm) in enumerate(p.entering):
        exit_arm = exit_arm if exit_arm != arm else (arm + 2) % 4
        dist = min(max(10.0 * arrival, 15.0), arm_len - 5.0)
        vehicles.append((0.0, vehicle_line(f"ent{i}", type_id="bg", route=f"r_{arm}{exit_arm}",
                                           depart_s=0.0, lane=0, pos_m=arm_len - dist,
                                           speed_mps=10.0)))
    ego_len = float(net.getEdge("A0in").getLength())
    ego_pos = ego_len - p.ego_dist_m
    if p.follower_gap_m is not None:
        vehicles.append((0.0, vehicle_line(
            "follower", type_id="bg", route=f"r_0{(p.exit_arm % 3) + 1}", depart_s=0.0, lane=0,
            pos_m=max(ego_pos - p.follower_gap_m, 1.0), speed_mps=p.ego_speed_mps)))
    route_file = scene_dir / "rab.rou.xml"
    write_routes(route_file, vtypes=[driver_vtype("bg", aggressiveness=p.aggressiveness)],
                 routes=routes, vehicles=vehicles)
    exit_edge = f"A{p.exit_arm}out"
    target = target_on_lanes(net, [f"{exit_edge}_0"], pos_m=TARGET_INTO_EXIT_M, radius_m=5.0)
    which = {1: "first", 2: "second", 3: "third"}[p.exit_arm]
    return Scene(
        family="rab", seed=seed, net_file=net_file, route_file=route_file, additional_files=(),
        ego_route_edges=routes["r_ego"], ego_depart_lane=0, ego_depart_pos_m=ego_pos,
        ego_depart_speed_mps=p.ego_speed_mps, target=target,
        description=(f"4-arm roundabout, radius {p.radius_m:.0f} m; ego enters at arm 0 "
                     f"{p.ego_dist_m:.0f} m before the ring at {p.ego_speed_mps:.1f} m/s and "
                     f"takes the {which} exit; {len(p.circulating)} circulating, "
                     f"{len(p.entering)} entering, follower={p.follower_gap_m is not None}."),
        params={"candidate": cand.index, "radius_m": round(p.radius_m, 3),
                "rot_deg": round(p.rot_deg, 3), "exit_arm": p.exit_arm,
                "ego_arrival_s": round(p.ego_arrival_s, 3),
                "aggressiveness": round(p.aggressiveness, 3),
                "n_circulating": len(p.circulating), "n_entering": len(p.entering),
                "follower": int(p.follower_gap_m is not None)},
        interaction=cand.reason,
    )
