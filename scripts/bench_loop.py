#!/usr/bin/env python3
"""The fast loop's benchmark (issue 19): the whole node graph, run by ``run_graph.py``
several times per variant, alternating, with the figures of each run and the ratios of
every variant to the first one named, measured in the same session.

    bench_loop.py --runs 3 --variants "--executor events" "--executor single"
    bench_loop.py --scene examples/city_dense.yaml --clock realtime \\
        --variants "--rt-priority 20" ""

A variant is extra ``run_graph.py`` arguments (quoted; "" = the defaults). Per run:
start-up (run start -> step 0) and episode wall seconds, the episode's real-time factor,
the bridge's step cycle median, the control cycle (ego state published -> control
received) median / p99 / max and the MPC's solve median / p99, in ms. Outcome and O.C.
are printed too: in sync mode every run of a scene must give the same ones. Summaries go
to ``--out`` (default a temporary folder). Run it on a quiet machine (or say what ran
beside it): the figures are wall times.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Optional, Sequence

from lmpc_msgs_py.discovery import stay_local
from lmpc_msgs_py.cli import folder_arg, int_arg

RUN_GRAPH = Path(__file__).resolve().parent / "run_graph.py"
COLUMNS = ("startup_s", "episode_s", "rtf", "step_ms", "cycle_med", "cycle_p99", "cycle_max",
           "solve_med", "solve_p99")
RATIOS = ("episode_s", "step_ms", "cycle_med", "cycle_p99", "solve_p99")


def figures(summary: dict[str, Any]) -> dict[str, Any]:
    """The benchmark's figures of one ``run_graph.py`` summary (None where it has none)."""
    cycle = summary.get("control_latency_ms") or {}
    solve = summary.get("mpc_solve_ms") or {}
    step = ((summary.get("profile_ms") or {}).get("bridge") or {}).get(
        "step cycle (publish to publish)") or {}
    metrics = summary.get("metrics") if isinstance(summary.get("metrics"), dict) else {}
    return {
        "outcome": summary.get("outcome"), "oc": (metrics or {}).get("overall_cost"),
        "startup_s": summary.get("startup_wall_s"), "episode_s": summary.get("episode_wall_s"),
        "rtf": summary.get("episode_real_time_factor"), "step_ms": step.get("median"),
        "cycle_med": cycle.get("median"), "cycle_p99": cycle.get("p99"),
        "cycle_max": cycle.get("max"), "solve_med": solve.get("median"),
        "solve_p99": solve.get("p99"),
    }


def table(runs: dict[str, list[dict[str, Any]]]) -> str:
    """Every run's figures, each variant's medians over its runs, and the ratio of those
    medians to the first variant's (``RATIOS``)."""
    head = f"{'variant':28s} {'run':>3s} {'outcome':8s} {'O.C.':>9s} " + " ".join(
        f"{c:>9s}" for c in COLUMNS)
    lines = [head, "-" * len(head)]
    medians: dict[str, dict[str, Optional[float]]] = {}
    for variant, rows in runs.items():
        name = variant or "(defaults)"
        for i, row in enumerate(rows, 1):
            oc = "" if row["oc"] is None else f"{row['oc']:.4f}"
            lines.append(f"{name[:28]:28s} {i:3d} {str(row['outcome'])[:8]:8s} {oc:>9s} "
                         + " ".join(_cell(row[c]) for c in COLUMNS))
        medians[variant] = {c: _median([r[c] for r in rows]) for c in COLUMNS}
        lines.append(f"{name[:28]:28s} {'med':>3s} {'':8s} {'':>9s} "
                     + " ".join(_cell(medians[variant][c]) for c in COLUMNS))
    first = next(iter(medians))
    for variant in list(medians)[1:]:
        parts = []
        for c in RATIOS:
            a, b = medians[variant][c], medians[first][c]
            parts.append(f"{c} {a / b:.2f}" if a is not None and b else f"{c} -")
        lines.append(f"ratio {variant or '(defaults)'} / {first or '(defaults)'}: "
                     + ", ".join(parts))
    return "\n".join(lines)


def _median(values: Sequence[Optional[float]]) -> Optional[float]:
    present = [v for v in values if v is not None]
    return float(statistics.median(present)) if present else None


def _cell(value: Optional[float]) -> str:
    return f"{'-':>9s}" if value is None else f"{value:9.3f}"


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="usi", help="scenario family (default usi)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scene", default=None, help="a scene file instead of --scenario/--seed")
    ap.add_argument("--planner", default="rules")
    ap.add_argument("--clock", choices=("sync", "realtime"), default="sync")
    ap.add_argument("--runs", type=int_arg(1), default=3, help="runs per variant (default 3)")
    ap.add_argument("--variants", nargs="+", default=["--executor events", "--executor single"],
                    help='extra run_graph.py arguments per variant, quoted ("" = defaults)')
    ap.add_argument("--domain-id", type=int, default=77, help="ROS domain of the runs")
    ap.add_argument("--out", type=folder_arg, default=None, help="folder for the run summaries")
    args = ap.parse_args(argv)
    for variant in args.variants:
        try:
            shlex.split(variant)
        except ValueError as exc:
            ap.error(f"variant {variant!r}: {exc}")
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_loop-"))
    out.mkdir(parents=True, exist_ok=True)
    env = stay_local(dict(os.environ))
    scene = ["--scene", args.scene] if args.scene \
        else ["--scenario", args.scenario, "--seed", str(args.seed)]
    runs: dict[str, list[dict[str, Any]]] = {v: [] for v in args.variants}
    for i in range(1, args.runs + 1):
        for k, variant in enumerate(args.variants):  # alternating: drift hits all alike
            tag = f"v{k}-run{i}"
            summary_path = out / f"{tag}.json"
            cmd = [sys.executable, str(RUN_GRAPH), *scene, "--planner", args.planner,
                   "--clock", args.clock, "--domain-id", str(args.domain_id), "--quiet",
                   "--run-dir", str(out / tag), "--summary-json", str(summary_path),
                   *shlex.split(variant)]
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if not summary_path.exists():
                print(f"{tag} ({variant or 'defaults'}): run_graph wrote no summary (exit "
                      f"{proc.returncode}):\n{(proc.stdout + proc.stderr)[-2000:]}",
                      file=sys.stderr)
                done = {v: rows for v, rows in runs.items() if rows}
                if done:  # the runs before it keep their figures
                    print(table(done))
                print(f"summaries in {out}")
                return 3
            row = figures(json.loads(summary_path.read_text()))
            runs[variant].append(row)
            print(f"[bench_loop] {tag} {variant or '(defaults)'}: {row['outcome']}, episode "
                  f"{row['episode_s']} s, cycle p99 {row['cycle_p99']} ms", flush=True)
    print(table(runs))
    print(f"summaries in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
