#!/usr/bin/env python3
"""MPC microbenchmark: solve time median / p99 / max and iterations per horizon, number of
attended agents and solver (FATROP, SQP-RTI and IPOPT in the same run, with ratios to the
first solver named; wall and process-CPU figures).

    bench_mpc.py --horizons 20 30 --agents 0 5 10 20 --solvers fatrop sqp_rti ipopt
    bench_mpc.py --horizons 30 --agents 10 --solvers fatrop fatrop+c   # generated C
"""
from __future__ import annotations

import sys

from lmpc_mpc.bench import main

if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
