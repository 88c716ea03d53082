"""An in-process episode one step at a time, with exact branching (docs/BRANCHING.md).

``Episode`` is the loop of ``run_episode`` (``lmpc_bridge.runner``) taken apart: per step
``begin_step`` (observe, the controller's control) and ``end_step(decision)`` (hand the
planner's decision to the controller, step SUMO with the control); ``step`` does both
with the episode's planner in between. ``snapshot()`` at any point of that cycle (also
between ``begin_step`` and ``end_step``, where a planner is asked) saves the whole
episode: SUMO's state (``SumoSim.save_state``), the controller's and the planner's
state (their ``snapshot()``), the loop's counters and the pending control.
``restore(snap)`` goes back to it, any number of times; the run from there repeats the
original one to the last digit (``test_bridge_branching.py``). libsumo runs one
simulation per process: branch in the process that runs the episode.

A planner that branches the episode itself (``lmpc-oracle``) gets it through
``attach_episode(episode)`` before the first step.
"""
from __future__ import annotations

import itertools
import math
import os
import pickle
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, TypeVar

from lmpc_msgs_py.messages import Control, Decision
from lmpc_msgs_py.observation import Observation

from lmpc_bridge.sim import SimError, SimState, SumoSim

_NO_PLANNER = object()
_T = TypeVar("_T")


def _finite(control: Control) -> bool:
    return math.isfinite(control.accel_mps2) and math.isfinite(control.steer_rad)


@dataclass(frozen=True)
class EpisodeSnapshot:
    """A branch point of one :class:`Episode` (``Episode.snapshot``)."""

    sim: SimState
    controller: Any
    planner: Any
    loop: dict[str, Any]

    @property
    def time_s(self) -> float:
        return round(self.sim.step_index * 0.1, 6)

    @property
    def step_index(self) -> int:
        return self.sim.step_index


