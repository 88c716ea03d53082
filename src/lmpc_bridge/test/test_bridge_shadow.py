"""The ego's shadow (issue 21, ``lmpc_bridge.shadow``): SUMO's drivers see an ego that
stands across two lanes.

The constructed case: a straight road of two 3.2 m lanes; the ego starts standing on lane 0
at 100 m, steers half-way into lane 1 and stops there (SUMO maps it to lane 1), and a car
``back`` comes along lane 0 at 13 m/s (lane changes off). Without the shadow ``back`` does
not see the ego's tail in its lane and runs into it (collision at 6.7 s); with it ``back``
stops behind the shadow and nothing collides. The shadow is no agent of the observation.
"""
from __future__ import annotations

from pathlib import Path

import libsumo
import pytest

from lmpc_msgs_py.messages import Control

from lmpc_bridge import shadow as shadow_mod
from lmpc_bridge.geometry import OrientedBox
from lmpc_bridge.scenarios.base import Scene, TargetSpec, run_netconvert
from lmpc_bridge.scenarios.common import (driver_vtype, vehicle_line, write_plain_net,
                                          write_routes)
from lmpc_bridge.shadow import LaneShape, blocking_depth_m, intrusion, shadow_id
from lmpc_bridge.sim import EGO_ID, SumoSim

LANE_W_M = 3.2


def _scene(work: Path) -> Scene:
    nod, edg = write_plain_net(
        work, "sh", nodes=[dict(id="A", x=0.0, y=0.0), dict(id="B", x=400.0, y=0.0)],
        edges=[dict(id="AB", **{"from": "A", "to": "B"}, numLanes=2, speed=13.89,
                    width=LANE_W_M)])
    net = work / "sh.net.xml"
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net)
    routes = work / "sh.rou.xml"
    write_routes(routes, vtypes=[driver_vtype("car", aggressiveness=0.0)],
                 routes={"r_ego": ["AB"], "r_bg": ["AB"]},
                 vehicles=[(0.0, vehicle_line("back", type_id="car", route="r_bg", depart_s=0.0,
                                              lane=0, pos_m=10.0, speed_mps=13.0,
                                              speed_factor=1.0))])
    return Scene(family="shadow", seed=0, net_file=net, route_file=routes,
                 additional_files=(), ego_route_edges=("AB",), ego_depart_lane=0,
                 ego_depart_pos_m=100.0, ego_depart_speed_mps=0.0,
                 target=TargetSpec(edge_id="AB", lane_ids=("AB_0", "AB_1"), lane_pos_m=380.0,
                                   center=(380.0, -1.6), radius_m=5.0),
                 max_time_s=40.0)


def _control(t: float, seq: int) -> Control:
    """Half-way into lane 1, stop there until 12 s, then on (straightening out)."""
    accel, steer = ((1.5, 0.3) if t < 2.0 else (0.0, -0.2) if t < 2.6 else
                    (-4.0, 0.0) if t < 12.0 else (2.0, -0.1))
    return Control(stamp_s=t, seq=seq, accel_mps2=accel, steer_rad=steer,
                   mode="baseline", solver_status="test", solve_time_ms=0.0)


def _run(sim: SumoSim, until_s: float) -> None:
    while sim.outcome == "running" and sim.time_s < until_s - 1e-9:
        if "back" in libsumo.vehicle.getIDList():
            libsumo.vehicle.setLaneChangeMode("back", 0)  # it stays in the ego's tail lane
        sim.step(_control(sim.time_s, sim.step_index))


def _lanes() -> dict[str, LaneShape]:
    def lane(i: int) -> LaneShape:
        y = -LANE_W_M / 2.0 - (1 - i) * LANE_W_M
        return LaneShape(id=f"e_{i}", edge_id="e", index=i, centerline=((0.0, y), (100.0, y)),
                         width_m=LANE_W_M, length_m=100.0, left="e_1" if i == 0 else None,
                         right="e_0" if i == 1 else None, internal=False)
    return {"e_0": lane(0), "e_1": lane(1)}


def test_intrusion_is_a_blocked_lane_the_ego_is_leaving() -> None:
    lanes = _lanes()
    assert blocking_depth_m(LANE_W_M) == pytest.approx(0.5)  # (3.2 - 1.8) / 2 - 0.2
    # mapped to lane 1 (the left one), heading left, its right-rear corner 0.8 m into
    # lane 0 (the case): lane 0, up to where the blocking part reaches (48.1 m)
    box = OrientedBox(50.0, -2.5, 0.3, 4.5, 1.8)
    got = intrusion(box, "e_1", lanes)
    assert got is not None and got[0] == "e_0" and got[1] == pytest.approx(48.1, abs=0.05)
    # the same body heading right (it is entering lane 0 from lane 1: its merge): none
    assert intrusion(OrientedBox(50.0, -2.5, -0.3, 4.5, 1.8), "e_1", lanes) is None
    # parallel to the lanes: neither leaving nor entering, none
    assert intrusion(OrientedBox(50.0, -2.5, 0.0, 4.5, 1.8), "e_1", lanes) is None
    # heading left but only 0.3 m into lane 0: a centred car passes it, none
    assert intrusion(OrientedBox(50.0, -2.49, 0.05, 4.5, 1.8), "e_1", lanes) is None
    # mapped to lane 0 heading left, the front-left corner in lane 1 (eoa seed 3): the
    # ego enters lane 1, no shadow
    assert intrusion(OrientedBox(50.0, -4.0, 0.2, 4.5, 1.8), "e_0", lanes) is None
    # unknown or internal lanes: none
    assert intrusion(box, None, lanes) is None
    lanes["e_1"] = LaneShape(**{**lanes["e_1"].__dict__, "internal": True})
    assert intrusion(box, "e_1", lanes) is None


