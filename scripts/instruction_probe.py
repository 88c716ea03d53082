#!/usr/bin/env python3
"""Text-modulated driving, measured in-process for any planner backend (paper Fig. 5 / 7).

The two scenes of ``test/test_graph_instruction.py``, run with the benchmark's wiring
(``benchmark.make_planner``: the same planner core and MPC as the nodes, no ROS), each
cut short as the graph test cuts it, with and without the user's instruction:

- ``construction`` seed 0, 12 s: the ego starts in the lane closed ~200 m ahead;
  printed: where (distance to the target) and when it first leaves that lane, plain vs
  "The right lane is closed ahead.";
- ``lane`` seed 101, 12 s: the ego starts in the fast left lane, its exit lane to the
  right; printed: when it first reaches the exit lane, "drive conservatively" vs
  "drive aggressively".

The graph test asserts these for ``rules``; for ``local`` (SmolLM2) they are a reported
figure. Every decision of a ``local`` run takes seconds of wall time (8 s here).

    instruction_probe.py --methods lmpc-rules,lmpc-local [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchmark import make_planner  # noqa: E402

CLOSED = "The right lane is closed ahead."
CASES = (  # (family, seed, cut at s, instruction)
    ("construction", 0, 12.0, None),
    ("construction", 0, 12.0, CLOSED),
    ("lane", 101, 12.0, "drive conservatively"),
    ("lane", 101, 12.0, "drive aggressively"),
)


def run_case(sim: Any, method: str, family: str, seed: int, max_time_s: float,
             instruction: Optional[str]) -> dict[str, Any]:
    from lmpc_bridge.runner import run_episode
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController

    t0 = time.perf_counter()
    res = run_episode(sim, family=family, seed=seed,
                      controller=MpcController(load_mpc_config()),
                      planner=make_planner(method, instruction), max_time_s=max_time_s)
    steps = res.record.steps
    start_lane = steps[0].lane_id or ""
    off = next((s for s in steps if s.lane_id is not None and s.lane_id != start_lane),
               None)
    exit_lane = start_lane.rsplit("_", 1)[0] + "_0"
    on_exit = next((s.t_s for s in steps if s.lane_id == exit_lane), math.inf)
    return {
        "method": method, "family": family, "seed": seed, "instruction": instruction,
        "outcome": res.outcome, "collision": res.outcome == "collision",
        "decisions": res.decisions, "fallbacks": res.fallbacks,
        "start_lane": start_lane,
        "left_start_lane_at_s": off.t_s if off else None,
        "left_start_lane_dist_to_target_m": round(off.dist_to_target_m, 1) if off else None,
        "first_on_exit_lane_s": on_exit, "wall_s": round(time.perf_counter() - t0, 1),
    }


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--methods", default="lmpc-rules,lmpc-local")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args(argv)
    from lmpc_bridge.sim import SumoSim

    sim = SumoSim(work_dir=Path(tempfile.mkdtemp(prefix="lmpc-instr-")))
    rows = []
    for method in args.methods.split(","):
        for family, seed, cut_s, text in CASES:
            row = run_case(sim, method.strip(), family, seed, cut_s, text)
            rows.append(row)
            where = (f"left lane {row['start_lane']} at t={row['left_start_lane_at_s']} s, "
                     f"{row['left_start_lane_dist_to_target_m']} m to target"
                     if family == "construction" else
                     f"first on the exit lane at t={row['first_on_exit_lane_s']} s")
            print(f"{method} {family} {seed} instruction={text!r}: {row['outcome']}, {where}, "
                  f"{row['decisions']} decisions, {row['fallbacks']} fallbacks, "
                  f"{row['wall_s']} s wall", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
