"""Pictures of a multi-ego run (issue 18): a strip of instants (``render_multi_strip``) and
an animated GIF (``render_multi_gif``) of e.g. the narrow-road encounter.

Input is a :class:`MultiRunData`: per ego its single-ego ``EpisodeRecord``, the
coordination's marks (``lmpc_bridge.multi_episode.EgoMark``: the command in force and
whether it was holding) and the map; built from a ``MultiResult`` by
:func:`multi_run_data`. Each ego has its own colour and label; an ego whose command in
force is ``yield`` gets a thick outline and a "yields" label ("holds" while the hold
obstacle is in its observation); the lanes in ``shaded_lanes`` (the one-lane section,
found by the caller: the bridge does not import the planner's conflict detection) are
shaded. Other vehicles are the union of what the egos sensed at that step (grey).

What is drawn is computed by :func:`frame` (plain data, tested); the drawing functions
only paint it.
"""
from __future__ import annotations

import functools
import json
import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, cast

import matplotlib.pyplot as plt
import numpy as np
from pydantic import ValidationError
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.patches import Circle, Polygon

from lmpc_msgs_py.messages import MapSnapshot
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge.record import EpisodeRecord, NearbyVehicle, StepRecord
from lmpc_bridge.render.draw import (
    OTHER,
    draw_agents,
    draw_box,
    draw_map,
    fit_to_axes,
    save_figure,
)
from lmpc_bridge.render.geometry import box_corners, lane_polygon, nose
from lmpc_bridge.render.gif import save_gif_under
from lmpc_bridge.render.runs import _GRAPH_PLANNERS, RenderError

EGO_COLOURS = ("#1f5fd6", "#e67e22", "#8e44ad", "#16a085")
"""ego_1, ego_2, ... (cycled beyond four)."""
YIELD = "#d62728"
SECTION = "#f4d03f"


@dataclass(frozen=True)
class MultiRunData:
    """Everything a multi-ego picture needs."""

    family: str
    seed: int
    records: dict[str, EpisodeRecord]
    marks: dict[str, dict[int, Any]]
    """Per ego: its ``EgoMark`` by record step (empty without coordination)."""
    map: MapSnapshot
    """The roads (any ego's map: they share the net)."""
    routes: dict[str, tuple[tuple[float, float], ...]]
    """Per ego, its route as a polyline."""
    method: str = ""
    mode: str = ""
    shaded_lanes: tuple[str, ...] = ()
    net_file: Optional[Path] = None
    vehicle: VehicleParams = DEFAULT_VEHICLE
    outcomes: dict[str, str] = field(default_factory=dict)

    @property
    def ego_ids(self) -> tuple[str, ...]:
        return tuple(sorted(self.records))

    @property
    def last_step(self) -> int:
        return max((r.steps[-1].step for r in self.records.values() if r.steps), default=0)

    @functools.cached_property
    def _by_step(self) -> dict[str, dict[int, StepRecord]]:
        return {eid: {s.step: s for s in r.steps} for eid, r in self.records.items()}

    def at(self, ego_id: str, step: int) -> Optional[StepRecord]:
        """``ego_id``'s record step ``step`` (None: not on the road then)."""
        return self._by_step[ego_id].get(step)

    def colour(self, ego_id: str) -> str:
        return EGO_COLOURS[self.ego_ids.index(ego_id) % len(EGO_COLOURS)]


def multi_run_data(result: Any, *, method: str = "", mode: str = "",
                   shaded_lanes: tuple[str, ...] = (),
                   net_file: Optional[Path] = None) -> MultiRunData:
    """From a ``lmpc_bridge.multi_episode.MultiResult`` (records, maps, marks kept)."""
    if not result.records:
        raise RenderError("the multi-ego result has no records (run it with this version "
                          "of run_multi_episode)")
    ids = sorted(result.records)
    return MultiRunData(
        family=result.family, seed=result.seed, records=dict(result.records),
        marks={eid: {m.step: m for m in result.marks.get(eid, ())} for eid in ids},
        map=result.maps[ids[0]], routes=_routes(result.maps, ids), method=method, mode=mode,
        shaded_lanes=tuple(shaded_lanes), net_file=net_file,
        outcomes={e.ego_id: e.outcome for e in result.egos})


