"""Multi-lane road families: ``lane`` (reach an exit), ``eoa`` (obstacle ahead), ``construction``.

Every background car keeps its seeded speed as its desired speed (per-vehicle
``speedFactor`` = speed / limit), so "slower traffic" stays slower; driver
aggressiveness still sets gaps, noise and lane-change assertiveness.

All three share one layout generator: a straight road of two or three edges in a
seeded direction (never axis-aligned on purpose), lanes 3.2 m, built with
netconvert from our plain XML. Lane index 0 is the rightmost lane (SUMO).

- ``lane``: ``main1`` (2-3 lanes, 380-460 m) splits at node ``X`` into ``main2``
  and a one-lane exit ramp ``ramp`` bending 18 deg to the right. The ego starts in
  the leftmost lane and must take the exit: it has to cross every lane to its
  right, where slower traffic (6-10 m/s, trucks among it) drives; faster cars
  use the left lanes. Target: 60 m into the ramp. Interaction check: at least
  two vehicles on lanes right of the ego start within [-40, +120] m of it.
- ``eoa``: two lanes, ``main1`` (500 m) then ``main2`` (150 m). A hazard vehicle
  drives 20-40 m ahead of the ego in its lane and either brakes hard (decel
  8 m/s^2) to a standstill at a seeded point 60-160 m ahead and stays there
  (a breakdown), or is a low-speed vehicle (2-4 m/s). Cars in the adjacent lane
  (1-4, some seeds none near the ego) make the swerve sometimes not free.
  Target: 30 m into ``main2``, either lane. Interaction: the hazard (always).
- ``construction``: 2-3 lanes, ``main1`` (450 m) then ``main2`` (150 m). The
  rightmost lane of ``main1`` is closed 180-260 m ahead of the ego by a work
  zone: 3-5 stationary ``construction`` objects (vClass ``custom1``, 6 m x 2 m,
  SUMO ``<stop>`` of 10000 s) spaced 8-12 m along the lane. The lane stays in
  the network (not a lane drop, not a permission change) so SUMO drivers treat
  it as blocked by stopped vehicles and merge out by their lane-change model.
  The ego starts in that lane. Target: 30 m into ``main2``, any lane.
  Interaction check: at least one car in the open lane(s) is nominally within
  [-40, +40] m of the work zone's start when the ego reaches it.
"""
from __future__ import annotations

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
TRUCK = {"vclass": "truck", "length_m": 10.0, "width_m": 2.5, "max_speed_mps": 25.0,
         "color": "0.5,0.5,0.5"}


@dataclass(frozen=True)
class Car:
    lane: int
    pos_m: float
    speed_mps: float
    route: str = "r_main"
    type_id: str = "bg"


@dataclass(frozen=True)
class RoadParams:
    rot_deg: float
    lanes: int
    main1_m: float
    ego_lane: int
    ego_pos_m: float
    ego_speed_mps: float
    aggressiveness: float
    cars: tuple[Car, ...]
    hazard: tuple[float, float, float] | None = None
    """eoa: (gap ahead m, stop position m or -1, low speed m/s or -1)."""
    zone: tuple[float, ...] = ()
    """construction: positions of the work-zone objects on lane 0 of main1."""


def _write_net(p: RoadParams, scene_dir: Path, *, ramp: bool, name: str) -> Path:
    rot = math.radians(p.rot_deg)
    x1 = p.main1_m
    nodes = [{"id": "S", "x": 0.0, "y": 0.0, "type": "dead_end"}]
    x, y = rotate(x1, 0.0, rot)
    nodes.append({"id": "X", "x": x, "y": y, "type": "priority"})
    x, y = rotate(x1 + 150.0, 0.0, rot)
    nodes.append({"id": "E", "x": x, "y": y, "type": "dead_end"})
    common = {"speed": SPEED_LIMIT_MPS, "width": LANE_WIDTH_M, "priority": 3}
    edges = [{"id": "main1", "from": "S", "to": "X", "numLanes": p.lanes, **common},
             {"id": "main2", "from": "X", "to": "E", "numLanes": p.lanes, **common}]
    if ramp:
        ang = -math.radians(18.0)
        x, y = rotate(x1 + 140.0 * math.cos(ang), 140.0 * math.sin(ang) - 6.0, rot)
        nodes.append({"id": "R", "x": x, "y": y, "type": "dead_end"})
        edges.append({"id": "ramp", "from": "X", "to": "R", "numLanes": 1,
                      **{**common, "speed": 11.11, "priority": 1}})
    nod, edg = write_plain_net(scene_dir, name, nodes=nodes, edges=edges)
    net_file = scene_dir / f"{name}.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net_file)
    return net_file


