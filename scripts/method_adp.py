"""The ``adp`` method: the MPC baseline with its solve replaced by the ADP network's
forward pass (``lmpc_mpc.adp``; docs/RL.md, "ADP").

No planner: like ``mpc``, the controller tracks the route with the baseline's weights;
each step it packs the same problem (reference, attended agents, obstacle half-planes)
and the network maps it to the horizon's controls in numpy (no JAX). The network is
``adp.npz`` in ``--policy-dir`` / ``$LMPC_POLICY_DIR``, else the repository's
``policies/`` (one network for every family)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional

from lmpc_bridge.evaluation.scenes import SceneSpec, Wiring
from lmpc_scripts.method_rl import DEFAULT_POLICY_DIR, POLICY_DIR_ENV

ADP_FILE = "adp.npz"
_SOLVER: Any = None  # one per process and network file


def adp_path(directory: Optional[Path] = None) -> Path:
    """``directory``, else ``$LMPC_POLICY_DIR``, else ``policies/``; file ``adp.npz``."""
    base = directory or Path(os.environ.get(POLICY_DIR_ENV) or DEFAULT_POLICY_DIR)
    return base / ADP_FILE


def make_controller(path: Optional[Path] = None) -> Any:
    """The MPC controller on this process's ADP solver (built once per network file),
    reset: no plan carried over from the previous episode."""
    global _SOLVER
    from lmpc_mpc.adp import load_adp, make_adp_solver
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController

    path = (path or adp_path()).resolve()
    cfg = load_mpc_config()
    if _SOLVER is None or _SOLVER[0] != path:
        _SOLVER = (path, make_adp_solver(cfg, load_adp(path)))
    solver = _SOLVER[1]
    solver.reset()
    return MpcController(cfg, solver=solver)


def build(spec: SceneSpec) -> Wiring:
    """``adp``: no planner, the controller's solve is the network's forward pass."""
    from lmpc_scripts import methods

    controller = make_controller()

    def finish(log: Optional[Path]) -> dict[str, Any]:
        cells = methods.controller_cells(controller, log)
        cells["note"] = f"adp: network {adp_path().name} (forward pass instead of the solve)"
        return cells

    return Wiring(None, controller, finish)