def _routes(maps: dict[str, MapSnapshot], ids: list[str]
            ) -> dict[str, tuple[tuple[float, float], ...]]:
    """Per ego, its route through its map as one polyline."""
    routes = {}
    for eid in ids:
        lanes = {ln.id: ln for ln in maps[eid].lanes}
        routes[eid] = tuple(p for lid in maps[eid].ego_route if lid in lanes
                            for p in lanes[lid].centerline)
    return routes


def load_multi_run(run_dir: Path, *, work_dir: Optional[Path] = None,
                   shade: Optional[Callable[[dict[str, MapSnapshot]], tuple[str, ...]]] = None
                   ) -> MultiRunData:
    """Read a multi-ego graph run folder (``run_graph.py --egos N``: an ``episode.json``
    with one record per ego) and rebuild each ego's map from the scene (from the bridge's
    cache in ``run_dir/scene`` when present). ``shade``: the maps -> the lanes to shade
    (the caller's, as for :func:`multi_run_data`). The graph keeps no coordination marks,
    so no ego is drawn as yielding or holding; an in-process run (``render.py multi
    --family``) has them."""
    from lmpc_bridge.mapping import build_map, read_net
    from lmpc_bridge.multi_scene import ego_scene, ego_specs
    from lmpc_bridge.scenarios import SceneError, build_scene

    episode_path = Path(run_dir) / "episode.json"
    if not episode_path.is_file():
        raise RenderError(f"{episode_path} not found: pass a run folder written by "
                          "run_graph.py --egos N")
    episode = json.loads(episode_path.read_text(encoding="utf-8"))
    raw = episode.get("records")
    if not isinstance(raw, dict) or not raw:
        what = "a single-ego run: draw it with render.py run" if "record" in episode \
            else "no per-ego 'records' (episode finished abnormally?)"
        raise RenderError(f"{episode_path}: {what}")
    try:
        records = {eid: EpisodeRecord.model_validate(rec) for eid, rec in raw.items()}
    except ValidationError as exc:
        raise RenderError(f"{episode_path}: a record is not an episode record "
                          f"({str(exc).splitlines()[0]})") from exc
    family, seed = str(episode.get("scenario", "")), int(episode.get("seed", 0))
    cache = Path(run_dir) / "scene"
    if work_dir is None:
        work_dir = cache if cache.is_dir() else Path(tempfile.mkdtemp(prefix="lmpc-render-"))
    try:
        scene = build_scene(family, seed, work_dir=work_dir)
        net = read_net(scene.net_file)
        maps = {spec.ego_id: build_map(ego_scene(scene, spec), net=net)[0]
                for spec in ego_specs(scene)}
    except SceneError as exc:
        raise RenderError(f"cannot rebuild scene {family}/{seed}: {exc}") from exc
    missing = sorted(set(records) - set(maps))
    if missing:
        raise RenderError(f"{episode_path}: egos {missing} are not in scene {family}/{seed}")
    summary_path = Path(run_dir) / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    planner = str(summary.get("planner", ""))
    egos = episode.get("egos") or {}
    return MultiRunData(
        family=family, seed=seed, records=records, marks={eid: {} for eid in records},
        map=maps[sorted(records)[0]], routes=_routes(maps, sorted(records)),
        method=_GRAPH_PLANNERS.get(planner, planner), mode=str(summary.get("coordination") or ""),
        shaded_lanes=shade(maps) if shade is not None else (),
        net_file=Path(scene.net_file),
        outcomes={eid: str((egos.get(eid) or {}).get("outcome", "")) for eid in records})


@dataclass(frozen=True)
class EgoFrame:
    """One ego as drawn at one step."""

    ego_id: str
    step: StepRecord
    colour: str
    yielding: bool
    holding: bool
    label: str


