"""Quick solve-time benchmark of the MPC (no ROS, synthetic scene): ``run(...)``.

The scene is synthetic: the ego drives a straight road in closed loop (same bicycle
model) with ``n_agents`` cars spread ahead in both lanes, all attended.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import MpcConfig, load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcSolver, simulate_bicycle


def run(*, n_agents: int = 10, steps: int = 100, solver: str = "fatrop",
        horizon: Optional[int] = None, config: Optional[MpcConfig] = None,
        verbose: bool = True) -> dict[str, float]:
    """Closed-loop solve times; returns and prints median / p99 / max in ms and failures."""
    cfg = config or load_mpc_config()
    upd: dict[str, object] = {"solver": solver, "time_budget_s": 10.0}
    if horizon is not None:
        upd["horizon"] = horizon
    cfg = cfg.model_copy(update=upd)
    mpc = MpcSolver(cfg, DEFAULT_VEHICLE)
    ctrl = MpcController(cfg, solver=mpc)
    m = S.straight_road(length_m=1000.0)
    x = np.array([10.0, -4.8, 0.0, 8.0])
    times: list[float] = []
    fails = 0
    for k in range(steps):
        t = k * cfg.dt_s
        agents = [S.agent(f"a{i}", x_m=40.0 + 15.0 * i + 6.0 * t,
                          y_m=-4.8 if i % 2 else -1.6, yaw_rad=0.0, v_mps=6.0,
                          lane_id="E0_0" if i % 2 else "E0_1") for i in range(n_agents)]
        ego = S.ego_state(x_m=float(x[0]), y_m=float(x[1]),
                          yaw_rad=float(math.remainder(x[2], 2 * math.pi)),
                          v_mps=float(x[3]), stamp_s=t, seq=k, lane_id="E0_0")
        ctl = ctrl.compute(S.observation(m, ego, agents))
        if ctl.mode in ("shifted", "brake"):
            fails += 1
        else:
            times.append(ctl.solve_time_ms)
        x = simulate_bicycle(x, np.array([[ctl.accel_mps2, ctl.steer_rad]]), dt_s=cfg.dt_s)[1]
    arr = np.array(times) if times else np.array([math.nan])
    out = {"median_ms": float(np.median(arr)), "p99_ms": float(np.percentile(arr, 99)),
           "max_ms": float(np.max(arr)), "failures": float(fails)}
    if verbose:
        print(f"{solver} N={cfg.horizon} agents={n_agents}: median {out['median_ms']:.2f} ms, "
              f"p99 {out['p99_ms']:.2f} ms, max {out['max_ms']:.2f} ms, failures {fails}")
    return out
