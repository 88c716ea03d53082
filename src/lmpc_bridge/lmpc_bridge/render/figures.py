"""Still pictures: a scene (``render_scene``) and a run (``render_run``: the ego path by
speed over the map plus zoomed snapshots at ``key_moments``)."""
from __future__ import annotations

import math
import tempfile
import textwrap
from pathlib import Path
from typing import Optional

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Polygon

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE

from lmpc_bridge.record import EpisodeRecord
from lmpc_bridge.render.draw import (
    ATTENDED,
    EGO,
    OTHER,
    draw_agents,
    draw_box,
    draw_ego,
    draw_map,
    fit_to_axes,
    mark_collision,
    save_figure,
    speed_line,
)
from lmpc_bridge.render.geometry import bounds, box_corners, ego_start_pose, nose, scene_window
from lmpc_bridge.render.runs import RenderError, RunData, scene_map


def render_scene(family: str, seed: int, *, out: Path, work_dir: Optional[Path] = None,
                 crop_pad_m: Optional[float] = 40.0, dpi: int = 150) -> Path:
    """Bird's-eye PNG of a scene: roads, junction, markings, ego route, target, ego start.

    ``crop_pad_m``: show the ego start, the route's junctions and the target with this
    margin (None: the whole map).
    """
    work_dir = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="lmpc-render-"))
    snapshot, scene = scene_map(family, seed, work_dir=work_dir)
    fig, ax = plt.subplots(figsize=(8, 8))
    draw_map(ax, snapshot, net_file=Path(scene.net_file))
    x, y, yaw = ego_start_pose(snapshot, scene.ego_depart_pos_m)
    corners = box_corners(x, y, yaw, DEFAULT_VEHICLE.length_m, DEFAULT_VEHICLE.width_m)
    draw_box(ax, corners, facecolor=EGO, zorder=6, label="ego start")
    ax.add_patch(Polygon(nose(corners), closed=True, facecolor="white", zorder=6.1))
    ax.annotate(f"ego {scene.ego_depart_speed_mps:.1f} m/s", (x, y), xytext=(8, 8),
                textcoords="offset points", fontsize=8, color=EGO, zorder=7)
    x0, x1, y0, y1 = scene_window(snapshot, (x, y), pad_m=crop_pad_m)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{family} seed {seed}"
    if scene.description:
        title += "\n" + "\n".join(textwrap.wrap(" ".join(scene.description.split()), 80))
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    return save_figure(fig, out, dpi=dpi)