class Episode:
    """One episode of ``sim`` with ``controller`` and ``planner`` (None: the MPC alone),
    run step by step; see the module docstring."""

    _ids = itertools.count()

    def __init__(self, sim: SumoSim, *, family: str, seed: int, controller: Any,
                 planner: Any = None, max_time_s: float = 200.0,
                 state_dir: Optional[Path] = None) -> None:
        self.sim, self.family, self.seed = sim, family, seed
        self.controller, self.planner = controller, planner
        self.max_time_s = max_time_s
        self._state_dir = Path(state_dir) if state_dir is not None else Path(
            tempfile.gettempdir()) / f"lmpc-branch-{os.getpid()}"
        self._snap_ids = itertools.count()
        self._loop: dict[str, Any] = {}

    # -- running --------------------------------------------------------------------------
    def start(self) -> Observation:
        """Reset the simulation (the scene's t = 0) and the loop's counters."""
        obs = self.sim.reset(self.family, self.seed, max_time_s=self.max_time_s)
        self._loop = {"decisions": 0, "fallbacks": 0, "controller_errors": 0,
                      "planner_errors": 0, "solve_ms": [], "wall_ms": [],
                      "last_decision_id": None, "pending": None}
        attach = getattr(self.planner, "attach_episode", None)
        if attach is not None:
            attach(self)
        return obs

    @property
    def running(self) -> bool:
        return self.sim.outcome == "running"

    @property
    def time_s(self) -> float:
        return self.sim.time_s

    @property
    def pending(self) -> Optional[tuple[Observation, Optional[Control]]]:
        """(observation, control) of a step begun and not yet ended, else None."""
        return self._loop["pending"]

    def begin_step(self) -> Observation:
        """Observe and compute this step's control (kept pending); returns the observation."""
        loop = self._loop
        if loop["pending"] is not None:
            raise SimError("begin_step: the step begun before has not ended")
        obs = self.sim.observe(required_decision_id=loop["last_decision_id"])
        control: Optional[Control]
        started = time.perf_counter()
        try:
            control = self.controller.compute(obs)
            if not _finite(control):
                control = None
                loop["controller_errors"] += 1
        except Exception:  # noqa: BLE001 - a controller bug must not kill the benchmark
            control = None
            loop["controller_errors"] += 1
        loop["wall_ms"].append((time.perf_counter() - started) * 1000.0)
        if control is not None:
            loop["solve_ms"].append(control.solve_time_ms)
            if control.mode in ("brake", "shifted"):
                loop["fallbacks"] += 1
        loop["pending"] = (obs, control)
        return obs

    def ask(self, planner: Any, obs: Observation) -> Optional[Decision]:
        """``planner.on_observation(obs)``, an exception counted as no decision."""
        try:
            return planner.on_observation(obs)
        except Exception:  # noqa: BLE001
            self._loop["planner_errors"] += 1
            return None

    def end_step(self, decision: Optional[Decision]) -> None:
        """Hand ``decision`` (if any) to the controller and step with the pending control."""
        loop = self._loop
        if loop["pending"] is None:
            raise SimError("end_step: no step begun")
        _, control = loop["pending"]
        if decision is not None:
            loop["decisions"] += 1
            loop["last_decision_id"] = decision.decision_id
            if decision.source == "fallback":
                loop["fallbacks"] += 1
            refusal = self.controller.on_decision(decision)
            if refusal is not None:
                # in process the planner and the controller were built together: a
                # refused decision is a wiring error, not a fault to ride out
                raise RuntimeError(f"the controller refused a decision: {refusal}")
        loop["pending"] = None
        self.sim.step(control)

    def step(self, planner: Any = _NO_PLANNER) -> None:
        """One step: ``begin_step``, the planner (the episode's unless given; None: none),
        ``end_step``."""
        planner = self.planner if planner is _NO_PLANNER else planner
        obs = self.begin_step()
        decision = self.ask(planner, obs) if planner is not None else None
        self.end_step(decision)

    def run(self, *, until_s: Optional[float] = None, planner: Any = _NO_PLANNER) -> None:
        """Step until the episode ends (or sim time ``until_s``); a step begun is ended
        first (without a decision)."""
        if self._loop.get("pending") is not None:
            self.end_step(None)
        while self.running and (until_s is None or self.time_s < until_s - 1e-9):
            self.step(planner)

    # -- branching ------------------------------------------------------------------------
    def snapshot(self) -> EpisodeSnapshot:
        """The whole episode now (see the module docstring). Raises ``SimError`` when the
        controller or the planner cannot be snapshotted."""
        for name, part in (("controller", self.controller), ("planner", self.planner)):
            if part is not None and not hasattr(part, "snapshot"):
                raise SimError(f"the {name} ({type(part).__name__}) has no snapshot(): this "
                               f"episode cannot be branched")
        path = self._state_dir / f"{next(self._ids)}-{next(self._snap_ids)}.xml"
        loop = dict(self._loop)
        loop["solve_ms"] = tuple(loop["solve_ms"])
        loop["wall_ms"] = tuple(loop["wall_ms"])
        return EpisodeSnapshot(
            sim=self.sim.save_state(path),
            controller=self.controller.snapshot(),
            planner=None if self.planner is None else self.planner.snapshot(),
            loop=loop)

    def restore(self, snap: EpisodeSnapshot, *, planner: bool = True) -> None:
        """Go back to ``snap`` (of this episode). ``planner=False`` leaves the planner as it
        is (a planner that branches the episode from inside its own call)."""
        self.sim.load_state(snap.sim)
        self.controller.restore(snap.controller)
        if planner and self.planner is not None and snap.planner is not None:
            self.planner.restore(snap.planner)
        loop = dict(snap.loop)
        loop["solve_ms"] = list(snap.loop["solve_ms"])
        loop["wall_ms"] = list(snap.loop["wall_ms"])
        self._loop = loop

    def fork(self, fn: Callable[["Episode"], _T]) -> _T:
        """``fn(episode)`` run in a forked copy of this process, its (picklable) result
        returned; this process's episode is left exactly as it was (POSIX ``fork``).

        A branch without a restore: the copy carries everything in memory, SUMO's own
        bookkeeping that its state file lacks included (its best-lanes cache, the
        externally moved ego's links; docs/BRANCHING.md), so the branch is exact and the
        episode goes on as if it had not been taken. Raises ``SimError`` when ``fn``
        raised (named) or the copy died."""
        if not hasattr(os, "fork"):
            raise SimError("Episode.fork needs os.fork (POSIX)")
        sys.stdout.flush()
        sys.stderr.flush()
        read_fd, write_fd = os.pipe()
        pid = os.fork()
        if pid == 0:  # the copy: run, send the result, leave without any clean-up
            code = 0
            try:
                os.close(read_fd)
                try:
                    payload = pickle.dumps((True, fn(self)))
                except BaseException as exc:  # noqa: BLE001 - reported to the parent
                    payload = pickle.dumps((False, f"{type(exc).__name__}: {exc}"[:500]))
                with os.fdopen(write_fd, "wb") as fh:
                    fh.write(payload)
            except BaseException:  # noqa: BLE001
                code = 1
            os._exit(code)
        os.close(write_fd)
        with os.fdopen(read_fd, "rb") as fh:
            data = fh.read()
        os.waitpid(pid, 0)
        if not data:
            raise SimError("the forked branch died without a result")
        ok, value = pickle.loads(data)
        if not ok:
            raise SimError(f"the forked branch failed: {value}")
        return value

    @staticmethod
    def discard(snap: EpisodeSnapshot) -> None:
        """Delete the snapshot's SUMO state file (the snapshot is unusable after)."""
        Path(snap.sim.path).unlink(missing_ok=True)

    # -- result ---------------------------------------------------------------------------
    def result(self) -> Any:
        """The ``EpisodeResult`` so far."""
        from lmpc_bridge.runner import EpisodeResult

        status = self.sim.status()
        loop = self._loop
        return EpisodeResult(
            family=self.family, seed=self.seed, outcome=status.outcome, detail=status.detail,
            metrics=status.metrics, record=self.sim.record(), decisions=loop["decisions"],
            fallbacks=loop["fallbacks"], controller_errors=loop["controller_errors"],
            planner_errors=loop["planner_errors"], solve_times_ms=tuple(loop["solve_ms"]),
            compute_wall_ms=tuple(loop["wall_ms"]))
