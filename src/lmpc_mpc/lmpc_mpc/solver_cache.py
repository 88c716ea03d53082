"""On-disk cache of the compiled MPC problems: a node starts in ~0.1 s instead of ~1.5 s.

Building the five problem sizes (symbolic set-up, then ``casadi.nlpsol``) is most of the
MPC node's start-up (docs/RESULTS.md, "Where the time goes"). CasADi serialises a built
solver (``Function.save`` / ``Function.load``, FATROP and IPOPT alike); a loaded solver
gives the same iterates to the last digit (test_mpc_solver_cache.py).

The key is a SHA-256 over everything the problem is built from: the source files of
``lmpc_mpc`` and ``lmpc_msgs_py`` (any code change is a new key), the MPC config, the
vehicle, the slot count, the solver and its options, and the CasADi and Python versions.
Entries are written to a temporary name and renamed, so parallel builders (benchmark
workers, graph tests) never read half a file; an unreadable entry is rebuilt.

Where: ``$LMPC_SOLVER_CACHE`` (a directory; ``off`` disables the cache), else
``$XDG_CACHE_HOME/languagempc/solvers``, else ``~/.cache/languagempc/solvers``.
Stale entries are never read again (a new key); delete the folder to reclaim the space
(~1 MB per entry).
"""
from __future__ import annotations

import hashlib
import logging
import os
import sys
from functools import lru_cache
from pathlib import Path
from typing import Optional

import casadi as ca
import numpy as np

CACHE_ENV = "LMPC_SOLVER_CACHE"
_PACKAGES = ("lmpc_mpc", "lmpc_msgs_py")
_LOG = logging.getLogger(__name__)


def cache_dir() -> Optional[Path]:
    """The cache folder, or None when ``$LMPC_SOLVER_CACHE`` is ``off``."""
    value = os.environ.get(CACHE_ENV, "")
    if value.lower() == "off":
        return None
    if value:
        return Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "languagempc" / "solvers"


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of the problem-building code: the .py files of both packages, CasADi, Python."""
    versions = f"casadi {getattr(ca, '__version__', '?')} python {sys.version}"
    digest = hashlib.sha256(versions.encode())
    for package in _PACKAGES:
        root = Path(str(__import__(package).__file__)).parent
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def entry_key(*parts: str) -> str:
    """The cache key of one problem: the code fingerprint and ``parts`` (its inputs)."""
    digest = hashlib.sha256(code_fingerprint().encode())
    for part in parts:
        digest.update(b"\0" + part.encode())
    return digest.hexdigest()[:32]


def load(key: str) -> Optional[tuple[ca.Function, dict[str, np.ndarray]]]:
    """The cached solver and its arrays, or None (no cache, no entry, unreadable entry)."""
    folder = cache_dir()
    if folder is None:
        return None
    fn_path, arr_path = folder / f"{key}.casadi", folder / f"{key}.npz"
    if not (fn_path.exists() and arr_path.exists()):
        return None
    try:
        with np.load(arr_path) as data:
            arrays = {name: data[name] for name in data.files}
        return ca.Function.load(str(fn_path)), arrays
    except Exception as exc:  # noqa: BLE001 - a broken entry is rebuilt, never fatal
        _LOG.warning("solver cache entry %s unreadable (%s): rebuilding it", fn_path, exc)
        return None


def store(key: str, solver: ca.Function, arrays: dict[str, np.ndarray]) -> bool:
    """Write an entry (atomically); False when there is no cache or it cannot be written."""
    folder = cache_dir()
    if folder is None:
        return False
    tmp = f".{os.getpid()}.tmp"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fn_tmp, arr_tmp = folder / f"{key}.casadi{tmp}", folder / f"{key}{tmp}.npz"
        solver.save(str(fn_tmp))
        np.savez(arr_tmp, **arrays)  # type: ignore[arg-type]
        # the arrays last: load() needs both, so a reader never pairs new with missing
        os.replace(fn_tmp, folder / f"{key}.casadi")
        os.replace(arr_tmp, folder / f"{key}.npz")
        return True
    except Exception as exc:  # noqa: BLE001 - a read-only home must not stop the MPC
        _LOG.warning("solver cache %s not writable (%s): building each start", folder, exc)
        return False