def _scene(p: RoadParams, *, family: str, seed: int, net_file: Path, route_file: Path,
           route_edges: tuple[str, ...], target_lanes: list[str], target_pos_m: float,
           description: str, reason: str, candidate: int, extra: dict) -> Scene:
    net = read_net(net_file)
    return Scene(
        family=family, seed=seed, net_file=net_file, route_file=route_file,
        additional_files=(), ego_route_edges=route_edges, ego_depart_lane=p.ego_lane,
        ego_depart_pos_m=p.ego_pos_m, ego_depart_speed_mps=p.ego_speed_mps,
        target=target_on_lanes(net, target_lanes, pos_m=target_pos_m, radius_m=1.5),
        description=description,
        params={"candidate": candidate, "lanes": p.lanes, "rot_deg": round(p.rot_deg, 3),
                "ego_lane": p.ego_lane, "ego_pos_m": round(p.ego_pos_m, 3),
                "ego_speed_mps": round(p.ego_speed_mps, 3),
                "aggressiveness": round(p.aggressiveness, 3), "n_cars": len(p.cars), **extra},
        interaction=reason,
    )


def _place(rng: np.random.Generator, lane: int, start_m: float, end_m: float,
           speed: tuple[float, float], *, gap: tuple[float, float] = (18.0, 45.0),
           truck_p: float = 0.0, route: str = "r_main", skip: tuple[float, float] | None = None
           ) -> list[Car]:
    """Cars along ``lane`` from ``start_m`` to ``end_m`` with seeded gaps and speeds."""
    cars = []
    pos = start_m + float(rng.uniform(0.0, gap[1]))
    while pos < end_m:
        truck = rng.uniform() < truck_p
        if skip is None or not (skip[0] - 14.0 < pos < skip[1] + 14.0):
            cars.append(Car(lane=lane, pos_m=round(pos, 2),
                            speed_mps=round(float(rng.uniform(*speed)), 2), route=route,
                            type_id="truck" if truck else "bg"))
        pos += float(rng.uniform(*gap)) + (8.0 if truck else 0.0)
    return cars


def _vtypes(p: RoadParams) -> list[str]:
    return [driver_vtype("bg", aggressiveness=p.aggressiveness),
            driver_vtype("truck", aggressiveness=p.aggressiveness, speed_factor=1.0, **TRUCK)]


def _vehicles(p: RoadParams) -> list[tuple[float, str]]:
    # each car keeps its seeded speed as its desired speed (slow traffic stays slow)
    return [(0.0, vehicle_line(f"v{i}", type_id=c.type_id, route=c.route, depart_s=0.0,
                               lane=c.lane, pos_m=c.pos_m, speed_mps=c.speed_mps,
                               speed_factor=round(c.speed_mps / SPEED_LIMIT_MPS, 3)))
            for i, c in enumerate(p.cars)]


# --- lane ------------------------------------------------------------------------------------
def _sample_lane(rng: np.random.Generator) -> RoadParams:
    lanes = int(rng.integers(2, 4))
    main1 = float(rng.uniform(380.0, 460.0))
    ego_pos = float(rng.uniform(30.0, 60.0))
    ego = (ego_pos - 12.0, ego_pos + 12.0)
    cars: list[Car] = []
    for lane in range(lanes - 1):  # slower traffic right of the ego
        cars += _place(rng, lane, 5.0, main1 - 60.0, (6.0, 10.0), truck_p=0.3, skip=ego,
                       route="r_exit" if lane == 0 and rng.uniform() < 0.3 else "r_main")
    cars += _place(rng, lanes - 1, 5.0, main1 - 60.0, (11.0, 13.5), gap=(30.0, 80.0),
                   skip=ego)
    return RoadParams(rot_deg=float(rng.uniform(0.0, 360.0)), lanes=lanes, main1_m=main1,
                      ego_lane=lanes - 1, ego_pos_m=ego_pos,
                      ego_speed_mps=float(rng.uniform(9.0, 12.0)),
                      aggressiveness=float(rng.uniform(0.0, 1.0)), cars=tuple(cars))


def _check_lane(p: RoadParams) -> str | None:
    near = [c for c in p.cars if c.lane < p.ego_lane and -40.0 <= c.pos_m - p.ego_pos_m <= 120.0]
    return f"{len(near)} slower vehicles on the lanes to cross" if len(near) >= 2 else None