@dataclass(frozen=True)
class Frame:
    """What one instant shows: the egos on the road and the other vehicles."""

    step: int
    t_s: float
    egos: tuple[EgoFrame, ...]
    others: tuple[NearbyVehicle, ...]
    done: tuple[str, ...]
    """Egos no longer on the road at this step (through, or ended)."""


def frame(run: MultiRunData, step: int) -> Frame:
    """The instant ``step`` (a ``StepRecord.step``) of ``run``."""
    egos: list[EgoFrame] = []
    others: dict[str, NearbyVehicle] = {}
    done: list[str] = []
    for eid in run.ego_ids:
        rec = run.at(eid, step)
        if rec is None:
            done.append(eid)
            continue
        mark = run.marks.get(eid, {}).get(step)
        yielding = bool(mark is not None and mark.yielding)
        holding = bool(mark is not None and mark.holding)
        label = f"{eid} {rec.v_mps:.1f} m/s"
        if yielding:
            label += "\nyields (holding)" if holding else "\nyields"
        elif mark is not None and mark.command == "proceed":
            label += "\nproceeds"
        egos.append(EgoFrame(ego_id=eid, step=rec, colour=run.colour(eid), yielding=yielding,
                             holding=holding, label=label))
        for v in rec.nearby:
            if v.id not in run.records:
                others.setdefault(v.id, v)
    return Frame(step=step, t_s=round(step * _dt(run), 6), egos=tuple(egos),
                 others=tuple(others[k] for k in sorted(others)), done=tuple(done))


def _dt(run: MultiRunData) -> float:
    return next(iter(run.records.values())).dt_s


def encounter_steps(run: MultiRunData, count: int = 4) -> list[int]:
    """Instants of the encounter (record steps, in time order): the first step with a
    yielding ego; the step during the yielding when a non-yielding ego is nearest the
    section's centre (it passes while the other waits); the last yielding step; the step
    when a yielder is nearest the centre (its turn). Without yielding (mode ``none``),
    ``count`` evenly spaced steps; more than four: evenly spaced ones added."""
    last = run.last_step
    if last < 1:
        raise RenderError("the records have no steps to draw")
    even = [int(round(x)) for x in np.linspace(1, last, count)]
    yields = sorted(st for marks in run.marks.values() for st, m in marks.items()
                    if m.yielding)
    if not yields:
        return sorted(set(even))
    (cx, cy), _ = section_axis(run)

    def near(st: int, ids: Any) -> float:
        recs = [run.at(eid, st) for eid in ids]
        return min((math.hypot(r.x_m - cx, r.y_m - cy) for r in recs if r is not None),
                   default=math.inf)

    def going(st: int) -> list[str]:
        return [eid for eid in run.ego_ids
                if not getattr(run.marks.get(eid, {}).get(st), "yielding", False)]
    yielders = [eid for eid in run.ego_ids
                if any(m.yielding for m in run.marks.get(eid, {}).values())]
    first, end = yields[0], yields[-1]
    passing = min(range(first, end + 1), key=lambda st: near(st, going(st)))
    turn = min(range(end, last + 1), key=lambda st: near(st, yielders))
    picks = [first, passing, end, turn]
    picks += [st for st in even if st not in picks][:max(count - 4, 0)]
    return sorted(set(picks[:count]))


def _rot(angle: float, origin: tuple[float, float]) -> Any:
    c, s = math.cos(angle), math.sin(angle)
    ox, oy = origin

    def point(x: float, y: float) -> tuple[float, float]:
        return (c * (x - ox) - s * (y - oy), s * (x - ox) + c * (y - oy))
    return point


