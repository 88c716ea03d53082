"""Real-city problems (issue 21): netconvert's long joined ids, the limits the messages
impose (checked at scene validation, one line each), and recorded demand that departs
hours after SUMO's start (``begin_s``, the traffic warnings).

Also holds :func:`make_joined_net`, the network with 191-character ids that
test/test_graph_external.py drives through the real graph.
"""
from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any, Optional

import pytest

from lmpc_msgs_py.messages import MAX_ID_CHARS

from lmpc_bridge.demand import (
    Demand,
    EntryCount,
    Flow,
    Window,
    declared_demand,
    entry_warnings,
    parse_time_s,
    window_warnings,
)
from lmpc_bridge.mapping import read_net
from lmpc_bridge.runner import run_episode
from lmpc_bridge.scenarios import SceneError
from lmpc_bridge.scenarios.base import sumo_binary
from lmpc_bridge.scenarios.common import write_plain_net
from lmpc_bridge.scenarios.external import build_external_scene
from lmpc_bridge.sim import SumoSim

JOINED_FROM, JOINED_TO = "eN_30648418330", "e30648418210_E"
"""A route across the joined cluster of :func:`make_joined_net` (north arm -> east arm)."""


# --- networks --------------------------------------------------------------------------
def make_joined_net(out_dir: Path) -> Path:
    """Three clusters of four OSM-like nodes (10-digit ids) and a single node, joined the
    way city imports are: netconvert ``--junctions.join`` joins each cluster, and a second
    pass over the joined net (``-s``, a larger join distance) joins the clusters into one
    junction named ``cluster_306484187_cluster_..._cluster_..._cluster_...``. Its internal
    lanes have 191-character ids (the issue's import: 170+)."""
    nodes: list[dict[str, Any]] = []
    edges: list[dict[str, Any]] = []
    groups = {}
    for g, (x0, y0) in (("1", (0.0, 0.0)), ("2", (40.0, 0.0)), ("3", (0.0, 40.0))):
        ids = [f"30648418{g}{k}0" for k in range(4)]
        for nid, (dx, dy) in zip(ids, ((0, 0), (3, 0), (3, 3), (0, 3))):
            nodes.append(dict(id=nid, x=x0 + dx, y=y0 + dy))
        for a, b in zip(ids, ids[1:] + ids[:1]):
            edges.append(dict(id=f"e{a}_{b}", **{"from": a, "to": b}, numLanes=1,
                              speed=13.9))
        groups[g] = ids
    nodes.append(dict(id="306484187", x=40.0, y=40.0))

    def both(a: str, b: str, lanes: int = 2) -> None:
        for u, v in ((a, b), (b, a)):
            edges.append(dict(id=f"e{u}_{v}", **{"from": u, "to": v}, numLanes=lanes,
                              speed=13.9))

    both(groups["1"][1], groups["2"][0])
    both(groups["1"][3], groups["3"][0])
    both(groups["2"][2], "306484187", 1)
    both(groups["3"][2], "306484187", 1)
    for name, x, y, to in (("W", -200.0, 1.0, groups["1"][0]), ("E", 220.0, 1.0, groups["2"][1]),
                           ("N", 1.0, 220.0, groups["3"][3]), ("S", 17.0, -200.0, groups["2"][0])):
        nodes.append(dict(id=name, x=x, y=y))
        both(name, to)
    nod, edg = write_plain_net(out_dir, "joined", nodes=nodes, edges=edges)
    first, net = out_dir / "joined_pass1.net.xml", out_dir / "joined.net.xml"
    common = ["--no-turnarounds", "true", "--no-warnings", "true", "--junctions.join", "true"]
    subprocess.run([sumo_binary("netconvert"), "--node-files", str(nod), "--edge-files",
                    str(edg), "--junctions.join-dist", "10", *common, "-o", str(first)],
                   check=True, capture_output=True, timeout=60)
    subprocess.run([sumo_binary("netconvert"), "-s", str(first), "--junctions.join-dist", "60",
                    *common, "-o", str(net)], check=True, capture_output=True, timeout=60)
    return net


def longest_ids(net_file: Path) -> tuple[int, str]:
    """(length, id) of the longest edge / lane / junction id of a net."""
    net = read_net(net_file)
    ids = [e.getID() for e in net.getEdges()] + [ln.getID() for e in net.getEdges()
                                                 for ln in e.getLanes()]
    ids += list(net.nodes)
    best = max(ids, key=len)
    return len(best), best


