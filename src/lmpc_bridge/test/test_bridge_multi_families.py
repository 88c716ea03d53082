"""The ``usi-multi`` and ``merge`` families (issue 18) and the junction / merge conflicts
their egos see (development seeds only)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from lmpc_bridge.mapping import build_map
from lmpc_bridge.multi_scene import ego_scene, ego_specs
from lmpc_bridge.scenarios import build_scene
from lmpc_bridge.scenarios.common import read_net
from lmpc_bridge.scenarios.usi_multi import ARMS, movements_conflict
from lmpc_llm_planner.coordination.conflicts import route_starts_m, shared_sections


def _sections(scene):
    net = read_net(scene.net_file)
    out = {}
    for spec in ego_specs(scene):
        mp, _ = build_map(ego_scene(scene, spec), net=net)
        out[spec.ego_id] = (mp, shared_sections(mp))
    return out


@pytest.mark.parametrize("family", ["usi-multi", "merge"])
def test_seeded_and_deterministic(family: str, tmp_path: Path) -> None:
    a = build_scene(family, 100, work_dir=tmp_path / "a")
    b = build_scene(family, 100, work_dir=tmp_path / "b")
    assert a.params == b.params and a.interaction == b.interaction
    assert build_scene(family, 101, work_dir=tmp_path / "a").params != a.params
    specs = ego_specs(a)
    assert specs[0].route_edges == a.ego_route_edges  # ego_1 = the single-ego task
    assert len({s.route_edges[0] for s in specs}) == len(specs)  # each from its own road


def test_usi_multi_has_two_to_four_egos_that_meet(tmp_path: Path) -> None:
    counts = set()
    for seed in range(100, 110):
        scene = build_scene("usi-multi", seed, work_dir=tmp_path)
        specs = ego_specs(scene)
        counts.add(len(specs))
        assert 2 <= len(specs) <= 4
        assert "every ego has a conflicting ego" in scene.interaction
        arrivals = [float(x) for x in str(scene.params["arrival_s"]).split()]
        moves = {s.ego_id: (ARMS.index(s.route_edges[0][0]), ARMS.index(s.route_edges[1][-1]))
                 for s in specs}
        for k, s in enumerate(specs):  # the check, recomputed from the scene's routes
            assert any(movements_conflict(moves[s.ego_id], moves[o.ego_id])
                       and abs(arrivals[k] - arrivals[j]) < 2.0
                       for j, o in enumerate(specs) if o is not s)
    assert len(counts) >= 2


def test_movement_conflicts() -> None:
    w, n, e, s = (ARMS.index(a) for a in "WNES")
    assert movements_conflict((w, n), (e, w))      # left turn vs the oncoming straight
    assert not movements_conflict((w, s), (e, w))  # right turn vs the oncoming straight
    assert not movements_conflict((w, e), (e, w))  # two opposite straights
    assert movements_conflict((w, e), (s, n))      # two crossing straights
    assert movements_conflict((w, s), (n, s))      # same exit: they merge


def test_usi_multi_egos_share_one_junction_zone(tmp_path: Path) -> None:
    scene = build_scene("usi-multi", 101, work_dir=tmp_path)
    seen = _sections(scene)
    for eid, (mp, secs) in seen.items():
        assert len(secs) == 1, eid
        sec = secs[0]
        assert sec.kind == "junction" and sec.conflict_id == "junction:C"
        assert mp.ego_route[sec.route_index] == sec.via and sec.via.startswith(":C_")
        assert sec.hold_index == sec.route_index  # waits at the stop line
        assert sec.via not in sec.partners
    vias = {secs[0].via for _, secs in seen.values()}
    assert len(vias) == len(seen)  # one movement per ego
    # every ego's movement is a foe of some other ego's
    for eid, (_, secs) in seen.items():
        others = {s[0].via for k, (_, s) in seen.items() if k != eid}
        assert others & set(secs[0].partners), eid


def test_merge_egos_see_one_merge_point(tmp_path: Path) -> None:
    scene = build_scene("merge", 100, work_dir=tmp_path)
    net = read_net(scene.net_file)
    seen = _sections(scene)
    (mp1, (s1,)), (mp2, (s2,)) = seen["ego_1"], seen["ego_2"]
    assert s1.kind == s2.kind == "merge" and s1.conflict_id == s2.conflict_id == "merge:J"
    assert s1.partners == (s2.via,) and s2.partners == (s1.via,)
    assert mp1.ego_route[-1] == mp2.ego_route[-1] == "JE_0"
    # the two connections end at the same point (the merge)
    end1 = net.getLane(s1.via).getShape()[-1]
    end2 = net.getLane(s2.via).getShape()[-1]
    assert math.dist(end1, end2) < 0.5
    starts = route_starts_m(mp1)
    assert starts[s1.route_index] > 100.0  # the hold point is on the approach


def test_merge_check_and_starts(tmp_path: Path) -> None:
    for seed in range(100, 106):
        scene = build_scene("merge", seed, work_dir=tmp_path)
        t1, t2 = (float(x) for x in str(scene.params["arrival_s"]).split())
        assert abs(t1 - t2) < 1.5
        egos = json.loads(str(scene.params["egos"]))
        net = read_net(scene.net_file)
        for e, t in zip(egos, (t1, t2)):
            approach = net.getLane(f"{e['route_edges'][0]}_0").getLength()
            dist = approach - e["depart_pos_m"]
            assert 30.0 <= dist <= 130.0
            # arrival_s is rounded to 0.01 s
            assert dist == pytest.approx(t * e["depart_speed_mps"], abs=0.1)


def test_narrow_tapers_are_not_junction_conflicts(tmp_path: Path) -> None:
    scene = build_scene("narrow", 100, work_dir=tmp_path)
    for _, secs in _sections(scene).values():
        assert [s.kind for s in secs] == ["narrow"]
