"""Runs for the pictures: a run folder read back (``load_run``), written (``save_run``) or
run in this process (``run_in_process``), and the decisions of its planner log.

No plotting here. ``run_in_process`` takes the method's ``build`` factory from the
composition root (``scripts/methods.py``): the bridge imports neither the planner nor
the MPC, only the Protocols of ``lmpc_bridge.runner``.
"""
from __future__ import annotations

import functools
import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

from lmpc_msgs_py.messages import MapSnapshot
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge.record import EpisodeRecord, StepRecord

if TYPE_CHECKING:
    from lmpc_bridge.evaluation.scenes import Build

_GRAPH_PLANNERS = {"none": "mpc (graph)", "rules": "lmpc-rules (graph)",
                   "mock": "mock LLM (graph)"}
"""run_graph.py ``--planner`` values as method labels."""


class RenderError(RuntimeError):
    """A picture cannot be made from what was given (missing file, bad record, bad option)."""


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


def scene_map(family: str, seed: int, *, work_dir: Path,
              scene_file: Optional[str] = None) -> tuple[MapSnapshot, Any]:
    """Build (or load from ``work_dir``'s cache) the scene and its ``MapSnapshot``: the
    family's template, or the scene file a ``--scene`` run drove."""
    from lmpc_bridge.mapping import build_map
    from lmpc_bridge.scenarios import SceneError, build_scene

    try:
        if scene_file:
            from lmpc_bridge.scenarios.external import build_external_scene

            scene = build_external_scene(scene_file, work_dir=work_dir)
        else:
            scene = build_scene(family, seed, work_dir=work_dir)
    except SceneError as exc:
        what = scene_file or f"{family}/{seed}"
        raise RenderError(f"cannot build scene {what}: {exc}") from exc
    snapshot, _ = build_map(scene)
    return snapshot, scene


def load_run(run_dir: Path, *, work_dir: Optional[Path] = None) -> RunData:
    """Read a run folder (``episode.json`` + optional ``decisions.jsonl``) and its map.

    The map is rebuilt from the record's family and seed, or from the scene file a
    ``--scene`` run recorded (``scene_file``); a scene cache in ``run_dir/scene`` (where
    the graph's bridge keeps it) is reused when present.
    """
    episode_path = Path(run_dir) / "episode.json"
    if not episode_path.is_file():
        raise RenderError(f"{episode_path} not found: pass a run folder written by "
                          "run_graph.py (or render.py run --save-run)")
    episode = json.loads(episode_path.read_text(encoding="utf-8"))
    if "record" not in episode:
        if isinstance(episode.get("records"), dict) and episode["records"]:
            raise RenderError(f"{episode_path} is a multi-ego run "
                              f"({', '.join(sorted(episode['records']))}): draw it with "
                              f"render.py multi {run_dir}")
        raise RenderError(f"{episode_path} has no 'record' (episode finished abnormally?)")
    record = EpisodeRecord.model_validate(episode["record"])
    if not record.steps:
        raise RenderError(f"{episode_path}: the record has no steps to draw")
    cache = Path(run_dir) / "scene"
    if work_dir is None:
        work_dir = cache if cache.is_dir() else Path(tempfile.mkdtemp(prefix="lmpc-render-"))
    snapshot, scene = scene_map(record.family, record.seed, work_dir=work_dir,
                                scene_file=episode.get("scene_file"))
    method = str(episode.get("method") or "")
    if not method:
        summary = Path(run_dir) / "summary.json"
        if summary.is_file():
            planner = str(json.loads(summary.read_text()).get("planner", ""))
            method = _GRAPH_PLANNERS.get(planner, planner)
    return RunData(record=record, map=snapshot,
                   decisions=read_decision_log(Path(run_dir) / "decisions.jsonl"),
                   method=method, net_file=Path(scene.net_file))


def run_in_process(family: str, seed: int, method: str, *, build: Build, work_dir: Path,
                   max_time_s: Optional[float] = None,
                   instruction: Optional[str] = None) -> RunData:
    """Run one episode of ``method`` in this process (as the benchmark does) and return it
    for drawing; ``build`` makes the method's planner and controller (the method registry's
    factory, ``lmpc_scripts.methods.build``).

    ``max_time_s`` caps the episode (outcome ``timeout`` at the cap); None uses the
    scene's own limit; ``instruction`` is the user's text for the planner (as
    ``benchmark.py --instruction``). libsumo runs one simulation per process: the simulation is
    closed before returning.
    """
    from lmpc_bridge.evaluation.scenes import SceneSpec
    from lmpc_bridge.runner import RecordingPlanner, run_episode
    from lmpc_bridge.scenarios import SceneError
    from lmpc_bridge.sim import SumoSim

    wiring = build(SceneSpec(method, family, seed, instruction=instruction))
    recorder = RecordingPlanner(wiring.planner) if wiring.planner is not None else None
    sim = SumoSim(work_dir=Path(work_dir))
    try:
        if max_time_s is None:
            max_time_s = _scene_max_time_s(family, seed, Path(work_dir))
        result = run_episode(sim, family=family, seed=seed, controller=wiring.controller,
                             planner=recorder, max_time_s=float(max_time_s))
        snapshot, scene = sim.map, sim.scene
    except SceneError as exc:
        raise RenderError(f"cannot build scene {family}/{seed}: {exc}") from exc
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
