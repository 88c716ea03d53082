#!/usr/bin/env python3
"""Benchmark: methods x scenario families x seeds, in-process (no ROS), in parallel workers.

The same logic objects as the nodes (DESIGN §1): ``lmpc_bridge.runner.run_episode``
with the MPC controller and, for ``lmpc-*`` methods, the planner core. Writes
``results.csv`` (one row per scene and method), ``table.md`` (the paper's Table I
layout), ``summary.json`` (per family and method, plus the relative O.C.
change of each method against ``mpc``) and, for ``lmpc-*`` methods, each scene's
decision log in ``decisions/<family>-<seed>-<method>.jsonl``.

    benchmark.py --families usi --seeds 0-24 --methods mpc,lmpc-rules --out runs/bench
    benchmark.py --scene examples/city.yaml --methods mpc,lmpc-rules   # your own network
    benchmark.py --scene examples/city.yaml --seeds 0-4   # five scenes: SUMO + traffic seeds
    benchmark.py --families lane --methods lmpc-rules --instruction "drive aggressively"
    benchmark.py --families eoa --methods lmpc-replay --replay-from runs/bench_local  # repeat
    benchmark.py --families si --methods lmpc-rules --decision-latency 2.5  # a slow LLM

``--decision-latency S`` simulates a planner whose decisions take effect S seconds (sim
time) after the observation they used, whatever the backend (the rules reasoner too);
emergency decisions get ``--emergency-latency`` (default min(S, 1.5 s), the paper's
short emergency path). Both are recorded per row and in summary.json.

``lmpc-replay`` repeats a finished run's LLM decisions without the model: each scene
answers from that run's decision log of the scene, matching prompts by hash, with the
recorded method's planner settings (``--replay-of``, default ``lmpc-local``), and is
compared with the recorded row. An exact repeat (every prompt found, same outcome, time
and O.C.) shows the recorded row still holds on the code that replays it.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import signal
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any, Optional, Sequence

METHODS = ("mpc", "lmpc-rules", "lmpc-local", "lmpc-openai", "lmpc-replay")
COLUMNS = ("family", "seed", "method", "outcome", "collision", "fail", "off_route", "time_s",
           "ineff",
           "pen_acc", "pen_dist", "overall_cost", "decisions", "fallbacks", "steps",
           "solve_ms_median", "solve_ms_p99", "compute_ms_median", "compute_ms_p99", "wall_s",
           "route_overrides", "latency_s", "emergency_latency_s", "stale_steps",
           "stale_agent_steps", "detail")
"""``latency_s`` / ``emergency_latency_s``: the simulated decision latencies of the run
(empty: the backend's own, e.g. 0 for rules; always empty for ``mpc``); ``stale_steps`` /
``stale_agent_steps``: steps on which the MPC found the decision in force stale for some
agent, and agent-steps it fell back for (``MpcController`` stats ``stale_*``)."""

_SIM: Any = None  # one SumoSim per worker process (libsumo: one simulation per process)
_SOLVER: Any = None  # one compiled MPC solver per worker (building all sizes takes ~1.5 s)


def parse_seeds(text: str) -> list[int]:
    """``"0-24"`` or ``"0,3,5-7"`` -> sorted unique seeds."""
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, _, hi = part.partition("-")
        seeds.update(range(int(lo), int(hi or lo) + 1))
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r}")
    return sorted(seeds)


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (nan for no values)."""
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def make_planner(method: str, instruction: Optional[str] = None, *,
                 log_path: Optional[Path] = None, replay_log: Optional[Path] = None,
                 replay_of: str = "lmpc-local",
                 latency: tuple[Optional[float], Optional[float]] = (None, None),
                 planner_config: Optional[Path] = None) -> Any:
    """The planner core of ``method`` (None for the ``mpc`` baseline); ``instruction``
    reaches it as the user's text through ``PlannerCore.on_instruction``, as the node's
    ``/lmpc/instruction`` subscription does; ``log_path``: its JSON-lines decision log.
    ``lmpc-replay`` answers from ``replay_log`` (prompts matched by hash only) with the
    planner settings of the method that recorded it, ``replay_of``. ``latency``: (decision,
    emergency) latency to simulate, s (None: the config's), see
    ``lmpc_llm_planner.config.latency_overrides``. ``planner_config``: the
    planner YAML of the LLM methods instead of the packaged one (``lmpc-local``: its own
    ``planner_local.yaml``); the method still names the backend."""
    if method == "mpc":
        return None
    from lmpc_llm_planner.backends import make_backend
    from lmpc_llm_planner.config import (
        LOCAL_CONFIG_PATH,
        latency_overrides,
        load_planner_config,
    )
    from lmpc_llm_planner.planner import PlannerCore
    from lmpc_mpc.config import load_mpc_config

    backend_name = method.removeprefix("lmpc-")
    overrides: dict[str, Any] = {"backend": backend_name}
    settings_of = backend_name
    if backend_name == "replay":
        if replay_log is None:
            raise ValueError("lmpc-replay needs the recorded decision log of the scene")
        # Hash only: a prompt the recording never saw is a miss (and a fallback decision),
        # never a look-alike answer, so "0 unmatched" means the decisions were the recorded ones.
        overrides["replay"] = {"log_path": str(replay_log), "match": "hash"}
        settings_of = replay_of.removeprefix("lmpc-")
    # The small local model needs its own config (a deadline it can meet on a small CPU,
    # a simulated latency: config/planner_local.yaml says why), or every call times out.
    path = planner_config if planner_config is not None else (
        LOCAL_CONFIG_PATH if settings_of == "local" else None)
    if latency != (None, None):
        base = load_planner_config(path, overrides=overrides)
        overrides.update(latency_overrides(*latency, period_s=base.period_s, ttl_s=base.ttl_s))
    config = load_planner_config(path, overrides=overrides)
    core = PlannerCore(config, make_backend(config), load_mpc_config(), log_path=log_path)
    if instruction:
        core.on_instruction(instruction)
    return core


class _SceneFileSim:
    """Presents one external scene through ``reset(family, seed)``, the call ``run_episode``
    makes; everything else is the worker's ``SumoSim``."""

    def __init__(self, sim: Any, scene: Any) -> None:
        self._sim, self._scene = sim, scene

    def reset(self, family: str, seed: int, *, max_time_s: Optional[float] = None) -> Any:
        return self._sim.reset_scene(self._scene, max_time_s=max_time_s)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)


