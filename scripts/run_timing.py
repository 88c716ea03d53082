"""Where a graph run's time went (issue 19), for ``run_graph.py``'s summary: the wall split
of the run (start-up, episode) and every node's stage times, and the ``--profile`` table.
Moved out of ``run_graph.py`` unchanged (2026-12-06)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional


PROFILE_FILES = {"mpc": "profile_mpc.json", "planner": "profile_planner.json"}
"""Stage times the MPC and the planner write when they end (the bridge's are in episode.json)."""


def wall_split(episode: dict[str, Any], start_epoch_s: Optional[float]) -> dict[str, object]:
    """``startup_wall_s`` (run start to step 0) and ``episode_wall_s`` (step 0 to the
    episode's end), from the bridge's wall-clock stamps; None where a stamp is missing."""
    step0, end = episode.get("step0_epoch_s"), episode.get("end_epoch_s")
    startup = None if step0 is None or start_epoch_s is None else step0 - start_epoch_s
    span = None if step0 is None or end is None else end - step0
    sim_s = float(episode.get("sim_time_s", 0.0))
    return {"startup_wall_s": None if startup is None else round(startup, 3),
            "episode_wall_s": None if span is None else round(span, 3),
            "episode_real_time_factor": round(sim_s / span, 2) if span else None}


def read_profiles(run_dir: Path, episode: dict[str, Any]) -> dict[str, object]:
    """Per node, per stage: n / median / p99 / max / total ms (``lmpc_msgs_py.profiling``)."""
    out: dict[str, object] = {}
    if episode.get("profile_ms"):
        out["bridge"] = episode["profile_ms"]
    for node, name in PROFILE_FILES.items():
        try:
            out[node] = json.loads((run_dir / name).read_text())["stages_ms"]
        except (OSError, ValueError, KeyError):
            continue  # the node did not run, or died before writing it
    return out


def profile_table(profile: dict[str, Any]) -> str:
    """The ``--profile`` table: one row per node and stage."""
    rows = [f"{'node':8} {'stage':58} {'n':>6} {'median':>8} {'p99':>8} {'max':>8} "
            f"{'total':>9}  (ms)"]
    for node, stages in profile.items():
        for stage, st in stages.items():
            rows.append(f"{node:8} {stage[:58]:58} {st['n']:6d} {st['median']:8.3f} "
                        f"{st['p99']:8.3f} {st['max']:8.3f} {st['total']:9.1f}")
    return "\n".join(rows)
