"""The planner's process loads what it needs: the MPC's stop rule and geometry, not the
MPC's solver or CasADi (~60 ms of every graph start-up; ``lmpc_mpc.stop_line``)."""
from __future__ import annotations

import subprocess
import sys


def test_the_planner_node_does_not_load_the_solver() -> None:
    probe = ("import sys, lmpc_llm_planner.planner_node; "
             "print(sorted(m for m in ('casadi', 'lmpc_mpc.solver', 'lmpc_mpc.controller') "
             "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]", out.stdout
