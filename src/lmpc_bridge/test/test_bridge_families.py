"""The new scenario families: deterministic builds, map structure, closed loop (stand-in).

The stand-in controller (conftest) is NOT the MPC; it only shows each scene is drivable.
"""
from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from lmpc_bridge.mapping import build_map
from lmpc_bridge.runner import run_episode
from lmpc_bridge.scenarios import build_scene, families
from lmpc_bridge.sim import SumoSim

sys.path.insert(0, str(Path(__file__).parent))
from conftest import StandInController  # noqa: E402

NEW = ("si", "lane", "rab", "eoa", "construction")


def _net_body(path: Path) -> str:
    text = path.read_text()
    return text[text.index("<net "):]  # the header comment carries a time stamp


def test_all_families_registered() -> None:
    assert set(NEW) | {"usi"} <= set(families())


@pytest.mark.parametrize("family", NEW)
def test_same_seed_same_scene_and_seeds_differ(family: str, tmp_path: Path,
                                               scene_dir: Path) -> None:
    a = build_scene(family, 1, work_dir=tmp_path / "a")
    b = build_scene(family, 1, work_dir=tmp_path / "b")
    assert a.route_file.read_text() == b.route_file.read_text()
    assert _net_body(a.net_file) == _net_body(b.net_file)
    assert replace(b, net_file=a.net_file, route_file=a.route_file,
                   additional_files=a.additional_files) == a
    assert a.params == b.params and a.interaction
    scenes = [build_scene(family, s, work_dir=scene_dir) for s in range(4)]
    assert len({s.route_file.read_text() for s in scenes}) == 4
    # scene i is the i-th candidate that passed the interaction check: strictly increasing
    cands = [int(s.params["candidate"]) for s in scenes]
    assert cands == sorted(set(cands)) and cands[0] >= 0


@pytest.fixture(scope="module")
def maps(tmp_path_factory: pytest.TempPathFactory) -> dict:
    work = tmp_path_factory.mktemp("family_maps")
    out = {}
    for family in NEW:
        scene = build_scene(family, 0, work_dir=work)
        out[family] = (scene, *build_map(scene))
    return out


def _lanes(snap):  # noqa: ANN001, ANN202
    return {lane.id: lane for lane in snap.lanes}


def test_si_map_has_signalized_links_and_crossings(maps: dict) -> None:
    scene, snap, _ = maps["si"]
    lanes = _lanes(snap)
    first = lanes[snap.ego_route[0]]
    link = next(s for s in first.successors if s.via_lane == snap.ego_route[1])
    assert link.signalized and link.tls_id == "C" and link.link_index is not None
    assert any(s.signalized for s in snap.stop_lines if s.lane_id == first.id)
    # sidewalks (lane 0 of each arm, pedestrians only) and crossings inside the junction
    assert lanes["A0in_0"].width_m == pytest.approx(2.0) and first.index >= 1
    assert lanes["A0in_0"].allowed == ("pedestrian",) and "passenger" in first.allowed
    assert first.right_lane != "A0in_0"  # a sidewalk is no neighbour for a car
    assert any(lane.id.startswith(":C_c") and lane.internal for lane in snap.lanes)
    assert scene.additional_files and "offset" in scene.additional_files[0].read_text()


def test_rab_map_has_a_ring(maps: dict) -> None:
    _, snap, _ = maps["rab"]
    lanes = _lanes(snap)
    ring = [f"R{k}R{(k + 1) % 4}_0" for k in range(4)]
    assert all(r in lanes for r in ring)
    for k, lane_id in enumerate(ring):  # each ring lane leads on to the next one
        nxt = ring[(k + 1) % 4]
        assert any(s.to_lane == nxt for s in lanes[lane_id].successors)
    route_ring = [lid for lid in snap.ego_route if lid in ring]
    assert route_ring and snap.ego_route[0] == "A0in_0"
    assert all(lanes[r].roundabout for r in ring) and not lanes["A0in_0"].roundabout


def test_lane_map_needs_a_lane_change(maps: dict) -> None:
    scene, snap, geometry = maps["lane"]
    lanes = _lanes(snap)
    main = [lane for lane in snap.lanes if lane.edge_id == "main1"]
    assert len(main) >= 2 and sorted(lane.index for lane in main) == list(range(len(main)))
    # the route runs on the rightmost lane (the exit leaves from it); the ego starts left of it
    assert snap.ego_route[0] == "main1_0" and scene.ego_depart_lane == len(main) - 1
    assert snap.ego_route[-1] == "ramp_0" and snap.target.lane_ids == ("ramp_0",)
    assert geometry.index_of(f"main1_{scene.ego_depart_lane}", previous_index=0) == 0
    assert lanes["main1_0"].successors
    assert lanes["main1_0"].left_lane == "main1_1" and lanes["main1_1"].right_lane == "main1_0"
    assert lanes["main1_0"].right_lane is None


@pytest.mark.parametrize("family", ["eoa", "construction"])
def test_obstacle_families_have_two_lanes_and_a_blocker(maps: dict, family: str) -> None:
    scene, snap, _ = maps[family]
    main = [lane for lane in snap.lanes if lane.edge_id == "main1"]
    assert len(main) >= 2
    routes = scene.route_file.read_text()
    assert ("hazard" in routes) if family == "eoa" else ('id="work0"' in routes)
    assert len(snap.target.lane_ids) >= 2  # any lane of the exit edge counts


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SumoSim]:
    s = SumoSim(work_dir=tmp_path_factory.mktemp("family_runs"))
    yield s
    s.close()


@pytest.mark.parametrize("family", NEW)
@pytest.mark.parametrize("seed", range(3))
def test_standin_reaches_target(sim: SumoSim, family: str, seed: int) -> None:
    result = run_episode(sim, family=family, seed=seed, controller=StandInController())
    assert result.outcome == "reached", f"{family}/{seed}: {result.detail}"
    assert result.metrics.collisions == 0
    # the scene counts: somebody came within 30 m of the ego box
    assert any(n.gap_m < 30.0 for s in result.record.steps for n in s.nearby)


def test_si_signal_states_ahead(sim: SumoSim) -> None:
    obs = sim.reset("si", 0)
    links = obs.signals.links
    assert links, "the ego approaches a signalized junction"
    first = links[0]
    assert first.tls_id == "C" and first.from_lane.startswith("A0in_")
    assert first.time_to_switch_s is not None and 0.0 <= first.time_to_switch_s <= 90.0
    assert first.distance_m > 0.0 and first.state in "rygGu"


def test_lane_attributes_generic(maps: dict) -> None:
    from lmpc_bridge.mapping import lane_attributes

    scene, _, _ = maps["rab"]
    attrs = lane_attributes(scene)
    assert all(attrs[f"R{k}R{(k + 1) % 4}_0"].roundabout for k in range(4))
    assert not attrs["A0in_0"].roundabout and attrs["A0in_0"].drivable
    assert any(a.roundabout for lid, a in attrs.items() if lid.startswith(":R0_"))
    si = lane_attributes(maps["si"][0])
    sidewalk = si["A0in_0"]
    assert not sidewalk.drivable and "pedestrian" in sidewalk.allowed_classes
    assert si["A0in_1"].right_neighbour is None  # a sidewalk is no neighbour of a car lane
    lane_scene = maps["lane"][0]
    la = lane_attributes(lane_scene)
    top = lane_scene.ego_depart_lane
    assert la[f"main1_{top}"].left_neighbour is None
    assert la[f"main1_{top}"].right_neighbour == f"main1_{top - 1}"
    assert la["main1_0"].right_neighbour is None and la["main1_0"].left_neighbour == "main1_1"
