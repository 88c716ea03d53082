"""SUMO never inserts a vehicle onto the ego's body (issue 23, ``lmpc_bridge.insertion``).

SUMO checks an insertion against the lane it has the ego on, not against the ego's body.
The constructed case: a straight road of two 2.0 m lanes; the ego (1.8 m wide) stands on
lane 0 with its front at 60 m, and a truck (2.5 m wide) departs at 2 s on lane 1 with its
front at 60 m, beside it: SUMO sees lane 1 free and inserts it, its box overlapping the
ego's by 0.15 m (the lane-104 mechanism: the ego's body across two lanes, SUMO checking
one). Without the guard the episode records a collision at 2.1 s; with it the truck is
held back until the ego has driven clear of its spot and is then inserted where the scene
put it.
"""
from __future__ import annotations

import math
from pathlib import Path

import libsumo
import pytest

from lmpc_msgs_py.messages import Control

from lmpc_bridge.geometry import OrientedBox
from lmpc_bridge.insertion import HEADWAY_S, MARGIN_LAT_M, MARGIN_M, guard_box
from lmpc_bridge.scenarios.base import Scene, TargetSpec, run_netconvert
from lmpc_bridge.scenarios.common import (driver_vtype, vehicle_line, write_plain_net,
                                          write_routes)
from lmpc_bridge.sim import SumoSim

TRUCK_FRONT_M = 60.0
DEPART_S = 2.0
MOVE_AFTER_S = 4.0
"""The ego stands until then, then drives on at 1.5 m/s^2."""


def _scene(work: Path) -> Scene:
    nod, edg = write_plain_net(
        work, "ins", nodes=[dict(id="A", x=0.0, y=0.0), dict(id="B", x=400.0, y=0.0)],
        edges=[dict(id="AB", **{"from": "A", "to": "B"}, numLanes=2, speed=13.89,
                    width=2.0)])
    net = work / "ins.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net)
    routes = work / "ins.rou.xml"
    write_routes(routes, vtypes=[driver_vtype("truck", aggressiveness=0.0, vclass="truck",
                                              length_m=10.0, width_m=2.5)],
                 routes={"r_ego": ["AB"], "r_bg": ["AB"]},
                 vehicles=[(DEPART_S, vehicle_line(
                     "late", type_id="truck", route="r_bg", depart_s=DEPART_S, lane=1,
                     pos_m=TRUCK_FRONT_M, speed_mps=0.0, speed_factor=0.5))])
    return Scene(family="insertion", seed=0, net_file=net, route_file=routes,
                 additional_files=(), ego_route_edges=("AB",), ego_depart_lane=0,
                 ego_depart_pos_m=TRUCK_FRONT_M, ego_depart_speed_mps=0.0,
                 target=TargetSpec(edge_id="AB", lane_ids=("AB_0", "AB_1"), lane_pos_m=380.0,
                                   center=(380.0, -1.0), radius_m=5.0),
                 max_time_s=40.0)


def _control(sim: SumoSim, accel: float) -> Control:
    return Control(stamp_s=sim.time_s, seq=sim.step_index, accel_mps2=accel, steer_rad=0.0,
                   mode="baseline", solver_status="test", solve_time_ms=0.0)


def test_guard_box_margins() -> None:
    """The grown box: MARGIN_M behind, MARGIN_M + HEADWAY_S * v ahead, MARGIN_LAT_M a side."""
    g = guard_box(10.0, 0.0, 0.0, 4.5, 1.8, 8.0)
    front, back = g.x_m + g.length_m / 2.0, g.x_m - g.length_m / 2.0
    assert front == pytest.approx(10.0 + 2.25 + MARGIN_M + HEADWAY_S * 8.0)
    assert back == pytest.approx(10.0 - 2.25 - MARGIN_M)
    assert g.width_m == pytest.approx(1.8 + 2 * MARGIN_LAT_M)
    # a car centred in the next 3.2 m lane beside the ego is not on its body
    from lmpc_bridge.geometry import boxes_overlap
    assert not boxes_overlap(g, OrientedBox(10.0, 3.2, 0.0, 10.0, 2.5))
    assert boxes_overlap(g, OrientedBox(10.0, 1.6, 0.0, 4.5, 1.8))


