"""Drawing on matplotlib axes: the map (roads, junctions, markings, stop lines, route,
target), oriented boxes for the ego and the participants, the speed-coloured path, the
collision ring; and saving a figure."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional, cast

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon

from lmpc_msgs_py.messages import Lane, MapSnapshot
from lmpc_msgs_py.vehicle import VehicleParams

from lmpc_bridge.record import EpisodeRecord, StepRecord
from lmpc_bridge.render.geometry import (
    agent_size_m,
    box_corners,
    junction_outlines,
    lane_polygon,
    nose,
    offset_polyline,
    point_along,
)

BACKGROUND = "#eef0ea"
ROAD = "#b9bcc0"
JUNCTION = "#b1b4b8"
SIDEWALK = "#dcd6cb"
BIKE_LANE = "#d9b8b0"
MARKING = "#ffffff"
TARGET = "#2e9e4f"
EGO = "#1f5fd6"
ATTENDED = "#d62728"
OTHER = "#8c8c8c"


def _is_sidewalk(lane: Lane) -> bool:
    return tuple(lane.allowed) == ("pedestrian",)


def _is_bike_lane(lane: Lane) -> bool:
    return bool(lane.allowed) and "passenger" not in lane.allowed and "bicycle" in lane.allowed


def draw_map(ax: Axes, snapshot: MapSnapshot, *, net_file: Optional[Path] = None,
             show_route: bool = True, show_target: bool = True,
             marking_lw: float = 0.8) -> None:
    """Roads, junctions, lane markings, stop lines, ego route and target on ``ax``."""
    ax.set_facecolor(BACKGROUND)
    _draw_surfaces(ax, snapshot, net_file)
    _draw_markings(ax, snapshot, marking_lw)
    lanes = {lane.id: lane for lane in snapshot.lanes}
    _draw_stop_lines(ax, snapshot, lanes, marking_lw)
    if show_route:
        route = [p for lane_id in snapshot.ego_route if lane_id in lanes
                 for p in lanes[lane_id].centerline]
        if route:
            xs, ys = zip(*route)
            ax.plot(xs, ys, color=EGO, lw=1.0, ls=(0, (1, 2)), alpha=0.8, zorder=2.5,
                    label="ego route")
    if show_target:
        target = snapshot.target
        ax.add_patch(Circle(target.center, target.radius_m, facecolor=TARGET, alpha=0.35,
                            edgecolor=TARGET, lw=1.5, zorder=2.6, label="target area"))
        ax.plot(*target.center, marker="*", color=TARGET, ms=9, zorder=2.7)
    ax.set_aspect("equal")


def _draw_surfaces(ax: Axes, snapshot: MapSnapshot, net_file: Optional[Path]) -> None:
    """Junction outlines, then sidewalks, bike lanes, junction lanes and roads."""
    junctions = junction_outlines(net_file)
    if junctions:
        ax.add_collection(PolyCollection(junctions, facecolors=JUNCTION, edgecolors=JUNCTION,
                                         linewidths=0.5, zorder=1))
    by_kind: dict[str, list[np.ndarray]] = {"road": [], "junction": [], "walk": [], "bike": []}
    for lane in snapshot.lanes:
        poly = lane_polygon(lane)
        if _is_sidewalk(lane):
            by_kind["walk"].append(poly)
        elif _is_bike_lane(lane):
            by_kind["bike"].append(poly)
        else:
            by_kind["junction" if lane.internal else "road"].append(poly)
    for kind, colour, z in (("walk", SIDEWALK, 1.1), ("bike", BIKE_LANE, 1.2),
                            ("junction", JUNCTION, 1.3), ("road", ROAD, 1.4)):
        if by_kind[kind]:
            # an edge line of the fill colour closes hairline gaps between adjacent lanes
            ax.add_collection(PolyCollection(by_kind[kind], facecolors=colour,
                                             edgecolors=colour, linewidths=0.6, zorder=z))


def _draw_markings(ax: Axes, snapshot: MapSnapshot, marking_lw: float) -> None:
    """Lane borders: dashed between lanes of one direction, solid at the road edge."""
    solid: list[np.ndarray] = []
    dashed: list[np.ndarray] = []
    for lane in snapshot.lanes:
        if lane.internal or _is_sidewalk(lane):
            continue
        half = lane.width_m / 2.0
        # each lane draws its left border (dashed towards a neighbour it shares) and its
        # right border only at the road edge, so shared borders are drawn once
        (dashed if lane.left_lane else solid).append(offset_polyline(lane.centerline, half))
        if not lane.right_lane:
            solid.append(offset_polyline(lane.centerline, -half))
    ax.add_collection(LineCollection(solid, colors=MARKING, linewidths=marking_lw, zorder=2))
    ax.add_collection(LineCollection(dashed, colors=MARKING, linewidths=marking_lw * 0.8,
                                     linestyles=(0, (4, 4)), zorder=2))


def _draw_stop_lines(ax: Axes, snapshot: MapSnapshot, lanes: dict[str, Lane],
                     marking_lw: float) -> None:
    """Stop lines across their lane's end: red when signal-controlled."""
    stop_segments, stop_colours = [], []
    for stop in snapshot.stop_lines:
        lane = lanes.get(stop.lane_id)
        if lane is None or _is_sidewalk(lane):
            continue
        x, y, heading = point_along(lane, lane.length_m + 1e3)
        nx, ny = -math.sin(heading) * lane.width_m / 2, math.cos(heading) * lane.width_m / 2
        stop_segments.append([(x - nx, y - ny), (x + nx, y + ny)])
        stop_colours.append("#c0392b" if stop.signalized else "#f5f5f5")
    if stop_segments:
        ax.add_collection(LineCollection(stop_segments, colors=stop_colours,
                                         linewidths=marking_lw * 2.2, zorder=2.1))


