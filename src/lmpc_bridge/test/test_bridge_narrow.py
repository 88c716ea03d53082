"""The ``narrow`` family (issue 18): two egos, one shared lane, seeded like the others."""
from __future__ import annotations

import math
from pathlib import Path

from lmpc_bridge.mapping import build_map
from lmpc_bridge.multi_scene import ego_scene, ego_specs
from lmpc_bridge.scenarios import build_scene
from lmpc_bridge.scenarios.common import read_net


def test_seeded_and_deterministic(tmp_path: Path) -> None:
    a = build_scene("narrow", 100, work_dir=tmp_path / "a")
    b = build_scene("narrow", 100, work_dir=tmp_path / "b")
    assert a.params == b.params and a.interaction == b.interaction
    assert build_scene("narrow", 101, work_dir=tmp_path / "a").params != a.params
    specs = ego_specs(a)
    assert [s.ego_id for s in specs] == ["ego_1", "ego_2"]
    assert specs[0].route_edges[0] == a.ego_route_edges[0]  # ego_1 = the single-ego task


def test_the_section_is_one_lane_for_both_directions(tmp_path: Path) -> None:
    from lmpc_llm_planner.coordination.conflicts import route_starts_m, shared_sections

    scene = build_scene("narrow", 102, work_dir=tmp_path)
    net = read_net(scene.net_file)
    ab, ba = net.getLane("AB_0").getShape(), net.getLane("BA_0").getShape()
    assert math.dist(ab[0], ba[-1]) < 0.1 and math.dist(ab[-1], ba[0]) < 0.1
    found = []
    for spec in ego_specs(scene):
        mp, _ = build_map(ego_scene(scene, spec), net=net)
        sections = shared_sections(mp)
        assert len(sections) == 1
        sec = sections[0]
        starts = route_starts_m(mp)
        # the hold point lies before the taper junction that leads into the section
        assert mp.ego_route[sec.hold_index].startswith(":")
        assert starts[sec.route_index] - starts[sec.hold_index] >= 15.0
        found.append(sec)
    assert found[0].conflict_id == found[1].conflict_id
    assert {found[0].via, found[1].via} == {"AB_0", "BA_0"}
    assert found[0].partner == found[1].via
