"""The MPC's NLP functions as generated C: a faster solve with the same iterates to the bit.

FATROP and IPOPT call CasADi functions (cost, constraints, their derivatives, the Lagrangian's
Hessian) at every iteration; CasADi evaluates them in its virtual machine unless they are
generated as C and compiled (``jit``). Compiled with ``gcc -O1`` they evaluate the same
operations in the same order (no ``-ffast-math``, no FMA contraction on the x86-64
baseline), so a solve gives the same iterates to the last bit (checked per solve in
test_mpc_codegen.py and on `make bench`'s rows: docs/RESULTS.md, "Generated C") while the
evaluations take about a third of their interpreted time: FATROP at N = 30 with 10 agents
~15 % faster (docs/RESULTS.md).

Compiling takes ~2-15 s a problem size, so it never happens inside a control step: the
compiled problem lives in the solver cache (:mod:`lmpc_mpc.solver_cache`, the binary
embedded in the entry, so loading needs no compiler) and ``MpcConfig.codegen`` says when it
is made and used:

- ``auto`` (default): use a compiled entry when the cache has one, else the interpreted
  functions (built or loaded as before). ``python -m lmpc_mpc.codegen`` makes the entries of
  the packaged config (``make solvers``, which ``make demo`` / ``test`` / ``bench`` run: a
  no-op when they exist);
- ``build``: compile a missing entry on first use;
- ``off``: never (the interpreted functions).

Any change to the MPC's code or config is a new cache key, so run the command again after
editing (until then the MPC runs interpreted: the same results, slower). Without a working C
compiler or a writable cache the build logs one warning and the MPC runs interpreted.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import tempfile
import time
from typing import Any, Callable, Optional, Sequence

import casadi as ca
import numpy as np

from lmpc_mpc import solver_cache

FLAGS = ("-O1",)
"""Compiler flags; -O2 / -O3 measured no faster (docs/RESULTS.md, "Generated C")."""
TAG = "generated C, gcc " + " ".join(FLAGS)
"""Part of a compiled entry's cache key (the interpreted entry's key has no such part)."""

_LOG = logging.getLogger(__name__)

Entry = tuple[ca.Function, dict[str, np.ndarray]]


def options(folder: str) -> dict[str, Any]:
    """``nlpsol`` options that compile the problem's functions in ``folder``."""
    return {"jit": True, "compiler": "shell", "jit_serialize": "embed",
            "jit_options": {"flags": list(FLAGS), "verbose": False, "directory": folder}}


def build_and_store(build: Callable[[dict[str, Any]], Entry], key: str) -> Optional[Entry]:
    """Compile with ``build(options)`` in a scratch folder (CasADi writes its C source to the
    working directory), store the result under ``key`` and return it as loaded from the
    cache; None when there is no cache or the compiler failed (the caller then runs the
    interpreted functions)."""
    if solver_cache.cache_dir() is None:
        _LOG.warning("generated C needs the solver cache (%s=off): interpreted functions",
                     solver_cache.CACHE_ENV)
        return None
    try:
        with tempfile.TemporaryDirectory(prefix="lmpc-codegen-") as tmp, contextlib.chdir(tmp):
            fn, arrays = build(options(tmp))
            # embed reads the compiled library now, while the scratch folder still holds it
            stored = solver_cache.store(key, fn, arrays)
            del fn
    except Exception as exc:  # noqa: BLE001 - no compiler must not stop the MPC
        _LOG.warning("compiling the MPC's functions failed (%s): interpreted functions",
                     str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__)
        return None
    return solver_cache.load(key) if stored else None


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Compile the problem sizes of an MPC config (default: the packaged one) into the cache."""
    from lmpc_mpc.config import MpcConfigError, load_mpc_config
    from lmpc_mpc.solver import MpcSolver

    ap = argparse.ArgumentParser(prog="python -m lmpc_mpc.codegen", description=__doc__.split(
        "\n\n")[0])
    ap.add_argument("--config", default=None, help="MPC config YAML (default: packaged)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_mpc_config(args.config)
    except MpcConfigError as exc:
        ap.error(f"--config: {exc}")
    solver = MpcSolver(cfg.model_copy(update={"codegen": "build"}))
    started = time.perf_counter()
    for size in cfg.agent_slot_sizes:
        solver.compiled(size)  # the hybrid sqp_rti's: its FATROP fallback's
    done = sorted(solver.generated_sizes())
    print(f"lmpc_mpc.codegen: {cfg.solver}, {len(done)} of "
          f"{len(cfg.agent_slot_sizes)} problem sizes as generated C (slots {done}) in "
          f"{time.perf_counter() - started:.1f} s; cache {solver_cache.cache_dir()}")
    if cfg.solver != "ipopt" and cfg.retry_solver != "none":
        # the retry of a failed FATROP solve (MpcConfig.retry_solver), interpreted, in the
        # cache for sync runs and for realtime ones (its wall-time cap is compiled in), so
        # no run builds it: a realtime MPC node loads it at warm-up
        started = time.perf_counter()
        for realtime in (False, True):
            retry = MpcSolver(cfg.model_copy(update={"codegen": "off"}),
                              solver=cfg.retry_solver)
            retry.enforce_time_budget = realtime
            for size in cfg.agent_slot_sizes:
                retry.compiled(size)
        print(f"lmpc_mpc.codegen: the {cfg.retry_solver} retry's sizes (sync, realtime) in "
              f"the cache in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
