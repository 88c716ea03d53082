#!/usr/bin/env python3
"""Soak: many consecutive episodes across scenario families; memory and leaked processes.

Runs ``run_graph.py`` once per episode (the graph is **restarted per episode**: each
episode gets fresh node processes, as a user running episodes one after another
would; a long-lived graph across episodes is not supported by the bridge, which ends
its process with its episode). While an episode runs it samples the resident memory
(VmRSS) of every node process of the run's ROS domain every ``--sample-s`` wall
seconds. Prints one line per episode (outcome, sim and wall time, peak RSS of each
node), then the RSS of the first vs the last episode of each family and of the whole
series, and checks that no LanguageMPC node process is left running.

    soak.py --episodes 30 --families usi,si,lane,rab,eoa --planner rules --domain-id 80

Exit code 0 when every check holds: no episode ended in ``error``, no process left,
and each node's peak RSS in the last episode of a family is within
``--rss-bound-mb`` (default 30 MB) plus ``--rss-bound-frac`` (default 10 %) of its
peak in the first episode of that family.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

from lmpc_msgs_py.cli import folder_arg
from lmpc_msgs_py.discovery import stay_local

SCRIPTS = Path(__file__).resolve().parent
RUN_GRAPH = SCRIPTS / "run_graph.py"
NODE_NAMES = {
    b"lmpc_bridge.bridge_node": "bridge",
    b"lmpc_mpc.mpc_node": "mpc",
    b"lmpc_llm_planner.planner_node": "planner",
    b"lmpc_llm_planner.mock_llm_node": "mock_llm",
}


@dataclass
class Episode:
    index: int
    family: str
    seed: int
    outcome: str = "error"
    sim_time_s: float = 0.0
    wall_s: float = 0.0
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    detail: str = ""


def node_processes(domain_id: int) -> dict[int, str]:
    """``{pid: node name}`` of LanguageMPC node processes on ``domain_id``."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            if b"-m" not in cmdline:
                continue
            module = cmdline[cmdline.index(b"-m") + 1] if cmdline.index(b"-m") + 1 < len(
                cmdline) else b""
            if module not in NODE_NAMES:
                continue
            environ = (entry / "environ").read_bytes().split(b"\0")
        except (OSError, ValueError):
            continue
        if f"ROS_DOMAIN_ID={domain_id}".encode() in environ:
            out[int(entry.name)] = NODE_NAMES[module]
    return out