def draw_box(ax: Axes, corners: np.ndarray, *, facecolor: str, edgecolor: str = "black",
             alpha: float = 1.0, zorder: float = 5, lw: float = 0.6,
             label: Optional[str] = None) -> Polygon:
    """An oriented box with a small nose triangle (heading) on ``ax``."""
    patch = Polygon(corners, closed=True, facecolor=facecolor, edgecolor=edgecolor,
                    alpha=alpha, lw=lw, zorder=zorder, label=label)
    ax.add_patch(patch)
    return patch


def fit_to_axes(ax: Axes, bounds: tuple[float, ...]) -> tuple[float, ...]:
    """Grow ``bounds`` (about their centre) to the shape of the axes box, so an
    equal-aspect map fills the panel instead of shrinking it."""
    x0, x1, y0, y1 = bounds
    fig_w, fig_h = cast(Figure, ax.figure).get_size_inches()
    box = ax.get_position(original=True)  # the slot, not the aspect-shrunk box
    want = (box.height * fig_h) / max(box.width * fig_w, 1e-9)  # height / width
    w, h = x1 - x0, y1 - y0
    if h / max(w, 1e-9) < want:
        grow = (w * want - h) / 2.0
        return x0, x1, y0 - grow, y1 + grow
    grow = (h / want - w) / 2.0
    return x0 - grow, x1 + grow, y0, y1


def save_figure(fig: Figure, out: Path, *, dpi: int) -> Path:
    """Write ``fig`` to ``out`` (folders made) on white and close it."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches="tight", facecolor="white")
    plt.close(fig)
    return out


def draw_agents(ax: Axes, step: StepRecord, attended: frozenset[str], *,
                labels: bool, zorder: float = 5, alpha: float = 1.0) -> None:
    """The participants of ``step`` as boxes: red when attended, grey otherwise."""
    for v in step.nearby:
        length, width = agent_size_m(v)
        corners = box_corners(v.x_m, v.y_m, v.yaw_rad, length, width)
        colour = ATTENDED if v.id in attended else OTHER
        draw_box(ax, corners, facecolor=colour, zorder=zorder, alpha=alpha)
        if labels and v.id in attended:
            ax.annotate(v.id, (v.x_m, v.y_m), xytext=(4, 4), textcoords="offset points",
                        fontsize=6, color=ATTENDED, zorder=zorder + 1, clip_on=True)


def draw_ego(ax: Axes, step: StepRecord, vehicle: VehicleParams, *, zorder: float = 6,
             alpha: float = 1.0) -> list[Polygon]:
    """The ego of ``step`` as a blue box with a white nose."""
    corners = box_corners(step.x_m, step.y_m, step.yaw_rad, vehicle.length_m, vehicle.width_m)
    body = draw_box(ax, corners, facecolor=EGO, zorder=zorder, alpha=alpha)
    front = Polygon(nose(corners), closed=True, facecolor="white", zorder=zorder + 0.1,
                    alpha=alpha)
    ax.add_patch(front)
    return [body, front]


def speed_line(ax: Axes, record: EpisodeRecord, *, v_max_mps: float,
               lw: float = 3.0) -> LineCollection:
    """The ego path of ``record`` coloured by speed (0 .. ``v_max_mps``)."""
    xy = np.array([(s.x_m, s.y_m) for s in record.steps])
    speeds = np.array([s.v_mps for s in record.steps])
    segments: Any = np.stack([xy[:-1], xy[1:]], axis=1) if len(xy) > 1 else np.zeros((0, 2, 2))
    line = LineCollection(segments, cmap="plasma", linewidths=lw, zorder=4,
                          capstyle="round")
    line.set_array(speeds[:-1] if len(speeds) > 1 else speeds)
    line.set_clim(0.0, max(v_max_mps, 1.0))
    ax.add_collection(line)
    return line


def mark_collision(ax: Axes, record: EpisodeRecord, *, ms: float = 22.0) -> None:
    """A ring around the ego at the collision step (the boxes stay visible inside)."""
    if record.outcome == "collision" and record.steps:
        last = record.steps[-1]
        ax.plot(last.x_m, last.y_m, marker="o", ms=ms, mfc="none", mec=ATTENDED, mew=2.0,
                zorder=9, label="collision", ls="none")
