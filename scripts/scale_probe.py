#!/usr/bin/env python3
"""Scale probe: load time of a big network and the bridge's per-step observation work.

Builds (or takes) a big random network, fills it with background traffic from
SUMO's randomTrips.py, inserts the ego after a warm-up and drives it along its
route with a small pure-pursuit follower (a probe, not the MPC). Prints:

- ``load``: wall seconds of ``SumoSim.reset_scene`` (SUMO start + net parse +
  map build + warm-up excluded) and of the map build alone, edges, map lanes and
  the encoded ``MapSnapshot`` size;
- ``observation`` (a 600 veh/h stream on the ego's route, ending 5 s before the
  ego starts, puts traffic ahead of it):
  per step, the wall time of the bridge's observation work
  (reading the context subscription, histories, route progress, signals —
  ``SumoSim._refresh`` — plus building the ``Observation``), median / p99, and
  the number of vehicles in the simulation.

    scale_probe.py                          # netgenerate --rand net, 2,000+ edges, 500+ vehicles
    scale_probe.py --net my.net.xml --from E1 --to E9
"""
from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Optional, Sequence

from lmpc_msgs_py.codec import encode
from lmpc_msgs_py.messages import Control

from lmpc_bridge.mapping import build_map, read_net
from lmpc_bridge.scenarios.base import sumo_binary
from lmpc_bridge.scenarios.external import build_external_scene, fastest_route
from lmpc_bridge.sim import SimError, SumoSim


def make_big_net(out: Path, *, iterations: int, seed: int) -> Path:
    subprocess.run([sumo_binary("netgenerate"), "--rand", "--rand.iterations", str(iterations),
                    "--seed", str(seed), "--default.lanenumber", "2", "--tls.guess", "true",
                    "--no-turnarounds", "true", "--no-warnings", "true", "-o", str(out)],
                   check=True, capture_output=True, timeout=300)
    return out


def pick_long_route(net_file: Path) -> tuple[str, str]:
    """A start / destination pair about 8-12 edges apart near the middle of the net."""
    net = read_net(net_file)
    edges = sorted(net.getEdges(withInternal=False), key=lambda e: e.getID())
    xs = [n.coord[0] for n in net.nodes.values()]
    ys = [n.coord[1] for n in net.nodes.values()]
    cx, cy = statistics.fmean(xs), statistics.fmean(ys)
    edges.sort(key=lambda e: math.hypot(e.getFromNode().coord[0] - cx,
                                        e.getFromNode().coord[1] - cy))
    for a in edges[:50]:
        if a.getLength() < 60:
            continue
        for b in edges[::7]:
            path = fastest_route(net, a.getID(), b.getID())
            if path and 8 <= len(path) <= 12:
                return a.getID(), b.getID()
    raise SystemExit("no suitable route found; pass --from / --to")


