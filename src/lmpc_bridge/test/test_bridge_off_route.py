"""Off-route: the bridge ends an episode with ``off_route`` when the ego leaves its route.

The networks (``short_lc_nets``) need a lane change on an 8.8 m edge before a junction;
a car that keeps its lane goes straight on, off the route that turns.
"""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from lmpc_msgs_py.messages import Control

from lmpc_bridge.mapping import read_net
from lmpc_bridge.route_watch import OFF_NETWORK_M, OFF_ROUTE_DIST_M, RouteWatch
from lmpc_bridge.scenarios.external import build_external_scene
from lmpc_bridge.sim import SumoSim

sys.path.insert(0, str(Path(__file__).resolve().parent))
from short_lc_nets import make_short_lc_net, route_of, scene_yaml  # noqa: E402


@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, bool], Path]:
    d = tmp_path_factory.mktemp("short_lc")
    return {(need, lh): make_short_lc_net(d, need=need, left_hand=lh)
            for need in ("inner", "outer") for lh in (False, True)}


@pytest.mark.parametrize("need", ["inner", "outer"])
@pytest.mark.parametrize("left_hand", [False, True])
def test_networks_need_a_lane_change_on_a_short_edge(
        nets: dict[tuple[str, bool], Path], need: str, left_hand: bool) -> None:
    net = read_net(nets[(need, left_hand)])
    assert net.lefthand == left_hand
    stub = net.getEdge("BC")
    assert all(5.0 <= lane.getLength() <= 10.0 for lane in stub.getLanes())
    entry = {c.getToLane().getID() for c in net.getEdge("WB").getLanes()[0].getOutgoing()}
    turn = route_of(need, left_hand)[-1]
    to_turn = {lane.getID() for lane in stub.getLanes()
               if any(c.getToLane().getEdge().getID() == turn for c in lane.getOutgoing())}
    # the ego enters the stub on one lane, and the route's turn leaves from the other
    assert len(entry) == 1 and len(to_turn) == 1 and entry.isdisjoint(to_turn)
    # the turn is a left turn exactly when it goes to N (in both traffic directions)
    dirs = {c.getDirection() for lane in stub.getLanes() for c in lane.getOutgoing()
            if c.getToLane().getEdge().getID() == turn}
    assert dirs == {"l" if turn == "CN" else "r"}


def test_route_watch_tolerance(nets: dict[tuple[str, bool], Path]) -> None:
    net = read_net(nets[("inner", False)])
    watch = RouteWatch.of_net(net, ["WB", "BC", "CN"])
    # both lanes of the stub and every lane inside the junction C are on the route
    for lane in ("BC_0", "BC_1", "CN_0", ":C_10_0", ":C_9_0"):
        assert watch.on_route_lane(lane), lane
    assert not watch.on_route_lane("CE_0") and watch.on_route_lane(None)
    ce = net.getLane("CE_0").getShape()
    x0, y0 = ce[0]
    # just out of the junction on the wrong road: within the tolerance
    assert watch.check("CE_0", x0 + 2.0, y0) is None
    off = watch.check("CE_0", x0 + 20.0, y0)
    assert off is not None and off.lane_id == "CE_0" and off.dist_m > OFF_ROUTE_DIST_M
    assert "left its route" in off.detail()
    # a lane SUMO cannot name, or a route lane, is not off the route within OFF_NETWORK_M
    # of it; beyond, it is whatever SUMO names (SUMO keeps the last lane of a car that
    # left the network: rab 10089 drove 165 s on ":R1_2_0")
    near, far = x0 + 10.0, x0 + 40.0
    assert OFF_ROUTE_DIST_M < watch.distance_m(near, y0) < OFF_NETWORK_M
    assert watch.check(None, near, y0) is None and watch.check("BC_0", near, y0) is None
    assert watch.distance_m(far, y0) > OFF_NETWORK_M
    for lane in (None, "BC_0"):
        gone = watch.check(lane, far, y0)
        assert gone is not None and gone.dist_m > OFF_NETWORK_M, lane


def _control(stamp_s: float, accel: float) -> Control:
    return Control(stamp_s=stamp_s, seq=int(round(stamp_s * 10)), accel_mps2=accel,
                   steer_rad=0.0, mode="baseline", solver_status="test", solve_time_ms=0.0)


def test_driving_straight_past_the_turn_ends_off_route(
        nets: dict[tuple[str, bool], Path], tmp_path: Path) -> None:
    """Keeping the entry lane and going straight on (what the planner did in issue 21):
    the episode ends ``off_route`` a few metres into the wrong road, counted as a failure
    at the time limit."""
    scene_file = tmp_path / "straight.yaml"
    scene_file.write_text(scene_yaml(nets[("outer", False)], need="outer", left_hand=False,
                                     background=False))
    scene = build_external_scene(scene_file, work_dir=tmp_path)
    sim = SumoSim(work_dir=tmp_path)
    try:
        obs = sim.reset_scene(scene, max_time_s=scene.max_time_s)
        x_start = obs.ego.x_m
        while sim.outcome == "running":
            v = sim.pose.v_mps
            sim.step(_control(sim.time_s, 1.0 if v < 10.0 else 0.0))
        status = sim.status()
        assert status.outcome == "off_route", status
        assert "CE_0" in status.detail and "left its route" in status.detail
        # the wrong road starts ~100 m from the start; ended within ~10 m of its start
        assert 100.0 < sim.pose.x_m - x_start < 125.0
        assert status.metrics.time_s == pytest.approx(scene.max_time_s)
        assert sim.record().outcome == "off_route"
    finally:
        sim.close()