@register_family("lane")
def generate_lane(seed: int, scene_dir: Path) -> Scene:
    """Generate lane scene ``seed``: cross all lanes to the right to take the exit."""
    cand = select_candidate("lane", seed, sample=_sample_lane, check=_check_lane)
    p = cand.params
    net_file = _write_net(p, scene_dir, ramp=True, name="lane")
    route_file = scene_dir / "lane.rou.xml"
    write_routes(route_file, vtypes=_vtypes(p),
                 routes={"r_ego": ("main1", "ramp"), "r_main": ("main1", "main2"),
                         "r_exit": ("main1", "ramp")}, vehicles=_vehicles(p))
    return _scene(p, family="lane", seed=seed, net_file=net_file, route_file=route_file,
                  route_edges=("main1", "ramp"), target_lanes=["ramp_0"], target_pos_m=60.0,
                  description=(f"{p.lanes}-lane road with an exit ramp on the right after "
                               f"{p.main1_m:.0f} m; ego in the leftmost lane must take the exit "
                               f"through slower traffic ({len(p.cars)} vehicles)."),
                  reason=cand.reason, candidate=cand.index,
                  extra={"main1_m": round(p.main1_m, 3)})


# --- eoa -------------------------------------------------------------------------------------
def _sample_eoa(rng: np.random.Generator) -> RoadParams:
    ego_pos = float(rng.uniform(60.0, 80.0))
    ego_speed = float(rng.uniform(9.5, 12.5))
    gap = float(rng.uniform(20.0, 40.0))
    if rng.uniform() < 0.5:
        hazard = (gap, ego_pos + gap + float(rng.uniform(60.0, 160.0)), -1.0)
    else:
        hazard = (gap, -1.0, float(rng.uniform(2.0, 4.0)))
    n_adj = int(rng.integers(1, 5))
    cars = [Car(lane=1, pos_m=round(ego_pos + float(rng.uniform(-60.0, 80.0)) + 9.0 * i, 2),
                speed_mps=round(float(rng.uniform(10.0, 13.5)), 2)) for i in range(n_adj)]
    cars = [c for c in cars if c.pos_m > 5.0]
    if rng.uniform() < 0.5:
        cars.append(Car(lane=0, pos_m=round(max(ego_pos - float(rng.uniform(38.0, 55.0)), 2.0),
                                            2), speed_mps=round(ego_speed, 2)))
    return RoadParams(rot_deg=float(rng.uniform(0.0, 360.0)), lanes=2, main1_m=500.0,
                      ego_lane=0, ego_pos_m=ego_pos, ego_speed_mps=ego_speed,
                      aggressiveness=float(rng.uniform(0.0, 1.0)), cars=tuple(cars),
                      hazard=hazard)


def _check_eoa(p: RoadParams) -> str | None:
    if p.hazard is None:
        return None
    gap, stop, _ = p.hazard
    kind = "brakes hard to a stop" if stop > 0 else "drives slowly"
    adjacent = sum(1 for c in p.cars if c.lane == 1)
    return f"hazard {gap:.0f} m ahead {kind}; {adjacent} car(s) in the adjacent lane"


@register_family("eoa")
def generate_eoa(seed: int, scene_dir: Path) -> Scene:
    """Generate eoa scene ``seed``: a hazard 20-40 m ahead of the ego, swerve or stop."""
    cand = select_candidate("eoa", seed, sample=_sample_eoa, check=_check_eoa)
    p = cand.params
    hazard = p.hazard if p.hazard is not None else (30.0, -1.0, 3.0)  # never None (check)
    gap, stop, slow = hazard
    net_file = _write_net(p, scene_dir, ramp=False, name="eoa")
    vehicles = _vehicles(p)
    hazard_pos = p.ego_pos_m + gap
    if stop > 0:
        line = vehicle_line("hazard", type_id="hazard", route="r_main", depart_s=0.0, lane=0,
                            pos_m=hazard_pos, speed_mps=p.ego_speed_mps,
                            stops=[{"lane": "main1_0", "endPos": round(stop, 2),
                                    "duration": 10000}])
    else:
        line = vehicle_line("hazard", type_id="slow", route="r_main", depart_s=0.0, lane=0,
                            pos_m=hazard_pos, speed_mps=slow)
    vehicles.append((0.0, line))
    route_file = scene_dir / "eoa.rou.xml"
    hazard_type = "  <vType " + " ".join([
        'id="hazard" vClass="passenger" length="4.5" width="1.8" accel="2.6" decel="8.0"',
        'emergencyDecel="9.0" sigma="0.0" tau="1.0" color="1,0.5,0"']) + "/>"
    slow_type = ("  <vType " + f'id="slow" vClass="passenger" length="4.5" width="1.8" '
                 f'maxSpeed="{max(slow, 1.0):.2f}" sigma="0.0" speedFactor="1.0" '
                 'lcStrategic="-1" lcSpeedGain="0" color="1,0.5,0"' + "/>")
    write_routes(route_file, vtypes=[*_vtypes(p), hazard_type, slow_type],
                 routes={"r_ego": ("main1", "main2"), "r_main": ("main1", "main2")},
                 vehicles=vehicles)
    return _scene(p, family="eoa", seed=seed, net_file=net_file, route_file=route_file,
                  route_edges=("main1", "main2"), target_lanes=["main2_0", "main2_1"],
                  target_pos_m=30.0,
                  description=(f"2-lane road; a vehicle {gap:.0f} m ahead of the ego "
                               + (f"brakes hard to a stop at {stop:.0f} m" if stop > 0 else
                                  f"crawls at {slow:.1f} m/s")
                               + f"; {sum(1 for c in p.cars if c.lane == 1)} car(s) in the "
                               "adjacent lane."),
                  reason=cand.reason, candidate=cand.index,
                  extra={"hazard_gap_m": round(gap, 3), "hazard_stop_m": round(stop, 3),
                         "hazard_speed_mps": round(slow, 3)})


