#!/usr/bin/env python3
"""Benchmark: methods x scenario families x seeds, in-process (no ROS), in parallel workers.

The same logic objects as the nodes (DESIGN §1): ``lmpc_bridge.runner.run_episode``
with the MPC controller and, for ``lmpc-*`` methods, the planner core. Writes
``results.csv`` (one row per scene and method), ``table.md`` (the paper's Table I
layout; with an ablation method also ``table2.md``, the paper's Table II),
``summary.json`` (per family and method, plus the relative O.C.
change of each method against ``mpc``) and, for ``lmpc-*`` methods, each scene's
decision log in ``decisions/<family>-<seed>-<method>.jsonl``.

    benchmark.py --families usi --seeds 0-24 --methods mpc,lmpc-rules --out runs/bench
    benchmark.py --scene examples/city.yaml --methods mpc,lmpc-rules   # your own network
    benchmark.py --scene examples/city.yaml --seeds 0-4   # five scenes: SUMO + traffic seeds
    benchmark.py --families lane --methods lmpc-rules --instruction "drive aggressively"
    benchmark.py --families si,lane --seeds 100-124 --methods lmpc-rules --instruction-set styles
    benchmark.py --families eoa --methods lmpc-replay --replay-from runs/bench_local  # repeat
    benchmark.py --families si --methods lmpc-rules --decision-latency 2.5  # a slow LLM
    benchmark.py --families si --methods lmpc-rules --planning-period 5   # a rarer decision
    benchmark.py --families usi --executor ray   # Ray tasks: local, or $RAY_ADDRESS

``--decision-latency S`` simulates a planner whose decisions take effect S seconds (sim
time) after the observation they used, whatever the backend (the rules reasoner too);
emergency decisions get ``--emergency-latency`` (default min(S, 1.5 s), the paper's
short emergency path). Both are recorded per row and in summary.json. ``--planning-period S``
runs the LLM methods at another cadence (``lmpc_llm_planner.config.cadence_config``: the
period, the rules' ``replan_s`` and the TTL; the config used is kept as
OUT/planner_config.yaml and the period in summary.json).

``--instruction-set styles`` runs every scene once per phrasing of the set (conservative,
normal = no instruction, aggressive; ``lmpc_bridge.evaluation.style.INSTRUCTION_SETS``) and
writes ``styles.csv`` (a row per scene and phrasing, with the style figures: gaps, peak
deceleration and jerk, accepted lane-change / junction gaps) and ``style_table.md`` (per
family and style, and the per-scene share whose time follows the style) beside the
normal outputs (results.csv / table.md of the uninstructed runs). ``--instruction-set
situations`` does the same with situational text (a closed lane, an ambulance to make room
for, pedestrians at the next junction) and writes ``situations.csv`` and
``situation_table.md`` (``lmpc_bridge.evaluation.situations``).

``lmpc-replay`` repeats a finished run's LLM decisions without the model: each scene
answers from that run's decision log of the scene, matching prompts by hash, with the
recorded method's planner settings (``--replay-of``, default ``lmpc-local``), and is
compared with the recorded row. An exact repeat (every prompt found, same outcome, time
and O.C.) shows the recorded row still holds on the code that replays it.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import yaml

from lmpc_bridge.evaluation.decisions import decision_stats, stats_md
from lmpc_bridge.evaluation.executors import EXECUTORS, ExecutorError, workers_arg
from lmpc_bridge.evaluation.replay import replay_check
from lmpc_bridge.evaluation.rows import (latency_cells, parse_seeds, read_rows, resume_rows,
                                         write_rows)
from lmpc_bridge.evaluation.scenes import RunSettings, run_scenes
from lmpc_bridge.evaluation.situations import (
    SITUATION_COLUMNS,
    situation_summary,
    situation_table_md,
)
from lmpc_bridge.evaluation.style import (
    INSTRUCTION_SETS,
    SITUATION_SETS,
    STYLE_COLUMNS,
    direction_shares,
    style_summary,
    style_table_md,
)
from lmpc_bridge.evaluation.table import aggregate, table2_md, table_md
from lmpc_llm_planner.config import add_timing_args, timing_arg_error
from lmpc_llm_planner.prompt import instruction_error
from lmpc_msgs_py.cli import folder_arg
from lmpc_scripts.method_rl import ALGOS, POLICY_DIR_ENV, policy_path
from lmpc_scripts.methods import (
    LLM_METHODS,
    METHODS,
    build,
    list_methods,
    prepare,
    resolve_latency,
)


def _multi_module() -> Any:
    """``lmpc_scripts.multi``, imported when a multi-ego family is asked for."""
    from lmpc_scripts import multi

    return multi


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--families", default="usi", help="comma-separated families")
    ap.add_argument("--seeds", type=parse_seeds, default=None,
                    help="e.g. 0-24 or 0,3,5-7 (default 0-24); with --scene: one scene per "
                         "seed, the seed replacing the file's SUMO seed and its background "
                         "traffic seed (default: the file's own seeds, one scene)")
    ap.add_argument("--methods", default="mpc,lmpc-rules",
                    help="comma-separated methods (--list-methods: what each is)")
    ap.add_argument("--policy-dir", type=Path, default=None,
                    help="folder of the saved policies of dqn / ppo / sac "
                         "(<algo>-<family>.npz; default $LMPC_POLICY_DIR, else policies/)")
    ap.add_argument("--list-methods", action="store_true",
                    help="print the registered methods, one line each, and exit")
    ap.add_argument("--workers", type=workers_arg, default=os.cpu_count() or 1,
                    help="worker processes (with --executor ray and no RAY_ADDRESS: the "
                         "CPUs of the local Ray; on a cluster, its CPUs decide)")
    ap.add_argument("--executor", choices=EXECUTORS, default="pool",
                    help="pool: local worker processes (default); ray: Ray tasks, on the "
                         "cluster at $RAY_ADDRESS if set, else on a local Ray (needs the "
                         "ray extra; README, 'Running on a Ray cluster')")
    ap.add_argument("--out", type=folder_arg, default=Path("runs/bench"))
    ap.add_argument("--scene", type=Path,
                    help="run this scene description (YAML) instead of families")
    ap.add_argument("--instruction", default=None, metavar="TEXT",
                    help="the user's instruction for the planner (e.g. 'drive conservatively'"
                         "); the mpc baseline ignores it")
    ap.add_argument("--instruction-set", choices=sorted(INSTRUCTION_SETS), metavar="NAME",
                    help="run every scene once per phrasing of the set (styles: "
                         "conservative / none / aggressive, several phrasings each; situations: "
                         "none / closed lane / make room / pedestrians) and write "
                         "styles.csv and style_table.md (situations.csv, situation_table.md)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the rows of OUT/results.csv (an earlier, interrupted run of "
                         "the same code) and run only the scenes it lacks; error rows are "
                         "run again, rows of scenes outside this selection are kept as they "
                         "are; a scene that ran at another simulated latency is an error")
    ap.add_argument("--replay-from", type=Path, metavar="DIR",
                    help="lmpc-replay: the finished run folder whose decision logs "
                         "(DIR/decisions/) answer and whose results.csv is compared with")
    ap.add_argument("--replay-of", default="lmpc-local", metavar="METHOD",
                    help="lmpc-replay: the recorded method (its logs and planner settings; "
                         "default lmpc-local)")
    add_timing_args(ap)
    ap.add_argument("--planner-config", type=Path, metavar="YAML",
                    help="planner settings of the LLM methods (default: the packaged "
                         "planner.yaml; planner_local.yaml for lmpc-local), e.g. "
                         "planner_server.yaml for lmpc-openai against a local CPU server")
    ap.add_argument("--oracle-lookahead-s", type=float, metavar="S",
                    help="lmpc-oracle: sim time each option is rolled out for (default 8)")
    ap.add_argument("--oracle-continuation", choices=("none", "rules"),
                    help="lmpc-oracle: what decides after an option in its rollout: nothing "
                         "(default) or the rules reasoner (docs/ORACLE.md)")
    ap.add_argument("--coordination", default="none,distributed,central", metavar="MODES",
                    help="multi-ego families (narrow): the coordination modes to run, "
                         "none|distributed|central (docs/MULTI.md)")
    ap.add_argument("--decision-stats", type=folder_arg, metavar="DIR",
                    help="only print the planner figures of a finished run folder "
                         "(DIR/decisions/*.jsonl) and write DIR/decisions.md")
    args = ap.parse_args(argv)
    if args.list_methods:
        print(list_methods(), end="")
        return 0
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
    if args.scene is None:
        from lmpc_bridge.scenarios import unknown_families

        misspelt = unknown_families(families)
        if misspelt:
            ap.error(misspelt)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        ap.error(f"--out {args.out}: cannot make the folder ({exc.strerror})")
    multi = _multi_module()
    several = [f for f in families if f in multi.MULTI_FAMILIES]
    if several:  # several egos per scene: their own loop and rows (docs/MULTI.md)
        modes = [m.strip() for m in args.coordination.split(",") if m.strip()]
        bad = [m for m in modes if m not in multi.MODES]
        other = [m for m in methods if m not in multi.MULTI_METHODS]
        if other:
            ap.error(f"multi-ego families run {', '.join(multi.MULTI_METHODS)} only, not "
                     f"{', '.join(other)} (docs/MULTI.md)")
        if bad or args.scene is not None:
            ap.error(f"--coordination {bad}: choose from {', '.join(multi.MODES)}" if bad
                     else "--scene does not combine with a multi-ego family")
        try:
            print(multi.run_multi_scenes(several, list(args.seeds), methods, modes, args.out))
        except ValueError as exc:
            ap.error(str(exc))
        families = [f for f in families if f not in several]
        if not families:
            return 0
    learned = [m for m in methods if m in ALGOS]
    if "adp" in methods:
        from lmpc_scripts.method_adp import adp_path

        if args.policy_dir is not None:
            os.environ[POLICY_DIR_ENV] = str(args.policy_dir.resolve())
        if not adp_path().is_file():
            print(f"benchmark: no ADP network {adp_path()}: train it "
                  "(scripts/train_adp.py --install) or give --policy-dir", file=sys.stderr)
            return 2
    if learned:
        if args.policy_dir is not None:  # the workers read it from the environment
            os.environ[POLICY_DIR_ENV] = str(args.policy_dir.resolve())
        missing = [str(policy_path(m, f)) for m in learned for f in families
                   if not policy_path(m, f).is_file()]
        if missing:
            print(f"benchmark: no saved policy {', '.join(missing)}: train it "
                  "(scripts/train_rl.py --install) or give --policy-dir", file=sys.stderr)
            return 2
    if args.planner_config is not None:
        from lmpc_llm_planner.config import PlannerConfigError, load_planner_config

        try:  # a bad file is named before any worker starts
            load_planner_config(args.planner_config)
        except PlannerConfigError as exc:
            ap.error(f"--planner-config: {exc}")
    method_options = oracle_options(args)
    if method_options:
        from lmpc_scripts.method_oracle import OracleConfig

        if "lmpc-oracle" not in methods:
            ap.error("--oracle-* options need --methods lmpc-oracle")
        try:
            OracleConfig.from_options(method_options)
        except ValueError as exc:
            ap.error(str(exc))
    timing_error = timing_arg_error(args)
    if timing_error:
        ap.error(timing_error)
    if args.planning_period is not None:
        error = cadence_file(args, methods)
        if error:
            ap.error(error)
    replay: Optional[tuple[str, str]] = None
    if "lmpc-replay" in methods:
        if args.replay_from is None or not (args.replay_from / "decisions").is_dir():
            ap.error("lmpc-replay needs --replay-from DIR, a finished run folder with "
                     f"DIR/decisions/ (got {args.replay_from})")
        if args.replay_of not in LLM_METHODS:
            ap.error(f"--replay-of {args.replay_of!r}: the method that recorded the logs, "
                     f"one of {', '.join(LLM_METHODS)}")
        replay = (str(args.replay_from.resolve()), args.replay_of)
    refused = None if args.instruction is None else instruction_error(args.instruction)
    if refused:  # the planner would cut it (in process) or drop it (the graph)
        ap.error(f"--instruction: {refused}")
    latency = resolve_latency(args.decision_latency, args.emergency_latency)
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
    if args.instruction_set is not None:
        if args.instruction is not None or args.resume or replay is not None:
            ap.error("--instruction-set runs its own instructions; it does not combine "
                     "with --instruction, --resume or lmpc-replay")
        return run_instruction_set(args, jobs, work_dir, scene_file, scene_seeds, latency)
    rows: list[dict[str, Any]] = []
    if args.resume:
        try:
            rows, others = resume_rows(args.out / "results.csv", set(jobs), latency=latency)
        except (OSError, ValueError, KeyError) as exc:
            print(f"benchmark: --resume: cannot read {args.out / 'results.csv'}: {exc}",
                  file=sys.stderr)
            return 2
        done = {(r["method"], r["family"], r["seed"]) for r in rows}
        jobs = [j for j in jobs if j not in done]
        print(f"benchmark: --resume: {len(rows)} scene(s) kept from "
              f"{args.out / 'results.csv'}, {len(jobs)} to run"
              + (f"; {len(others)} row(s) of scenes outside this selection kept as they "
                 "are (in results.csv and the tables)" if others else ""), flush=True)
        rows += others
    kept = len(rows)
    t0 = time.monotonic()
    log_dir = args.out / "decisions"
    settings = RunSettings(
        work_dir=work_dir, scene_file=scene_file, instruction=args.instruction,
        log_dir=str(log_dir), replay=replay, scene_seed=scene_seeds, latency=latency,
        planner_config=str(args.planner_config.resolve()) if args.planner_config else None,
        method_options=method_options)

    def progress(done: int, row: dict[str, Any], elapsed: float) -> None:
        eta = elapsed / done * (len(jobs) - done)
        print(f"[{done}/{len(jobs)}] {row['family']} seed {row['seed']} {row['method']}: "
              f"{row['outcome']} t={row['time_s']}s O.C.={row['overall_cost']} "
              f"({row['wall_s']}s wall) elapsed {elapsed:.0f}s ETA {eta:.0f}s", flush=True)

    try:
        interrupted = run_scenes(jobs, settings, build=build, prepare=prepare,
                                 workers=args.workers, rows=rows,
                                 results_csv=args.out / "results.csv", progress=progress,
                                 executor=args.executor)
    except ExecutorError as exc:
        print(f"benchmark: --executor {args.executor}: {exc}", file=sys.stderr)
        return 2
    if interrupted:
        print(f"benchmark: interrupted after {len(rows)} of {len(jobs)} scenes; writing "
              f"those", file=sys.stderr, flush=True)
    partial = ({"scenes_done": len(rows), "scenes_planned": len(jobs) + kept}
               if interrupted else None)
    write_outputs(args, rows, log_dir, time.monotonic() - t0, partial, resumed=kept,
                  latency=latency)
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


def run_instruction_set(args: argparse.Namespace, jobs: list[tuple[str, str, int]],
                        work_dir: str, scene_file: Optional[str], scene_seeds: bool,
                        latency: tuple[Optional[float], Optional[float]]) -> int:
    """Every job once per (style, phrasing) of ``args.instruction_set``: styles.csv,
    style_table.md, and the normal outputs of the uninstructed runs."""
    import csv

    phrasings = INSTRUCTION_SETS[args.instruction_set]
    t0 = time.monotonic()
    all_rows: list[dict[str, Any]] = []
    normal: list[dict[str, Any]] = []
    interrupted = False
    # family by family, every phrasing of a family before the next family: an
    # interrupted run still has whole families to compare
    groups = [[j for j in jobs if j[1] == fam] for fam in dict.fromkeys(j[1] for j in jobs)]
    for k, (fam_jobs, (style, text)) in enumerate(
            (g, p) for g in groups for p in phrasings):
        if interrupted:
            break
        phr = phrasings.index((style, text))
        log_dir = args.out / ("decisions" if text is None else f"decisions-{phr}")
        settings = RunSettings(
            work_dir=work_dir, scene_file=scene_file, instruction=text, log_dir=str(log_dir),
            scene_seed=scene_seeds, latency=latency,
            planner_config=str(args.planner_config.resolve()) if args.planner_config
            else None, method_options=oracle_options(args))
        rows: list[dict[str, Any]] = []

        def progress(done: int, row: dict[str, Any], elapsed: float) -> None:
            print(f"[{style} {text!r} {done}/{len(fam_jobs)}] {row['family']} seed "
                  f"{row['seed']} {row['method']}: {row['outcome']} t={row['time_s']}s "
                  f"min gap {row.get('min_gap_m')} m ({row['wall_s']}s wall)", flush=True)

        interrupted = run_scenes(fam_jobs, settings, build=build, prepare=prepare,
                                 workers=args.workers, rows=rows,
                                 results_csv=args.out / f"results-{k}.csv",
                                 progress=progress)
        (args.out / f"results-{k}.csv").unlink(missing_ok=True)
        for r in rows:
            r.update(style=style, instruction=text or "")
        all_rows += rows
        if text is None:
            normal += rows
    situational = args.instruction_set in SITUATION_SETS
    label = "situation" if situational else "style"
    for r in all_rows:
        r[label] = r["style"]
    columns = ("family", "seed", "method", label, "instruction", "outcome", "collision",
               "fail", "time_s", "overall_cost",
               *(SITUATION_COLUMNS if situational else STYLE_COLUMNS), "wall_s", "detail")
    with open(args.out / f"{label}s.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(sorted(all_rows, key=lambda r: (r["family"], r["method"], r["seed"],
                                                         r["style"], r["instruction"])))
    parts = []
    for method in sorted({r["method"] for r in all_rows}):
        mine = [r for r in all_rows if r["method"] == method]
        table = situation_table_md(situation_summary(mine)) if situational else \
            style_table_md(style_summary(mine), direction_shares(mine))
        parts.append(f"### {method}\n\n{table}")
    head = ("Instruction set " + args.instruction_set + ": " + "; ".join(
        f"{s}: {t!r}" if t else f"{s}: no instruction" for s, t in phrasings) + "\n\n")
    text_md = head + "\n".join(parts)
    if interrupted:
        text_md = "PARTIAL: interrupted.\n\n" + text_md
    (args.out / f"{label}_table.md").write_text(text_md)
    print(text_md)
    if normal:
        write_outputs(args, normal, args.out / "decisions", time.monotonic() - t0,
                      None, latency=latency)
    return 130 if interrupted else 0


def oracle_options(args: argparse.Namespace) -> tuple[tuple[str, Any], ...]:
    """The ``--oracle-*`` options given, as ``lmpc-oracle``'s method options."""
    given = (("lookahead_s", args.oracle_lookahead_s),
             ("continuation", args.oracle_continuation))
    return tuple((k, v) for k, v in given if v is not None)


