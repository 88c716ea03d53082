"""``narrow``: two egos meet on a two-way road with a one-lane section (issue 18).

Layout (rotated by a seeded angle, never axis-aligned): ``W --- A === B --- E``. The
two-way parts ``W-A`` and ``B-E`` have one lane per direction (3.2 m, lanes 1.6 m either
side of the road's axis); between ``A`` and ``B`` (40-70 m) the road narrows to ONE lane
on the axis, used by both directions: the edges ``AB`` (eastbound) and ``BA`` (westbound)
have the same centreline (``spreadType="center"``, ``bidi``). The approach lanes taper
onto the axis over ``TAPER_M`` (the junctions A and B) before the section. SUMO knows
the pair as bidi edges; the bridge's own box check finds every collision of the egos
(SUMO does not detect those of moved vehicles).

- ``ego_1`` drives ``WA AB BE`` (east), ``ego_2`` ``EB BA AW`` (west); each starts on its
  approach edge at a seeded position and speed; target: 50 m into its exit edge.
- Interaction check: the nominal times at which the two egos reach the section (at their
  start speeds) differ by less than the time one needs to cross it, so without
  coordination they meet inside it.
- Background traffic, by seed: none (about half the seeds) or one car following one of
  the egos 25-45 m behind it at its speed.

The scene is a normal :class:`Scene` for ``ego_1`` (route ``r_ego``, so a single-ego run
works too); ``params["egos"]`` lists every ego (JSON, see ``lmpc_bridge.multi_scene``).
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

SPEED_LIMIT_MPS = 11.11
TAPER_M = 20.0
"""The approach lanes move onto the road's axis over this distance before the section."""
APPROACH_M = 130.0
"""From the road's start to the one-lane section (the taper included)."""
EXIT_M = 100.0
TARGET_INTO_EXIT_M = 50.0


@dataclass(frozen=True)
class NarrowParams:
    rot_deg: float
    section_m: float
    pos_m: tuple[float, float]
    """Front-bumper start of ego_1 on ``WA`` and ego_2 on ``EB``."""
    speed_mps: tuple[float, float]
    follower: int
    """0: no background car; k: one car behind ego_k."""
    follower_gap_m: float
    aggressiveness: float


def _sample(rng: np.random.Generator) -> NarrowParams:
    return NarrowParams(
        rot_deg=float(rng.uniform(0.0, 360.0)), section_m=float(rng.uniform(40.0, 70.0)),
        pos_m=(float(rng.uniform(20.0, 80.0)), float(rng.uniform(20.0, 80.0))),
        speed_mps=(float(rng.uniform(6.0, 10.0)), float(rng.uniform(6.0, 10.0))),
        follower=int(rng.choice([0, 0, 1, 2])), follower_gap_m=float(rng.uniform(25.0, 45.0)),
        aggressiveness=float(rng.uniform(0.0, 1.0)))


def _entry_s(p: NarrowParams, k: int) -> float:
    return (APPROACH_M - p.pos_m[k]) / p.speed_mps[k]


def _check(p: NarrowParams) -> str | None:
    t1, t2 = _entry_s(p, 0), _entry_s(p, 1)
    cross_s = (p.section_m + 4.5) / min(p.speed_mps)
    if abs(t1 - t2) < cross_s:
        return (f"the egos reach the section {abs(t1 - t2):.1f} s apart, less than the "
                f"{cross_s:.1f} s one needs to cross it")
    return None


