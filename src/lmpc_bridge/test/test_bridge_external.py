"""External scenes: scene files on networks unlike the templates, their errors, the map.

Also holds the network builders the graph test (test/test_graph_external.py) uses:
``netgenerate --rand`` and ``--spider`` nets, and a roundabout next to a signalized
junction in right- and left-hand traffic.
"""
from __future__ import annotations

import math
import subprocess
import textwrap
from pathlib import Path

import pytest
import sumolib

from lmpc_msgs_py.codec import encode

from lmpc_bridge.mapping import build_map, lane_attributes, read_net
from lmpc_bridge.scenarios import SceneError
from lmpc_bridge.scenarios.base import run_netconvert, sumo_binary
from lmpc_bridge.scenarios.common import write_plain_net
from lmpc_bridge.scenarios.external import build_external_scene, fastest_route, load_scene_file
from lmpc_bridge.sim import SimError, SumoSim


# --- network builders (also used by test/test_graph_external.py) --------------------------
def make_rand_net(out_dir: Path) -> Path:
    net = out_dir / "rand.net.xml"
    subprocess.run([sumo_binary("netgenerate"), "--rand", "--rand.iterations", "40",
                    "--seed", "5", "--default.lanenumber", "2", "--rand.min-distance", "70",
                    "--tls.guess", "true", "--no-turnarounds", "true", "--no-warnings", "true",
                    "-o", str(net)], check=True, capture_output=True, timeout=60)
    return net


def make_spider_net(out_dir: Path) -> Path:
    net = out_dir / "spider.net.xml"
    subprocess.run([sumo_binary("netgenerate"), "--spider", "--spider.arm-number", "5",
                    "--spider.circle-number", "3", "--spider.space-radius", "70",
                    "--no-turnarounds", "true", "--no-warnings", "true", "-o", str(net)],
                   check=True, capture_output=True, timeout=60)
    return net


def make_rab_tls_net(out_dir: Path, *, left_hand: bool = False) -> Path:
    """A signalized T junction 70 m from a 4-arm roundabout (ring clockwise if left-hand)."""
    name = "rab_tls_lh" if left_hand else "rab_tls"
    nodes = [dict(id="W", x=-120.0, y=0.0), dict(id="N", x=0.0, y=100.0),
             dict(id="S", x=0.0, y=-100.0), dict(id="T", x=0.0, y=0.0, type="traffic_light"),
             dict(id="R0", x=90.0, y=0.0), dict(id="R1", x=110.0, y=-20.0),
             dict(id="R2", x=130.0, y=0.0), dict(id="R3", x=110.0, y=20.0),
             dict(id="E", x=240.0, y=0.0), dict(id="S2", x=110.0, y=-120.0),
             dict(id="N2", x=110.0, y=120.0)]
    ring = ["R0", "R1", "R2", "R3"]
    if left_hand:
        ring = ring[::-1]
    angle = {"R0": 180.0, "R1": 270.0, "R2": 360.0, "R3": 90.0}

    def arc(a: str, b: str) -> str:
        # ring edges follow the circle (netconvert guesses a roundabout from a round loop)
        a0, a1 = angle[a], angle[b]
        if left_hand:
            a1 = a1 if a1 < a0 else a1 - 360.0
        else:
            a1 = a1 if a1 > a0 else a1 + 360.0
        pts = [(110.0 + 20.0 * math.cos(math.radians(a0 + (a1 - a0) * k / 6)),
                20.0 * math.sin(math.radians(a0 + (a1 - a0) * k / 6))) for k in range(7)]
        return " ".join(f"{x:.2f},{y:.2f}" for x, y in pts)

    edges = [dict(id=f"{a}{b}", **{"from": a, "to": b}, numLanes=1, speed=8.33,
                  shape=arc(a, b)) for a, b in zip(ring, ring[1:] + ring[:1])]
    for a, b in (("W", "T"), ("N", "T"), ("S", "T"), ("T", "R0"), ("R2", "E"), ("R1", "S2"),
                 ("R3", "N2")):
        edges.append(dict(id=f"{a}{b}", **{"from": a, "to": b}, numLanes=1, speed=13.89))
        edges.append(dict(id=f"{b}{a}", **{"from": b, "to": a}, numLanes=1, speed=13.89))
    nod, edg = write_plain_net(out_dir, name, nodes=nodes, edges=edges)
    net = out_dir / f"{name}.net.xml"
    extra = ("--roundabouts.guess", "true") + (("--lefthand", "true") if left_hand else ())
    run_netconvert(nodes_file=nod, edges_file=edg, net_file=net, extra_args=extra)
    return net