def cadence_file(args: argparse.Namespace, methods: list[str]) -> Optional[str]:
    """``--planning-period``: write the LLM methods' planner config at that period to
    OUT/planner_config.yaml and point ``args.planner_config`` at it; returns an error
    message for a bad period or file, else None."""
    from lmpc_llm_planner.config import PlannerConfigError, cadence_config

    if args.planner_config is None and ({"lmpc-local", "lmpc-replay"} & set(methods)):
        return ("--planning-period with lmpc-local / lmpc-replay: give the base config as "
                "--planner-config (e.g. the packaged planner_local.yaml)")
    try:
        data = cadence_config(args.planning_period, args.planner_config)
    except PlannerConfigError as exc:
        return f"--planning-period: {exc}"
    args.out.mkdir(parents=True, exist_ok=True)
    args.planner_config = args.out / "planner_config.yaml"
    args.planner_config.write_text(yaml.safe_dump(data, sort_keys=False))
    return None


def write_outputs(args: argparse.Namespace, rows: list[dict[str, Any]], log_dir: Path,
                  wall_s: float, partial: Optional[dict[str, int]], resumed: int = 0, *,
                  latency: tuple[Optional[float], Optional[float]] = (None, None)) -> None:
    """results.csv, summary.json, table.md, decisions.md and the bar chart of ``rows``;
    ``partial``: how many of the planned scenes an interrupted run finished (recorded in
    summary.json and table.md); ``resumed``: how many of ``rows`` an earlier run left."""
    write_rows(args.out / "results.csv", rows)
    summary = aggregate(rows)
    stats = decision_stats(log_dir)  # {} when no planner wrote a log
    (args.out / "summary.json").write_text(json.dumps(
        {"families": summary, "planner": stats, "wall_time_s": round(wall_s, 1),
         "decision_latency_s": args.decision_latency,
         "emergency_latency_s": latency_cells("lmpc", latency)["emergency_latency_s"] or None,
         "planning_period_s": args.planning_period,
         "workers": args.workers, "executor": args.executor, "seeds": args.seeds,
         "instruction": args.instruction,
         "partial": partial, "resumed_rows": resumed}, indent=2))
    table = table_md(summary)
    if args.decision_latency is not None or args.emergency_latency is not None:
        cells = latency_cells("lmpc", latency)
        table = (f"Simulated decision latency {cells['latency_s'] or 'as configured'} s, "
                 f"emergency {cells['emergency_latency_s']} s.\n\n" + table)
    if args.planning_period is not None:
        table = f"Planning period {args.planning_period:g} s.\n\n" + table
    if partial is not None:
        table = (f"PARTIAL: interrupted after {partial['scenes_done']} of "
                 f"{partial['scenes_planned']} scenes.\n\n" + table)
    (args.out / "table.md").write_text(table)
    print(table)
    ablation = table2_md(summary)
    if ablation:  # an ablation method ran: the paper's Table II as well
        (args.out / "table2.md").write_text(ablation)
        print(ablation)
    if stats:
        (args.out / "decisions.md").write_text(stats_md(stats))
        print(stats_md(stats))
    try:
        from lmpc_bridge.render import plot_oc_bars

        plot_oc_bars(summary, args.out / "oc_bars.png")
    except Exception as exc:  # noqa: BLE001 - a plotting problem must not lose the results
        print(f"bar chart not drawn: {type(exc).__name__}: {exc}", file=sys.stderr)
    print(f"wrote {args.out}/results.csv, table.md, summary.json in {wall_s:.0f}s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
