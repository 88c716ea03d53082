"""``merge``: two egos merge into one lane (issue 18).

Layout (rotated by a seeded angle): a main road ``W -> J`` and an on-ramp ``R -> J``
meeting it at a seeded angle of 12-30 degrees, both one lane, joining at the priority
junction ``J`` into the one-lane road ``J -> E``. ``ego_1`` drives the main road
(``WJ JE``), ``ego_2`` the ramp (``RJ JE``); each starts at a seeded speed (7-11 m/s) and
position (30-130 m before the junction); target: 50 m into ``JE``.

- Interaction check: their nominal arrival times at the junction (at their start speeds)
  differ by less than ``MEET_S``: without coordination they reach the merge together.
- Background traffic by seed: none (about half the seeds) or one car following one of
  the egos 20-35 m behind it at its speed.

As ``narrow``: a normal :class:`Scene` for ``ego_1`` and ``params["egos"]`` (JSON).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lmpc_bridge.scenarios.base import Scene, register_family, run_netconvert
from lmpc_bridge.scenarios.common import (
    LANE_WIDTH_M,
    driver_vtype,
    read_net,
    rotate,
    select_candidate,
    target_on_lanes,
    vehicle_line,
    write_plain_net,
    write_routes,
)

SPEED_LIMIT_MPS = 13.89
APPROACH_M = 150.0
EXIT_M = 120.0
TARGET_INTO_EXIT_M = 50.0
MEET_S = 1.5
MIN_DIST_M, MAX_DIST_M = 30.0, 130.0


@dataclass(frozen=True)
class MergeParams:
    rot_deg: float
    ramp_deg: float
    arrival_s: tuple[float, float]
    speed_mps: tuple[float, float]
    follower: int
    follower_gap_m: float
    aggressiveness: float

    def dist_m(self, k: int) -> float:
        return self.arrival_s[k] * self.speed_mps[k]


def _sample(rng: np.random.Generator) -> MergeParams:
    t1 = float(rng.uniform(5.0, 10.0))
    return MergeParams(
        rot_deg=float(rng.uniform(0.0, 360.0)), ramp_deg=float(rng.uniform(12.0, 30.0)),
        arrival_s=(t1, t1 + float(rng.uniform(-2.0, 2.0))),
        speed_mps=(float(rng.uniform(7.0, 11.0)), float(rng.uniform(7.0, 11.0))),
        follower=int(rng.choice([0, 0, 1, 2])), follower_gap_m=float(rng.uniform(20.0, 35.0)),
        aggressiveness=float(rng.uniform(0.0, 1.0)))


def _check(p: MergeParams) -> str | None:
    if any(not MIN_DIST_M <= p.dist_m(k) <= MAX_DIST_M for k in (0, 1)):
        return None
    gap = abs(p.arrival_s[0] - p.arrival_s[1])
    if gap >= MEET_S:
        return None
    return (f"the egos reach the merge {gap:.1f} s apart (less than {MEET_S} s) at "
            f"{p.speed_mps[0]:.1f} / {p.speed_mps[1]:.1f} m/s")


def _write_net(p: MergeParams, scene_dir: Path) -> Path:
    rot, phi = math.radians(p.rot_deg), math.radians(p.ramp_deg)
    xj = APPROACH_M
    rx, ry = xj - APPROACH_M * math.cos(phi), -APPROACH_M * math.sin(phi)
    nodes = []
    for nid, (x, y), typ in (("W", (0.0, 0.0), "dead_end"), ("R", (rx, ry), "dead_end"),
                             ("J", (xj, 0.0), "priority"), ("E", (xj + EXIT_M, 0.0), "dead_end")):
        px, py = rotate(x, y, rot)
        nodes.append({"id": nid, "x": px, "y": py, "type": typ})
    common = {"speed": SPEED_LIMIT_MPS, "width": LANE_WIDTH_M, "numLanes": 1}
    edges = [{"id": "WJ", "from": "W", "to": "J", "priority": 2, **common},
             {"id": "RJ", "from": "R", "to": "J", "priority": 1, **common},
             {"id": "JE", "from": "J", "to": "E", "priority": 2, **common}]
    nod, edg = write_plain_net(scene_dir, "merge", nodes=nodes, edges=edges)
    net_file = scene_dir / "merge.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net_file)
    return net_file


ROUTES = {"r_ego_1": ("WJ", "JE"), "r_ego_2": ("RJ", "JE")}


@register_family("merge")
def generate_merge(seed: int, scene_dir: Path) -> Scene:
    """Generate merge scene ``seed`` (see the module docstring)."""
    cand = select_candidate("merge", seed, sample=_sample, check=_check)
    p = cand.params
    net_file = _write_net(p, scene_dir)
    net = read_net(net_file)
    target = target_on_lanes(net, ["JE_0"], pos_m=TARGET_INTO_EXIT_M, radius_m=1.5)
    egos = []
    for k, rid in enumerate(ROUTES):
        approach = float(net.getLane(f"{ROUTES[rid][0]}_0").getLength())
        egos.append({"ego_id": f"ego_{k + 1}", "route_id": rid, "route_edges": ROUTES[rid],
                     "depart_lane": 0, "depart_pos_m": round(approach - p.dist_m(k), 3),
                     "depart_speed_mps": round(p.speed_mps[k], 3),
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
                "bg0", type_id="bg", route=ego["route_id"], depart_s=0.0, lane=0,
                pos_m=round(pos, 3), speed_mps=speed,
                speed_factor=round(speed / SPEED_LIMIT_MPS, 3))))
        else:
            follower = 0
    route_file = scene_dir / "merge.rou.xml"
    write_routes(route_file, vtypes=[driver_vtype("bg", aggressiveness=p.aggressiveness)],
                 routes={"r_ego": ROUTES["r_ego_1"], **ROUTES}, vehicles=vehicles)
    first = egos[0]
    return Scene(
        family="merge", seed=seed, net_file=net_file, route_file=route_file,
        additional_files=(), ego_route_edges=ROUTES["r_ego_1"], ego_depart_lane=0,
        ego_depart_pos_m=first["depart_pos_m"], ego_depart_speed_mps=first["depart_speed_mps"],
        target=target,
        description=(f"A one-lane on-ramp joins a one-lane road at {p.ramp_deg:.0f} degrees; "
                     f"ego_1 (main road) and ego_2 (ramp) reach the merge together"
                     + (f"; a car follows ego_{follower}." if follower else ".")),
        params={"candidate": cand.index, "rot_deg": round(p.rot_deg, 3),
                "ramp_deg": round(p.ramp_deg, 3),
                "arrival_s": " ".join(f"{a:.2f}" for a in p.arrival_s),
                "follower": follower, "follower_gap_m": round(p.follower_gap_m, 3),
                "aggressiveness": round(p.aggressiveness, 3),
                "n_egos": len(egos), "egos": json.dumps(egos)},
        interaction=cand.reason,
    )
