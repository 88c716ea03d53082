#!/usr/bin/env python3
"""Pictures of scenes, runs and benchmark results (matplotlib; no ROS).

    render.py scene --family usi --seed 0 --out scene.png
    render.py run RUN_DIR [--out run.png] [--gif run.gif]
    render.py run --family usi --seed 0 --method lmpc-rules [--max-time-s 60] --out run.png
    render.py bars RESULTS_DIR                      -> RESULTS_DIR/oc_bars.png

What is drawn and what is approximated (see docs/PICTURES.md):

- Roads are the map's lane centerlines widened to the lane width (mitred
  offsets), junctions are the union of their internal lanes plus the junction
  outline from the SUMO net file when it is available. It is a drawing of the
  ``MapSnapshot``, not SUMO's own renderer.
- Other participants are oriented boxes at the recorded centre, heading and size
  (size from the record; records written before it carried sizes fall back to a
  typical size per kind). The record holds only participants within the ego's
  sensing range, so nobody further away appears.
- "Attended" (red) means: listed in the ``attention`` of the decision in force at
  that step (the step's ``decision_id``, i.e. the decision the MPC used). Runs
  without a planner have no decisions, so every participant is grey.

Only this script imports matplotlib: the packages stay free of plotting code.
``plot_oc_bars``, ``render_scene``, ``render_run`` and ``render_gif`` are the
entry points other scripts (the benchmark) call.
"""
from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import tempfile
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import matplotlib

matplotlib.use("Agg")  # files only; never open a window (headless machines, workers)

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402

from lmpc_msgs_py.messages import Lane, MapSnapshot  # noqa: E402
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams  # noqa: E402

from lmpc_bridge.record import EpisodeRecord, NearbyVehicle, StepRecord  # noqa: E402

METHODS = ("mpc", "lmpc-rules")
MAX_GIF_BYTES = 5_000_000
"""GIFs above this are re-rendered with fewer frames / a smaller canvas."""

# Typical box sizes (length, width) in metres per kind, for records without sizes
# (SUMO default vTypes: passenger 5.0 x 1.8, truck 7.1 x 2.4, bus 12 x 2.5, ...).
_DEFAULT_SIZE_M = {
    "car": (5.0, 1.8), "truck": (7.1, 2.4), "bus": (12.0, 2.5), "motorcycle": (2.2, 0.9),
    "bicycle": (1.6, 0.65), "pedestrian": (0.5, 0.5),
}

_BACKGROUND = "#eef0ea"
_ROAD = "#b9bcc0"
_JUNCTION = "#b1b4b8"
_SIDEWALK = "#dcd6cb"
_BIKE_LANE = "#d9b8b0"
_MARKING = "#ffffff"
_TARGET = "#2e9e4f"
_EGO = "#1f5fd6"
_ATTENDED = "#d62728"
_OTHER = "#8c8c8c"
_WEIGHT_LABELS = (("tracking", "track"), ("action", "action"), ("smoothness", "smooth"),
                  ("safety", "safety"))
_METHOD_COLOURS = {"mpc": "#8c8c8c", "lmpc-rules": "#1f5fd6"}
_EXTRA_COLOURS = ("#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf")


_GRAPH_PLANNERS = {"none": "mpc (graph)", "rules": "lmpc-rules (graph)",
                   "mock": "mock LLM (graph)"}
"""run_graph.py ``--planner`` values as method labels."""


class RenderError(RuntimeError):
    """A picture cannot be made from what was given (missing file, bad record, bad option)."""


# --- data ------------------------------------------------------------------------------
@dataclass(frozen=True)
class DecisionInfo:
    """What a picture shows of one decision (read leniently from a decision log line)."""

    decision_id: str
    stamp_s: float
    source: str
    mode: str
    attention: tuple[str, ...]
    ego_candidate: Optional[int]
    accel_bias_mps2: float
    steer_bias_rad: float
    weights: dict[str, str] = field(default_factory=dict)
    reasoning: str = ""

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "DecisionInfo":
        """From a ``Decision`` dumped as JSON (``model_dump(mode="json")``)."""
        ego = data.get("ego_trajectory") or {}
        return cls(
            decision_id=str(data["decision_id"]), stamp_s=float(data.get("stamp_s", 0.0)),
            source=str(data.get("source", "?")), mode=str(data.get("mode", "normal")),
            attention=tuple(str(a) for a in data.get("attention", ())),
            ego_candidate=ego.get("candidate_id"),
            accel_bias_mps2=_bias(data, "accel_bias_mps2", 0),
            steer_bias_rad=_bias(data, "steer_bias_rad", 1),
            weights={k: str(v) for k, v in (data.get("weights") or {}).items()},
            reasoning=str(data.get("reasoning", "")),
        )