def run_scene(method: str, family: str, seed: int, work_dir: str,
              scene_file: Optional[str] = None,
              instruction: Optional[str] = None,
              log_dir: Optional[str] = None,
              replay: Optional[tuple[str, str]] = None,
              scene_seed: bool = False,
              latency: tuple[Optional[float], Optional[float]] = (None, None),
              planner_config: Optional[str] = None) -> dict[str, Any]:
    """One episode in this worker process; returns its results row.

    With ``scene_file`` the episode runs that scene description (``family`` and
    ``seed`` are then its name and SUMO seed, for the row; ``scene_seed``: ``seed``
    replaces the file's SUMO seed and background-traffic seed). Anything that raises gives
    an ``error`` row with the reason (exceptions holding SUMO objects do not pickle).
    ``instruction``: the user's text for the planner (ignored by ``mpc``); ``log_dir``:
    where the planner's decision log of the scene goes (``<family>-<seed>-<method>.jsonl``);
    ``replay``: (run folder, recorded method) whose log of the scene ``lmpc-replay`` answers
    from (the row then also carries ``replay_answered`` / ``replay_unmatched``, the prompts
    found in the log and not, which ``results.csv`` does not keep); ``latency``: the
    (decision, emergency) latency to simulate (``make_planner``).
    """
    try:
        return _run_scene(method, family, seed, work_dir, scene_file, instruction, log_dir,
                          replay, scene_seed, latency, planner_config)
    except Exception as exc:  # noqa: BLE001 - one broken scene must not end the run
        return error_row(method, family, seed, f"{type(exc).__name__}: {exc}", latency)


def error_row(method: str, family: str, seed: int, detail: str,
              latency: tuple[Optional[float], Optional[float]] = (None, None)
              ) -> dict[str, Any]:
    row: dict[str, Any] = {c: math.nan for c in COLUMNS}
    row.update(family=family, seed=seed, method=method, outcome="error", collision=0, fail=1,
               off_route=0, route_overrides=0, decisions=0, fallbacks=0, steps=0, wall_s=0.0,
               detail=detail, stale_steps=0, stale_agent_steps=0,
               **latency_cells(method, latency))
    return row


