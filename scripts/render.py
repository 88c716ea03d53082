#!/usr/bin/env python3
"""Pictures of scenes, runs and benchmark results (matplotlib; no ROS).

    render.py scene --family usi --seed 0 --out scene.png
    render.py run RUN_DIR [--out run.png] [--gif run.gif]
    render.py run --family usi --seed 0 --method lmpc-rules [--max-time-s 60] --out run.png
    render.py bars RESULTS_DIR                      -> RESULTS_DIR/oc_bars.png

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

METHODS = ("mpc", "lmpc-rules")


def run_in_process(family: str, seed: int, method: str, *, work_dir: Path,
                   max_time_s: Optional[float] = None) -> RunData:
    """``lmpc_bridge.render.run_in_process`` with the method registry's planner and
    controller; ``method`` is one of ``METHODS``."""
    if method not in METHODS:
        raise RenderError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    from lmpc_scripts.methods import build

    return render.run_in_process(family, seed, method, build=build, work_dir=work_dir,
                                 max_time_s=max_time_s)


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