def test_insertion_onto_the_ego_is_held_until_clear(tmp_path: Path) -> None:
    sim = SumoSim(work_dir=tmp_path)
    sim.reset_scene(_scene(tmp_path))
    held_at = inserted_at = None
    try:
        while sim.outcome == "running" and sim.time_s < 20.0 - 1e-9:
            sim.step(_control(sim, 0.0 if sim.time_s < MOVE_AFTER_S - 1e-9 else 1.5))
            present = "late" in libsumo.vehicle.getIDList()
            seen = any(a.id == "late" for a in sim.observe().agents.agents)
            if held_at is None and sim.record().held_insertions:
                held_at = sim.time_s
            if present and inserted_at is None:
                inserted_at = sim.time_s
                # inserted where the scene put it, behind the ego now
                assert libsumo.vehicle.getLaneIndex("late") == 1
                assert libsumo.vehicle.getLanePosition("late") == pytest.approx(
                    TRUCK_FRONT_M, abs=1e-3)
                assert libsumo.vehicle.getTypeID("late") == "truck"
                assert libsumo.vehicle.getSpeedFactor("late") == pytest.approx(0.5)
                ego_back = sim.pose.x_m - sim.vehicle.length_m / 2.0
                assert ego_back - MARGIN_M >= TRUCK_FRONT_M - 1e-6
            if inserted_at is None:
                assert not present and not seen, f"truck in SUMO at {sim.time_s}"
        record = sim.record()
    finally:
        sim.close()
    assert record.collided_with is None, record.collided_with
    # SUMO inserted it at its depart time (our t = 0 is SUMO's first step, t = 0.1 s)
    assert held_at == pytest.approx(DEPART_S, abs=0.15)
    assert record.held_insertions == 1
    assert inserted_at is not None and inserted_at > MOVE_AFTER_S
    assert [line.split(": ")[1].split(" ")[0] for line in record.insertion_holds] == [
        "held", "released"]
    assert all(s.collided_with is None for s in record.steps)
    assert not any(n.id == "late" for s in record.steps if s.t_s < inserted_at
                   for n in s.nearby)


def test_insertion_guard_is_deterministic(tmp_path: Path) -> None:
    """Same scene, same controls: the same record (holds included) twice."""
    records = []
    for run in range(2):
        work = tmp_path / str(run)
        work.mkdir()
        sim = SumoSim(work_dir=work)
        sim.reset_scene(_scene(work))
        try:
            while sim.outcome == "running" and sim.time_s < 12.0 - 1e-9:
                sim.step(_control(sim, 0.0 if sim.time_s < MOVE_AFTER_S - 1e-9 else 1.5))
            records.append(sim.record())
        finally:
            sim.close()
    a, b = records
    assert a.insertion_holds == b.insertion_holds and a.held_insertions == 1
    assert [(s.x_m, [(n.id, n.x_m) for n in s.nearby]) for s in a.steps] == \
        [(s.x_m, [(n.id, n.x_m) for n in s.nearby]) for s in b.steps]
    assert not math.isnan(a.steps[-1].x_m)


def test_a_branch_taken_while_a_vehicle_is_held_repeats_the_run(tmp_path: Path) -> None:
    """``save_state`` while the truck is held (it is in no SUMO state file) and
    ``load_state``: the run from there repeats, the truck's release and insertion too."""
    sim = SumoSim(work_dir=tmp_path)
    sim.reset_scene(_scene(tmp_path))

    def run_to(until_s: float) -> list[tuple[float, float, tuple[str, ...]]]:
        out = []
        while sim.outcome == "running" and sim.time_s < until_s - 1e-9:
            sim.step(_control(sim, 0.0 if sim.time_s < MOVE_AFTER_S - 1e-9 else 1.5))
            out.append((sim.time_s, sim.pose.x_m,
                        tuple(sorted(a.id for a in sim.observe().agents.agents))))
        return out

    try:
        run_to(3.0)
        assert sim.record().held_insertions == 1 and "late" not in libsumo.vehicle.getIDList()
        state = sim.save_state(tmp_path / "held.xml")
        first = run_to(12.0)
        holds = sim.record().insertion_holds
        sim.load_state(state)
        assert sim.record().insertion_holds == holds[:1]
        again = run_to(12.0)
        assert again == first and sim.record().insertion_holds == holds
        assert any("late" in agents for _, _, agents in first)
    finally:
        sim.close()