def latency_cells(method: str, latency: tuple[Optional[float], Optional[float]]
                  ) -> dict[str, Any]:
    """The row's latency columns: what the run simulated (empty for ``mpc``, which has no
    planner, and where the backend's own latency applies)."""
    dec, emg = latency
    if method == "mpc" or (dec is None and emg is None):
        return {"latency_s": "", "emergency_latency_s": ""}
    if dec is not None and emg is None:
        from lmpc_llm_planner.config import DEFAULT_EMERGENCY_LATENCY_S

        emg = min(dec, DEFAULT_EMERGENCY_LATENCY_S)
    return {"latency_s": "" if dec is None else dec, "emergency_latency_s": emg}


def _run_scene(method: str, family: str, seed: int, work_dir: str,
               scene_file: Optional[str], instruction: Optional[str] = None,
               log_dir: Optional[str] = None,
               replay: Optional[tuple[str, str]] = None,
               scene_seed: bool = False,
               latency: tuple[Optional[float], Optional[float]] = (None, None),
               planner_config: Optional[str] = None) -> dict[str, Any]:
    global _SIM, _SOLVER
    from lmpc_bridge.runner import run_episode
    from lmpc_bridge.sim import SumoSim
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController
    from lmpc_mpc.solver import MpcSolver

    config = load_mpc_config()
    if _SIM is None:
        # a scene folder per worker: two workers must never write the same scene files
        _SIM = SumoSim(work_dir=Path(work_dir) / f"worker-{os.getpid()}")
        _SOLVER = MpcSolver(config)
        _SOLVER.warm_up()
    _SOLVER.reset()  # no warm start carried over from the previous episode
    started = time.perf_counter()
    sim, max_time_s = _SIM, 200.0
    log_path = None if log_dir is None else Path(log_dir) / scene_log_name(family, seed, method)
    if log_path is not None:
        log_path.unlink(missing_ok=True)  # a rerun into the same folder starts the log afresh
    if scene_file is not None:
        from lmpc_bridge.scenarios.external import build_external_scene

        scene = build_external_scene(
            scene_file, work_dir=Path(work_dir) / f"worker-{os.getpid()}",
            seed=seed if scene_seed else None)
        sim, max_time_s = _SceneFileSim(_SIM, scene), scene.max_time_s
    replay_log = None
    if method == "lmpc-replay":
        if replay is None:
            raise ValueError("lmpc-replay needs --replay-from DIR (a finished run folder)")
        replay_log = Path(replay[0]) / "decisions" / scene_log_name(family, seed, replay[1])
        if not replay_log.is_file():
            raise FileNotFoundError(f"no recorded decision log {replay_log}")
    planner = make_planner(method, instruction, log_path=log_path, replay_log=replay_log,
                           replay_of=replay[1] if replay else "lmpc-local", latency=latency,
                           planner_config=Path(planner_config) if planner_config else None)
    controller = MpcController(config, solver=_SOLVER)
    result = run_episode(sim, family=family, seed=seed, controller=controller,
                         planner=planner, max_time_s=max_time_s)
    cstats = controller.stats()
    if log_path is not None and controller.stale_log:
        # the MPC's stale-decision check, per decision it overrode (lmpc_mpc.stale), next
        # to the planner's records of those decisions
        with log_path.open("a", encoding="utf-8") as fh:
            for rec in controller.stale_log.values():
                fh.write(json.dumps({"kind": "mpc_stale_check", **rec.as_dict()}) + "\n")
    m = result.metrics
    # external scenes: demand that never reached the episode (issue 21: a recorded file
    # starting at 7:00 on a scene starting at 0 "reached" with every penalty 0)
    notes = ([result.detail] if result.detail else []) + [
        f"traffic: {w}" for w in sim.traffic_warnings()]
    detail = "; ".join(notes)
    row = {
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
        # decisions whose candidate left the route: the MPC followed the route instead
        "route_overrides": cstats.route_overrides,
        "stale_steps": cstats.stale_steps, "stale_agent_steps": cstats.stale_agent_steps,
        **latency_cells(method, latency),
        "detail": detail,
    }
    if replay_log is not None:
        hits = planner.backend.hits
        row["replay_unmatched"] = hits["miss"]
        row["replay_answered"] = sum(hits.values()) - hits["miss"]
        note = (f"replayed {replay_log.name}: {row['replay_answered']} prompt(s) answered "
                f"from it, {row['replay_unmatched']} not in it")
        row["detail"] = f"{detail}; {note}" if detail else note
    return row


