"""Scenes of a method: one in a worker process (``run_scene``), many in parallel workers
(``run_scenes``, which keeps every finished row through an interrupt), on the local
process pool or Ray (``executors``).

A method's planner and controller come from ``build(spec)``, a factory of the
composition root (``scripts/methods.py``): this module knows neither the planner nor
the MPC, only the Protocols of ``lmpc_bridge.runner``. Both ``build`` and ``prepare``
must be module-level functions (they are sent to the worker processes by name).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import signal
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from lmpc_bridge.evaluation.executors import Executor, make_executor
from lmpc_bridge.evaluation.rows import (
    Latency,
    error_row,
    latency_cells,
    percentile,
    scene_log_name,
    write_rows,
)
from lmpc_bridge.evaluation.situations import situation_metrics
from lmpc_bridge.evaluation.style import style_metrics
from lmpc_bridge.runner import ControllerLike, PlannerLike, run_episode

FAMILY_MAX_TIME_S = 200.0
"""The episode cap of a family scene (a scene file carries its own)."""


@dataclass(frozen=True)
class SceneSpec:
    """What a method's factory needs to build its planner and controller for one scene.

    ``instruction``: the user's text for the planner; ``log_path``: the planner's decision
    log of the scene; ``replay``: (run folder, recorded method) whose log of the scene
    ``lmpc-replay`` answers from; ``latency``: the (decision, emergency) latency to
    simulate; ``planner_config``: the planner YAML instead of the packaged one;
    ``backend``: a backend object that replaces the one the method names (a tool that
    wraps or swaps the backend, e.g. ``planner_stats.py``); ``method_options``: the
    method's own settings as (name, value) pairs (e.g. the oracle's lookahead), the
    method's factory checks them."""

    method: str
    family: str
    seed: int
    instruction: Optional[str] = None
    log_path: Optional[Path] = None
    replay: Optional[tuple[str, str]] = None
    latency: Latency = (None, None)
    planner_config: Optional[Path] = None
    backend: Any = None
    method_options: tuple[tuple[str, Any], ...] = ()


@dataclass
class Wiring:
    """A method's planner (None: the MPC alone) and controller for one scene, and
    ``finish(log_path)``: after the episode, the row cells the method owns
    (``route_overrides``, ``stale_steps``, ``stale_agent_steps``; a replay adds
    ``replay_answered`` / ``replay_unmatched``; ``note`` is appended to ``detail``)."""

    planner: Optional[PlannerLike]
    controller: ControllerLike
    finish: Callable[[Optional[Path]], dict[str, Any]] = field(default=lambda _log: {})


Build = Callable[[SceneSpec], Wiring]


@dataclass(frozen=True)
class RunSettings:
    """What every scene of one run shares (plain values: it is sent to the workers).

    ``scene_file``: a scene description run instead of a family (``family`` and ``seed``
    are then its name and SUMO seed; ``scene_seed``: the seed replaces the file's SUMO and
    background-traffic seeds); ``log_dir``: where the decision logs go."""

    work_dir: str
    scene_file: Optional[str] = None
    instruction: Optional[str] = None
    log_dir: Optional[str] = None
    replay: Optional[tuple[str, str]] = None
    scene_seed: bool = False
    latency: Latency = (None, None)
    planner_config: Optional[str] = None
    method_options: tuple[tuple[str, Any], ...] = ()


_SIM: Any = None  # one SumoSim per worker process (libsumo: one simulation per process)


class _SceneFileSim:
    """Presents one external scene through ``reset(family, seed)``, the call ``run_episode``
    makes; everything else is the worker's ``SumoSim``."""

    def __init__(self, sim: Any, scene: Any) -> None:
        self._sim, self._scene = sim, scene

    def reset(self, family: str, seed: int, *, max_time_s: Optional[float] = None) -> Any:
        return self._sim.reset_scene(self._scene, max_time_s=max_time_s)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)