def rss_mb(pid: int) -> Optional[float]:
    """Resident set size of ``pid`` in MB (None when it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def run_episode(ep: Episode, *, args: argparse.Namespace, out_dir: Path) -> Episode:
    run_dir = out_dir / f"{ep.index:02d}-{ep.family}-{ep.seed}"
    summary_path = run_dir / "summary.json"
    cmd = [sys.executable, str(RUN_GRAPH), "--scenario", ep.family, "--seed", str(ep.seed),
           "--planner", args.planner, "--clock", args.clock, "--run-dir", str(run_dir),
           "--summary-json", str(summary_path), "--domain-id", str(args.domain_id),
           "--max-time-s", str(args.max_time_s), "--quiet"]
    env = stay_local(dict(os.environ))
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    peaks: dict[str, float] = {}
    while proc.poll() is None:
        for pid, name in node_processes(args.domain_id).items():
            value = rss_mb(pid)
            if value is not None:
                peaks[name] = max(peaks.get(name, 0.0), value)
        time.sleep(args.sample_s)
        if time.monotonic() - t0 > args.episode_timeout_s:
            proc.kill()
            ep.detail = f"killed after {args.episode_timeout_s:.0f} s wall"
    output = proc.communicate()[0]
    ep.wall_s = time.monotonic() - t0
    ep.peak_rss_mb = {k: round(v, 1) for k, v in sorted(peaks.items())}
    if summary_path.exists():
        summary = json.loads(summary_path.read_text())
        ep.outcome = str(summary.get("outcome", "error"))
        ep.sim_time_s = float(summary.get("sim_time_s", 0.0))
        ep.detail = ep.detail or str(summary.get("detail", ""))
    else:
        ep.detail = ep.detail or output.strip().splitlines()[-1:][0] if output.strip() else \
            "no summary"
    return ep


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--families", default="usi,si,lane,rab,eoa",
                    help="comma-separated families, used in turn; seed = round number")
    ap.add_argument("--planner", default="rules",
                    choices=["rules", "none", "openai", "local", "replay"])
    ap.add_argument("--clock", default="sync", choices=["sync", "realtime"])
    ap.add_argument("--max-time-s", type=float, default=120.0)
    ap.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", 80)))
    ap.add_argument("--out", type=folder_arg, default=Path("runs") / "soak")
    ap.add_argument("--sample-s", type=float, default=0.5)
    ap.add_argument("--episode-timeout-s", type=float, default=600.0)
    ap.add_argument("--rss-bound-mb", type=float, default=30.0)
    ap.add_argument("--rss-bound-frac", type=float, default=0.10)
    return ap.parse_args(argv)


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    if not families or args.episodes < 1:
        print("soak: need at least one family and one episode", file=sys.stderr)
        return 2
    out_dir = args.out.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    left = node_processes(args.domain_id)
    if left:
        print(f"soak: node processes already running on domain {args.domain_id}: {left}; "
              "choose another --domain-id", file=sys.stderr)
        return 2
    episodes: list[Episode] = []
    t_start = time.monotonic()
    print(f"soak: {args.episodes} episodes, families {families}, planner {args.planner}, "
          f"clock {args.clock}, domain {args.domain_id}, graph restarted per episode",
          flush=True)
    for i in range(args.episodes):
        ep = Episode(i, families[i % len(families)], i // len(families))
        run_episode(ep, args=args, out_dir=out_dir)
        episodes.append(ep)
        rss = " ".join(f"{k}={v:.0f}MB" for k, v in ep.peak_rss_mb.items())
        print(f"[{i + 1:2d}/{args.episodes}] {ep.family:5s} seed {ep.seed:2d}: {ep.outcome:9s} "
              f"sim {ep.sim_time_s:6.1f} s wall {ep.wall_s:6.1f} s peak RSS {rss}"
              + (f"  ({ep.detail})" if ep.outcome == "error" else ""), flush=True)
    time.sleep(1.0)
    leftover = node_processes(args.domain_id)
    ok = True
    print(f"\nsoak done in {time.monotonic() - t_start:.0f} s wall", flush=True)
    outcomes: dict[str, int] = {}
    for ep in episodes:
        outcomes[ep.outcome] = outcomes.get(ep.outcome, 0) + 1
    print(f"outcomes: {outcomes}")
    if outcomes.get("error"):
        ok = False
    first, last = episodes[0], episodes[-1]
    print(f"peak RSS first episode ({first.family} {first.seed}): {first.peak_rss_mb}")
    print(f"peak RSS last episode  ({last.family} {last.seed}): {last.peak_rss_mb}")
    for fam in families:
        runs = [e for e in episodes if e.family == fam and e.peak_rss_mb]
        if len(runs) < 2:
            continue
        a, b = runs[0], runs[-1]
        for node, mb in a.peak_rss_mb.items():
            if node not in b.peak_rss_mb:
                continue
            bound = mb * (1 + args.rss_bound_frac) + args.rss_bound_mb
            good = b.peak_rss_mb[node] <= bound
            ok &= good
            print(f"  {fam:5s} {node:8s} first {mb:7.1f} MB  last {b.peak_rss_mb[node]:7.1f} MB"
                  f"  bound {bound:7.1f} MB  {'ok' if good else 'GROWTH'}")
    print(f"node processes left on domain {args.domain_id}: {sorted(leftover) or 'none'}")
    ok &= not leftover
    summary = {"episodes": [ep.__dict__ for ep in episodes], "outcomes": outcomes,
               "leftover_pids": sorted(leftover), "ok": ok}
    (out_dir / "soak.json").write_text(json.dumps(summary, indent=1))
    print(f"soak {'PASSED' if ok else 'FAILED'} (details: {out_dir / 'soak.json'})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
