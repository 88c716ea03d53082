"""The animated GIF of a run (``render_gif``): the map drawn once, each frame the boxes,
the ego trail and the decision in force (blitting), kept under a byte limit."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, cast

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

from lmpc_bridge.record import StepRecord
from lmpc_bridge.render.draw import (
    EGO,
    draw_agents,
    draw_ego,
    draw_map,
    fit_to_axes,
    mark_collision,
)
from lmpc_bridge.render.figures import run_title
from lmpc_bridge.render.geometry import bounds
from lmpc_bridge.render.runs import RenderError, RunData

MAX_GIF_BYTES = 5_000_000
"""GIFs above this are re-rendered with fewer frames / a smaller canvas."""
_WEIGHT_LABELS = (("tracking", "track"), ("action", "action"), ("smoothness", "smooth"),
                  ("safety", "safety"))


def _decision_text(run: RunData, step: StepRecord) -> str:
    info = run.decisions.get(step.decision_id or "")
    if info is None:
        if step.decision_id:
            return f"decision {step.decision_id} (not in the log)"
        return "no decision in force (MPC baseline)" if not run.decisions else \
            "no decision in force yet"
    w = info.weights
    weights = "weights: " + " ".join(f"{short}={w[k]}" for k, short in _WEIGHT_LABELS
                                     if k in w)
    return (f"decision {info.decision_id} ({info.source}, {info.mode}): "
            f"attends {len(info.attention)} · path {info.ego_candidate} · "
            f"a-bias {info.accel_bias_mps2:+.1f} m/s²\n{weights}")


def render_gif(run: RunData, *, out: Path, every_k: int = 3, fps: float = 8.0,
               width_px: int = 640, max_frames: int = 160,
               max_bytes: int = MAX_GIF_BYTES) -> Path:
    """Animated GIF of the run: every ``every_k``-th step, agents as boxes, ego in blue.

    Overlay: time, speed, acceleration and the decision in force. If the file
    comes out above ``max_bytes`` it is rendered again with half the frames and a
    smaller canvas (up to three times), so the result stays small.
    """
    rec = run.record
    if not rec.steps:
        raise RenderError("the record has no steps to draw")
    if every_k < 1:
        raise RenderError(f"every_k must be >= 1, got {every_k}")
    every_k = max(every_k, math.ceil(len(rec.steps) / max_frames))
    return save_gif_under(
        out, lambda k, w: _gif_frames(run, every_k=k, width_px=w),
        every_k=every_k, width_px=width_px, fps=fps, max_bytes=max_bytes)


def save_gif_under(out: Path, frames_for: Callable[[int, int], list[Any]], *, every_k: int,
                   width_px: int, fps: float, max_bytes: int) -> Path:
    """Write the GIF of ``frames_for(every_k, width_px)`` (PIL images) to ``out``; if it
    comes out above ``max_bytes``, render again with half the frames and a 0.8x canvas
    (up to three times), then give up with a :class:`RenderError`."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(4):
        frames = frames_for(every_k, width_px)
        frames[0].save(out, save_all=True, append_images=frames[1:],
                       duration=int(round(1000.0 / fps)), loop=0, optimize=True, disposal=1)
        if out.stat().st_size <= max_bytes:
            return out
        every_k *= 2
        width_px = int(width_px * 0.8)
    raise RenderError(f"{out}: GIF still above {max_bytes} bytes; pass a larger every_k")


def _gif_frames(run: RunData, *, every_k: int, width_px: int) -> list[Any]:
    from PIL import Image

    rec = run.record
    # the ego path, the target and whoever came within 30 m of the ego
    pts = [(s.x_m, s.y_m) for s in rec.steps] + [tuple(rec.target_center)]
    pts += [(v.x_m, v.y_m) for s in rec.steps for v in s.nearby if v.gap_m <= 30.0]
    x0, x1, y0, y1 = bounds(pts, 15.0)
    aspect = (y1 - y0) / max(x1 - x0, 1e-6)
    dpi = 100
    width_in = width_px / dpi
    title_in = 0.3
    map_h_in = min(max(width_in * 0.98 * aspect, 3.0), width_in * 1.3)
    height_in = map_h_in + title_in + 0.05
    fig, ax = plt.subplots(figsize=(width_in, height_in), dpi=dpi)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.05 / height_in,
                        top=1.0 - title_in / height_in)
    draw_map(ax, run.map, net_file=run.net_file)
    x0, x1, y0, y1 = fit_to_axes(ax, (x0, x1, y0, y1))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(run_title(run) + "   (red: attended, grey: not)", fontsize=9)
    xy = np.array([(s.x_m, s.y_m) for s in rec.steps])
    (trail,) = ax.plot([], [], color=EGO, lw=1.5, alpha=0.7, zorder=4)
    text = ax.text(0.01, 0.99, "", transform=ax.transAxes, va="top", ha="left", fontsize=7,
                   family="monospace", zorder=10,
                   bbox=dict(boxstyle="round,pad=0.3", fc="white", ec="#999999", alpha=0.9))
    indices = list(range(0, len(rec.steps), every_k))
    if indices[-1] != len(rec.steps) - 1:
        indices.append(len(rec.steps) - 1)  # the last frame shows how it ended
    frames = []
    trail.set_animated(True)
    text.set_animated(True)
    # the map is drawn once; each frame restores it and draws only what moves (blitting)
    canvas = cast(FigureCanvasAgg, fig.canvas)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    dynamic: list[Any] = []
    for idx in indices:
        for artist in dynamic:
            artist.remove()
        step = rec.steps[idx]
        n_patches, n_texts, n_lines = len(ax.patches), len(ax.texts), len(ax.lines)
        draw_agents(ax, step, run.attended(step), labels=True)
        draw_ego(ax, step, run.vehicle)
        status = ""
        if idx == len(rec.steps) - 1 and rec.outcome != "running":
            status = f"   [{rec.outcome}]"
            mark_collision(ax, rec)
        dynamic = (list(ax.patches[n_patches:]) + list(ax.texts[n_texts:])
                   + list(ax.lines[n_lines:]))
        trail.set_data(xy[: idx + 1, 0], xy[: idx + 1, 1])
        text.set_text(f"t = {step.t_s:5.1f} s   v = {step.v_mps:4.1f} m/s   "
                      f"a = {step.applied_accel_mps2:+4.1f} m/s²   "
                      f"mode {step.control_mode or '-'}{status}\n"
                      + _decision_text(run, step))
        canvas.restore_region(background)
        for artist in (trail, *sorted(dynamic, key=lambda a: a.get_zorder()), text):
            ax.draw_artist(artist)
        rgba = np.asarray(canvas.buffer_rgba())
        image = Image.fromarray(rgba[..., :3].copy())
        frames.append(image.quantize(colors=128, method=Image.Quantize.FASTOCTREE,
                                     dither=Image.Dither.NONE))
    plt.close(fig)
    return frames