def run_scene(method: str, family: str, seed: int, settings: RunSettings, build: Build,
              prepare: Optional[Callable[[], None]] = None) -> dict[str, Any]:
    """One episode in this worker process; returns its results row. Anything that raises
    gives an ``error`` row with the reason (exceptions holding SUMO objects do not
    pickle). ``prepare``: called before the worker's first scene (e.g. compiling the
    solver), outside the scene's wall time. A replay row also carries
    ``replay_answered`` / ``replay_unmatched``, which ``results.csv`` does not keep."""
    try:
        return _run_scene(method, family, seed, settings, build, prepare)
    except Exception as exc:  # noqa: BLE001 - one broken scene must not end the run
        return error_row(method, family, seed, f"{type(exc).__name__}: {exc}",
                         settings.latency)


def _run_scene(method: str, family: str, seed: int, settings: RunSettings, build: Build,
               prepare: Optional[Callable[[], None]]) -> dict[str, Any]:
    global _SIM
    from lmpc_bridge.sim import SumoSim

    work_dir = Path(settings.work_dir) / f"worker-{os.getpid()}"
    if _SIM is None:
        # a scene folder per worker: two workers must never write the same scene files
        _SIM = SumoSim(work_dir=work_dir)
        if prepare is not None:
            prepare()
    started = time.perf_counter()
    sim, max_time_s = _SIM, FAMILY_MAX_TIME_S
    log_path = None if settings.log_dir is None else \
        Path(settings.log_dir) / scene_log_name(family, seed, method)
    if log_path is not None:
        log_path.unlink(missing_ok=True)  # a rerun into the same folder starts the log afresh
    if settings.scene_file is not None:
        from lmpc_bridge.scenarios.external import build_external_scene

        scene = build_external_scene(settings.scene_file, work_dir=work_dir,
                                     seed=seed if settings.scene_seed else None)
        sim, max_time_s = _SceneFileSim(_SIM, scene), scene.max_time_s
    wiring = build(SceneSpec(
        method=method, family=family, seed=seed, instruction=settings.instruction,
        log_path=log_path, replay=settings.replay, latency=settings.latency,
        planner_config=Path(settings.planner_config) if settings.planner_config else None,
        method_options=settings.method_options))
    result = run_episode(sim, family=family, seed=seed, controller=wiring.controller,
                         planner=wiring.planner, max_time_s=max_time_s)
    own = wiring.finish(log_path)
    m = result.metrics
    # external scenes: demand that never reached the episode (issue 21: a recorded file
    # starting at 7:00 on a scene starting at 0 "reached" with every penalty 0)
    notes = ([result.detail] if result.detail else []) + [
        f"traffic: {w}" for w in sim.traffic_warnings()]
    detail = "; ".join(notes)
    note = own.pop("note", None)
    if note:
        detail = f"{detail}; {note}" if detail else note
    return {
        "family": family, "seed": seed, "method": method, "outcome": result.outcome,
        "collision": int(result.outcome == "collision"),
        # off_route is a failure of its own (also counted in "off_route"): the ego drove
        # onto a road not on its route (docs/METRICS.md)
        "fail": int(result.outcome in ("timeout", "off_route", "error")),
        "off_route": int(result.outcome == "off_route"),
        "time_s": round(m.time_s, 3), "ineff": round(m.ineff, 4), "pen_acc": round(m.pen_acc, 4),
        "pen_dist": round(m.pen_dist, 4), "overall_cost": round(m.overall_cost, 4),
        "decisions": result.decisions, "fallbacks": result.fallbacks, "steps": m.steps,
        "solve_ms_median": round(statistics.median(result.solve_times_ms), 3)
        if result.solve_times_ms else math.nan,
        "solve_ms_p99": round(percentile(result.solve_times_ms, 0.99), 3),
        "compute_ms_median": round(statistics.median(result.compute_wall_ms), 3)
        if result.compute_wall_ms else math.nan,
        "compute_ms_p99": round(percentile(result.compute_wall_ms, 0.99), 3),
        "wall_s": round(time.perf_counter() - started, 2),
        **latency_cells(method, settings.latency),
        "held_insertions": result.record.held_insertions,
        "shadows": result.record.shadows,
        "detail": detail,
        # the style and situation figures (lmpc_bridge.evaluation.style / .situations);
        # not columns of results.csv
        **style_metrics(result.record),
        **situation_metrics(result.record),
        **own,
    }