def _write_net(p: NarrowParams, scene_dir: Path) -> Path:
    rot = math.radians(p.rot_deg)
    xa, xb = APPROACH_M, APPROACH_M + p.section_m
    xe = xb + EXIT_M
    half = LANE_WIDTH_M / 2.0

    def pts(*xy: tuple[float, float]) -> str:
        return " ".join("%.3f,%.3f" % rotate(x, y, rot) for x, y in xy)

    # the tapers are the junctions A and B: the approach edges end TAPER_M before the
    # one-lane section, and the junctions' internal lanes lead onto the axis
    ta, tb = xa - TAPER_M, xb + TAPER_M
    nodes = [{"id": nid, "x": rotate(x, 0.0, rot)[0], "y": rotate(x, 0.0, rot)[1],
              "type": typ} for nid, x, typ in
             (("W", 0.0, "dead_end"), ("A", xa - TAPER_M / 2.0, "priority"),
              ("B", xb + TAPER_M / 2.0, "priority"), ("E", xe, "dead_end"))]
    common = {"speed": SPEED_LIMIT_MPS, "width": LANE_WIDTH_M, "numLanes": 1, "priority": 2,
              "spreadType": "center"}
    edges = [
        {"id": "WA", "from": "W", "to": "A", "shape": pts((0.0, -half), (ta, -half)),
         **common},
        {"id": "AW", "from": "A", "to": "W", "shape": pts((ta, half), (0.0, half)), **common},
        # ``bidi``: one lane used by both directions (netconvert shifts two opposite edges
        # of the same geometry apart otherwise; SUMO's drivers see the bidi edge's traffic)
        {"id": "AB", "from": "A", "to": "B", "shape": pts((xa, 0.0), (xb, 0.0)), "bidi": "BA",
         **common},
        {"id": "BA", "from": "B", "to": "A", "shape": pts((xb, 0.0), (xa, 0.0)), **common},
        {"id": "BE", "from": "B", "to": "E", "shape": pts((tb, -half), (xe, -half)), **common},
        {"id": "EB", "from": "E", "to": "B", "shape": pts((xe, half), (tb, half)), **common},
    ]
    nod, edg = write_plain_net(scene_dir, "narrow", nodes=nodes, edges=edges)
    net_file = scene_dir / "narrow.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net_file)
    return net_file


ROUTES = {"r_ego_1": ("WA", "AB", "BE"), "r_ego_2": ("EB", "BA", "AW")}
EXITS = {"r_ego_1": "BE", "r_ego_2": "AW"}


@register_family("narrow")
def generate_narrow(seed: int, scene_dir: Path) -> Scene:
    """Generate narrow scene ``seed`` (see the module docstring)."""
    cand = select_candidate("narrow", seed, sample=_sample, check=_check)
    p = cand.params
    net_file = _write_net(p, scene_dir)
    net = read_net(net_file)
    vehicles = []
    if p.follower:
        k = p.follower - 1
        route = f"r_ego_{p.follower}"
        pos = max(p.pos_m[k] - p.follower_gap_m, 1.0)
        speed = p.speed_mps[k]
        vehicles.append((0.0, vehicle_line(
            "bg0", type_id="bg", route=route, depart_s=0.0, lane=0, pos_m=pos,
            speed_mps=speed, speed_factor=round(speed / SPEED_LIMIT_MPS, 3))))
    route_file = scene_dir / "narrow.rou.xml"
    write_routes(route_file, vtypes=[driver_vtype("bg", aggressiveness=p.aggressiveness)],
                 routes={"r_ego": ROUTES["r_ego_1"], **ROUTES}, vehicles=vehicles)
    egos = []
    for k, rid in enumerate(ROUTES):
        exit_lane = f"{EXITS[rid]}_0"
        target = target_on_lanes(net, [exit_lane], pos_m=TARGET_INTO_EXIT_M, radius_m=1.5)
        egos.append({"ego_id": f"ego_{k + 1}", "route_id": rid, "route_edges": ROUTES[rid],
                     "depart_lane": 0, "depart_pos_m": round(p.pos_m[k], 3),
                     "depart_speed_mps": round(p.speed_mps[k], 3),
                     "target": {"edge_id": target.edge_id, "lane_ids": target.lane_ids,
                                "lane_pos_m": target.lane_pos_m, "center": target.center,
                                "radius_m": target.radius_m}})
    first = egos[0]
    return Scene(
        family="narrow", seed=seed, net_file=net_file, route_file=route_file,
        additional_files=(), ego_route_edges=ROUTES["r_ego_1"], ego_depart_lane=0,
        ego_depart_pos_m=first["depart_pos_m"], ego_depart_speed_mps=first["depart_speed_mps"],
        target=target_on_lanes(net, ["BE_0"], pos_m=TARGET_INTO_EXIT_M, radius_m=1.5),
        description=(f"Two-way road narrowing to one shared lane for {p.section_m:.0f} m; "
                     f"ego_1 (east) and ego_2 (west) meet there"
                     + (f"; a car follows ego_{p.follower}." if p.follower else ".")),
        params={"candidate": cand.index, "rot_deg": round(p.rot_deg, 3),
                "section_m": round(p.section_m, 3), "follower": p.follower,
                "follower_gap_m": round(p.follower_gap_m, 3),
                "aggressiveness": round(p.aggressiveness, 3),
                "n_egos": len(egos), "egos": json.dumps(egos)},
        interaction=cand.reason,
    )