def _scene(path: Path, net: Path, *, body: str = "", start: str = JOINED_FROM,
           to: str = JOINED_TO) -> Path:
    path.write_text(f"net: {net}\n{body}ego: {{start: {{edge: '{start}', pos_m: 100}}, "
                    f"speed_mps: 5, to_edge: '{to}'}}\ntarget: {{pos_m: 60}}\nmax_time_s: 90\n")
    return path


@pytest.fixture(scope="module")
def joined_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_joined_net(tmp_path_factory.mktemp("joined"))


class _SceneSim:
    """``run_episode`` calls ``reset(family, seed)``; this one starts a built scene."""

    def __init__(self, sim: SumoSim, scene: Any) -> None:
        self._sim, self._scene = sim, scene

    def reset(self, family: str, seed: int, *, max_time_s: Optional[float] = None) -> Any:
        return self._sim.reset_scene(self._scene, max_time_s=max_time_s)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)


# --- ids -------------------------------------------------------------------------------
def test_joined_net_reproduces_long_cluster_ids_and_drives(
        joined_net: Path, tmp_path: Path, standin_controller: Any) -> None:
    length, longest = longest_ids(joined_net)
    print(f"longest id in the joined net: {length} characters: {longest}")
    assert length >= 170 and longest.startswith(":cluster_306484187_cluster_")
    assert length < MAX_ID_CHARS // 4  # the bound sits far above what joining produces
    (tmp_path / "bg.rou.xml").write_text(
        f'<routes><flow id="through" begin="0" end="200" period="6" from="eW_30648418100" '
        f'to="{JOINED_TO}" departSpeed="max"/></routes>')
    scene = build_external_scene(_scene(tmp_path / "s.yaml", joined_net,
                                        body="routes: [bg.rou.xml]\nwarmup_s: 10\n"),
                                 work_dir=tmp_path / "w")
    sim = SumoSim(work_dir=tmp_path / "w")
    try:
        result = run_episode(_SceneSim(sim, scene), family=scene.family, seed=scene.seed,
                             controller=standin_controller, max_time_s=scene.max_time_s)
        route_lanes = sim.map.ego_route
    finally:
        sim.close()
    assert max(len(lane) for lane in route_lanes) >= 170  # the ego drove over them
    assert result.outcome == "reached", result.detail
    on_long = {s.lane_id for s in result.record.steps if s.lane_id and len(s.lane_id) >= 170}
    assert on_long, "the ego never was on a lane with a long id"


def _long_node_net(out_dir: Path, node_id: str) -> Path:
    nodes = [dict(id="A", x=0.0, y=0.0), dict(id=node_id, x=200.0, y=0.0),
             dict(id="C", x=400.0, y=0.0)]
    edges = [dict(id="AB", **{"from": "A", "to": node_id}, numLanes=1, speed=13.9),
             dict(id="BC", **{"from": node_id, "to": "C"}, numLanes=1, speed=13.9)]
    nod, edg = write_plain_net(out_dir, "long", nodes=nodes, edges=edges)
    net = out_dir / "long.net.xml"
    subprocess.run([sumo_binary("netconvert"), "--node-files", str(nod), "--edge-files",
                    str(edg), "--no-warnings", "true", "-o", str(net)], check=True,
                   capture_output=True, timeout=60)
    return net


def test_an_id_over_the_bound_fails_at_validation_in_one_line(tmp_path: Path) -> None:
    net = _long_node_net(tmp_path, "J" * (MAX_ID_CHARS + 1))
    with pytest.raises(SceneError) as err:
        build_external_scene(_scene(tmp_path / "s.yaml", net, start="AB", to="BC"),
                             work_dir=tmp_path / "w")
    text = str(err.value)
    assert "\n" not in text
    assert "junction 'JJJ" in text and f"{MAX_ID_CHARS + 1} characters" in text
    assert "MAX_ID_CHARS" in text and "long.net.xml" in text
    # at the bound it is accepted, and the map carries it
    (tmp_path / "ok").mkdir()
    ok = _long_node_net(tmp_path / "ok", "J" * (MAX_ID_CHARS - 8))  # ':' + id + '_0_0' fits
    scene = build_external_scene(_scene(tmp_path / "ok.yaml", ok, start="AB", to="BC"),
                                 work_dir=tmp_path / "w")
    assert scene.ego_route_edges == ("AB", "BC")