def key_moments(record: EpisodeRecord, count: int = 4, *,
                interaction_gap_m: float = 40.0) -> list[int]:
    """Indices into ``record.steps`` worth a snapshot, in time order.

    Interactions first: the closest approach to any participant and the last step
    (how it ended); the rest evenly spaced over the steps with somebody within
    ``interaction_gap_m`` (all steps when nobody came that close), never two
    closer than 1/(2 count) of that span.
    """
    steps = record.steps
    n = len(steps)
    if n == 0:
        return []
    gaps = [min((v.gap_m for v in s.nearby), default=math.inf) for s in steps]
    busy = [i for i, g in enumerate(gaps) if g <= interaction_gap_m] or list(range(n))
    first, last = busy[0], busy[-1]
    chosen: list[int] = []
    if math.isfinite(min(gaps)):
        chosen.append(int(np.argmin(gaps)))
    min_sep = max((last - first) // (2 * count), 1)
    spread = [round(first + f * (last - first)) for f in np.linspace(0, 1, 2 * count - 1)]
    # even picks first, then the odd ones in between if the closest approach took a slot
    for idx in [n - 1, *spread[::2], *spread[1::2]]:
        if len(chosen) >= min(count, n):
            break
        if all(abs(idx - c) >= min_sep for c in chosen):
            chosen.append(int(idx))
    return sorted(chosen)


def run_title(run: RunData) -> str:
    """``family seed N · method · outcome`` of a run."""
    rec = run.record
    end = rec.steps[-1].t_s if rec.steps else 0.0
    outcome = rec.outcome
    if rec.outcome == "reached" and rec.reached_at_s is not None:
        outcome = f"reached in {rec.reached_at_s:.1f} s"
    elif rec.outcome == "collision":
        outcome = f"collision with {rec.collided_with} at {end:.1f} s"
    elif rec.outcome == "timeout":
        outcome = f"timeout at {end:.1f} s"
    method = f" · {run.method}" if run.method else ""
    return f"{rec.family} seed {rec.seed}{method} · {outcome}"


def render_run(run: RunData, *, out: Path, moments: int = 4, window_m: float = 60.0,
               dpi: int = 130) -> Path:
    """The ego path over the map coloured by speed, plus ``moments`` zoomed snapshots.

    In the snapshots, participants are red when the decision in force at that step
    attended them, grey otherwise (the paper's Fig. 6 convention).
    """
    rec = run.record
    if not rec.steps:
        raise RenderError("the record has no steps to draw")
    picks = key_moments(rec, moments)
    fig = plt.figure(figsize=(3.2 * max(len(picks), 3), 10.5))
    grid = fig.add_gridspec(2, max(len(picks), 1), height_ratios=(2.1, 1.0), hspace=0.25,
                            wspace=0.08)
    ax = fig.add_subplot(grid[0, :])
    draw_map(ax, run.map, net_file=run.net_file)
    v_max = max(max(s.v_mps for s in rec.steps), 1.0)
    line = speed_line(ax, rec, v_max_mps=v_max)
    cbar = fig.colorbar(line, ax=ax, fraction=0.03, pad=0.01)
    cbar.set_label("ego speed [m/s]")
    pts = [(s.x_m, s.y_m) for s in rec.steps] + [tuple(rec.target_center)]
    for number, idx in enumerate(picks, start=1):
        step = rec.steps[idx]
        # earlier moments fainter: the snapshots below show each moment on its own
        alpha = 0.35 + 0.65 * number / len(picks)
        draw_agents(ax, step, run.attended(step), labels=False, zorder=5, alpha=alpha)
        draw_ego(ax, step, run.vehicle, zorder=6, alpha=alpha)
        ax.annotate(str(number), (step.x_m, step.y_m), xytext=(0, 10 if number % 2 else -16),
                    textcoords="offset points", ha="center", fontsize=9, weight="bold",
                    color=EGO, zorder=8,
                    bbox=dict(boxstyle="circle,pad=0.15", fc="white", ec=EGO, lw=0.8))
        pts += [(v.x_m, v.y_m) for v in step.nearby if v.gap_m < window_m / 2]
    mark_collision(ax, rec)
    x0, x1, y0, y1 = fit_to_axes(ax, bounds(pts, 20.0))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_title(run_title(run), fontsize=11)
    handles = [Polygon(np.zeros((3, 2)), facecolor=EGO, edgecolor="black", label="ego"),
               Polygon(np.zeros((3, 2)), facecolor=ATTENDED, edgecolor="black",
                       label="attended by the decision in force"),
               Polygon(np.zeros((3, 2)), facecolor=OTHER, edgecolor="black",
                       label="not attended")]
    ax.legend(handles=handles + ax.get_legend_handles_labels()[0], loc="best", fontsize=7,
              framealpha=0.9)
    for col, idx in enumerate(picks):
        sub = fig.add_subplot(grid[1, col])
        step = rec.steps[idx]
        draw_map(sub, run.map, net_file=run.net_file, show_route=False, marking_lw=1.2)
        xy = np.array([(s.x_m, s.y_m) for s in rec.steps])
        sub.plot(xy[: idx + 1, 0], xy[: idx + 1, 1], color=EGO, lw=1.2, alpha=0.6, zorder=4)
        sub.plot(xy[idx:, 0], xy[idx:, 1], color=EGO, lw=1.0, ls=":", alpha=0.6, zorder=4)
        attended = run.attended(step)
        draw_agents(sub, step, attended, labels=True)
        draw_ego(sub, step, run.vehicle)
        half = window_m / 2.0
        sub.set_xlim(step.x_m - half, step.x_m + half)
        sub.set_ylim(step.y_m - half, step.y_m + half)
        sub.set_xticks([])
        sub.set_yticks([])
        n_att = sum(1 for v in step.nearby if v.id in attended)
        if idx == len(rec.steps) - 1:
            mark_collision(sub, rec, ms=30.0)
        sub.set_title(f"({col + 1}) t = {step.t_s:.1f} s · v = {step.v_mps:.1f} m/s\n"
                      f"attended {n_att} of {len(step.nearby)} in sensing range", fontsize=8)
    return save_figure(fig, out, dpi=dpi)