@functools.cache
def _packaged_space() -> Any:
    from lmpc_msgs_py.vocabulary import load_decision_space

    return load_decision_space()


def _bias(data: dict[str, Any], name: str, axis: int) -> float:
    """A decision's bias for the picture: ``Decision@1`` logs carry it (``name``);
    ``Decision@2`` carries interval indices, resolved here in the packaged decision space
    (0.0 when the log names another space or no indices)."""
    if name in data:
        return float(data[name])
    space = _packaged_space()
    try:
        if data.get("space_hash") == space.space_hash:
            return space.bias_for(int(data["accel_interval"]), int(data["steer_interval"]))[axis]
    except (KeyError, IndexError, TypeError, ValueError):
        pass
    return 0.0


@dataclass(frozen=True)
class RunData:
    """Everything a run picture needs: the record, the map and the decisions by id."""

    record: EpisodeRecord
    map: MapSnapshot
    decisions: dict[str, DecisionInfo]
    method: str = ""
    """Label for titles (``mpc``, ``lmpc-rules``, the planner of a graph run...)."""
    net_file: Optional[Path] = None
    """SUMO net file of the scene (junction outlines); None draws lanes only."""
    vehicle: VehicleParams = DEFAULT_VEHICLE

    def attended(self, step: StepRecord) -> frozenset[str]:
        """Ids the decision in force at ``step`` attended (empty without a decision)."""
        info = self.decisions.get(step.decision_id or "")
        return frozenset(info.attention) if info is not None else frozenset()


def read_decision_log(path: Path) -> dict[str, DecisionInfo]:
    """Decisions of a planner ``decisions.jsonl`` by id (lines without a decision skipped)."""
    out: dict[str, DecisionInfo] = {}
    if not path.is_file():
        return out
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except ValueError as exc:
            raise RenderError(f"{path}:{number}: not JSON ({exc}); is it a decisions.jsonl?") \
                from exc
        decision = entry.get("decision") if isinstance(entry, dict) else None
        if isinstance(decision, dict) and "decision_id" in decision:
            info = DecisionInfo.from_json(decision)
            out[info.decision_id] = info
    return out


def scene_map(family: str, seed: int, *, work_dir: Path) -> tuple[MapSnapshot, Any]:
    """Build (or load from ``work_dir``'s cache) the scene and its ``MapSnapshot``."""
    from lmpc_bridge.mapping import build_map
    from lmpc_bridge.scenarios import SceneError, build_scene

    try:
        scene = build_scene(family, seed, work_dir=work_dir)
    except SceneError as exc:
        raise RenderError(f"cannot build scene {family}/{seed}: {exc}") from exc
    snapshot, _ = build_map(scene)
    return snapshot, scene


def load_run(run_dir: Path, *, work_dir: Optional[Path] = None) -> RunData:
    """Read a run folder (``episode.json`` + optional ``decisions.jsonl``) and its map.

    The map is rebuilt from the record's family and seed; a scene cache in
    ``run_dir/scene`` (where the graph's bridge keeps it) is reused when present.
    """
    episode_path = Path(run_dir) / "episode.json"
    if not episode_path.is_file():
        raise RenderError(f"{episode_path} not found: pass a run folder written by "
                          "run_graph.py (or render.py run --save-run)")
    episode = json.loads(episode_path.read_text(encoding="utf-8"))
    if "record" not in episode:
        raise RenderError(f"{episode_path} has no 'record' (episode finished abnormally?)")
    record = EpisodeRecord.model_validate(episode["record"])
    if not record.steps:
        raise RenderError(f"{episode_path}: the record has no steps to draw")
    cache = Path(run_dir) / "scene"
    if work_dir is None:
        work_dir = cache if cache.is_dir() else Path(tempfile.mkdtemp(prefix="lmpc-render-"))
    snapshot, scene = scene_map(record.family, record.seed, work_dir=work_dir)
    method = str(episode.get("method") or "")
    if not method:
        summary = Path(run_dir) / "summary.json"
        if summary.is_file():
            planner = str(json.loads(summary.read_text()).get("planner", ""))
            method = _GRAPH_PLANNERS.get(planner, planner)
    return RunData(record=record, map=snapshot,
                   decisions=read_decision_log(Path(run_dir) / "decisions.jsonl"),
                   method=method, net_file=Path(scene.net_file))