@pytest.mark.parametrize("routes, needle", [
    ('<vehicle id="{long}" depart="0"><route edges="AB BC"/></vehicle>', "vehicle 'vvv"),
    ('<flow id="{flow}" begin="0" end="10" period="5" from="AB" to="BC"/>',
     "for its vehicles"),
    ('<vType id="train" length="67.5"/>', "vType 'train' has length 67.5 m"),
])
def test_traffic_files_over_a_message_limit_fail_at_validation(
        tmp_path: Path, routes: str, needle: str) -> None:
    net = _long_node_net(tmp_path, "B")
    text = routes.format(long="v" * (MAX_ID_CHARS + 1), flow="f" * (MAX_ID_CHARS - 2))
    (tmp_path / "r.rou.xml").write_text(f"<routes>{text}</routes>")
    with pytest.raises(SceneError) as err:
        build_external_scene(_scene(tmp_path / "s.yaml", net, body="routes: [r.rou.xml]\n",
                                    start="AB", to="BC"), work_dir=tmp_path / "w")
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_a_lane_the_schema_refuses_is_named_at_validation(tmp_path: Path) -> None:
    nodes = [dict(id="A", x=0.0, y=0.0), dict(id="B", x=200.0, y=0.0),
             dict(id="C", x=400.0, y=0.0)]
    edges = [dict(id="AB", **{"from": "A", "to": "B"}, numLanes=1, speed=13.9),
             dict(id="BC", **{"from": "B", "to": "C"}, numLanes=1, speed=83.0)]  # 300 km/h
    nod, edg = write_plain_net(tmp_path, "fast", nodes=nodes, edges=edges)
    net = tmp_path / "fast.net.xml"
    subprocess.run([sumo_binary("netconvert"), "--node-files", str(nod), "--edge-files",
                    str(edg), "--no-warnings", "true", "-o", str(net)], check=True,
                   capture_output=True, timeout=60)
    with pytest.raises(SceneError) as err:
        build_external_scene(_scene(tmp_path / "s.yaml", net, start="AB", to="BC"),
                             work_dir=tmp_path / "w")
    text = str(err.value)
    assert "\n" not in text and "lane 'BC_0'" in text and "speed_limit_mps" in text


# --- demand ----------------------------------------------------------------------------
def test_times_and_flow_counts() -> None:
    assert parse_time_s("25200") == 25200.0 and parse_time_s("7:00:00") == 25200.0
    assert parse_time_s("1:00:00:10") == 86410.0 and parse_time_s("triggered") is None
    flow = Flow("f", begin_s=100.0, end_s=200.0, period_s=10.0)
    assert flow.count_between(0.0, 99.0) == 0.0
    assert flow.count_between(100.0, 200.0) == 10.0  # 100, 110, ..., 190
    assert flow.count_between(105.0, 130.0) == 3.0  # 110, 120, 130 (closed window)
    capped = Flow("g", begin_s=0.0, end_s=1000.0, period_s=1.0, number=5)
    assert capped.count_between(0.0, 1000.0) == 5.0
    rand = Flow("p", begin_s=0.0, end_s=100.0, rate_per_s=0.1)
    demand = Demand(departures_s=(5.0, 50.0), flows=(flow, rand))
    assert demand.count_between(0.0, 100.0) == pytest.approx(2 + 1 + 10.0)
    assert demand.count_between(0.0, 100.0, random_flows=False) == 3.0
    assert demand.span_s() == (0.0, 200.0)


def test_demand_file_elements_are_read(tmp_path: Path) -> None:
    (tmp_path / "d.rou.xml").write_text(
        '<routes><vType id="car" length="4.5" width="1.8"/>'
        '<vehicle id="a" depart="7:00:00"><route edges="x"/></vehicle>'
        '<trip id="b" depart="25210" from="x" to="y"/>'
        '<flow id="c" begin="25200" end="25300" vehsPerHour="360" from="x" to="y"/>'
        '<flow id="d" begin="25200" number="4" period="exp(0.5)" from="x" to="y"/>'
        '<person id="p" depart="triggered"><walk edges="x"/></person></routes>')
    d = declared_demand([tmp_path / "d.rou.xml"])
    assert d.departures_s == (25200.0, 25210.0)
    assert [f.period_s for f in d.flows] == [10.0, None]
    assert d.flows[1].rate_per_s == 0.5
    assert ("person", "p") in d.ids and d.vtypes == (("car", 4.5, 1.8),)
    w = Window(begin_s=0.0, warmup_s=30.0, max_time_s=200.0)
    (line,) = window_warnings(d, w)
    assert "no background vehicle departs between t = 0 s and 230 s" in line
    assert "set begin_s: 25200" in line
    assert window_warnings(d, Window(begin_s=25190.0, warmup_s=30.0, max_time_s=200.0)) == []
    (empty,) = window_warnings(Demand(), w)
    assert "declare no vehicle" in empty
    count = EntryCount(inserted=3, waiting=4, sumo_time_s=25300.0)  # 2 of them + the ego
    (fewer,) = entry_warnings(d, Window(25190.0, 10.0, 100.0), count)
    assert "2 of the 12 declared" in fewer and "4 still waiting" in fewer