def section_axis(run: MultiRunData) -> tuple[tuple[float, float], float]:
    """Centre and heading of the shaded section (of the whole map without one); the
    heading is that of the section lane on the map's route (the first ego's direction)."""
    lanes = {ln.id: ln for ln in run.map.lanes}
    shaded = sorted((lanes[lid] for lid in run.shaded_lanes if lid in lanes),
                    key=lambda ln: ln.id not in run.map.ego_route)
    if shaded:
        line = shaded[0].centerline
        (x0, y0), (x1, y1) = line[0], line[-1]
        pts = [p for ln in shaded for p in ln.centerline]
    else:
        pts = [p for ln in run.map.lanes for p in ln.centerline]
        (x0, y0), (x1, y1) = pts[0], pts[-1]
    return ((float(np.mean([p[0] for p in pts])), float(np.mean([p[1] for p in pts]))),
            math.atan2(y1 - y0, x1 - x0))


def levelled(run: MultiRunData) -> MultiRunData:
    """``run`` rotated about the section's centre so the first ego drives through it left to
    right (the narrow family's road has a seeded angle; level, wide panels show it)."""
    origin, heading = section_axis(run)
    angle = -heading
    rot = _rot(angle, origin)
    lanes = tuple(ln.model_copy(update={"centerline": tuple(rot(*p) for p in ln.centerline)})
                  for ln in run.map.lanes)
    target = run.map.target.model_copy(update={"center": rot(*run.map.target.center)})
    stops = tuple(sl.model_copy(update={"position": rot(*sl.position)})
                  for sl in run.map.stop_lines)
    mp = run.map.model_copy(update={"lanes": lanes, "target": target, "stop_lines": stops})

    def step(s: StepRecord) -> StepRecord:
        x, y = rot(s.x_m, s.y_m)
        nearby = tuple(v.model_copy(update=dict(zip(("x_m", "y_m"), rot(v.x_m, v.y_m)),
                                                yaw_rad=v.yaw_rad + angle)) for v in s.nearby)
        return s.model_copy(update={"x_m": x, "y_m": y, "yaw_rad": s.yaw_rad + angle,
                                    "nearby": nearby})
    records = {eid: r.model_copy(update={"steps": tuple(step(s) for s in r.steps),
                                         "target_center": rot(*r.target_center)})
               for eid, r in run.records.items()}
    routes = {eid: tuple(rot(*p) for p in pts) for eid, pts in run.routes.items()}
    # the net file's junction outlines are not rotated: drawn from the map's lanes only
    return MultiRunData(family=run.family, seed=run.seed, records=records, marks=run.marks,
                        map=mp, routes=routes, method=run.method, mode=run.mode,
                        shaded_lanes=run.shaded_lanes, net_file=None, vehicle=run.vehicle,
                        outcomes=run.outcomes)


# --- drawing ------------------------------------------------------------------------------
def _draw_static(ax: Axes, run: MultiRunData) -> None:
    draw_map(ax, run.map, net_file=run.net_file, show_route=False, show_target=False)
    lanes = {ln.id: ln for ln in run.map.lanes}
    shaded = [lane_polygon(lanes[lid]) for lid in run.shaded_lanes if lid in lanes]
    if shaded:
        ax.add_collection(PolyCollection(shaded, facecolors=SECTION, edgecolors=SECTION,
                                         alpha=0.45, linewidths=0.5, zorder=1.9,
                                         label="one-lane section"))
    for eid in run.ego_ids:
        colour, route = run.colour(eid), run.routes.get(eid, ())
        if route:
            xs, ys = zip(*route)
            ax.plot(xs, ys, color=colour, lw=1.0, ls=(0, (1, 2)), alpha=0.8, zorder=2.5)
        rec = run.records[eid]
        ax.add_patch(Circle(rec.target_center, rec.target_radius_m, facecolor=colour,
                            alpha=0.2, edgecolor=colour, lw=1.0, zorder=2.6))


