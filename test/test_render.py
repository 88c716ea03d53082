"""Pictures (lmpc_bridge.render, scripts/render.py): scene PNG, run PNG + GIF, O.C. bars. No ROS.

One short in-process run (usi seed 0, capped at a few seconds of sim time) is shared
by the run tests; everything else uses the scene's map and hand-made records.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lmpc_bridge.record import EpisodeRecord, NearbyVehicle, StepRecord
from lmpc_bridge import render
from lmpc_bridge.render import bars, draw, geometry
from lmpc_scripts import render as render_cli

RUN_CAP_S = 3.0


@pytest.fixture(scope="module")
def work_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("render_scenes")


@pytest.fixture(scope="module")
def short_run(work_dir: Path) -> render.RunData:
    return render_cli.run_in_process("usi", 0, "lmpc-rules", work_dir=work_dir,
                                     max_time_s=RUN_CAP_S)


def _image(path: Path) -> Image.Image:
    assert path.is_file() and path.stat().st_size > 0
    return Image.open(path)


def _pixels_near(path: Path, hex_colour: str, tol: int = 30) -> int:
    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=int)
    target = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(rgb - target).max(axis=2) <= tol).sum())


def test_scene_png(work_dir: Path, tmp_path: Path) -> None:
    out = render.render_scene("usi", 0, out=tmp_path / "scene.png", work_dir=work_dir)
    img = _image(out)
    assert img.format == "PNG"
    assert img.width >= 600 and img.height >= 600
    # the ego start box and the target area are drawn
    assert _pixels_near(out, draw.EGO) > 20
    assert _pixels_near(out, "#a6d8b3", tol=25) > 100  # target fill (green at alpha 0.35)


def test_offset_polyline_is_parallel() -> None:
    line = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    left = geometry.offset_polyline(line, 1.5)
    assert np.allclose(left[0], (0.0, 1.5))
    assert np.allclose(left[-1], (8.5, 10.0))
    assert np.allclose(left[1], (8.5, 1.5))  # mitred corner of a right angle


def test_short_run_png_gif_and_round_trip(short_run: render.RunData, tmp_path: Path) -> None:
    rec = short_run.record
    assert rec.steps and rec.steps[-1].t_s <= RUN_CAP_S + 1e-6
    png = render.render_run(short_run, out=tmp_path / "run.png", moments=3)
    img = _image(png)
    assert img.width >= 800 and img.height >= 600
    gif = render.render_gif(short_run, out=tmp_path / "run.gif", every_k=3)
    anim = _image(gif)
    assert anim.format == "GIF"
    expected = math.ceil(len(rec.steps) / 3)
    assert anim.n_frames >= min(expected, 5)
    assert gif.stat().st_size < render.MAX_GIF_BYTES
    # a saved run reads back to the same record and decisions
    run_dir = render.save_run(short_run, tmp_path / "saved")
    loaded = render.load_run(run_dir, work_dir=tmp_path / "scenes")
    assert loaded.record == rec
    assert loaded.decisions == short_run.decisions
    assert len(loaded.map.lanes) == len(short_run.map.lanes)


def test_gif_shrinks_to_the_byte_limit(short_run: render.RunData, tmp_path: Path) -> None:
    full = render.render_gif(short_run, out=tmp_path / "full.gif", every_k=1, width_px=400)
    limit = full.stat().st_size // 2
    small = render.render_gif(short_run, out=tmp_path / "small.gif", every_k=1,
                              width_px=400, max_bytes=limit)
    assert small.stat().st_size <= limit
    assert Image.open(small).n_frames < Image.open(full).n_frames


def _stub_run(short_run: render.RunData, *, attended: bool) -> render.RunData:
    """Two steps on the ego route with one car 12 m ahead; attended or not."""
    start = short_run.record.steps[0]
    cos, sin = math.cos(start.yaw_rad), math.sin(start.yaw_rad)
    steps = []
    for k in (1, 2):
        x, y = start.x_m + 0.5 * k * cos, start.y_m + 0.5 * k * sin
        car = NearbyVehicle(id="car7", kind="car", x_m=x + 12 * cos, y_m=y + 12 * sin,
                            yaw_rad=start.yaw_rad, v_mps=5.0, v_max_mps=14.0, a_mps2=0.0,
                            gap_m=7.5, length_m=4.5, width_m=1.8)
        steps.append(StepRecord(step=k, t_s=0.1 * k, x_m=x, y_m=y, yaw_rad=start.yaw_rad,
                                v_mps=5.0, a_mps2=0.0, steer_rad=0.0, decision_id="d1",
                                nearby=(car,)))
    record = EpisodeRecord(family="usi", seed=0, dt_s=0.1, max_time_s=10.0,
                           target_center=short_run.record.target_center, target_radius_m=5.0,
                           outcome="running", steps=tuple(steps))
    decision = render.DecisionInfo(decision_id="d1", stamp_s=0.0, source="rules",
                                   mode="normal", attention=("car7",) if attended else (),
                                   ego_candidate=1, accel_bias_mps2=0.0, steer_bias_rad=0.0)
    return render.RunData(record=record, map=short_run.map, decisions={"d1": decision},
                          net_file=short_run.net_file)


def test_attended_agents_are_red(short_run: render.RunData, tmp_path: Path) -> None:
    red = render.render_run(_stub_run(short_run, attended=True), out=tmp_path / "a.png",
                            moments=2)
    grey = render.render_run(_stub_run(short_run, attended=False), out=tmp_path / "b.png",
                             moments=2)
    # the legend shows a red swatch in both: compare, do not expect zero
    assert _pixels_near(red, draw.ATTENDED, tol=20) > _pixels_near(
        grey, draw.ATTENDED, tol=20) + 100
    assert _pixels_near(grey, draw.OTHER, tol=6) > _pixels_near(red, draw.OTHER, tol=6)


def test_key_moments_include_closest_approach_and_end(short_run: render.RunData) -> None:
    base = _stub_run(short_run, attended=True).record
    steps = []
    for k in range(40):
        gap = abs(k - 23) + 2.0  # closest at step index 23
        car = base.steps[0].nearby[0].model_copy(update={"gap_m": gap})
        steps.append(base.steps[0].model_copy(update={"step": k + 1, "nearby": (car,)}))
    record = base.model_copy(update={"steps": tuple(steps)})
    picks = render.key_moments(record, 4)
    assert picks == sorted(set(picks)) and len(picks) == 4
    assert 23 in picks and 39 in picks


def test_oc_bars(tmp_path: Path) -> None:
    summary = {"families": {
        "usi": {"mpc": {"overall_cost": 150.0, "collisions": 1, "fails": 0, "scenes": 5},
                "lmpc-rules": {"overall_cost": 120.0, "collisions": 0, "fails": 1,
                               "oc_change_vs_mpc": -0.2, "scenes": 5}},
        "rab": {"mpc": {"overall_cost": 90.0, "collisions": 0, "fails": 0, "scenes": 5}},
    }}
    out = render.plot_oc_bars(summary, tmp_path / "direct.png")
    img = _image(out)
    assert img.width >= 600 and img.height >= 400
    assert _pixels_near(out, bars.METHOD_COLOURS["lmpc-rules"], tol=10) > 500
    # the CLI writes oc_bars.png next to summary.json
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert render_cli.main(["bars", str(tmp_path)]) == 0
    assert _image(tmp_path / "oc_bars.png").format == "PNG"
    with pytest.raises(render.RenderError):
        render.plot_oc_bars({"families": {}}, tmp_path / "none.png")


def test_load_run_missing_folder_is_actionable(tmp_path: Path) -> None:
    with pytest.raises(render.RenderError, match="episode.json"):
        render.load_run(tmp_path)


def test_an_in_process_run_follows_the_instruction(work_dir: Path) -> None:
    run = render_cli.run_in_process("usi", 0, "lmpc-rules", work_dir=work_dir,
                                    max_time_s=1.0, instruction="drive conservatively")
    assert run.decisions and all("careful" in d.reasoning for d in run.decisions.values())
    with pytest.raises(SystemExit):  # a recorded run was driven with its own instruction
        render_cli.main(["run", str(work_dir), "--instruction", "drive aggressively"])


def test_cli_refuses_an_unknown_method(tmp_path: Path) -> None:
    with pytest.raises(render.RenderError, match="unknown method"):
        render_cli.run_in_process("usi", 0, "lmpc-openai", work_dir=tmp_path)


def test_cli_names_an_unknown_family_without_a_traceback(tmp_path: Path, capsys) -> None:
    assert render_cli.main(["run", "--family", "usii", "--seed", "0", "--method", "mpc",
                            "--work-dir", str(tmp_path), "--out", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert "render.py: cannot build scene usii/0: unknown scenario family 'usii'" in err
    assert not (tmp_path / "a.png").exists()


def test_the_bridge_stays_free_of_plotting_planner_and_mpc() -> None:
    """``import lmpc_bridge`` loads no matplotlib; the pictures load neither the planner
    nor the MPC (they come in through ``build``)."""
    code = ("import sys, lmpc_bridge, lmpc_bridge.runner, lmpc_bridge.evaluation.scenes\n"
            "assert 'matplotlib' not in sys.modules, 'matplotlib'\n"
            "import lmpc_bridge.render\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('lmpc_mpc', 'lmpc_llm_planner', 'lmpc_scripts', 'casadi'))\n"
            "assert not bad, bad\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
