#!/usr/bin/env python3
"""Pictures of scenes, runs and benchmark results (matplotlib; no ROS).

    render.py scene --family usi --seed 0 --out scene.png
    render.py run RUN_DIR [--out run.png] [--gif run.gif]
    render.py run --family usi --seed 0 --method lmpc-rules [--max-time-s 60] --out run.png
    render.py bars RESULTS_DIR                      -> RESULTS_DIR/oc_bars.png
    render.py multi RUN_DIR [--out multi.png] [--gif multi.gif]   (run_graph.py --egos N)
    render.py multi --family narrow --seed 0 --method mpc --coordination central \
        --out strip.png [--gif encounter.gif]         (a multi-ego run, issue 18)

What is drawn and what is approximated: docs/PICTURES.md. The drawing library is
``lmpc_bridge.render``; this command line adds the method registry's wiring for the
in-process run (``run_in_process``).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Optional, Sequence

from lmpc_bridge import render
from lmpc_bridge.render import (
    RenderError,
    RunData,
    load_run,
    plot_oc_bars,
    render_gif,
    render_run,
    render_scene,
    save_run,
)
from lmpc_msgs_py.cli import file_arg, folder_arg

METHODS = ("mpc", "lmpc-rules")
MULTI_MODES = ("none", "distributed", "central")


def run_in_process(family: str, seed: int, method: str, *, work_dir: Path,
                   max_time_s: Optional[float] = None,
                   instruction: Optional[str] = None) -> RunData:
    """``lmpc_bridge.render.run_in_process`` with the method registry's planner and
    controller; ``method`` is one of ``METHODS``."""
    if method not in METHODS:
        raise RenderError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    from lmpc_scripts.methods import build

    return render.run_in_process(family, seed, method, build=build, work_dir=work_dir,
                                 max_time_s=max_time_s, instruction=instruction)


def shaded_sections(maps: dict) -> tuple[str, ...]:
    """The lanes of the shared (one-lane) sections on the egos' maps, both directions
    (the planner's conflict detection, ``coordination.conflicts.shared_sections``)."""
    from lmpc_llm_planner.coordination.conflicts import shared_sections

    lanes = {lid for mp in maps.values() for sec in shared_sections(mp)
             for lid in (sec.via, sec.partner)}
    return tuple(sorted(lanes))


def run_multi(family: str, seed: int, method: str, mode: str, *, work_dir: Path,
              max_time_s: float = 120.0) -> render.MultiRunData:
    """One multi-ego episode in this process (``scripts/multi.py``'s wiring), for drawing."""
    if method not in METHODS:
        raise RenderError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if mode not in MULTI_MODES:
        raise RenderError(f"unknown coordination {mode!r}; choose from "
                          f"{', '.join(MULTI_MODES)}")
    from lmpc_bridge.scenarios import SceneError, build_scene
    from lmpc_scripts.multi import run_one

    try:
        scene = build_scene(family, seed, work_dir=work_dir)
        result, _ = run_one(family, seed, method, mode, work_dir, max_time_s=max_time_s)
    except SceneError as exc:
        raise RenderError(f"cannot run {family}/{seed} with several egos: {exc}") from exc
    return render.multi_run_data(result, method=method, mode=mode,
                                 shaded_lanes=shaded_sections(result.maps),
                                 net_file=Path(scene.net_file))


# --- command line ----------------------------------------------------------------------
def _parse(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    sc = sub.add_parser("scene", help="bird's-eye PNG of a scene")
    sc.add_argument("--family", required=True)
    sc.add_argument("--seed", type=int, default=0)
    sc.add_argument("--out", type=file_arg, default=None, help="default <family>_<seed>_scene.png")
    sc.add_argument("--work-dir", type=Path, default=None, help="scene cache folder")
    sc.add_argument("--full", action="store_true", help="the whole map, not the route area")
    rn = sub.add_parser("run", help="a run: path by speed, key moments, optional GIF")
    rn.add_argument("run_dir", type=Path, nargs="?", help="run folder with episode.json")
    rn.add_argument("--family", help="run this family in-process instead of reading a folder")
    rn.add_argument("--seed", type=int, default=0)
    rn.add_argument("--method", choices=METHODS, default="lmpc-rules")
    rn.add_argument("--max-time-s", type=float, default=None, help="cap an in-process run")
    rn.add_argument("--instruction", default=None,
                    help="the user's text for the in-process run's planner (e.g. 'drive "
                         "aggressively')")
    rn.add_argument("--save-run", type=folder_arg, default=None,
                    help="write the in-process run's episode.json / decisions.jsonl here")
    rn.add_argument("--out", type=file_arg, default=None, help="PNG (default RUN_DIR/run.png)")
    rn.add_argument("--gif", type=file_arg, default=None, help="also write an animated GIF")
    rn.add_argument("--every-k", type=int, default=3, help="GIF: every k-th step")
    rn.add_argument("--work-dir", type=Path, default=None, help="scene cache folder")
    bars = sub.add_parser("bars", help="O.C. bars from a benchmark's summary.json")
    bars.add_argument("results_dir", type=Path)
    bars.add_argument("--out", type=file_arg, default=None, help="default RESULTS_DIR/oc_bars.png")
    mu = sub.add_parser("multi", help="a multi-ego run: strip of instants, optional GIF")
    mu.add_argument("run_dir", type=Path, nargs="?",
                    help="a run folder of run_graph.py --egos N (else an in-process run)")
    mu.add_argument("--family", default=None, help="in-process run (default narrow)")
    mu.add_argument("--seed", type=int, default=0)
    mu.add_argument("--method", choices=METHODS, default="mpc")
    mu.add_argument("--coordination", choices=MULTI_MODES, default="central")
    mu.add_argument("--max-time-s", type=float, default=120.0)
    mu.add_argument("--instants", type=int, default=4, help="panels of the strip")
    mu.add_argument("--out", type=file_arg, default=None,
                    help="PNG strip (default <family>_<seed>_<coordination>_multi.png)")
    mu.add_argument("--gif", type=file_arg, default=None, help="also write an animated GIF")
    mu.add_argument("--every-k", type=int, default=4, help="GIF: every k-th step")
    mu.add_argument("--work-dir", type=Path, default=None, help="scene cache folder")
    args = ap.parse_args(argv)
    if args.command == "multi" and args.run_dir is not None and args.family is not None:
        ap.error("multi: give either RUN_DIR or --family (with --seed / --method)")
    if args.command == "multi" and args.run_dir is None and args.family is None:
        args.family = "narrow"
    if args.command == "run" and (args.run_dir is None) == (args.family is None):
        ap.error("run: give either RUN_DIR or --family (with --seed / --method)")
    if args.command == "run" and args.instruction is not None and args.run_dir is not None:
        ap.error("run: --instruction is for an in-process run (--family); a run folder "
                 "was driven with its own")
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
                                     max_time_s=args.max_time_s,
                                     instruction=args.instruction)
                default_out = Path(f"{args.family}_{args.seed}_{args.method}_run.png")
                if args.save_run:
                    print(save_run(run, args.save_run))
            print(render_run(run, out=args.out or default_out))
            if args.gif:
                print(render_gif(run, out=args.gif, every_k=args.every_k))
        elif args.command == "multi":
            if args.run_dir is not None:
                data = render.load_multi_run(args.run_dir, work_dir=args.work_dir,
                                             shade=shaded_sections)
                out = args.out or args.run_dir / "multi.png"
            else:
                work_dir = args.work_dir or Path(tempfile.mkdtemp(prefix="lmpc-render-"))
                data = run_multi(args.family, args.seed, args.method, args.coordination,
                                 work_dir=work_dir, max_time_s=args.max_time_s)
                out = args.out or Path(
                    f"{args.family}_{args.seed}_{args.coordination}_multi.png")
            print(render.render_multi_strip(data, out=out, instants=args.instants))
            if args.gif:
                print(render.render_multi_gif(data, out=args.gif, every_k=args.every_k))
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
