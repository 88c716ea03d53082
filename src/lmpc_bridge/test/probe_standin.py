"""Probe (not a test): the stand-in controller on seeds 0-24 of each family, one line each.

Usage::

    .venv/bin/python src/lmpc_bridge/test/probe_standin.py /tmp/scenes \
        usi,si,lane,rab,eoa,construction

Prints per family: outcome counts, time to target, in how many scenes somebody
came within 30 m of the ego, scene build time, and the seeds not reached.
"""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from conftest import StandInController  # noqa: E402

from lmpc_bridge.runner import run_episode  # noqa: E402
from lmpc_bridge.scenarios import build_scene  # noqa: E402
from lmpc_bridge.sim import SumoSim  # noqa: E402


def main(work: Path, families: list[str], n_seeds: int = 25) -> None:
    for fam in families:
        t0 = time.perf_counter()
        for s in range(n_seeds):
            build_scene(fam, s, work_dir=work)
        build_s = (time.perf_counter() - t0) / n_seeds
        sim = SumoSim(work_dir=work)
        counts: dict[str, int] = {}
        times: list[float] = []
        bad: list[str] = []
        interact = 0
        for seed in range(n_seeds):
            r = run_episode(sim, family=fam, seed=seed, controller=StandInController())
            counts[r.outcome] = counts.get(r.outcome, 0) + 1
            if r.outcome == "reached":
                times.append(r.metrics.time_s)
            else:
                bad.append(f"{seed}:{r.outcome}({r.detail[:40]})")
            if any(n.gap_m < 30.0 for st in r.record.steps for n in st.nearby):
                interact += 1
        sim.close()
        span = (f"time {min(times):.1f}-{max(times):.1f} s (median "
                f"{statistics.median(times):.1f})") if times else "no time"
        print(f"{fam}: {counts} {span}; someone within 30 m in {interact}/{n_seeds}; "
              f"build {build_s:.2f} s/scene; not reached: {bad}", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2].split(","))
