"""SUMO's static random number generators across the simulations of one process (exact
branching, docs/BRANCHING.md): which generators carry their call counts from one libsumo
simulation to the next (:data:`CARRIED_RNGS`), the counts the last simulation left
(:func:`counts_at_close`, noted by :func:`note_counts` when a simulation closes) and the
correction a state saved in a later simulation needs (:func:`correct_counts`)."""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import libsumo

CARRIED_RNGS = ("default", "routeHandler", "device", "device.btreceiver", "driverState",
                "device.toc")
"""The generators of a state file's ``<rngState>`` that are static in libsumo: a new
simulation in the same process seeds them afresh but does not reset their call counts,
and a state file stores a generator as its call count (``--save-state.rng``), which
``--load-state`` replays as that many draws from the fresh seed. A state saved in the
second simulation of a process therefore put these generators too far on (by every draw
of the simulations before it: usi seed 100 after one earlier run, vehicle ``onc2`` got
another speed factor). The per-lane generators (``<rngLane>``) and the flow generator
(``insertionControl``) belong to the simulation and start at 0 (measured on the five
families; docs/BRANCHING.md)."""
_COUNTS_AT_CLOSE: dict[str, int] | None = {}
"""Call counts of :data:`CARRIED_RNGS` when libsumo's last simulation in this process
was closed, i.e. what the next simulation's counts start from; None: not known (it could
not be read)."""
_RNG_STATE = re.compile(r"<rngState ([^>]*)>")
_RNG_ATTR = re.compile(r'([\w.]+)="([^"]*)"')


def rng_counts(state_text: str) -> dict[str, int]:
    """The call counts of :data:`CARRIED_RNGS` in a state file's text (a generator saved
    as its full state instead, which SUMO does past 10^6 calls, is left out)."""
    m = _RNG_STATE.search(state_text)
    if m is None:
        return {}
    return {k: int(v) for k, v in _RNG_ATTR.findall(m.group(1))
            if k in CARRIED_RNGS and v.isdigit() and len(v) < 10}


def counts_at_close() -> dict[str, int] | None:
    """What the last closed simulation of this process left (None: unknown)."""
    return _COUNTS_AT_CLOSE


def forget_counts() -> None:
    """The counts are unknown until the next :func:`note_counts` (a simulation restarted
    on a saved state)."""
    global _COUNTS_AT_CLOSE
    _COUNTS_AT_CLOSE = None


def note_counts(traci: Any, work_dir: Path) -> None:
    """Read the running simulation's counts of :data:`CARRIED_RNGS` (from a saved state:
    TraCI has no query) as the counts at close; None when that fails. Call it just
    before closing a libsumo simulation."""
    global _COUNTS_AT_CLOSE
    path = Path(work_dir) / f".rng-counts-{os.getpid()}.xml"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        traci.simulation.saveState(str(path))
        with path.open() as fh:
            head = fh.read(16384)  # <rngState> follows the options header
        _COUNTS_AT_CLOSE = rng_counts(head) if _RNG_STATE.search(head) else None
    except Exception:  # noqa: BLE001 - a broken simulation: the counts are not known
        _COUNTS_AT_CLOSE = None
    finally:
        path.unlink(missing_ok=True)


def correct_counts(path: Path, carry: dict[str, int]) -> None:
    """Rewrite the call counts of the static generators saved in the state file ``path``
    as draws since this simulation's seed (what ``--load-state`` replays from a fresh
    seed): subtract ``carry``, the counts carried from earlier simulations of the
    process. Raises ``ValueError`` when a saved count is below its carry."""
    if not any(carry.values()):
        return
    text = path.read_text()
    m = _RNG_STATE.search(text)
    if m is None:
        return

    def fix(a: re.Match) -> str:
        name, value = a.group(1), a.group(2)
        if name not in carry or not value.isdigit() or len(value) >= 10:
            return a.group(0)
        own = int(value) - carry[name]
        if own < 0:
            raise ValueError(f"SUMO's {name} generator counted {value} calls, fewer than "
                             f"the {carry[name]} carried from before this simulation")
        return f'{name}="{own}"'

    fixed = _RNG_ATTR.sub(fix, m.group(1))
    path.write_text(text[:m.start(1)] + fixed + text[m.end(1):])


def close_simulation(traci: Any, work_dir: Path) -> None:
    """Close a running simulation; with libsumo, first :func:`note_counts` (what the next
    simulation of this process starts from). Every simulator of the bridge closes here."""
    if traci is libsumo:
        note_counts(traci, work_dir)
    traci.close()