def pick_route(net_file: Path, *, min_edges: int = 3, max_edges: int = 4) -> tuple[str, str]:
    """A deterministic (start edge, destination edge) pair a few junctions apart."""
    net = read_net(net_file)
    edges = sorted(e.getID() for e in net.getEdges(withInternal=False))
    for a in edges:
        if net.getEdge(a).getLength() < 60:
            continue
        for b in edges:
            path = fastest_route(net, a, b)
            if path and min_edges <= len(path) <= max_edges \
                    and net.getEdge(b).getLength() > 45:
                return a, b
    raise AssertionError(f"no route of {min_edges}-{max_edges} edges in {net_file}")


def write_scene(path: Path, body: str) -> Path:
    path.write_text(textwrap.dedent(body))
    return path


# --- scene files and their errors ----------------------------------------------------------
@pytest.fixture(scope="module")
def nets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("ext_nets")
    return {"rand": make_rand_net(d), "spider": make_spider_net(d),
            "rab_tls": make_rab_tls_net(d), "rab_tls_lh": make_rab_tls_net(d, left_hand=True)}


def test_bad_fields_are_named_one_per_line(tmp_path: Path, nets: dict[str, Path]) -> None:
    f = write_scene(tmp_path / "bad.yaml", f"""
        net: {nets['rand']}
        warmup_s: -3
        colour: red
        ego:
          start: {{edge: a, x_m: 1, y_m: 2}}
          speed_mps: fast
        """)
    with pytest.raises(SceneError) as err:
        load_scene_file(f)
    text = str(err.value)
    assert "field 'warmup_s'" in text and "field 'colour': unknown field" in text
    assert "field 'ego.start'" in text and "field 'ego.speed_mps'" in text
    assert text.count("\n  field") == 4


@pytest.mark.parametrize("body, needle", [
    ("ego: {start: {edge: nowhere}, to_edge: WT}", "no edge 'nowhere'"),
    ("ego: {start: {edge: WT}, route: [WT, R2E]}", "unreachable: no lane of edge 'WT'"),
    ("ego: {start: {edge: WT, lane: 3}, to_edge: R2E}", "ego.start.lane"),
    ("ego: {start: {edge: R2E}, to_edge: WT}", "unreachable: no route"),
    ("ego: {start: {x_m: 5000, y_m: 0}, to_edge: R2E}", "not within 10 m"),
])
def test_network_errors_name_the_problem(tmp_path: Path, nets: dict[str, Path], body: str,
                                         needle: str) -> None:
    f = write_scene(tmp_path / "s.yaml", f"net: {nets['rab_tls']}\n{body}\n")
    with pytest.raises(SceneError, match=needle):
        build_external_scene(f, work_dir=tmp_path / "w")


def test_unreadable_net_is_one_clear_error(tmp_path: Path) -> None:
    (tmp_path / "broken.net.xml").write_text("<net><edge id='a'")
    f = write_scene(tmp_path / "s.yaml", "net: broken.net.xml\nego: {start: {edge: a}}\n")
    with pytest.raises(SceneError, match="cannot read SUMO network"):
        build_external_scene(f, work_dir=tmp_path / "w")
    with pytest.raises(SceneError, match="not found"):
        build_external_scene(write_scene(tmp_path / "m.yaml", "net: missing.net.xml\n"
                                         "ego: {start: {edge: a}}\n"), work_dir=tmp_path)


def test_sumo_refusing_a_net_leaves_nothing_running(tmp_path: Path, nets: dict[str, Path]
                                                    ) -> None:
    f = write_scene(tmp_path / "s.yaml", f"net: {nets['rab_tls']}\n"
                    "ego: {start: {edge: WT, pos_m: 20}, to_edge: R2E}\n")
    scene = build_external_scene(f, work_dir=tmp_path / "w")
    broken = tmp_path / "half.net.xml"
    broken.write_text(nets["rab_tls"].read_text()[:5000])
    from dataclasses import replace
    sim = SumoSim(work_dir=tmp_path / "w")
    with pytest.raises(SimError, match="SUMO cannot load"):
        sim.reset_scene(replace(scene, net_file=broken))
    obs = sim.reset_scene(scene)  # the process can start SUMO again: nothing was left open
    assert obs.ego.lane_id == "WT_0"
    sim.close()


def test_start_overlapping_a_vehicle_after_warmup(tmp_path: Path, nets: dict[str, Path]
                                                  ) -> None:
    (tmp_path / "parked.rou.xml").write_text(
        '<routes><vType id="p" length="4.5"/><route id="rp" edges="WT TR0"/>'
        '<vehicle id="parked" type="p" route="rp" depart="0" departPos="30">'
        '<stop lane="WT_0" endPos="32" duration="1000"/></vehicle></routes>')
    f = write_scene(tmp_path / "s.yaml", f"net: {nets['rab_tls']}\nroutes: [parked.rou.xml]\n"
                    "warmup_s: 20\nego: {start: {edge: WT, pos_m: 31}, to_edge: R2E}\n")
    sim = SumoSim(work_dir=tmp_path / "w")
    with pytest.raises(SimError, match="overlaps vehicle 'parked'"):
        sim.reset_scene(build_external_scene(f, work_dir=tmp_path / "w"))
    sim.close()