class _RecordingPlanner:
    """Wraps a planner and keeps every decision it makes (for the attention colours)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.decisions: list[Any] = []

    def on_observation(self, obs: Any) -> Any:
        decision = self.inner.on_observation(obs)
        if decision is not None:
            self.decisions.append(decision)
        return decision


def run_in_process(family: str, seed: int, method: str, *, work_dir: Path,
                   max_time_s: Optional[float] = None) -> RunData:
    """Run one episode in this process (as the benchmark does) and return it for drawing.

    ``max_time_s`` caps the episode (outcome ``timeout`` at the cap); None uses the
    scene's own limit. libsumo runs one simulation per process: the simulation is
    closed before returning.
    """
    if method not in METHODS:
        raise RenderError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    from lmpc_bridge.evaluation.scenes import SceneSpec
    from lmpc_bridge.runner import run_episode
    from lmpc_bridge.sim import SumoSim
    from lmpc_scripts.methods import build

    wiring = build(SceneSpec(method, family, seed))
    recorder = _RecordingPlanner(wiring.planner) if wiring.planner is not None else None
    sim = SumoSim(work_dir=Path(work_dir))
    try:
        if max_time_s is None:
            max_time_s = _scene_max_time_s(family, seed, Path(work_dir))
        result = run_episode(sim, family=family, seed=seed, controller=wiring.controller,
                             planner=recorder, max_time_s=float(max_time_s))
        snapshot, scene = sim.map, sim.scene
    finally:
        sim.close()
    decisions = {}
    for decision in (recorder.decisions if recorder is not None else ()):
        info = DecisionInfo.from_json(decision.model_dump(mode="json", by_alias=True))
        decisions[info.decision_id] = info
    return RunData(record=result.record, map=snapshot, decisions=decisions, method=method,
                   net_file=Path(scene.net_file))


def _scene_max_time_s(family: str, seed: int, work_dir: Path) -> float:
    from lmpc_bridge.scenarios import build_scene

    return build_scene(family, seed, work_dir=work_dir).max_time_s


def save_run(run: RunData, run_dir: Path) -> Path:
    """Write ``episode.json`` (record) and ``decisions.jsonl`` so ``load_run`` reads it back."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    record = run.record
    episode = {"scenario": record.family, "seed": record.seed, "method": run.method,
               "outcome": record.outcome, "record": record.to_json()}
    (run_dir / "episode.json").write_text(json.dumps(episode), encoding="utf-8")
    with (run_dir / "decisions.jsonl").open("w", encoding="utf-8") as fh:
        for info in run.decisions.values():
            decision = {"decision_id": info.decision_id, "stamp_s": info.stamp_s,
                        "source": info.source, "mode": info.mode,
                        "attention": list(info.attention),
                        "ego_trajectory": {"candidate_id": info.ego_candidate},
                        "accel_bias_mps2": info.accel_bias_mps2,
                        "steer_bias_rad": info.steer_bias_rad, "weights": info.weights,
                        "reasoning": info.reasoning}
            fh.write(json.dumps({"decision_id": info.decision_id, "stamp_s": info.stamp_s,
                                 "decision": decision}) + "\n")
    return run_dir


# --- geometry --------------------------------------------------------------------------
def offset_polyline(points: Sequence[tuple[float, float]], offset_m: float) -> np.ndarray:
    """The polyline shifted ``offset_m`` to its left (negative: right), mitred joints.

    The mitre length is capped at twice the offset so sharp kinks do not spike.
    """
    pts = np.asarray(points, dtype=float)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    keep = np.concatenate(([True], lengths > 1e-9))
    pts = pts[keep]
    if len(pts) < 2:
        return pts
    seg = np.diff(pts, axis=0)
    seg /= np.hypot(seg[:, 0], seg[:, 1])[:, None]
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # left normals
    vertex_normals = np.empty_like(pts)
    vertex_normals[0], vertex_normals[-1] = normals[0], normals[-1]
    if len(pts) > 2:
        mid = normals[:-1] + normals[1:]
        norm = np.hypot(mid[:, 0], mid[:, 1])[:, None]
        mid = np.where(norm > 1e-9, mid / np.maximum(norm, 1e-9), normals[:-1])
        cos_half = np.sum(mid * normals[:-1], axis=1)[:, None]
        vertex_normals[1:-1] = mid / np.maximum(cos_half, 0.5)
    return pts + offset_m * vertex_normals


def lane_polygon(lane: Lane) -> np.ndarray:
    """The lane's surface: centerline +- half its width."""
    half = lane.width_m / 2.0
    left = offset_polyline(lane.centerline, half)
    right = offset_polyline(lane.centerline, -half)
    return np.concatenate([left, right[::-1]])