def _draw_frame(ax: Axes, run: MultiRunData, fr: Frame, *, labels: bool = True) -> list[Any]:
    """Paint ``fr``; return the artists (to remove them for the next GIF frame)."""
    n_patches, n_texts = len(ax.patches), len(ax.texts)
    if fr.others:
        stand_in = fr.egos[0].step.model_copy(update={"nearby": fr.others}) if fr.egos \
            else None
        if stand_in is not None:
            draw_agents(ax, stand_in, frozenset(), labels=False)
    for e in fr.egos:
        s = e.step
        corners = box_corners(s.x_m, s.y_m, s.yaw_rad, run.vehicle.length_m,
                              run.vehicle.width_m)
        draw_box(ax, corners, facecolor=e.colour, zorder=6,
                 edgecolor=YIELD if e.yielding else "black", lw=2.5 if e.yielding else 0.6)
        ax.add_patch(Polygon(nose(corners), closed=True, facecolor="white", zorder=6.1))
        if labels:
            ax.annotate(e.label, (s.x_m, s.y_m), xytext=(0, 9), textcoords="offset points",
                        ha="center", va="bottom", fontsize=7, weight="bold",
                        color=YIELD if e.yielding else e.colour, zorder=8, clip_on=True,
                        bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none",
                                  alpha=0.75))
    return list(ax.patches[n_patches:]) + list(ax.texts[n_texts:])


def _window(run: MultiRunData, steps: list[int], margin_m: float) -> tuple[float, ...]:
    """The section and the egos at ``steps``, ``margin_m`` beyond them along x, at least
    12 m either side of the section's centre across."""
    lanes = {ln.id: ln for ln in run.map.lanes}
    pts = [p for lid in run.shaded_lanes if lid in lanes for p in lanes[lid].centerline]
    pts += [(e.step.x_m, e.step.y_m) for st in steps for e in frame(run, st).egos]
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    (_, cy), _ = section_axis(run)
    return (min(xs) - margin_m, max(xs) + margin_m, min(min(ys) - 4.0, cy - 12.0),
            max(max(ys) + 4.0, cy + 12.0))


def title(run: MultiRunData) -> str:
    mode = f" · coordination {run.mode}" if run.mode else ""
    method = f" · {run.method}" if run.method else ""
    ends = ", ".join(f"{eid} {run.outcomes.get(eid, run.records[eid].outcome)}"
                     for eid in run.ego_ids)
    return f"{run.family} seed {run.seed}{method}{mode} · {ends}"


def _legend(ax: Axes, run: MultiRunData, *, figure_bottom: bool = False) -> None:
    handles = [Polygon(np.zeros((3, 2)), facecolor=run.colour(eid), edgecolor="black",
                       label=eid) for eid in run.ego_ids]
    handles += [Polygon(np.zeros((3, 2)), facecolor="white", edgecolor=YIELD, lw=2.5,
                        label="yielding (command in force)"),
                Polygon(np.zeros((3, 2)), facecolor=OTHER, edgecolor="black",
                        label="other vehicle")]
    if run.shaded_lanes:
        handles.append(Polygon(np.zeros((3, 2)), facecolor=SECTION, alpha=0.45,
                               label="one-lane section"))
    if figure_bottom:
        ax.figure.legend(handles=handles, loc="lower center", ncol=len(handles),
                         fontsize=8 if figure_bottom else 6, frameon=False)
    else:
        ax.legend(handles=handles, loc="lower left", fontsize=6, framealpha=0.9)