def scene_log_name(family: str, seed: int, method: str) -> str:
    """The file name of one scene's decision log in a run's ``decisions/`` folder."""
    return f"{family}-{seed:03d}-{method}.jsonl"


REPEAT_OC_TOL = 2e-4
"""O.C. difference still counted as a repeat: rows round it to 4 decimals, and a
floating-point difference far below that can move the last digit (seen once in 50 scenes:
eoa seed 5, 395.9955 vs 395.9954, every prompt answered from the log)."""


def replay_check(rows: list[dict[str, Any]], recorded: list[dict[str, Any]],
                 recorded_method: str) -> list[str]:
    """One line per ``lmpc-replay`` row of ``rows``: whether it repeats the row of
    ``recorded`` (same family and seed, ``recorded_method``) exactly: every prompt
    answered from the log, the same outcome and time, O.C. within ``REPEAT_OC_TOL``.
    Resumed rows (read back from results.csv, without the prompt counts) are reported as
    not checked."""
    by_scene = {(r["family"], r["seed"]): r for r in recorded if r["method"] == recorded_method}
    lines = []
    for row in sorted((r for r in rows if r["method"] == "lmpc-replay"),
                      key=lambda r: (r["family"], r["seed"])):
        scene = f"{row['family']} seed {row['seed']}"
        old = by_scene.get((row["family"], row["seed"]))
        if row["outcome"] == "error":
            lines.append(f"{scene}: not checked ({row['detail']})")
        elif "replay_unmatched" not in row:
            lines.append(f"{scene}: not checked (row kept by --resume)")
        elif old is None:
            lines.append(f"{scene}: no recorded {recorded_method} row to compare with")
        else:
            same = (row["outcome"] == old["outcome"] and row["time_s"] == old["time_s"]
                    and abs(row["overall_cost"] - old["overall_cost"]) <= REPEAT_OC_TOL)
            verdict = "exact repeat" if same and row["replay_unmatched"] == 0 else "differs"
            lines.append(
                f"{scene}: {verdict}: {row['replay_unmatched']} of "
                f"{row['replay_unmatched'] + row['replay_answered']} prompt(s) not in the log; "
                f"{row['outcome']} t={row['time_s']}s O.C.={row['overall_cost']} vs recorded "
                f"{old['outcome']} t={old['time_s']}s O.C.={old['overall_cost']}")
    return lines


def _mean(values: Any) -> float:
    finite = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return round(statistics.fmean(finite), 3) if finite else math.nan