def test_point_start_and_target_and_warmup(tmp_path: Path, nets: dict[str, Path]) -> None:
    f = write_scene(tmp_path / "s.yaml", f"""
        net: {nets['rab_tls']}
        background: {{period_s: 3, end_s: 100, seed: 2}}
        warmup_s: 15
        ego: {{start: {{x_m: -80, y_m: -1.6}}, speed_mps: 5}}
        target: {{x_m: 200, y_m: -1.6, radius_m: 4}}
        """)
    scene = build_external_scene(f, work_dir=tmp_path / "w")
    assert scene.ego_route_edges[0] == "WT" and scene.ego_route_edges[-1] == "R2E"
    assert any(e in scene.ego_route_edges for e in ("R0R1", "R1R2"))  # through the ring
    assert abs(scene.target.center[0] - 200.0) < 1.0
    again = build_external_scene(f, work_dir=tmp_path / "w")
    assert again == scene  # cached build reused
    sim = SumoSim(work_dir=tmp_path / "w")
    obs = sim.reset_scene(scene)
    assert obs.stamp_s == 0.0 and obs.ego.lane_id == "WT_0"
    import libsumo
    assert libsumo.simulation.getTime() >= 15.0  # SUMO ran the warm-up first
    sim.close()


# --- the map on other networks ---------------------------------------------------------------
@pytest.mark.parametrize("name", ["rand", "spider", "rab_tls", "rab_tls_lh"])
def test_fast_reader_equals_sumolib(nets: dict[str, Path], name: str, tmp_path: Path) -> None:
    start, dest = pick_route(nets[name])
    f = write_scene(tmp_path / "s.yaml", f"net: {nets[name]}\n"
                    f"ego: {{start: {{edge: '{start}'}}, to_edge: '{dest}'}}\n")
    scene = build_external_scene(f, work_dir=tmp_path / "w")
    slow = sumolib.net.readNet(str(nets[name]), withInternal=True)
    fast, _ = build_map(scene)
    ref, _ = build_map(scene, net=slow)
    assert fast.model_copy(update={"left_hand_traffic": False}) == ref
    assert lane_attributes(scene) == lane_attributes(scene, net=slow)


def test_map_features_roundabout_signals_left_hand(nets: dict[str, Path], tmp_path: Path
                                                   ) -> None:
    for name, left in (("rab_tls", False), ("rab_tls_lh", True)):
        f = write_scene(tmp_path / f"{name}.yaml", f"net: {nets[name]}\n"
                        "ego: {start: {edge: WT}, to_edge: R2E}\n")
        snap, _ = build_map(build_external_scene(f, work_dir=tmp_path / "w"))
        lanes = {ln.id: ln for ln in snap.lanes}
        assert snap.left_hand_traffic is left
        assert any(ln.roundabout and not ln.internal for ln in snap.lanes)
        assert any(s.signalized and s.junction_id == "T" for s in snap.stop_lines)
        assert any(link.signalized for link in lanes["WT_0"].successors)
        assert not lanes["WT_0"].roundabout
        ring = [ln for ln in snap.lanes if ln.roundabout and not ln.internal]
        # ring direction: counter-clockwise for right-hand traffic, clockwise for left-hand
        (x0, y0), (x1, y1) = ring[0].centerline[0], ring[0].centerline[-1]
        cross = (x0 - 110.0) * (y1 - 0.0) - (y0 - 0.0) * (x1 - 110.0)
        assert (cross < 0) is left


def test_big_map_is_clipped_to_the_payload_budget(nets: dict[str, Path], tmp_path: Path) -> None:
    start, dest = pick_route(nets["rand"])
    f = write_scene(tmp_path / "s.yaml", f"net: {nets['rand']}\n"
                    f"ego: {{start: {{edge: '{start}'}}, to_edge: '{dest}'}}\n")
    scene = build_external_scene(f, work_dir=tmp_path / "w")
    full, _ = build_map(scene)
    budget = len(encode(full)) // 3
    small, _ = build_map(scene, max_bytes=budget)
    assert len(encode(small)) <= budget < len(encode(full))
    assert set(small.ego_route) <= {ln.id for ln in small.lanes}
    with pytest.raises(SceneError, match="does not fit"):
        build_map(scene, max_bytes=500)