def render_multi_strip(run: MultiRunData, *, out: Path, instants: int = 4,
                       margin_m: float = 10.0, level: bool = True, dpi: int = 120) -> Path:
    """The encounter at ``instants`` instants (``encounter_steps``), one panel per row,
    the same window each (the section and the egos at those instants, ``margin_m``
    beyond); ``level``: rotated so the section runs left to right."""
    if level:
        run = levelled(run)
    picks = encounter_steps(run, instants)
    window = _window(run, picks, margin_m)
    aspect = (window[3] - window[2]) / max(window[1] - window[0], 1e-6)
    width_in = 12.0
    row_in = max(width_in * aspect, 1.3) + 0.35
    fig, axes = plt.subplots(len(picks), 1, figsize=(width_in, row_in * len(picks) + 0.5),
                             squeeze=False)
    for row, (ax, st) in enumerate(zip(axes[:, 0], picks)):
        _draw_static(ax, run)
        fr = frame(run, st)
        _draw_frame(ax, run, fr)
        x0, x1, y0, y1 = fit_to_axes(ax, window)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_xticks([])
        ax.set_yticks([])
        gone = f" · off the road: {', '.join(fr.done)}" if fr.done else ""
        who = ", ".join(f"{e.ego_id} yields{' (holding)' if e.holding else ''}"
                        for e in fr.egos if e.yielding) or "nobody yields"
        ax.set_title(f"({row + 1}) t = {fr.t_s:.1f} s · {who}{gone}", fontsize=9, loc="left")
    _legend(axes[0, 0], run, figure_bottom=True)
    fig.suptitle(title(run), fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return save_figure(fig, out, dpi=dpi)


def render_multi_gif(run: MultiRunData, *, out: Path, every_k: int = 4, fps: float = 8.0,
                     width_px: int = 800, margin_m: float = 10.0, level: bool = True,
                     max_frames: int = 150, max_bytes: int = 2_000_000) -> Path:
    """Animated GIF of the whole run (every ``every_k``-th step) in the strip's window
    (vehicles outside it are cut off),
    kept under ``max_bytes`` (re-rendered with half the frames and a smaller canvas, up to
    three times)."""
    from PIL import Image

    if level:
        run = levelled(run)
    last = run.last_step
    if last < 1:
        raise RenderError("the records have no steps to draw")
    if every_k < 1:
        raise RenderError(f"every_k must be >= 1, got {every_k}")
    every_k = max(every_k, math.ceil(last / max_frames))

    def frames_for(every_k: int, width_px: int) -> list[Any]:
        steps = list(range(1, last + 1, every_k))
        if steps[-1] != last:
            steps.append(last)
        window = _window(run, encounter_steps(run), margin_m)
        aspect = (window[3] - window[2]) / max(window[1] - window[0], 1e-6)
        width_in = width_px / 100
        height_in = min(max(width_in * aspect, 1.6), width_in * 1.2) + 0.65
        fig, ax = plt.subplots(figsize=(width_in, height_in), dpi=100)
        fig.subplots_adjust(left=0.01, right=0.99, bottom=0.3 / height_in,
                            top=1 - 0.35 / height_in)
        _draw_static(ax, run)
        ax.set_xlim(*fit_to_axes(ax, window)[:2])
        ax.set_ylim(*fit_to_axes(ax, window)[2:])
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title(run), fontsize=8)
        _legend(ax, run, figure_bottom=True)
        text = ax.text(0.01, 0.98, "", transform=ax.transAxes, va="top", ha="left",
                       fontsize=7, family="monospace", zorder=10, animated=True,
                       bbox=dict(boxstyle="round,pad=0.3", fc="white", ec="#999999",
                                 alpha=0.9))
        canvas = cast(FigureCanvasAgg, fig.canvas)
        canvas.draw()
        background = canvas.copy_from_bbox(fig.bbox)
        frames: list[Any] = []
        dynamic: list[Any] = []
        for st in steps:
            for artist in dynamic:
                artist.remove()
            fr = frame(run, st)
            dynamic = _draw_frame(ax, run, fr)
            lines = [f"t = {fr.t_s:5.1f} s"]
            lines += [f"{e.ego_id}: {'YIELDS' if e.yielding else 'goes'}"
                      f"{' (holding)' if e.holding else ''}" for e in fr.egos]
            lines += [f"{eid}: off the road" for eid in fr.done]
            text.set_text("\n".join(lines))
            canvas.restore_region(background)
            for artist in (*sorted(dynamic, key=lambda a: a.get_zorder()), text):
                ax.draw_artist(artist)
            rgba = np.asarray(canvas.buffer_rgba())
            frames.append(Image.fromarray(rgba[..., :3].copy()).quantize(
                colors=64, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE))
        plt.close(fig)
        return frames

    return save_gif_under(out, frames_for, every_k=every_k, width_px=width_px, fps=fps,
                          max_bytes=max_bytes)