def _pursuit(sim: SumoSim, path: list[tuple[float, float]]) -> Control:
    """Pure pursuit at 8 m/s along the route centerlines (probe only)."""
    p = sim.pose
    best = min(range(len(path)), key=lambda i: math.hypot(path[i][0] - p.x_m,
                                                          path[i][1] - p.y_m))
    look = path[min(best + 4, len(path) - 1)]
    alpha = math.atan2(look[1] - p.y_m, look[0] - p.x_m) - p.yaw_rad
    alpha = math.atan2(math.sin(alpha), math.cos(alpha))
    dist = max(math.hypot(look[0] - p.x_m, look[1] - p.y_m), 1.0)
    steer = math.atan2(2.0 * sim.vehicle.wheelbase_m * math.sin(alpha), dist)
    return Control(stamp_s=sim.time_s, seq=sim.step_index, accel_mps2=0.5 * (8.0 - p.v_mps),
                   steer_rad=max(min(steer, 0.5), -0.5), solve_time_ms=0.0, mode="baseline",
                   solver_status="probe")


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--net", type=Path, help="network (default: build a random one)")
    ap.add_argument("--iterations", type=int, default=1100,
                    help="netgenerate --rand iterations for the default net")
    ap.add_argument("--from", dest="from_edge")
    ap.add_argument("--to", dest="to_edge")
    ap.add_argument("--period-s", type=float, default=0.5,
                    help="randomTrips period (s): lower = more vehicles")
    ap.add_argument("--warmup-s", type=float, default=300.0)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--work-dir", type=Path)
    args = ap.parse_args(argv)
    work = args.work_dir or Path(tempfile.mkdtemp(prefix="lmpc-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    net_file = args.net or work / "big.net.xml"
    if not net_file.is_file():
        print(f"building {net_file} (netgenerate --rand, {args.iterations} iterations)...",
              flush=True)
        make_big_net(net_file, iterations=args.iterations, seed=3)
    a, b = (args.from_edge, args.to_edge) if args.from_edge else pick_long_route(net_file)
    # A dense stream on the ego's own route, so the ego drives in traffic (randomTrips
    # alone spreads the vehicles thinly over a big net).
    stream = work / "stream.rou.xml"
    stream.write_text(
        f'<routes><flow id="stream" from="{a}" to="{b}" begin="{args.warmup_s - 120}"'
        f' end="{args.warmup_s - 5}"'
        f' vehsPerHour="600" departLane="best" departSpeed="max"/></routes>\n')
    scene_yaml = work / "scale.yaml"
    scene_yaml.write_text(
        f"name: scale\nnet: {net_file.resolve()}\nseed: 1\nwarmup_s: {args.warmup_s}\n"
        f"routes: [{stream.name}]\n"
        f"max_time_s: 3600\nbackground: {{period_s: {args.period_s}, "
        f"end_s: {args.warmup_s + args.steps * 0.1 + 60:.0f}, seed: 1,"
        f" min_distance_m: 300}}\n"
        f"ego: {{start: {{edge: '{a}', pos_m: 5}}, to_edge: '{b}'}}\n")
    print("building the scene (randomTrips)...", flush=True)
    scene = build_external_scene(scene_yaml, work_dir=work)
    net = read_net(net_file)
    edges = len(net.getEdges(withInternal=False))

    t0 = time.perf_counter()
    snap, _ = build_map(scene)
    map_s = time.perf_counter() - t0
    sim = SumoSim(work_dir=work)
    # Load time = reset_scene without the warm-up (SUMO start, net parse, map, insertion).
    cold = scene.__class__(**{**scene.__dict__, "params": {**scene.params, "warmup_s": 0.0}})
    t0 = time.perf_counter()
    sim.reset_scene(cold)
    load_s = time.perf_counter() - t0
    sim.close()
    print(f"load: {edges} edges, reset_scene {load_s:.2f} s (map build alone {map_s:.2f} s), "
          f"map {len(snap.lanes)} lanes, {len(encode(snap)) / 1e3:.0f} kB encoded", flush=True)

    print(f"warm-up {args.warmup_s:.0f} s of traffic...", flush=True)
    for extra_s in range(0, 20, 2):  # the stream may occupy the start slot: a bit later
        try:
            sim.reset_scene(scene.__class__(**{**scene.__dict__, "params": {
                **scene.params, "warmup_s": args.warmup_s + extra_s}}))
            break
        except SimError as exc:
            print(f"  {exc}; trying {extra_s + 2} s later", flush=True)
    else:
        raise SystemExit("the ego's start stayed blocked; pass another --from edge")
    import libsumo

    path = [p for lane_id in sim.map.ego_route
            for lane in sim.map.lanes if lane.id == lane_id for p in lane.centerline]
    refresh = sim._refresh  # the bridge's per-step observation work (timed below)
    obs_ms: list[float] = []
    counts: list[int] = []
    agents: list[int] = []

    def timed_refresh() -> None:
        t = time.perf_counter()
        refresh()
        obs_ms.append((time.perf_counter() - t) * 1e3)

    sim._refresh = timed_refresh  # type: ignore[method-assign]
    for _ in range(args.steps):
        if sim.outcome != "running":
            break
        t = time.perf_counter()
        obs = sim.observe()
        obs_ms[-1:] = [obs_ms[-1] + (time.perf_counter() - t) * 1e3] if obs_ms else []
        agents.append(len(obs.agents.agents))
        counts.append(libsumo.vehicle.getIDCount())
        sim.step(_pursuit(sim, path))
    sim.close()
    ordered = sorted(obs_ms)
    p99 = ordered[min(len(ordered) - 1, math.ceil(0.99 * len(ordered)) - 1)]
    print(f"observation: {len(obs_ms)} steps, median {statistics.median(ordered):.3f} ms, "
          f"p99 {p99:.3f} ms; vehicles in the simulation {min(counts)}-{max(counts)} "
          f"(median {statistics.median(counts):.0f}), agents in sensing range "
          f"{min(agents)}-{max(agents)}; episode {sim.outcome}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
