"""MapSnapshot content of a usi scene: route lanes incl. internal, left-turn link, stop lines."""
from __future__ import annotations

import math

import pytest

from lmpc_bridge.mapping import build_map
from lmpc_bridge.scenarios import build_scene


@pytest.fixture(scope="module", params=[0, 1])
def usi_map(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    scene = build_scene("usi", request.param, work_dir=tmp_path_factory.mktemp("map"))
    return scene, *build_map(scene)


def test_route_runs_through_internal_lanes(usi_map) -> None:
    scene, snap, geometry = usi_map
    lanes = {lane.id: lane for lane in snap.lanes}
    route = snap.ego_route
    assert route[0].startswith("W2C_") and route[-1].startswith("C2N_")
    assert any(lanes[lane_id].internal for lane_id in route[1:-1])
    assert all(lanes[lane_id].internal for lane_id in route[1:-1])
    # consecutive route lanes are connected end to start (within a few cm)
    for a, b in zip(route, route[1:]):
        assert math.dist(lanes[a].centerline[-1], lanes[b].centerline[0]) < 0.5
    assert geometry.lane_ids == route


def test_left_turn_link_direction(usi_map) -> None:
    _, snap, _ = usi_map
    first = next(lane for lane in snap.lanes if lane.id == snap.ego_route[0])
    link = next(link for link in first.successors if link.to_lane.startswith("C2N"))
    assert link.direction == "l"
    assert link.via_lane == snap.ego_route[1]
    assert not link.signalized and link.tls_id is None
    straight = [link for link in first.successors if link.to_lane.startswith("C2E")]
    assert straight and straight[0].direction == "s"


def test_stop_lines_and_target(usi_map) -> None:
    scene, snap, geometry = usi_map
    stop_lanes = {s.lane_id for s in snap.stop_lines}
    assert snap.ego_route[0] in stop_lanes
    assert not any(s.signalized for s in snap.stop_lines)
    assert snap.target.lane_ids == scene.target.lane_ids
    exit_lane = next(lane for lane in snap.lanes if lane.id == snap.ego_route[-1])
    # the target centre lies on the exit lane's centerline, 40 m in
    (x0, y0), (x1, y1) = exit_lane.centerline[0], exit_lane.centerline[-1]
    tx, ty = snap.target.center
    cross = abs((x1 - x0) * (ty - y0) - (y1 - y0) * (tx - x0))
    assert cross / math.dist((x0, y0), (x1, y1)) < 0.1
    assert math.dist((x0, y0), snap.target.center) == pytest.approx(40.0, abs=0.5)


def test_route_distance_to_target(usi_map) -> None:
    _, _, geometry = usi_map
    full = geometry.dist_to_target_m(0, 0.0)
    assert full == pytest.approx(sum(geometry.lengths_m[:-1]) + 40.0)
    assert geometry.dist_to_target_m(0, 10.0) == pytest.approx(full - 10.0)
    assert geometry.dist_to_target_m(len(geometry.lane_ids) - 1, 45.0) == 0.0
    # off-route lanes keep the previous progress; a parallel lane of the edge maps to it
    assert geometry.index_of("S2C_0", previous_index=1) == 1
    assert geometry.index_of(geometry.lane_ids[-1], previous_index=0) == len(geometry.lane_ids) - 1