# --- construction ------------------------------------------------------------------------------
def _sample_construction(rng: np.random.Generator) -> RoadParams:
    lanes = int(rng.integers(2, 4))
    ego_pos = float(rng.uniform(30.0, 60.0))
    zone_start = ego_pos + float(rng.uniform(180.0, 260.0))
    zone = [zone_start]
    for _ in range(int(rng.integers(2, 5))):
        zone.append(zone[-1] + float(rng.uniform(8.0, 12.0)))
    cars: list[Car] = []
    for lane in range(1, lanes):
        cars += _place(rng, lane, 5.0, 430.0, (8.0, 13.0), gap=(20.0, 60.0), truck_p=0.15,
                       skip=(ego_pos - 12.0, ego_pos + 12.0))
    return RoadParams(rot_deg=float(rng.uniform(0.0, 360.0)), lanes=lanes, main1_m=450.0,
                      ego_lane=0, ego_pos_m=ego_pos, ego_speed_mps=float(rng.uniform(9.0, 12.0)),
                      aggressiveness=float(rng.uniform(0.0, 1.0)), cars=tuple(cars),
                      zone=tuple(round(z, 2) for z in zone))


def _check_construction(p: RoadParams) -> str | None:
    t_arrive = (p.zone[0] - p.ego_pos_m) / p.ego_speed_mps
    near = [c for c in p.cars if c.lane == 1
            and abs(c.pos_m + c.speed_mps * t_arrive - p.zone[0]) <= 40.0]
    if not near:
        return None
    return (f"work zone {p.zone[0] - p.ego_pos_m:.0f} m ahead in the ego lane; {len(near)} "
            "car(s) in the open lane near it when the ego arrives")


@register_family("construction")
def generate_construction(seed: int, scene_dir: Path) -> Scene:
    """Generate construction scene ``seed``: the ego's (rightmost) lane is closed ahead."""
    cand = select_candidate("construction", seed, sample=_sample_construction,
                            check=_check_construction)
    p = cand.params
    net_file = _write_net(p, scene_dir, ramp=False, name="construction")
    vehicles = _vehicles(p)
    for i, pos in enumerate(p.zone):
        vehicles.append((0.0, vehicle_line(
            f"work{i}", type_id="construction", route="r_main", depart_s=0.0, lane=0,
            pos_m=pos, speed_mps=0.0,
            stops=[{"lane": "main1_0", "endPos": pos, "duration": 10000}])))
    route_file = scene_dir / "construction.rou.xml"
    work_type = ('  <vType id="construction" vClass="custom1" length="6.0" width="2.0" '
                 'minGap="0.5" maxSpeed="1.0" color="1,0.6,0"/>')
    write_routes(route_file, vtypes=[*_vtypes(p), work_type],
                 routes={"r_ego": ("main1", "main2"), "r_main": ("main1", "main2")},
                 vehicles=vehicles)
    return _scene(p, family="construction", seed=seed, net_file=net_file,
                  route_file=route_file, route_edges=("main1", "main2"),
                  target_lanes=[f"main2_{i}" for i in range(p.lanes)], target_pos_m=30.0,
                  description=(f"{p.lanes}-lane road; the right lane is closed by a work zone "
                               f"{p.zone[0] - p.ego_pos_m:.0f} m ahead of the ego "
                               f"({len(p.zone)} objects over {p.zone[-1] - p.zone[0] + 6:.0f} m)"
                               f"; {len(p.cars)} cars in the open lane(s)."),
                  reason=cand.reason, candidate=cand.index,
                  extra={"zone_start_m": p.zone[0], "zone_objects": len(p.zone)})