def _late_demand(path: Path, begin_s: float) -> Path:
    path.write_text(
        f'<routes><flow id="late" begin="{begin_s:g}" end="{begin_s + 300:g}" period="4" '
        f'from="eW_30648418100" to="{JOINED_TO}" departSpeed="max"/></routes>')
    return path


def test_late_demand_warns_and_begin_s_starts_there(joined_net: Path, tmp_path: Path) -> None:
    """A generated demand file whose departures start at 7:00 (25200 s)."""
    _late_demand(tmp_path / "late.rou.xml", 25200.0)
    sim = SumoSim(work_dir=tmp_path / "w")
    try:
        plain = build_external_scene(
            _scene(tmp_path / "plain.yaml", joined_net, body="routes: [late.rou.xml]\n"
                   "warmup_s: 20\n"), work_dir=tmp_path / "w")
        sim.reset_scene(plain)
        (line,) = sim.traffic_warnings()
        assert "no background vehicle departs between t = 0 s and 110 s" in line
        assert "set begin_s: 25200" in line
        sim.close()
        begun = build_external_scene(
            _scene(tmp_path / "begun.yaml", joined_net, body="routes: [late.rou.xml]\n"
                   "begin_s: 25200\nwarmup_s: 20\n"), work_dir=tmp_path / "w")
        assert begun.params["begin_s"] == 25200.0
        sim.reset_scene(begun)
        import libsumo

        assert libsumo.simulation.getTime() == pytest.approx(25220.1)  # begin + warm-up
        assert int(libsumo.simulation.getParameter("", "stats.vehicles.inserted")) >= 5
        assert sim.traffic_warnings() == ()
    finally:
        sim.close()


def test_fewer_vehicles_entering_than_declared_is_said(joined_net: Path,
                                                       tmp_path: Path) -> None:
    # a car every 0.2 s on one lane: SUMO cannot insert them as fast
    (tmp_path / "jam.rou.xml").write_text(
        '<routes><flow id="jam" begin="0" end="100" period="0.2" from="eW_30648418100" '
        f'to="{JOINED_TO}" departLane="0"/></routes>')
    scene = build_external_scene(_scene(tmp_path / "s.yaml", joined_net,
                                        body="routes: [jam.rou.xml]\nwarmup_s: 10\n"),
                                 work_dir=tmp_path / "w")
    sim = SumoSim(work_dir=tmp_path / "w")
    try:
        sim.reset_scene(scene)
        (line,) = sim.traffic_warnings()
    finally:
        sim.close()
    assert line.startswith("fewer vehicles entered than the files declare")
    assert "still waiting for insertion" in line


def test_background_trips_depart_from_begin_s(joined_net: Path, tmp_path: Path) -> None:
    scene = build_external_scene(_scene(
        tmp_path / "s.yaml", joined_net,
        body="begin_s: 3600\nbackground: {period_s: 5, end_s: 100, seed: 1}\n"),
        work_dir=tmp_path / "w")
    trips = declared_demand([p for p in scene.additional_files if "background" in p.name])
    assert trips.departures_s and 3600.0 <= trips.departures_s[0] <= trips.departures_s[-1]
    assert trips.departures_s[-1] <= 3700.0


def test_seed_override_sets_sumo_and_background_seeds(joined_net: Path, tmp_path: Path
                                                      ) -> None:
    f = _scene(tmp_path / "s.yaml", joined_net,
               body="seed: 9\nbackground: {period_s: 5, end_s: 100, seed: 7}\n")
    own = build_external_scene(f, work_dir=tmp_path / "w")
    s1 = build_external_scene(f, work_dir=tmp_path / "w", seed=1)
    s2 = build_external_scene(f, work_dir=tmp_path / "w", seed=2)
    assert (own.seed, s1.seed, s2.seed) == (9, 1, 2)

    def trips(scene: Any) -> list[tuple[str, str]]:
        import xml.etree.ElementTree as ET

        (bg,) = [p for p in scene.additional_files if "background" in p.name]
        return [(t.get("from", ""), t.get("to", "")) for t in ET.parse(bg).iter("trip")]

    assert trips(s1) != trips(s2)  # each seed its own background traffic
    assert trips(build_external_scene(f, work_dir=tmp_path / "w2", seed=1)) == trips(s1)