def aggregate(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family and method: counts of collisions and fails, means of the rest."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for family in sorted({r["family"] for r in rows}):
        out[family] = {}
        for method in sorted({r["method"] for r in rows if r["family"] == family},
                             key=lambda m: (m != "mpc", m)):
            sel = [r for r in rows if r["family"] == family and r["method"] == method]
            out[family][method] = {
                "scenes": len(sel),
                "collisions": sum(r["collision"] for r in sel),
                "fails": sum(r["fail"] for r in sel),
                "off_route": sum(int(r.get("off_route", 0) or 0) for r in sel),
                # means over the scenes that produced metrics (error rows count as fails)
                **{k: _mean(r[k] for r in sel)
                   for k in ("ineff", "time_s", "pen_acc", "pen_dist", "overall_cost")},
                # how often the MPC found the decision in force stale (MpcController)
                "stale_scenes": sum(1 for r in sel if (r.get("stale_steps") or 0) > 0),
                "stale_steps": sum(int(r.get("stale_steps") or 0) for r in sel),
                "steps": sum(int(r.get("steps") or 0) for r in sel
                             if isinstance(r.get("steps"), int)),
            }
        base = out[family].get("mpc")
        for method, agg in out[family].items():
            if base and base["overall_cost"] > 0:
                agg["oc_change_vs_mpc"] = round(agg["overall_cost"] / base["overall_cost"] - 1, 4)
    return out


def table_md(summary: dict[str, dict[str, dict[str, Any]]]) -> str:
    lines = ["| Scenario | Method | Coll. | Fail | Off route | Ineff | Time | Acc | Dist | O.C. "
             "| vs MPC |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for family, methods in summary.items():
        for method, a in methods.items():
            change = a.get("oc_change_vs_mpc")
            lines.append(
                f"| {family.upper()} | {method} | {a['collisions']} | {a['fails']} | "
                f"{a.get('off_route', 0)} | "
                f"{a['ineff']:.1f} | {a['time_s']:.1f} | {a['pen_acc']:.2f} | "
                f"{a['pen_dist']:.2f} | {a['overall_cost']:.1f} | "
                f"{'' if change is None or method == 'mpc' else f'{change:+.1%}'} |")
    return "\n".join(lines) + "\n"


_LOG_NAME = re.compile(r"^(?P<family>.+)-(?P<seed>\d{3,})-(?P<method>lmpc-[a-z]+)\.jsonl$")


def decision_stats(log_dir: Path) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family, method and decision mode, from the scenes' decision logs: decisions,
    fallbacks, the share answered validly at the first attempt, the measured backend
    latency (wall, median / p95 / max; a backend run with a fixed simulated latency
    still logs the measured one) and the tokens in / out (median, max in)."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for path in sorted(Path(log_dir).glob("*.jsonl")):
        m = _LOG_NAME.match(path.name)
        if m is None:
            continue
        for line in path.read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                if rec.get("kind") == "mpc_stale_check":
                    continue  # the MPC's record of a decision, not a planner decision
                groups.setdefault((m["family"], m["method"], rec.get("mode", "normal")),
                                  []).append(rec)
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (family, method, mode), recs in sorted(groups.items()):
        lat = [float(r["measured_latency_s"]) for r in recs if r.get("attempts")]
        first_ok = [r for r in recs if r.get("attempts") and
                    r["attempts"][0].get("error_kind") is None]
        asked = [r for r in recs if r.get("attempts")]
        fallbacks = sum(1 for r in recs if (r.get("decision") or {}).get("source") == "fallback")
        tok_in = [int(r["tokens_in"]) for r in asked]
        tok_out = [int(r["tokens_out"]) for r in asked]
        out.setdefault(family, {}).setdefault(method, {})[mode] = {
            "decisions": len(recs), "fallbacks": fallbacks,
            "valid_first_answer": round(len(first_ok) / len(asked), 4) if asked else math.nan,
            "latency_s_median": round(statistics.median(lat), 3) if lat else math.nan,
            "latency_s_p95": round(percentile(lat, 0.95), 3),
            "latency_s_max": round(max(lat), 3) if lat else math.nan,
            "tokens_in_median": statistics.median(tok_in) if tok_in else math.nan,
            "tokens_in_max": max(tok_in) if tok_in else math.nan,
            "tokens_out_median": statistics.median(tok_out) if tok_out else math.nan,
        }
    return out


def stats_md(stats: dict[str, dict[str, dict[str, Any]]]) -> str:
    lines = ["| Scenario | Method | Mode | Decisions | Fallbacks | Valid 1st | Latency med / "
             "p95 / max s | Tokens in med / max | Tokens out med |",
             "|---|---|---|---|---|---|---|---|---|"]
    for family, methods in stats.items():
        for method, modes in methods.items():
            for mode, a in modes.items():
                lines.append(
                    f"| {family.upper()} | {method} | {mode} | {a['decisions']} | "
                    f"{a['fallbacks']} | {a['valid_first_answer']:.0%} | "
                    f"{a['latency_s_median']:.2f} / {a['latency_s_p95']:.2f} / "
                    f"{a['latency_s_max']:.2f} | {a['tokens_in_median']:.0f} / "
                    f"{a['tokens_in_max']:.0f} | {a['tokens_out_median']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--families", default="usi", help="comma-separated families")
    ap.add_argument("--seeds", type=parse_seeds, default=None,
                    help="e.g. 0-24 or 0,3,5-7 (default 0-24); with --scene: one scene per "
                         "seed, the seed replacing the file's SUMO seed and its background "
                         "traffic seed (default: the file's own seeds, one scene)")
    ap.add_argument("--methods", default="mpc,lmpc-rules")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", type=Path, default=Path("runs/bench"))
    ap.add_argument("--scene", type=Path,
                    help="run this scene description (YAML) instead of families")
    ap.add_argument("--instruction", default=None, metavar="TEXT",
                    help="the user's instruction for the planner (e.g. 'drive conservatively'"
                         "); the mpc baseline ignores it")
    ap.add_argument("--resume", action="store_true",
                    help="keep the rows of OUT/results.csv (an earlier, interrupted run of "
                         "the same code) and run only the scenes it lacks; error rows are "
                         "run again")
    ap.add_argument("--replay-from", type=Path, metavar="DIR",
                    help="lmpc-replay: the finished run folder whose decision logs "
                         "(DIR/decisions/) answer and whose results.csv is compared with")
    ap.add_argument("--replay-of", default="lmpc-local", metavar="METHOD",
                    help="lmpc-replay: the recorded method (its logs and planner settings; "
                         "default lmpc-local)")
    ap.add_argument("--decision-latency", type=float, metavar="S",
                    help="simulate a planner latency: every decision takes effect S s (sim "
                         "time) after its observation, whatever the backend (rules too; "
                         "ttl raised to S + period where needed); default: the config's")
    ap.add_argument("--emergency-latency", type=float, metavar="S",
                    help="the latency of emergency decisions (default with "
                         "--decision-latency: min(S, 1.5), the paper's emergency path)")
    ap.add_argument("--planner-config", type=Path, metavar="YAML",
                    help="planner settings of the LLM methods (default: the packaged "
                         "planner.yaml; planner_local.yaml for lmpc-local), e.g. "
                         "planner_server.yaml for lmpc-openai against a local CPU server")
    ap.add_argument("--decision-stats", type=Path, metavar="DIR",
                    help="only print the planner figures of a finished run folder "
                         "(DIR/decisions/*.jsonl) and write DIR/decisions.md")
    args = ap.parse_args(argv)
    scene_seeds = args.scene is not None and args.seeds is not None
    if args.seeds is None:
        args.seeds = parse_seeds("0-24")
    if args.decision_stats is not None:
        stats = decision_stats(args.decision_stats / "decisions")
        text = stats_md(stats)
        (args.decision_stats / "decisions.md").write_text(text)
        print(text)
        return 0
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        ap.error(f"unknown method(s) {unknown}; choose from {', '.join(METHODS)}")
    if args.planner_config is not None:
        from lmpc_llm_planner.config import PlannerConfigError, load_planner_config

        try:  # a bad file is named before any worker starts
            load_planner_config(args.planner_config)
        except PlannerConfigError as exc:
            ap.error(f"--planner-config: {exc}")
    replay: Optional[tuple[str, str]] = None
    if "lmpc-replay" in methods:
        if args.replay_from is None or not (args.replay_from / "decisions").is_dir():
            ap.error("lmpc-replay needs --replay-from DIR, a finished run folder with "
                     f"DIR/decisions/ (got {args.replay_from})")
        if args.replay_of not in METHODS or args.replay_of in ("mpc", "lmpc-replay"):
            ap.error(f"--replay-of {args.replay_of!r}: the method that recorded the logs, "
                     "one of lmpc-rules, lmpc-local, lmpc-openai")
        replay = (str(args.replay_from.resolve()), args.replay_of)
    for name in ("decision_latency", "emergency_latency"):
        value = getattr(args, name)
        if value is not None and not (0.0 <= value <= 600.0):
            ap.error(f"--{name.replace('_', '-')} must be within 0..600 s, got {value}")
    latency = (args.decision_latency, args.emergency_latency)
    args.out.mkdir(parents=True, exist_ok=True)
    work_dir = tempfile.mkdtemp(prefix="lmpc-bench-")
    jobs = [(m, f, s) for f in families for s in args.seeds for m in methods]
    scene_file: Optional[str] = None
    if args.scene is not None:
        from lmpc_bridge.scenarios import SceneError
        from lmpc_bridge.scenarios.external import build_external_scene

        try:  # validate (and build once per seed) before any worker starts
            scenes = [build_external_scene(args.scene, work_dir=Path(work_dir), seed=s)
                      for s in args.seeds] if scene_seeds \
                else [build_external_scene(args.scene, work_dir=Path(work_dir))]
        except SceneError as exc:
            print(f"benchmark: {exc}", file=sys.stderr)
            return 2
        scene_file = str(args.scene.resolve())
        jobs = [(m, sc.family, sc.seed) for sc in scenes for m in methods]
    rows: list[dict[str, Any]] = []
    if args.resume:
        try:
            rows = read_rows(args.out / "results.csv", set(jobs), latency=latency)
        except (OSError, ValueError, KeyError) as exc:
            print(f"benchmark: --resume: cannot read {args.out / 'results.csv'}: {exc}",
                  file=sys.stderr)
            return 2
        done = {(r["method"], r["family"], r["seed"]) for r in rows}
        jobs = [j for j in jobs if j not in done]
        print(f"benchmark: --resume: {len(rows)} scene(s) kept from "
              f"{args.out / 'results.csv'}, {len(jobs)} to run", flush=True)
    kept = len(rows)
    t0 = time.monotonic()
    log_dir = args.out / "decisions"
    interrupted = False
    # SIGTERM ends a run as Ctrl-C does: the finished scenes are written, not lost
    signal.signal(signal.SIGTERM, _raise_interrupt)
    pool = ProcessPoolExecutor(max_workers=max(1, args.workers))
    try:
        futures = {pool.submit(run_scene, m, f, s, work_dir, scene_file, args.instruction,
                               str(log_dir), replay, scene_seeds, latency,
                               str(args.planner_config.resolve()) if args.planner_config
                               else None): (m, f, s) for m, f, s in jobs}
        for fut in as_completed(futures):
            m, f, s = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. a worker process that died
                row = error_row(m, f, s, f"{type(exc).__name__}: {exc}", latency)
            rows.append(row)
            write_rows(args.out / "results.csv", rows)  # a long run keeps every finished scene
            done = len(rows) - kept
            elapsed = time.monotonic() - t0
            eta = elapsed / done * (len(jobs) - done)
            print(f"[{done}/{len(jobs)}] {f} seed {s} {m}: {row['outcome']} "
                  f"t={row['time_s']}s O.C.={row['overall_cost']} ({row['wall_s']}s wall) "
                  f"elapsed {elapsed:.0f}s ETA {eta:.0f}s", flush=True)
    except KeyboardInterrupt:
        interrupted = True
        print(f"benchmark: interrupted after {len(rows)} of {len(jobs)} scenes; writing "
              f"those", file=sys.stderr, flush=True)
        # the running scenes are abandoned: stop their workers (the executor has no
        # public way to, and a worker may be minutes into an LLM episode)
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.kill()
    finally:
        pool.shutdown(wait=not interrupted, cancel_futures=True)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    partial = ({"scenes_done": len(rows), "scenes_planned": len(jobs) + kept}
               if interrupted else None)
    write_outputs(args, rows, log_dir, time.monotonic() - t0, partial, resumed=kept)
    if replay is not None:
        try:
            recorded = read_rows(args.replay_from / "results.csv",
                                 {(args.replay_of, r["family"], r["seed"]) for r in rows})
        except (OSError, ValueError, KeyError) as exc:
            print(f"benchmark: replay check: cannot read {args.replay_from / 'results.csv'}: "
                  f"{exc}", file=sys.stderr)
            recorded = []
        lines = replay_check(rows, recorded, args.replay_of)
        exact = sum(": exact repeat:" in line for line in lines)
        report = (f"replay of {args.replay_from} ({args.replay_of}): {exact} of {len(lines)} "
                  "scene(s) repeat the recorded row exactly\n" + "\n".join(lines) + "\n")
        (args.out / "replay_check.txt").write_text(report)
        print(report, end="")
    if interrupted:
        return 130
    if rows and all(r["outcome"] == "error" for r in rows):
        print(f"benchmark: every one of the {len(rows)} scene(s) ended in an error; the "
              f"first: {rows[0]['family']} seed {rows[0]['seed']} {rows[0]['method']}: "
              f"{rows[0]['detail']}", file=sys.stderr, flush=True)
        return 1
    return 0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


_INT_COLUMNS = ("seed", "collision", "fail", "off_route", "decisions", "fallbacks", "steps",
                "route_overrides", "stale_steps", "stale_agent_steps")
_TEXT_COLUMNS = ("family", "method", "outcome", "detail", "latency_s", "emergency_latency_s")


def read_rows(path: Path, jobs: set[tuple[str, str, int]], *,
              latency: tuple[Optional[float], Optional[float]] = (None, None)
              ) -> list[dict[str, Any]]:
    """The rows of an earlier ``results.csv`` that belong to ``jobs`` ((method, family,
    seed)), ran with the same simulated ``latency`` and did not end in ``error``, typed as
    ``run_scene`` returns them (latency cells as text; a missing file: none). Raises
    ``ValueError`` / ``KeyError`` naming a malformed row."""
    if not path.exists():
        return []
    rows = []
    with open(path, newline="") as fh:
        for line, raw in enumerate(csv.DictReader(fh), start=2):
            missing = [c for c in COLUMNS if c not in raw]
            if missing:
                raise KeyError(f"line {line}: no column(s) {missing}")
            try:
                row: dict[str, Any] = {
                    c: raw[c] if c in _TEXT_COLUMNS
                    else int(raw[c]) if c in _INT_COLUMNS else float(raw[c])
                    for c in COLUMNS}
            except ValueError as exc:
                raise ValueError(f"line {line}: {exc}") from None
            want = latency_cells(row["method"], latency)
            same_latency = all(_same_cell(row[k], v) for k, v in want.items())
            if row["outcome"] != "error" and same_latency and \
                    (row["method"], row["family"], row["seed"]) in jobs:
                rows.append(row)
    return rows


def _same_cell(text: str, value: Any) -> bool:
    """A latency cell read back from results.csv against the value this run writes."""
    if text == "" or value == "":
        return text == "" and value == ""
    return math.isclose(float(text), float(value))


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """``results.csv``, rows sorted by family, method, seed (written anew, atomically)."""
    ordered = sorted(rows, key=lambda r: (r["family"], r["method"], r["seed"]))
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(ordered)
    tmp.replace(path)


def write_outputs(args: argparse.Namespace, rows: list[dict[str, Any]], log_dir: Path,
                  wall_s: float, partial: Optional[dict[str, int]], resumed: int = 0) -> None:
    """results.csv, summary.json, table.md, decisions.md and the bar chart of ``rows``;
    ``partial``: how many of the planned scenes an interrupted run finished (recorded in
    summary.json and table.md); ``resumed``: how many of ``rows`` an earlier run left."""
    write_rows(args.out / "results.csv", rows)
    summary = aggregate(rows)
    stats = decision_stats(log_dir)  # {} when no planner wrote a log
    (args.out / "summary.json").write_text(json.dumps(
        {"families": summary, "planner": stats, "wall_time_s": round(wall_s, 1),
         "decision_latency_s": args.decision_latency,
         "emergency_latency_s": latency_cells(
             "lmpc", (args.decision_latency, args.emergency_latency))["emergency_latency_s"]
         or None,
         "workers": args.workers, "seeds": args.seeds, "instruction": args.instruction,
         "partial": partial, "resumed_rows": resumed}, indent=2))
    table = table_md(summary)
    if args.decision_latency is not None or args.emergency_latency is not None:
        cells = latency_cells("lmpc", (args.decision_latency, args.emergency_latency))
        table = (f"Simulated decision latency {cells['latency_s'] or 'as configured'} s, "
                 f"emergency {cells['emergency_latency_s']} s.\n\n" + table)
    if partial is not None:
        table = (f"PARTIAL: interrupted after {partial['scenes_done']} of "
                 f"{partial['scenes_planned']} scenes.\n\n" + table)
    (args.out / "table.md").write_text(table)
    print(table)
    if stats:
        (args.out / "decisions.md").write_text(stats_md(stats))
        print(stats_md(stats))
    try:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from render import plot_oc_bars

        plot_oc_bars(summary, args.out / "oc_bars.png")
    except Exception as exc:  # noqa: BLE001 - a plotting problem must not lose the results
        print(f"bar chart not drawn: {type(exc).__name__}: {exc}", file=sys.stderr)
    print(f"wrote {args.out}/results.csv, table.md, summary.json in {wall_s:.0f}s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
