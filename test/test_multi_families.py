"""Multi-vehicle joint control in-process (issue 18) on ``usi-multi`` and ``merge``.

Development seeds only: usi-multi 100 and 103 have four egos (on 103 without coordination
three lmpc-rules egos time out, two mpc egos collide: measured), merge 101 two egos that
come within 3.5 m of each other without coordination (lmpc-rules) and collide when their
controllers do not see each other.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from lmpc_bridge.multi_sim import MultiSumoSim
from lmpc_llm_planner.coordination.conflicts import JUNCTION_HOLD_MARGIN_M, route_starts_m
from lmpc_llm_planner.coordination.ego import EgoCoordination
from lmpc_msgs_py.vocabulary import load_decision_space
from lmpc_scripts import multi


def _clean(result) -> None:
    assert result.ego_collisions == 0 and result.other_collisions == 0, result
    assert not result.deadlock, result
    assert result.all_reached, [(e.ego_id, e.outcome, e.detail) for e in result.egos]


def test_statuses_and_hold_point_at_the_junction(tmp_path: Path) -> None:
    sim = MultiSumoSim(work_dir=tmp_path)
    obs = sim.reset("usi-multi", 100)
    try:
        assert sorted(obs) == ["ego_1", "ego_2", "ego_3", "ego_4"]
        space = load_decision_space()
        vias = set()
        for eid, o in obs.items():
            ego = EgoCoordination(eid, space)
            st = ego.status(o)
            c = st.conflict
            assert st.intent == "approach" and c is not None
            assert c.kind == "junction" and c.conflict_id == "junction:C"
            assert c.dist_to_hold_m == pytest.approx(
                c.dist_to_entry_m - JUNCTION_HOLD_MARGIN_M, abs=1e-6)
            assert 20.0 < c.dist_to_entry_m < c.dist_to_exit_m
            vias.add(c.via)
            # the hold obstacle: on the approach lane, its rear 1 m before the stop line
            sec, _ = ego._ahead(o)
            from lmpc_llm_planner.coordination.conflicts import hold_agent

            hold = hold_agent(o, sec, route_starts_m(o.map))
            approach = o.map.ego_route[sec.route_index - 1]
            assert hold.lane_id == approach
            length = next(ln.length_m for ln in o.map.lanes if ln.id == approach)
            assert hold.lane_pos_m == pytest.approx(length - JUNCTION_HOLD_MARGIN_M + 1.0,
                                                    abs=0.05)
        assert len(vias) == 4
    finally:
        sim.close()


@pytest.mark.parametrize("mode", ["distributed", "central"])
@pytest.mark.parametrize("family,seed", [("usi-multi", 103), ("merge", 101)])
def test_coordination_lets_every_ego_through(family: str, seed: int, mode: str,
                                             tmp_path: Path) -> None:
    result, row = multi.run_one(family, seed, "lmpc-rules", mode, tmp_path)
    _clean(result)
    assert row["hold_steps"] > 0  # somebody waited at its stop line
    if mode == "central":
        assert row["directives"] > 0 and row["directives_refused"] == 0
    if family == "merge":  # one behind the other in the merged lane, never side by side
        assert row["min_gap_m"] > 5.0


def test_blind_egos_meet_at_the_merge(tmp_path: Path) -> None:
    result, row = multi.run_one("merge", 101, "mpc", "none", tmp_path, blind=True,
                                max_time_s=60.0)
    assert result.ego_collisions == 1
    assert {e.collided_with for e in result.egos} == {"ego_1", "ego_2"}


def test_a_vehicle_sumo_refuses_at_start_is_reported(tmp_path: Path) -> None:
    """As the single-ego sim: a background vehicle of the scene that SUMO drops at the start
    with an error (here usi-multi 0's bg0, moved to its lane's end at 13.9 m/s: "unpriorised
    junction too close") is named in ``traffic_warnings`` and the result's row detail; the
    scene as built has none."""
    import re

    import libsumo

    from lmpc_bridge.scenarios import build_scene

    scene = build_scene("usi-multi", 0, work_dir=tmp_path)
    routes = scene.route_file.read_text()
    edited = re.sub(r'(id="bg0"[^>]*departPos=")[0-9.]+(" departSpeed=")[0-9.]+',
                    r"\g<1>-2\g<2>13.9", routes)
    assert edited != routes
    sim = MultiSumoSim(work_dir=tmp_path / "fresh")
    try:
        sim.reset("usi-multi", 0)
        assert "bg0" in libsumo.vehicle.getIDList() and sim.traffic_warnings() == ()
    finally:
        sim.close()
    scene.route_file.write_text(edited)
    sim = MultiSumoSim(work_dir=tmp_path)  # the cached scene, with the edited route file
    try:
        sim.reset("usi-multi", 0)
        assert "bg0" not in libsumo.vehicle.getIDList()
        assert sim.traffic_warnings() == (
            "SUMO refused bg0, a vehicle the scene starts with (it never entered)",)
    finally:
        sim.close()
    _, row = multi.run_one("usi-multi", 0, "mpc", "none", tmp_path, max_time_s=2.0)
    assert "traffic: SUMO refused bg0" in row["detail"]
