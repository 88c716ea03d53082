"""Pictures of a multi-ego run (issue 18 item 5): the narrow encounter with the yielding
ego marked (lmpc_bridge.render.multi, ``scripts/render.py multi``). No ROS.

One short in-process episode (narrow development seed 101, central coordination,
capped at 15 s of sim time: the yielding happens in it) is shared by the tests; the
assertions are on what is passed to the drawing, not on pixels.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
from PIL import Image

from lmpc_bridge.render import RenderError, multi
from lmpc_scripts import render as render_cli

SEED = 101
CAP_S = 15.0


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> multi.MultiRunData:
    work_dir = tmp_path_factory.mktemp("render_multi")
    return render_cli.run_multi("narrow", SEED, "lmpc-rules", "central", work_dir=work_dir,
                                max_time_s=CAP_S)


def test_the_episode_keeps_what_the_picture_needs(run: multi.MultiRunData) -> None:
    assert run.ego_ids == ("ego_1", "ego_2")
    assert run.shaded_lanes, "the one-lane section was not found on the egos' maps"
    yielding: set[str] = set()
    for eid in run.ego_ids:
        steps = [s.step for s in run.records[eid].steps]
        assert steps and steps == sorted(steps)
        # a mark for every step the ego was on the road (central: statuses every step)
        assert set(run.marks[eid]) == set(steps)
        yielding |= {eid for m in run.marks[eid].values() if m.yielding}
        # the other ego appears among the vehicles this one sensed at some step
        other = next(e for e in run.ego_ids if e != eid)
        assert any(v.id == other for s in run.records[eid].steps for v in s.nearby)
    assert len(yielding) >= 1
    # never both at once: the coordinator lets one direction through
    for st in range(1, run.last_step + 1):
        assert sum(e.yielding for e in multi.frame(run, st).egos) <= 1, st


def test_frame_marks_the_yielding_ego(run: multi.MultiRunData) -> None:
    for st in range(1, run.last_step + 1):
        fr = multi.frame(run, st)
        assert not {e.ego_id for e in fr.egos} & set(fr.done)
        for e in fr.egos:
            mark = run.marks[e.ego_id][st]
            assert e.yielding == mark.yielding and e.holding == mark.holding
            assert ("yields" in e.label) == mark.yielding
            assert e.colour == run.colour(e.ego_id)
        assert all(v.id not in run.records for v in fr.others)


def test_strip_and_gif_draw_the_yielding_ego(run: multi.MultiRunData, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    drawn: list[multi.Frame] = []
    paint = multi._draw_frame

    def spy(ax, data, fr, **kw):  # type: ignore[no-untyped-def]
        drawn.append(fr)
        return paint(ax, data, fr, **kw)

    monkeypatch.setattr(multi, "_draw_frame", spy)
    strip = multi.render_multi_strip(run, out=tmp_path / "strip.png", instants=4)
    assert strip.stat().st_size > 20_000
    assert len(drawn) == 4 and [f.step for f in drawn] == sorted(f.step for f in drawn)
    assert any(e.yielding and "yields" in e.label for f in drawn for e in f.egos)
    drawn.clear()
    gif = multi.render_multi_gif(run, out=tmp_path / "run.gif", every_k=6)
    assert 20_000 < gif.stat().st_size < 2_000_000
    with Image.open(gif) as img:
        assert img.n_frames == len(drawn) > 10
    assert any(e.yielding for f in drawn for e in f.egos)
    assert any(not e.yielding for f in drawn for e in f.egos)


def test_without_coordination_nobody_is_marked(run: multi.MultiRunData) -> None:
    bare = dataclasses.replace(run, marks={})
    assert not any(e.yielding or e.holding
                   for st in range(1, bare.last_step + 1)
                   for e in multi.frame(bare, st).egos)
    picks = multi.encounter_steps(bare, 4)
    assert picks[0] == 1 and picks[-1] == bare.last_step and len(picks) == 4


def test_levelled_runs_the_section_left_to_right(run: multi.MultiRunData) -> None:
    level = multi.levelled(run)
    lanes = {ln.id: ln for ln in level.map.lanes}
    for lid in level.shaded_lanes:
        assert all(abs(y) < 0.5 for _, y in lanes[lid].centerline)
    (_, _), heading = multi.section_axis(level)
    assert abs(heading) < 1e-6  # the first ego's section lane points along +x
    st = run.last_step // 2
    a, b = (multi.frame(r, st).egos for r in (run, level))

    def dist(egos: tuple[multi.EgoFrame, ...]) -> float:
        return math.hypot(egos[0].step.x_m - egos[1].step.x_m,
                          egos[0].step.y_m - egos[1].step.y_m)
    assert len(a) == len(b) == 2 and dist(a) == pytest.approx(dist(b), abs=1e-6)


def test_a_single_ego_family_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RenderError, match="several egos"):
        render_cli.run_multi("usi", 0, "mpc", "central", work_dir=tmp_path)
    with pytest.raises(RenderError, match="coordination"):
        render_cli.run_multi("narrow", 0, "mpc", "sometimes", work_dir=tmp_path)


def test_a_run_folder_that_is_not_a_multi_ego_run_is_named(tmp_path: Path) -> None:
    """``render.py multi RUN_DIR`` (``load_multi_run``) on a folder it cannot draw says why
    in one line; ``render.py run`` on a multi-ego folder names ``render.py multi``. The
    drawing of a real multi-ego graph folder: ``test_graph_multi.py``."""
    import json

    from lmpc_bridge.render import load_run

    with pytest.raises(RenderError, match="not found"):
        multi.load_multi_run(tmp_path)
    (tmp_path / "episode.json").write_text(json.dumps({"record": {}}))
    with pytest.raises(RenderError, match="a single-ego run: draw it with render.py run"):
        multi.load_multi_run(tmp_path)
    (tmp_path / "episode.json").write_text(json.dumps(
        {"scenario": "narrow", "seed": SEED, "records": {"ego_1": {"steps": "none"}}}))
    with pytest.raises(RenderError, match="not an episode record"):
        multi.load_multi_run(tmp_path)
    with pytest.raises(RenderError, match=f"render.py multi {tmp_path}"):
        load_run(tmp_path)
    with pytest.raises(SystemExit):  # RUN_DIR and --family: argparse refuses the pair
        render_cli.main(["multi", str(tmp_path), "--family", "narrow"])
