"""Solve-time benchmark of the MPC (no ROS, synthetic scene): ``run(...)`` and ``main(argv)``.

The scene is synthetic: the ego drives a straight road in closed loop (same bicycle
model as the solver's plant, :func:`lmpc_mpc.solver.simulate_bicycle`) with
``n_agents`` cars spread 20-78 m ahead over both eastbound lanes and the westbound
lane, all within sensing range and so all attended (the nearest ones end up in
the ego's way and make it brake). Figures are wall times on whatever else the
machine is doing: run it on an idle machine for numbers to quote.

``python -m lmpc_mpc.bench`` (or ``scripts/bench_mpc.py``) prints median / p99 / max
solve time, the controller's whole ``compute`` time and the solver iterations for
horizons 20 and 30 and 0, 5, 10, 20 agents, FATROP, SQP-RTI and IPOPT in the same run,
and every solver's ratios to the first one named (wall and CPU). A second table keeps
``--present`` agents (default 20) in the scene but attends only the nearest k of them
(k from ``--agents``; the controller's ``max_agents``): only attended agents enter the
problem, so this shows what attention saves. ``cpu med`` is the process CPU time of
``compute`` and ``solve cpu`` that of the solve (what a loaded machine inflates least);
the other columns are wall time.
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Optional, Sequence

import numpy as np

from lmpc_msgs_py.cli import int_arg
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import MpcConfig, MpcConfigError, load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import SOLVERS, MpcProblem, MpcResult, MpcSolver, simulate_bicycle

_LANES = (("E0_0", -4.8, 0.0, 6.0), ("E0_1", -1.6, 0.0, 7.0), ("-E0_0", 1.6, math.pi, 8.0))
"""(lane id, y_m, yaw_rad, speed_mps) of the lanes the agents are spread over."""


def _agents(n_agents: int, t_s: float) -> list:
    out = []
    for i in range(n_agents):
        lane, y, yaw, v = _LANES[i % len(_LANES)]
        x0 = 30.0 + 58.0 * (i + 0.5) / max(n_agents, 1)
        x = x0 + (v if yaw == 0.0 else -v) * t_s
        out.append(S.agent(f"a{i}", x_m=x, y_m=y, yaw_rad=yaw, v_mps=v, lane_id=lane))
    return out


def run(*, n_agents: int = 10, steps: int = 100, solver: str = "fatrop",
        horizon: Optional[int] = None, config: Optional[MpcConfig] = None,
        attended: Optional[int] = None, verbose: bool = True) -> dict[str, float]:
    """Closed-loop solve times; returns (and prints) median / p99 / max in ms of the
    solve and of the controller's whole ``compute`` (and its thread CPU time, which a
    busy machine inflates less), solver iterations and failures.

    ``attended``: attend only the nearest this many of the ``n_agents`` present (None:
    all in sensing range, the baseline). The first step (which builds the compiled
    problems) is left out of the figures."""
    cfg = config or load_mpc_config()
    name, _, steps_text = solver.partition(":")
    # "fatrop+c": the problem as generated C (lmpc_mpc.codegen; compiled on first use);
    # without "+c" the interpreted functions, today's baseline, whatever the cache holds
    name, generated = name.removesuffix("+c"), name.endswith("+c")
    upd: dict[str, object] = {"solver": name, "time_budget_s": 10.0,
                              "codegen": "build" if generated else "off"}
    if steps_text:
        # "sqp_rti:1": the RTI with at most this many Gauss-Newton steps per control step
        upd["rti_iterations"] = int(steps_text)
    if horizon is not None:
        upd["horizon"] = horizon
    if attended is not None:
        upd["max_agents"] = attended
    cfg = cfg.model_copy(update=upd)
    mpc = MpcSolver(cfg, DEFAULT_VEHICLE)
    mpc.warm_up()
    iters: list[int] = []
    solve_cpu: list[float] = []
    inner = mpc.solve

    def counting_solve(problem: MpcProblem) -> MpcResult:
        res = inner(problem)
        iters.append(res.iterations)
        solve_cpu.append(res.solve_cpu_s * 1e3)
        return res

    mpc.solve = counting_solve  # type: ignore[method-assign]
    ctrl = MpcController(cfg, solver=mpc)
    m = S.straight_road(length_m=1000.0)
    x = np.array([10.0, -4.8, 0.0, 8.0])
    times: list[float] = []
    wall: list[float] = []
    cpu: list[float] = []
    fails = 0
    for k in range(steps):
        t = k * cfg.dt_s
        ego = S.ego_state(x_m=float(x[0]), y_m=float(x[1]),
                          yaw_rad=float(math.remainder(x[2], 2 * math.pi)),
                          v_mps=float(x[3]), stamp_s=t, seq=k, lane_id="E0_0")
        obs = S.observation(m, ego, _agents(n_agents, t))
        started = time.perf_counter()
        cpu0 = time.process_time()
        ctl = ctrl.compute(obs)
        elapsed_ms = (time.perf_counter() - started) * 1e3
        cpu_ms = (time.process_time() - cpu0) * 1e3
        if ctl.mode in ("shifted", "brake"):
            fails += 1
        elif k > 0:
            times.append(ctl.solve_time_ms)
            wall.append(elapsed_ms)
            cpu.append(cpu_ms)
        x = simulate_bicycle(x, np.array([[ctl.accel_mps2, ctl.steer_rad]]), dt_s=cfg.dt_s)[1]
    arr = np.array(times) if times else np.array([math.nan])
    w = np.array(wall) if wall else np.array([math.nan])
    it = np.array(iters[1:] if len(iters) > 1 else [0])
    sc = np.array(solve_cpu[1:] if len(solve_cpu) > 1 else [math.nan])
    out = {"median_ms": float(np.median(arr)), "p99_ms": float(np.percentile(arr, 99)),
           "max_ms": float(np.max(arr)), "compute_median_ms": float(np.median(w)),
           "compute_p99_ms": float(np.percentile(w, 99)),
           "compute_cpu_median_ms": float(np.median(cpu)) if cpu else math.nan,
           "compute_cpu_p99_ms": float(np.percentile(cpu, 99)) if cpu else math.nan,
           "solve_cpu_median_ms": float(np.median(sc)),
           "solve_cpu_p99_ms": float(np.percentile(sc, 99)),
           "iter_median": float(np.median(it)),
           "iter_max": float(np.max(it)), "failures": float(fails),
           # sqp_rti: steps FATROP answered because the RTI did not deliver them
           "rti_fallbacks": float(mpc.rti_fallbacks)}
    if verbose:
        print(f"{solver} N={cfg.horizon} agents={n_agents}: median {out['median_ms']:.2f} ms, "
              f"p99 {out['p99_ms']:.2f} ms, max {out['max_ms']:.2f} ms, iterations "
              f"{out['iter_median']:.0f} / {out['iter_max']:.0f} (median / max), compute "
              f"{out['compute_median_ms']:.2f} / {out['compute_p99_ms']:.2f} ms, "
              f"failures {fails}, FATROP fallbacks {mpc.rti_fallbacks} of {steps} steps")
    return out


def _table(rows: dict[tuple[int, int, str], dict[str, float]], what: str) -> None:
    head = (f"{'N':>3} {what:>6} {'solver':>9} | {'median':>7} {'p99':>7} {'max':>7} ms"
            f" | {'iter med':>8} {'max':>4} | {'compute med':>11} {'p99':>7} | "
            f"{'cpu med':>7} {'p99':>7} ms | {'solve cpu':>9} {'p99':>6} ms | fail | "
            f"FATROP fallbacks")
    print(head)
    print("-" * len(head))
    for (horizon, n_agents, name), r in rows.items():
        print(f"{horizon:>3} {n_agents:>6} {name:>9} | {r['median_ms']:7.2f} {r['p99_ms']:7.2f}"
              f" {r['max_ms']:7.2f}    | {r['iter_median']:8.0f} {r['iter_max']:4.0f} | "
              f"{r['compute_median_ms']:11.2f} {r['compute_p99_ms']:7.2f} | "
              f"{r['compute_cpu_median_ms']:7.2f} {r['compute_cpu_p99_ms']:7.2f}    | "
              f"{r['solve_cpu_median_ms']:9.2f} {r['solve_cpu_p99_ms']:6.2f}    | "
              f"{r['failures']:4.0f} | {r['rti_fallbacks']:.0f}")


def _solver_arg(text: str) -> str:
    name, _, steps = text.partition(":")
    name = name.removesuffix("+c")
    if name not in SOLVERS or (steps and (name != "sqp_rti" or not steps.isdigit()
                                          or int(steps) < 1)):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected one of {', '.join(SOLVERS)} (+c: as generated C) or "
            "sqp_rti:K (K >= 1)")
    return text


def _horizon_range() -> tuple[int, int]:
    """The horizons ``MpcConfig`` accepts (its field's bounds)."""
    meta = MpcConfig.model_fields["horizon"].metadata
    lo = next(int(m.ge) for m in meta if hasattr(m, "ge"))
    hi = next(int(m.le) for m in meta if hasattr(m, "le"))
    return lo, hi


def _ratio(num: dict[str, float], den: dict[str, float], key: str) -> str:
    d = den[key]
    return f"{num[key] / d:.2f}" if d > 0 and math.isfinite(d) else "nan"


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: the solvers' table over horizons and agent counts, then each solver's
    ratios to the first one named (``--solvers``, default FATROP)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    n_lo, n_hi = _horizon_range()
    ap.add_argument("--horizons", type=int_arg(n_lo, n_hi), nargs="+", default=[20, 30],
                    help=f"control steps N ({n_lo}-{n_hi}, the config's range)")
    ap.add_argument("--agents", type=int_arg(0), nargs="+", default=[0, 5, 10, 20])
    ap.add_argument("--solvers", nargs="+", default=["fatrop", "sqp_rti", "ipopt"],
                    type=_solver_arg,
                    help=f"any of {', '.join(SOLVERS)} (interpreted); with '+c' (e.g. "
                         "fatrop+c) the NLP as generated C (lmpc_mpc.codegen, compiled on "
                         "first use); 'sqp_rti:K' caps the RTI at K Gauss-Newton steps per "
                         "control step (config: rti_iterations)")
    ap.add_argument("--steps", type=int_arg(1), default=100,
                    help="closed-loop steps per cell")
    ap.add_argument("--present", type=int_arg(0), default=20,
                    help="agents present in the attention table (0: no such table)")
    ap.add_argument("--config", default=None, help="MPC config YAML (default: packaged)")
    args = ap.parse_args(list(argv) if argv is not None else None)
    try:
        cfg = load_mpc_config(args.config)
    except MpcConfigError as exc:
        ap.error(f"--config: {exc}")
    rows: dict[tuple[int, int, str], dict[str, float]] = {}
    for horizon in args.horizons:
        for n_agents in args.agents:
            for name in args.solvers:
                rows[(horizon, n_agents, name)] = run(
                    n_agents=n_agents, steps=args.steps, solver=name, horizon=horizon,
                    config=cfg, verbose=False)
    _table(rows, "agents")
    if args.present > 0:
        att: dict[tuple[int, int, str], dict[str, float]] = {}
        for horizon in args.horizons:
            for k in args.agents:
                if k > args.present:
                    continue
                for name in args.solvers:
                    att[(horizon, k, name)] = run(
                        n_agents=args.present, attended=k, steps=args.steps, solver=name,
                        horizon=horizon, config=cfg, verbose=False)
        print(f"\n{args.present} agents present, only the nearest k attended "
              f"(the others never enter the problem):")
        _table(att, "k att")
    base = args.solvers[0]
    for other in args.solvers[1:]:
        print(f"\n{other} / {base} (p99 and median; < 1: {other} is faster):")
        for horizon in args.horizons:
            for n_agents in args.agents:
                b, o = rows[(horizon, n_agents, base)], rows[(horizon, n_agents, other)]
                print(f"  N={horizon:<3} agents={n_agents:<3} "
                      f"solve wall med x{_ratio(o, b, 'median_ms')}  "
                      f"p99 x{_ratio(o, b, 'p99_ms')} | "
                      f"solve cpu med x{_ratio(o, b, 'solve_cpu_median_ms')}  "
                      f"p99 x{_ratio(o, b, 'solve_cpu_p99_ms')} | "
                      f"compute cpu p99 x{_ratio(o, b, 'compute_cpu_p99_ms')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
