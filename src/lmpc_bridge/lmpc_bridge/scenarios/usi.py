"""``usi``: unprotected left turn at an unsignalized four-way junction (paper Fig. 1).

Layout (SUMO network metres, junction ``C`` at the origin)::

                 N (0, 150)
                    |  minor road, 1 lane each way
    W (-150, 0) ----C---- E (150, 0)   major road, 1-2 lanes each way, 50 km/h
                    |
                 S (0, -150)

The junction is of type ``priority`` (no lights): the major road W-E has
priority over the minor road N-S. The ego drives on the major road from W
(heading east, leftmost lane) and turns left into ``C2N``; by the junction's
right-of-way it must yield to the oncoming major-road stream ``E2C -> C2W``,
which goes straight. Optional extras (seeded): cross traffic on the minor road,
a leader ahead of the ego, a follower behind it.

Interaction ("a scene only counts if the ego meets somebody", DESIGN §6): the
oncoming stream is built backwards from the ego's nominal arrival time at the
junction (constant speed): the first oncoming car reaches the junction within
``[-2.5, +1.5] s`` of the ego, the following ones after seeded headways of
1.5-6 s, so every seed has an oncoming car in conflict with the left turn;
some seeds leave an acceptable gap (>= 5 s), others force a wait. The
generator records the arrival times in ``Scene.params`` and raises SceneError
if no oncoming car arrives within ``[-3, +8] s`` of the ego (never expected).

Approximations: arrival times assume constant speeds (SUMO's drivers have
``sigma`` noise and react to each other), so the realised gaps differ a little.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from lmpc_bridge.scenarios.base import (
    Scene,
    SceneError,
    TargetSpec,
    register_family,
    run_netconvert,
    xml_attrs,
)

ARM_LENGTH_M = 150.0
SPEED_LIMIT_MPS = 13.89  # 50 km/h
LANE_WIDTH_M = 3.2
TARGET_INTO_EXIT_M = 40.0
TARGET_RADIUS_M = 5.0
EGO_LENGTH_M = 4.5
EGO_WIDTH_M = 1.8

_NODES = {"C": (0.0, 0.0), "W": (-ARM_LENGTH_M, 0.0), "E": (ARM_LENGTH_M, 0.0),
          "N": (0.0, ARM_LENGTH_M), "S": (0.0, -ARM_LENGTH_M)}


def _write_plain_net(scene_dir: Path, *, major_lanes: int) -> tuple[Path, Path]:
    nodes = scene_dir / "usi.nod.xml"
    edges = scene_dir / "usi.edg.xml"
    node_lines = [
        f'  <node {xml_attrs(id=nid, x=x, y=y, type="priority" if nid == "C" else "dead_end")}/>'
        for nid, (x, y) in _NODES.items()
    ]
    nodes.write_text("<nodes>\n" + "\n".join(node_lines) + "\n</nodes>\n")
    edge_lines = []
    for a, b in (("W", "C"), ("C", "W"), ("E", "C"), ("C", "E")):
        edge_lines.append(f'  <edge {xml_attrs(id=f"{a}2{b}", **{"from": a}, to=b, priority=3, numLanes=major_lanes, speed=SPEED_LIMIT_MPS, width=LANE_WIDTH_M)}/>')  # noqa: E501
    for a, b in (("N", "C"), ("C", "N"), ("S", "C"), ("C", "S")):
        edge_lines.append(f'  <edge {xml_attrs(id=f"{a}2{b}", **{"from": a}, to=b, priority=1, numLanes=1, speed=SPEED_LIMIT_MPS, width=LANE_WIDTH_M)}/>')  # noqa: E501
    edges.write_text("<edges>\n" + "\n".join(edge_lines) + "\n</edges>\n")
    return nodes, edges


def _read_net(net_file: Path):  # noqa: ANN202 (sumolib has no types)
    import sumolib  # parsed once per generated scene (the scene is cached afterwards)

    return sumolib.net.readNet(str(net_file), withInternal=True)


def _vtype_line(type_id: str, *, aggressiveness: float, color: str) -> str:
    """Driver model of the background traffic: bolder drivers keep shorter gaps,
    react less noisily-cautious and accept shorter gaps at the junction."""
    agg = aggressiveness
    return "  <vType " + xml_attrs(
        id=type_id, vClass="passenger", length=4.5, width=1.8,
        accel=2.6 + 0.8 * agg, decel=4.5, emergencyDecel=9.0,
        sigma=0.5 - 0.3 * agg, tau=1.0 - 0.4 * agg, minGap=2.5 - 1.0 * agg,
        speedFactor=1.0 + 0.15 * agg, speedDev=0.05,
        impatience=0.5 * agg, jmTimegapMinor=1.0 - 0.5 * agg,
        color=color,
    ) + "/>"


@register_family("usi")
def generate_usi(seed: int, scene_dir: Path) -> Scene:
    """Generate usi scene ``seed`` into ``scene_dir`` (see the module docstring)."""
    rng = np.random.Generator(np.random.PCG64(seed))
    major_lanes = int(rng.integers(1, 3))  # 1 or 2 lanes per direction
    nodes, edges = _write_plain_net(scene_dir, major_lanes=major_lanes)
    net_file = scene_dir / "usi.net.xml"
    run_netconvert(nodes_file=nodes, edges_file=edges, net_file=net_file)

    ego_lane = major_lanes - 1  # left turns leave from the leftmost lane
    net = _read_net(net_file)
    approach_len_m = float(net.getLane(f"W2C_{ego_lane}").getLength())
    oncoming_len_m = float(net.getLane("E2C_0").getLength())
    exit_lane = net.getLane("C2N_0")
    exit_len_m = float(exit_lane.getLength())

    # --- ego -------------------------------------------------------------------------
    ego_dist_m = float(rng.uniform(50.0, 70.0))  # front bumper to the stop line
    ego_speed_mps = float(rng.uniform(6.0, 12.0))
    ego_arrival_s = ego_dist_m / ego_speed_mps
    aggressiveness = float(rng.uniform(0.0, 1.0))

    vehicles: list[tuple[float, str]] = []  # (depart time, XML line)

    # --- oncoming stream: E2C -> C2W (straight), conflicting with the left turn -------
    n_oncoming = int(rng.integers(3, 7))
    arrivals = [ego_arrival_s + float(rng.uniform(-2.5, 1.5))]
    for _ in range(n_oncoming - 1):
        arrivals.append(arrivals[-1] + float(rng.uniform(1.5, 6.0)))
    for i, arrival_s in enumerate(arrivals):
        speed = float(rng.uniform(10.0, 13.5))
        lane = int(rng.integers(0, major_lanes))
        dist_m = speed * max(arrival_s, 0.0)
        if dist_m < 10.0:  # never spawn inside or at the mouth of the junction
            dist_m, arrival_s = 10.0, 10.0 / speed
            arrivals[i] = arrival_s
        if dist_m <= oncoming_len_m - 5.0:
            depart_s, pos_m = 0.0, oncoming_len_m - dist_m
        else:
            depart_s, pos_m = (dist_m - (oncoming_len_m - 5.0)) / speed, 5.0
        vehicles.append((depart_s, "  <vehicle " + xml_attrs(
            id=f"onc{i}", type="bg", route="r_oncoming", depart=depart_s, departLane=lane,
            departPos=pos_m, departSpeed=speed) + "/>"))
    conflicts = [a for a in arrivals if -3.0 <= a - ego_arrival_s <= 8.0]
    if not conflicts:
        raise SceneError(f"usi seed {seed}: no oncoming car near the ego's arrival")

    # --- optional extras ---------------------------------------------------------------
    n_cross = int(rng.integers(0, 3))
    for i in range(n_cross):
        route = "r_cross_ns" if rng.uniform() < 0.5 else "r_cross_sn"
        speed = float(rng.uniform(7.0, 12.0))
        arrival_s = ego_arrival_s + float(rng.uniform(-1.0, 6.0))
        dist_m = min(max(speed * arrival_s, 15.0), oncoming_len_m - 5.0)
        vehicles.append((0.0, "  <vehicle " + xml_attrs(
            id=f"cross{i}", type="bg", route=route, depart=0.0, departLane=0,
            departPos=oncoming_len_m - dist_m, departSpeed=speed) + "/>"))
    has_leader = bool(rng.uniform() < 0.4)
    if has_leader:
        gap_m = float(rng.uniform(20.0, 35.0))
        vehicles.append((0.0, "  <vehicle " + xml_attrs(
            id="leader", type="bg", route="r_leader", depart=0.0, departLane=ego_lane,
            departPos=approach_len_m - ego_dist_m + gap_m, departSpeed=ego_speed_mps) + "/>"))
    has_follower = bool(rng.uniform() < 0.5)
    if has_follower:
        gap_m = float(rng.uniform(20.0, 35.0))
        vehicles.append((0.0, "  <vehicle " + xml_attrs(
            id="follower", type="bg", route="r_follower", depart=0.0, departLane=ego_lane,
            departPos=max(approach_len_m - ego_dist_m - gap_m, 0.0),
            departSpeed=ego_speed_mps) + "/>"))

    route_file = scene_dir / "usi.rou.xml"
    lines = ["<routes>",
             _vtype_line("bg", aggressiveness=aggressiveness, color="0.6,0.6,0.9"),
             "  <vType " + xml_attrs(id="ego_type", vClass="passenger", length=EGO_LENGTH_M,
                                     width=EGO_WIDTH_M, color="1,0,0") + "/>",
             '  <route id="r_ego" edges="W2C C2N"/>',
             '  <route id="r_oncoming" edges="E2C C2W"/>',
             '  <route id="r_cross_ns" edges="N2C C2S"/>',
             '  <route id="r_cross_sn" edges="S2C C2N"/>',
             '  <route id="r_leader" edges="W2C C2E"/>',
             '  <route id="r_follower" edges="W2C C2N"/>']
    lines += [line for _, line in sorted(vehicles, key=lambda item: item[0])]
    lines.append("</routes>")
    route_file.write_text("\n".join(lines) + "\n")

    # target: TARGET_INTO_EXIT_M along the exit edge C2N (heading north from the junction)
    target_pos_m = min(TARGET_INTO_EXIT_M, exit_len_m - 5.0)
    import sumolib

    cx, cy = sumolib.geomhelper.positionAtShapeOffset(exit_lane.getShape(), target_pos_m)
    center = (round(float(cx), 3), round(float(cy), 3))
    return Scene(
        family="usi",
        seed=seed,
        net_file=net_file,
        route_file=route_file,
        additional_files=(),
        ego_route_edges=("W2C", "C2N"),
        ego_depart_lane=ego_lane,
        ego_depart_pos_m=approach_len_m - ego_dist_m,
        ego_depart_speed_mps=ego_speed_mps,
        target=TargetSpec(edge_id="C2N", lane_ids=("C2N_0",), lane_pos_m=target_pos_m,
                          center=center, radius_m=TARGET_RADIUS_M),
        description=(
            f"Unprotected left turn W->N at an unsignalized priority junction, "
            f"{major_lanes} lane(s) per direction on the major road; ego {ego_dist_m:.0f} m "
            f"before the junction at {ego_speed_mps:.1f} m/s; {n_oncoming} oncoming cars, "
            f"{n_cross} crossing, leader={has_leader}, follower={has_follower}, "
            f"aggressiveness {aggressiveness:.2f}."
        ),
        params={
            "major_lanes": major_lanes, "ego_dist_to_junction_m": round(ego_dist_m, 3),
            "ego_arrival_s": round(ego_arrival_s, 3), "aggressiveness": round(aggressiveness, 3),
            "n_oncoming": n_oncoming, "n_cross": n_cross, "leader": int(has_leader),
            "follower": int(has_follower),
            "oncoming_arrivals_s": " ".join(f"{a:.2f}" for a in arrivals),
            "max_oncoming_gap_s": round(float(max(np.diff(arrivals))), 3),
        },
        interaction=(f"{len(conflicts)} oncoming car(s) reach the junction within [-3, +8] s "
                     f"of the ego's nominal arrival at {ego_arrival_s:.1f} s"),
    )