def run_scene_shipped(method: str, family: str, seed: int, settings: RunSettings,
                      build: Build, prepare: Optional[Callable[[], None]] = None
                      ) -> tuple[dict[str, Any], Optional[str]]:
    """``run_scene`` for a worker that may not share the driver's file system (a Ray
    node): the decision log goes to a folder of this process and comes back as text
    (None: the scene wrote none), for the driver to write into ``settings.log_dir``."""
    if settings.log_dir is None:
        return run_scene(method, family, seed, settings, build, prepare), None
    # in the run's scratch folder (a worker killed mid-scene leaves it there, as its scenes)
    scratch = Path(settings.work_dir)
    scratch.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"logs-{os.getpid()}-", dir=scratch) as local_dir:
        here = dataclasses.replace(settings, log_dir=local_dir)
        row = run_scene(method, family, seed, here, build, prepare)
        log = Path(local_dir) / scene_log_name(family, seed, method)
        return row, log.read_text() if log.exists() else None


def run_scenes(jobs: Sequence[tuple[str, str, int]], settings: RunSettings, *, build: Build,
               prepare: Optional[Callable[[], None]] = None, workers: int = 1,
               rows: list[dict[str, Any]], results_csv: Path,
               progress: Optional[Callable[[int, dict[str, Any], float], None]] = None,
               executor: str | Executor = "pool") -> bool:
    """Run ``jobs`` ((method, family, seed)) in ``workers`` processes, appending each
    finished row to ``rows`` and rewriting ``results_csv`` after each (a long run keeps
    every finished scene). ``progress(done, row, elapsed_s)`` after each row. Ctrl-C or
    SIGTERM ends the run: the running scenes are abandoned, their workers killed, and
    True is returned (``rows`` then holds what finished).

    ``executor``: ``pool`` (local processes) or ``ray`` (Ray tasks on a local Ray or the
    cluster at ``RAY_ADDRESS``; the decision logs come back to this process:
    ``executors``), started and closed here; or an executor the caller started (e.g.
    one Ray for several calls), left open. Raises ``ExecutorError`` when the executor
    cannot start."""
    kept = len(rows)
    interrupted = False
    ex = make_executor(executor, workers) if isinstance(executor, str) else executor
    shipped = ex.name != "pool"
    fn: Callable[..., Any] = run_scene_shipped if shipped else run_scene
    calls = [(m, f, s, settings, build, prepare) for m, f, s in jobs]
    with ex if isinstance(executor, str) else contextlib.nullcontext(ex):
        t0 = time.monotonic()  # after the executor started: the ETA is about the scenes
        # SIGTERM ends a run as Ctrl-C does: the finished scenes are written, not lost
        # (set after the executor started: ray.init installs its own handler)
        signal.signal(signal.SIGTERM, raise_interrupt)
        try:
            for i, result in ex.results(fn, calls):
                m, f, s = jobs[i]
                if isinstance(result, BaseException):
                    row = error_row(m, f, s, f"{type(result).__name__}: {result}",
                                    settings.latency)
                elif shipped:
                    row, log = result
                    _write_log(settings, m, f, s, log)
                else:
                    row = result
                rows.append(row)
                write_rows(results_csv, rows)
                if progress is not None:
                    progress(len(rows) - kept, row, time.monotonic() - t0)
        except KeyboardInterrupt:
            interrupted = True
            # the running scenes are abandoned: stop their workers
            ex.abort()
        finally:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return interrupted


def _write_log(settings: RunSettings, method: str, family: str, seed: int,
               log: Optional[str]) -> None:
    """A shipped decision log into ``settings.log_dir`` (none: a stale one is removed, as
    a worker does before the scene)."""
    if settings.log_dir is None:
        return
    path = Path(settings.log_dir) / scene_log_name(family, seed, method)
    if log is None:
        path.unlink(missing_ok=True)
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(log)


def raise_interrupt(signum: int, frame: Any) -> None:
    """A signal handler that ends a run as Ctrl-C does (SIGTERM: the finished scenes are
    written; also scripts/regret.py)."""
    raise KeyboardInterrupt(f"signal {signum}")