def test_a_car_stops_behind_an_ego_standing_across_two_lanes(tmp_path: Path) -> None:
    sim = SumoSim(work_dir=tmp_path)
    try:
        sim.reset_scene(_scene(tmp_path))
        _run(sim, 11.5)
        assert sim.outcome == "running", sim.record().collided_with
        assert sim._ego_lane == "AB_1"  # SUMO has the ego on lane 1 ...
        sid = shadow_id(EGO_ID)
        assert libsumo.vehicle.getLaneID(sid) == "AB_0"  # ... and its shadow on lane 0
        assert libsumo.vehicle.getLeader("back", 50.0)[0] == sid
        assert libsumo.vehicle.getSpeed("back") < 1.0
        ids = {a.id for a in sim.observe().agents.agents}
        assert "back" in ids and sid not in ids
        _run(sim, 18.0)  # the ego drives on: the shadow is taken out
        assert sid not in libsumo.vehicle.getIDList()
        record = sim.record()
        assert record.shadows == 1 and len(record.shadow_log) == 2
        assert record.collided_with is None
    finally:
        sim.close()


def test_without_the_shadow_the_car_runs_into_the_ego(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The case is a real one: no shadow (never slow enough for it), a collision."""
    monkeypatch.setattr(shadow_mod, "MAX_SPEED_MPS", -1.0)
    sim = SumoSim(work_dir=tmp_path)
    try:
        sim.reset_scene(_scene(tmp_path))
        _run(sim, 9.0)
        assert sim.outcome == "collision" and sim.record().collided_with == "back"
        assert sim.record().shadows == 0
    finally:
        sim.close()


def test_a_saved_state_with_the_shadow_continues_identically(tmp_path: Path) -> None:
    sim = SumoSim(work_dir=tmp_path)
    try:
        sim.reset_scene(_scene(tmp_path))
        _run(sim, 5.0)
        assert sim._shadow.lane_id == "AB_0"
        state = sim.save_state(tmp_path / "at5.xml")
        _run(sim, 16.0)
        first = sim.record()
        sim.load_state(state)
        _run(sim, 16.0)
        second = sim.record()
        assert first.shadows == 1 and first.shadow_log == second.shadow_log
        assert first.model_dump() == second.model_dump()
    finally:
        sim.close()


def test_multi_ego_sim_shadows_an_ego_across_two_lanes(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """``MultiSumoSim``: the same case with a second ego parked far ahead on lane 1; the
    first ego's shadow stops ``back``, the second ego never sees it."""
    import dataclasses
    import json

    from lmpc_bridge import multi_sim

    base = _scene(tmp_path)
    target = dict(edge_id="AB", lane_ids=["AB_0", "AB_1"], lane_pos_m=380.0,
                  center=[380.0, -1.6], radius_m=5.0)
    egos = [dict(ego_id=f"ego_{k + 1}", route_id="r_ego", route_edges=["AB"], depart_lane=lane,
                 depart_pos_m=pos, depart_speed_mps=0.0, target=target)
            for k, (lane, pos) in enumerate([(0, 100.0), (1, 160.0)])]
    scene = dataclasses.replace(base, params={"egos": json.dumps(egos)})
    monkeypatch.setattr(multi_sim, "build_scene", lambda *a, **k: scene)
    sim = multi_sim.MultiSumoSim(work_dir=tmp_path)
    try:
        sim.reset("shadow", 0)
        while sim.time_s < 11.5 - 1e-9:
            if "back" in libsumo.vehicle.getIDList():
                libsumo.vehicle.setLaneChangeMode("back", 0)
            t = sim.time_s
            first = _control(t, sim._step_index)
            still = Control(stamp_s=t, seq=sim._step_index, accel_mps2=-4.0, steer_rad=0.0,
                            mode="baseline", solver_status="test", solve_time_ms=0.0)
            sim.step({"ego_1": first, "ego_2": still})
        assert sim.running_ids() == ("ego_1", "ego_2")
        sid = shadow_id("ego_1")
        assert libsumo.vehicle.getLaneID(sid) == "AB_0"
        assert libsumo.vehicle.getLeader("back", 50.0)[0] == sid
        assert sim.record("ego_1").shadows == 1 and sim.record("ego_2").shadows == 0
        seen = {a.id for a in sim.observe("ego_2").agents.agents}
        assert "ego_1" in seen and sid not in seen
    finally:
        sim.close()


def test_a_sumo_refusal_drops_the_shadow_not_the_episode(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """SUMO refusing the shadow's move is logged; the episode goes on (here: into the
    collision the shadow would have prevented)."""
    def refuse(*args: object, **kwargs: object) -> None:
        raise libsumo.TraCIException("refused for the test")

    monkeypatch.setattr(libsumo.vehicle, "moveTo", refuse)
    sim = SumoSim(work_dir=tmp_path)
    try:
        sim.reset_scene(_scene(tmp_path))
        _run(sim, 9.0)
        record = sim.record()
        assert record.outcome == "collision" and record.collided_with == "back"
        assert shadow_id(EGO_ID) not in libsumo.vehicle.getIDList()
        refusals = [line for line in record.shadow_log if "SUMO refused it" in line]
        assert len(refusals) == 1 and "refused for the test" in refusals[0]
        assert len(record.shadow_log) == 1  # tried once, then no shadow in this episode
        assert record.shadows == 0  # it never stood in the simulation
    finally:
        sim.close()
