"""Scene type, the family registry and the SUMO tool helpers shared by all families.

A *family* is a generator ``(seed, work_dir) -> Scene``. Generators write plain
SUMO inputs (nodes / edges XML, routes XML) and build the network with SUMO's
own ``netconvert``; everything is cached per (family, seed) under ``work_dir``.
Later families (si, lane, rab, eoa, construction) only add a generator and a
``register_family`` call.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Optional, Protocol
from xml.sax.saxutils import quoteattr

GENERATOR_VERSION = 7
"""Bump when a generator changes; cached scenes of another version are rebuilt."""

DEFAULT_MAX_TIME_S = 200.0


class SceneError(RuntimeError):
    """A scene could not be built (unknown family, SUMO tool failure, bad parameters)."""


@dataclass(frozen=True)
class TargetSpec:
    """Target area of the ego: lanes of the exit edge, a centre point and a radius."""

    edge_id: str
    lane_ids: tuple[str, ...]
    lane_pos_m: float
    """Position of ``center`` along the target lanes (distance from the edge start)."""
    center: tuple[float, float]
    radius_m: float


@dataclass(frozen=True)
class Scene:
    """Everything needed to start one episode: SUMO inputs plus the ego's task."""

    family: str
    seed: int
    net_file: Path
    route_file: Path
    additional_files: tuple[Path, ...]
    ego_route_edges: tuple[str, ...]
    ego_depart_lane: int
    ego_depart_pos_m: float
    """Front-bumper position on the first route edge (SUMO convention)."""
    ego_depart_speed_mps: float
    target: TargetSpec
    max_time_s: float = DEFAULT_MAX_TIME_S
    description: str = ""
    params: dict[str, float | int | str] = field(default_factory=dict, compare=False)
    """Seeded generator parameters, for the record and the docs (not used by the sim)."""
    interaction: str = ""
    """How the generator made sure the ego meets somebody (the 'scene counts' check)."""

    def to_json(self) -> str:
        data = asdict(self)
        for key in ("net_file", "route_file"):
            data[key] = str(data[key])
        data["additional_files"] = [str(p) for p in self.additional_files]
        return json.dumps({"generator_version": GENERATOR_VERSION, "scene": data}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> "Scene":
        data = json.loads(text)["scene"]
        target = TargetSpec(
            edge_id=data["target"]["edge_id"],
            lane_ids=tuple(data["target"]["lane_ids"]),
            lane_pos_m=float(data["target"]["lane_pos_m"]),
            center=(float(data["target"]["center"][0]), float(data["target"]["center"][1])),
            radius_m=float(data["target"]["radius_m"]),
        )
        return cls(
            family=data["family"],
            seed=int(data["seed"]),
            net_file=Path(data["net_file"]),
            route_file=Path(data["route_file"]),
            additional_files=tuple(Path(p) for p in data["additional_files"]),
            ego_route_edges=tuple(data["ego_route_edges"]),
            ego_depart_lane=int(data["ego_depart_lane"]),
            ego_depart_pos_m=float(data["ego_depart_pos_m"]),
            ego_depart_speed_mps=float(data["ego_depart_speed_mps"]),
            target=target,
            max_time_s=float(data["max_time_s"]),
            description=data["description"],
            params=dict(data["params"]),
            interaction=data["interaction"],
        )


class SceneGenerator(Protocol):
    def __call__(self, seed: int, scene_dir: Path) -> Scene: ...


_REGISTRY: dict[str, SceneGenerator] = {}


def register_family(name: str) -> Callable[[SceneGenerator], SceneGenerator]:
    """Decorator: register ``fn(seed, scene_dir) -> Scene`` as the generator of ``name``."""

    def _register(fn: SceneGenerator) -> SceneGenerator:
        if name in _REGISTRY:
            raise SceneError(f"scenario family {name!r} is registered twice")
        _REGISTRY[name] = fn
        return fn

    return _register


def families() -> tuple[str, ...]:
    """Names of the registered scenario families."""
    return tuple(sorted(_REGISTRY))


def unknown_families(names: Iterable[str]) -> Optional[str]:
    """The one message for family names that are not registered (None: all are), so the
    scene builder, the benchmark, the graph runner and training say it the same way."""
    unknown = [name for name in names if name not in _REGISTRY]
    if not unknown:
        return None
    listed = ", ".join(repr(name) for name in unknown)
    plural = "families" if len(unknown) > 1 else "family"
    return f"unknown scenario {plural} {listed}; known: {', '.join(families())}"


def build_scene(family: str, seed: int, *, work_dir: Path) -> Scene:
    """Build (or load from the cache) the scene ``(family, seed)`` under ``work_dir``.

    Deterministic: the same (family, seed) gives the same files and the same Scene.
    """
    unknown = unknown_families([family])
    if unknown:
        raise SceneError(unknown)
    if seed < 0:
        raise SceneError(f"seed must be >= 0, got {seed}")
    scene_dir = Path(work_dir) / family / f"seed_{seed:04d}"
    cache = scene_dir / "scene.json"
    if cache.is_file():
        try:
            cached = json.loads(cache.read_text())
            scene = Scene.from_json(cache.read_text())
            if (cached.get("generator_version") == GENERATOR_VERSION
                    and scene.net_file.is_file() and scene.route_file.is_file()):
                return scene
        except (ValueError, KeyError, TypeError):
            pass  # a broken cache entry is rebuilt below
    scene_dir.mkdir(parents=True, exist_ok=True)
    scene = _REGISTRY[family](seed, scene_dir)
    tmp = cache.with_suffix(".json.tmp")
    tmp.write_text(scene.to_json())
    os.replace(tmp, cache)  # atomic: a half-written cache is never read
    return scene


# --- SUMO tool helpers -----------------------------------------------------------------
def sumo_binary(name: str) -> str:
    """Path of a SUMO binary (``netconvert``, ``sumo``...) from PATH or the eclipse-sumo wheel."""
    found = shutil.which(name)
    if found:
        return found
    try:
        import sumo  # the eclipse-sumo wheel

        candidate = Path(sumo.SUMO_HOME) / "bin" / name
        if candidate.is_file():
            return str(candidate)
    except ImportError:
        pass
    raise SceneError(f"SUMO tool {name!r} not found: install eclipse-sumo or put it on PATH")


def check_sumo_path(path: Path, what: str) -> Path:
    """``path`` if SUMO's tools can be given files under it: they split file options at
    ``,`` (a list of files), so a folder named ``a,b`` fails later with a "could not open"
    error naming only the part before the comma. SceneError naming ``what`` otherwise."""
    if "," in str(path):
        raise SceneError(f"{what} {str(path)!r} contains ',': SUMO reads ',' in a file "
                         "option as a list separator; choose a path without one")
    return path


def run_netconvert(*, nodes_file: Path, edges_file: Path, net_file: Path,
                   extra_args: tuple[str, ...] = ()) -> None:
    """Build ``net_file`` from plain XML with netconvert (SceneError on failure)."""
    cmd = [
        sumo_binary("netconvert"),
        "--node-files", str(nodes_file),
        "--edge-files", str(edges_file),
        "--output-file", str(net_file),
        "--offset.disable-normalization", "true",
        "--no-turnarounds", "true",
        "--junctions.corner-detail", "5",
        "--no-warnings", "true",
        *extra_args,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    if proc.returncode != 0 or not net_file.is_file():
        raise SceneError(f"netconvert failed ({proc.returncode}): {proc.stderr.strip()[:800]}")


def xml_attrs(**attrs: object) -> str:
    """``key="value"`` pairs for hand-written SUMO XML (values escaped)."""
    parts = []
    for key, value in attrs.items():
        if value is None:
            continue
        if isinstance(value, float):
            value = f"{value:.3f}"
        parts.append(f"{key}={quoteattr(str(value))}")
    return " ".join(parts)