def box_corners(x_m: float, y_m: float, yaw_rad: float, length_m: float,
                width_m: float) -> np.ndarray:
    """The four corners of an oriented box centred at (x, y)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    hl, hw = length_m / 2.0, width_m / 2.0
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.array([x_m, y_m])


def agent_size_m(vehicle: NearbyVehicle) -> tuple[float, float]:
    """Recorded (length, width), or a typical size of its kind for older records."""
    if vehicle.length_m and vehicle.width_m:
        return vehicle.length_m, vehicle.width_m
    return _DEFAULT_SIZE_M.get(vehicle.kind, _DEFAULT_SIZE_M["car"])


def point_along(lane: Lane, distance_m: float) -> tuple[float, float, float]:
    """(x, y, heading) at ``distance_m`` along the lane centerline (clamped to its ends)."""
    pts = np.asarray(lane.centerline, dtype=float)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    remaining = min(max(distance_m, 0.0), float(lengths.sum()))
    for (x0, y0), (dx, dy), length in zip(pts[:-1], seg, lengths):
        if length <= 1e-9:
            continue
        if remaining <= length:
            f = remaining / length
            return float(x0 + f * dx), float(y0 + f * dy), math.atan2(dy, dx)
        remaining -= length
    dx, dy = seg[-1]
    return float(pts[-1, 0]), float(pts[-1, 1]), math.atan2(dy, dx)


def junction_outlines(net_file: Optional[Path]) -> list[np.ndarray]:
    """Junction polygons from the SUMO net file (empty when it is missing / unreadable)."""
    if net_file is None or not Path(net_file).is_file():
        return []
    stat = Path(net_file).stat()
    return list(_junction_outlines(str(net_file), stat.st_mtime_ns, stat.st_size))


@functools.lru_cache(maxsize=8)
def _junction_outlines(net_file: str, mtime_ns: int, size: int) -> tuple[np.ndarray, ...]:
    """Cached per file version: a run picture draws the map several times."""
    del mtime_ns, size  # cache key only
    import sumolib

    try:
        net = sumolib.net.readNet(str(net_file), withInternal=True)
    except Exception:  # noqa: BLE001 - the outline is decoration; lanes still get drawn
        return ()
    out = []
    for node in net.getNodes():
        shape = node.getShape()
        if shape and len(shape) >= 3 and node.getType() != "dead_end":
            out.append(np.asarray([(p[0], p[1]) for p in shape], dtype=float))
    return tuple(out)


# --- drawing ---------------------------------------------------------------------------
def _is_sidewalk(lane: Lane) -> bool:
    return tuple(lane.allowed) == ("pedestrian",)


def _is_bike_lane(lane: Lane) -> bool:
    return bool(lane.allowed) and "passenger" not in lane.allowed and "bicycle" in lane.allowed


def draw_map(ax: Axes, snapshot: MapSnapshot, *, net_file: Optional[Path] = None,
             show_route: bool = True, show_target: bool = True,
             marking_lw: float = 0.8) -> None:
    """Roads, junctions, lane markings, stop lines, ego route and target on ``ax``."""
    ax.set_facecolor(_BACKGROUND)
    junctions = junction_outlines(net_file)
    if junctions:
        ax.add_collection(PolyCollection(junctions, facecolors=_JUNCTION, edgecolors=_JUNCTION,
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
    for kind, colour, z in (("walk", _SIDEWALK, 1.1), ("bike", _BIKE_LANE, 1.2),
                            ("junction", _JUNCTION, 1.3), ("road", _ROAD, 1.4)):
        if by_kind[kind]:
            # an edge line of the fill colour closes hairline gaps between adjacent lanes
            ax.add_collection(PolyCollection(by_kind[kind], facecolors=colour,
                                             edgecolors=colour, linewidths=0.6, zorder=z))
    solid, dashed = [], []
    for lane in snapshot.lanes:
        if lane.internal or _is_sidewalk(lane):
            continue
        half = lane.width_m / 2.0
        # each lane draws its left border (dashed towards a neighbour it shares) and its
        # right border only at the road edge, so shared borders are drawn once
        (dashed if lane.left_lane else solid).append(offset_polyline(lane.centerline, half))
        if not lane.right_lane:
            solid.append(offset_polyline(lane.centerline, -half))
    ax.add_collection(LineCollection(solid, colors=_MARKING, linewidths=marking_lw, zorder=2))
    ax.add_collection(LineCollection(dashed, colors=_MARKING, linewidths=marking_lw * 0.8,
                                     linestyles=(0, (4, 4)), zorder=2))
    lanes = {lane.id: lane for lane in snapshot.lanes}
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
    if show_route:
        route = [p for lane_id in snapshot.ego_route if lane_id in lanes
                 for p in lanes[lane_id].centerline]
        if route:
            xs, ys = zip(*route)
            ax.plot(xs, ys, color=_EGO, lw=1.0, ls=(0, (1, 2)), alpha=0.8, zorder=2.5,
                    label="ego route")
    if show_target:
        target = snapshot.target
        ax.add_patch(Circle(target.center, target.radius_m, facecolor=_TARGET, alpha=0.35,
                            edgecolor=_TARGET, lw=1.5, zorder=2.6, label="target area"))
        ax.plot(*target.center, marker="*", color=_TARGET, ms=9, zorder=2.7)
    ax.set_aspect("equal")


def draw_box(ax: Axes, corners: np.ndarray, *, facecolor: str, edgecolor: str = "black",
             alpha: float = 1.0, zorder: float = 5, lw: float = 0.6,
             label: Optional[str] = None) -> Polygon:
    """An oriented box with a small nose triangle (heading) on ``ax``."""
    patch = Polygon(corners, closed=True, facecolor=facecolor, edgecolor=edgecolor,
                    alpha=alpha, lw=lw, zorder=zorder, label=label)
    ax.add_patch(patch)
    return patch


def _nose(corners: np.ndarray) -> np.ndarray:
    """Triangle marking the front of a box (corners 0 and 3 are the front ones)."""
    front_mid = (corners[0] + corners[3]) / 2.0
    centre = corners.mean(axis=0)
    back = front_mid + (centre - front_mid) * 0.5
    side = (corners[0] - corners[3]) * 0.35
    return np.array([front_mid, back + side, back - side])


def ego_start_pose(snapshot: MapSnapshot, depart_pos_m: float,
                   vehicle: VehicleParams = DEFAULT_VEHICLE) -> tuple[float, float, float]:
    """Ego box centre and heading at departure (``depart_pos_m`` is the front bumper)."""
    lanes = {lane.id: lane for lane in snapshot.lanes}
    if not snapshot.ego_route or snapshot.ego_route[0] not in lanes:
        raise RenderError("the map has no ego route: cannot place the ego start")
    return point_along(lanes[snapshot.ego_route[0]], depart_pos_m - vehicle.length_m / 2.0)


def _bounds(points: Iterable[tuple[float, float]], pad_m: float) -> tuple[float, ...]:
    arr = np.asarray(list(points), dtype=float)
    lo, hi = arr.min(axis=0) - pad_m, arr.max(axis=0) + pad_m
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _fit_to_axes(ax: Axes, bounds: tuple[float, ...]) -> tuple[float, ...]:
    """Grow ``bounds`` (about their centre) to the shape of the axes box, so an
    equal-aspect map fills the panel instead of shrinking it."""
    x0, x1, y0, y1 = bounds
    fig_w, fig_h = ax.figure.get_size_inches()
    box = ax.get_position(original=True)  # the slot, not the aspect-shrunk box
    want = (box.height * fig_h) / max(box.width * fig_w, 1e-9)  # height / width
    w, h = x1 - x0, y1 - y0
    if h / max(w, 1e-9) < want:
        grow = (w * want - h) / 2.0
        return x0, x1, y0 - grow, y1 + grow
    grow = (h / want - w) / 2.0
    return x0 - grow, x1 + grow, y0, y1


def _map_points(snapshot: MapSnapshot) -> list[tuple[float, float]]:
    return [p for lane in snapshot.lanes for p in lane.centerline]


def _scene_window(snapshot: MapSnapshot, ego_xy: tuple[float, float], *,
                  pad_m: Optional[float]) -> tuple[float, ...]:
    """Map bounds, or (``pad_m`` given) the ego start, the route's junctions and the
    target padded by ``pad_m`` and clipped to the map: the arms are long, the
    interaction happens near the route."""
    full = _bounds(_map_points(snapshot), 5.0)
    if pad_m is None:
        return full
    lanes = {lane.id: lane for lane in snapshot.lanes}
    pts = [ego_xy, tuple(snapshot.target.center)]
    pts += [p for lane_id in snapshot.ego_route if lane_id in lanes and lanes[lane_id].internal
            for p in lanes[lane_id].centerline]
    x0, x1, y0, y1 = _bounds(pts, pad_m)
    return max(x0, full[0]), min(x1, full[1]), max(y0, full[2]), min(y1, full[3])


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
    draw_box(ax, corners, facecolor=_EGO, zorder=6, label="ego start")
    ax.add_patch(Polygon(_nose(corners), closed=True, facecolor="white", zorder=6.1))
    ax.annotate(f"ego {scene.ego_depart_speed_mps:.1f} m/s", (x, y), xytext=(8, 8),
                textcoords="offset points", fontsize=8, color=_EGO, zorder=7)
    x0, x1, y0, y1 = _scene_window(snapshot, (x, y), pad_m=crop_pad_m)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{family} seed {seed}"
    if scene.description:
        title += "\n" + "\n".join(textwrap.wrap(" ".join(scene.description.split()), 80))
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    return _save(fig, out, dpi=dpi)


def _save(fig: Figure, out: Path, *, dpi: int) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches="tight", facecolor="white")
    plt.close(fig)
    return out


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


def _run_title(run: RunData) -> str:
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


def _draw_agents(ax: Axes, step: StepRecord, attended: frozenset[str], *,
                 labels: bool, zorder: float = 5, alpha: float = 1.0) -> None:
    for v in step.nearby:
        length, width = agent_size_m(v)
        corners = box_corners(v.x_m, v.y_m, v.yaw_rad, length, width)
        colour = _ATTENDED if v.id in attended else _OTHER
        draw_box(ax, corners, facecolor=colour, zorder=zorder, alpha=alpha)
        if labels and v.id in attended:
            ax.annotate(v.id, (v.x_m, v.y_m), xytext=(4, 4), textcoords="offset points",
                        fontsize=6, color=_ATTENDED, zorder=zorder + 1, clip_on=True)


def _draw_ego(ax: Axes, step: StepRecord, vehicle: VehicleParams, *, zorder: float = 6,
              alpha: float = 1.0) -> list[Polygon]:
    corners = box_corners(step.x_m, step.y_m, step.yaw_rad, vehicle.length_m, vehicle.width_m)
    body = draw_box(ax, corners, facecolor=_EGO, zorder=zorder, alpha=alpha)
    nose = Polygon(_nose(corners), closed=True, facecolor="white", zorder=zorder + 0.1,
                   alpha=alpha)
    ax.add_patch(nose)
    return [body, nose]


def _speed_line(ax: Axes, record: EpisodeRecord, *, v_max_mps: float,
                lw: float = 3.0) -> LineCollection:
    xy = np.array([(s.x_m, s.y_m) for s in record.steps])
    speeds = np.array([s.v_mps for s in record.steps])
    segments = np.stack([xy[:-1], xy[1:]], axis=1) if len(xy) > 1 else np.zeros((0, 2, 2))
    line = LineCollection(segments, cmap="plasma", linewidths=lw, zorder=4,
                          capstyle="round")
    line.set_array(speeds[:-1] if len(speeds) > 1 else speeds)
    line.set_clim(0.0, max(v_max_mps, 1.0))
    ax.add_collection(line)
    return line


def _mark_collision(ax: Axes, record: EpisodeRecord, *, ms: float = 22.0) -> None:
    """A ring around the ego at the collision step (the boxes stay visible inside)."""
    if record.outcome == "collision" and record.steps:
        last = record.steps[-1]
        ax.plot(last.x_m, last.y_m, marker="o", ms=ms, mfc="none", mec=_ATTENDED, mew=2.0,
                zorder=9, label="collision", ls="none")


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
    line = _speed_line(ax, rec, v_max_mps=v_max)
    cbar = fig.colorbar(line, ax=ax, fraction=0.03, pad=0.01)
    cbar.set_label("ego speed [m/s]")
    pts = [(s.x_m, s.y_m) for s in rec.steps] + [tuple(rec.target_center)]
    for number, idx in enumerate(picks, start=1):
        step = rec.steps[idx]
        # earlier moments fainter: the snapshots below show each moment on its own
        alpha = 0.35 + 0.65 * number / len(picks)
        _draw_agents(ax, step, run.attended(step), labels=False, zorder=5, alpha=alpha)
        _draw_ego(ax, step, run.vehicle, zorder=6, alpha=alpha)
        ax.annotate(str(number), (step.x_m, step.y_m), xytext=(0, 10 if number % 2 else -16),
                    textcoords="offset points", ha="center", fontsize=9, weight="bold",
                    color=_EGO, zorder=8,
                    bbox=dict(boxstyle="circle,pad=0.15", fc="white", ec=_EGO, lw=0.8))
        pts += [(v.x_m, v.y_m) for v in step.nearby if v.gap_m < window_m / 2]
    _mark_collision(ax, rec)
    x0, x1, y0, y1 = _fit_to_axes(ax, _bounds(pts, 20.0))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_title(_run_title(run), fontsize=11)
    handles = [Polygon(np.zeros((3, 2)), facecolor=_EGO, edgecolor="black", label="ego"),
               Polygon(np.zeros((3, 2)), facecolor=_ATTENDED, edgecolor="black",
                       label="attended by the decision in force"),
               Polygon(np.zeros((3, 2)), facecolor=_OTHER, edgecolor="black",
                       label="not attended")]
    ax.legend(handles=handles + ax.get_legend_handles_labels()[0], loc="best", fontsize=7,
              framealpha=0.9)
    for col, idx in enumerate(picks):
        sub = fig.add_subplot(grid[1, col])
        step = rec.steps[idx]
        draw_map(sub, run.map, net_file=run.net_file, show_route=False, marking_lw=1.2)
        xy = np.array([(s.x_m, s.y_m) for s in rec.steps])
        sub.plot(xy[: idx + 1, 0], xy[: idx + 1, 1], color=_EGO, lw=1.2, alpha=0.6, zorder=4)
        sub.plot(xy[idx:, 0], xy[idx:, 1], color=_EGO, lw=1.0, ls=":", alpha=0.6, zorder=4)
        attended = run.attended(step)
        _draw_agents(sub, step, attended, labels=True)
        _draw_ego(sub, step, run.vehicle)
        half = window_m / 2.0
        sub.set_xlim(step.x_m - half, step.x_m + half)
        sub.set_ylim(step.y_m - half, step.y_m + half)
        sub.set_xticks([])
        sub.set_yticks([])
        n_att = sum(1 for v in step.nearby if v.id in attended)
        if idx == len(rec.steps) - 1:
            _mark_collision(sub, rec, ms=30.0)
        sub.set_title(f"({col + 1}) t = {step.t_s:.1f} s · v = {step.v_mps:.1f} m/s\n"
                      f"attended {n_att} of {len(step.nearby)} in sensing range", fontsize=8)
    return _save(fig, out, dpi=dpi)


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
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(4):
        frames = _gif_frames(run, every_k=every_k, width_px=width_px)
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
    x0, x1, y0, y1 = _bounds(pts, 15.0)
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
    x0, x1, y0, y1 = _fit_to_axes(ax, (x0, x1, y0, y1))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(_run_title(run) + "   (red: attended, grey: not)", fontsize=9)
    xy = np.array([(s.x_m, s.y_m) for s in rec.steps])
    (trail,) = ax.plot([], [], color=_EGO, lw=1.5, alpha=0.7, zorder=4)
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
    fig.canvas.draw()
    background = fig.canvas.copy_from_bbox(fig.bbox)
    dynamic: list[Any] = []
    for idx in indices:
        for artist in dynamic:
            artist.remove()
        step = rec.steps[idx]
        n_patches, n_texts, n_lines = len(ax.patches), len(ax.texts), len(ax.lines)
        _draw_agents(ax, step, run.attended(step), labels=True)
        _draw_ego(ax, step, run.vehicle)
        status = ""
        if idx == len(rec.steps) - 1 and rec.outcome != "running":
            status = f"   [{rec.outcome}]"
            _mark_collision(ax, rec)
        dynamic = (list(ax.patches[n_patches:]) + list(ax.texts[n_texts:])
                   + list(ax.lines[n_lines:]))
        trail.set_data(xy[: idx + 1, 0], xy[: idx + 1, 1])
        text.set_text(f"t = {step.t_s:5.1f} s   v = {step.v_mps:4.1f} m/s   "
                      f"a = {step.applied_accel_mps2:+4.1f} m/s²   "
                      f"mode {step.control_mode or '-'}{status}\n"
                      + _decision_text(run, step))
        fig.canvas.restore_region(background)
        for artist in (trail, *sorted(dynamic, key=lambda a: a.get_zorder()), text):
            ax.draw_artist(artist)
        rgba = np.asarray(fig.canvas.buffer_rgba())
        image = Image.fromarray(rgba[..., :3].copy())
        frames.append(image.quantize(colors=128, method=Image.Quantize.FASTOCTREE,
                                     dither=Image.Dither.NONE))
    plt.close(fig)
    return frames


def plot_oc_bars(summary: dict[str, Any], out: Path, *, dpi: int = 150) -> Path:
    """Bar chart of the mean overall cost (O.C.) per scenario family and method.

    ``summary`` is a benchmark ``summary.json`` (``{"families": {family: {method:
    {"overall_cost", "collisions", "fails", ...}}}}``) or its ``families`` part.
    Each bar is labelled with its O.C., collisions (C) and fails (F); non-MPC bars
    also carry the relative O.C. change against ``mpc`` when the summary has it.
    """
    families = summary.get("families", summary)
    if not isinstance(families, dict) or not families:
        raise RenderError("summary has no families: expected {'families': {family: "
                          "{method: {'overall_cost': ...}}}}")
    names = list(families)
    methods: list[str] = []
    for fam in names:
        if not isinstance(families[fam], dict):
            raise RenderError(f"summary family {fam!r}: expected a dict of methods")
        for method in families[fam]:
            if method not in methods:
                methods.append(method)
    methods.sort(key=lambda m: (m != "mpc", m))
    width = min(0.8 / max(len(methods), 1), 0.3)  # one family: no slab-wide bars
    fig, ax = plt.subplots(figsize=(max(5.5, 0.8 * len(names) * max(len(methods), 1) + 2),
                                    4.2))
    top = 0.0
    for j, method in enumerate(methods):
        colour = _METHOD_COLOURS.get(method, _EXTRA_COLOURS[j % len(_EXTRA_COLOURS)])
        xs, heights, labels = [], [], []
        for i, fam in enumerate(names):
            agg = families[fam].get(method)
            if not agg or agg.get("overall_cost") is None:
                continue
            oc = float(agg["overall_cost"])
            if not math.isfinite(oc):
                continue
            xs.append(i + (j - (len(methods) - 1) / 2) * width)
            heights.append(oc)
            label = f"{oc:.1f}\nC{agg.get('collisions', 0)} F{agg.get('fails', 0)}"
            change = agg.get("oc_change_vs_mpc")
            if method != "mpc" and change is not None:
                label += f"\n{float(change):+.0%}"
            labels.append(label)
        bars = ax.bar(xs, heights, width=width * 0.92, color=colour, label=method,
                      edgecolor="black", linewidth=0.5)
        ax.bar_label(bars, labels=labels, fontsize=7, padding=2)
        top = max([top, *heights])
    ax.set_xticks(range(len(names)))
    ax.set_xlim(-0.6, len(names) - 0.4)
    scenes = [next((a.get("scenes") for a in families[n].values() if a.get("scenes")), None)
              for n in names]
    ax.set_xticklabels([n.upper() + (f"\n({k} scenes)" if k else "")
                        for n, k in zip(names, scenes)])
    ax.set_ylabel("overall cost O.C. (lower is better)")
    ax.set_ylim(0, top * 1.35 if top > 0 else 1.0)
    ax.set_title("Mean overall cost per scenario family (C = collisions, F = fails)",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    return _save(fig, out, dpi=dpi)


# --- command line ----------------------------------------------------------------------
def _parse(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    sc = sub.add_parser("scene", help="bird's-eye PNG of a scene")
    sc.add_argument("--family", required=True)
    sc.add_argument("--seed", type=int, default=0)
    sc.add_argument("--out", type=Path, default=None, help="default <family>_<seed>_scene.png")
    sc.add_argument("--work-dir", type=Path, default=None, help="scene cache folder")
    sc.add_argument("--full", action="store_true", help="the whole map, not the route area")
    rn = sub.add_parser("run", help="a run: path by speed, key moments, optional GIF")
    rn.add_argument("run_dir", type=Path, nargs="?", help="run folder with episode.json")
    rn.add_argument("--family", help="run this family in-process instead of reading a folder")
    rn.add_argument("--seed", type=int, default=0)
    rn.add_argument("--method", choices=METHODS, default="lmpc-rules")
    rn.add_argument("--max-time-s", type=float, default=None, help="cap an in-process run")
    rn.add_argument("--save-run", type=Path, default=None,
                    help="write the in-process run's episode.json / decisions.jsonl here")
    rn.add_argument("--out", type=Path, default=None, help="PNG (default RUN_DIR/run.png)")
    rn.add_argument("--gif", type=Path, default=None, help="also write an animated GIF")
    rn.add_argument("--every-k", type=int, default=3, help="GIF: every k-th step")
    rn.add_argument("--work-dir", type=Path, default=None, help="scene cache folder")
    bars = sub.add_parser("bars", help="O.C. bars from a benchmark's summary.json")
    bars.add_argument("results_dir", type=Path)
    bars.add_argument("--out", type=Path, default=None, help="default RESULTS_DIR/oc_bars.png")
    args = ap.parse_args(argv)
    if args.command == "run" and (args.run_dir is None) == (args.family is None):
        ap.error("run: give either RUN_DIR or --family (with --seed / --method)")
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = _parse(argv)
    try:
        if args.command == "scene":
            out = args.out or Path(f"{args.family}_{args.seed}_scene.png")
            print(render_scene(args.family, args.seed, out=out, work_dir=args.work_dir,
                               crop_pad_m=None if args.full else 40.0))
        elif args.command == "run":
            if args.run_dir is not None:
                run = load_run(args.run_dir, work_dir=args.work_dir)
                default_out = args.run_dir / "run.png"
            else:
                work_dir = args.work_dir or Path(tempfile.mkdtemp(prefix="lmpc-render-"))
                run = run_in_process(args.family, args.seed, args.method, work_dir=work_dir,
                                     max_time_s=args.max_time_s)
                default_out = Path(f"{args.family}_{args.seed}_{args.method}_run.png")
                if args.save_run:
                    print(save_run(run, args.save_run))
            print(render_run(run, out=args.out or default_out))
            if args.gif:
                print(render_gif(run, out=args.gif, every_k=args.every_k))
        else:
            path = args.results_dir / "summary.json"
            if not path.is_file():
                raise RenderError(f"{path} not found: pass the --out folder of benchmark.py")
            print(plot_oc_bars(json.loads(path.read_text()),
                               args.out or args.results_dir / "oc_bars.png"))
    except RenderError as exc:
        print(f"render.py: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
