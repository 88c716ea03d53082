"""The benchmark's result row: columns, error rows, latency cells, ``results.csv``."""
from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence

Latency = tuple[Optional[float], Optional[float]]
"""(decision, emergency) latency to simulate, s; None: the backend's own. The composition
root resolves the emergency default before it reaches this library."""

COLUMNS = ("family", "seed", "method", "outcome", "collision", "fail", "off_route", "time_s",
           "ineff",
           "pen_acc", "pen_dist", "overall_cost", "decisions", "fallbacks", "steps",
           "solve_ms_median", "solve_ms_p99", "compute_ms_median", "compute_ms_p99", "wall_s",
           "route_overrides", "latency_s", "emergency_latency_s", "stale_steps",
           "stale_agent_steps", "held_insertions", "shadows", "detail")
"""``latency_s`` / ``emergency_latency_s``: the simulated decision latencies of the run
(empty: the backend's own, e.g. 0 for rules; always empty for ``mpc``); ``stale_steps`` /
``stale_agent_steps``: steps on which the MPC found the decision in force stale for some
agent, and agent-steps it fell back for (``MpcController`` stats ``stale_*``);
``held_insertions``: vehicles SUMO inserted onto the ego's body that the bridge held back
until their spot was clear (``lmpc_bridge.insertion``, one per hold); ``shadows``: how
often the ego stood across two lanes and the bridge put its shadow on the second one
(``lmpc_bridge.shadow``)."""

BASELINE = "mpc"
"""The method without a planner: no latency cells, the reference of ``oc_change_vs_mpc``."""


def parse_seeds(text: str) -> list[int]:
    """``"0-24"`` or ``"0,3,5-7"`` -> sorted unique seeds."""
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, _, hi = part.partition("-")
        try:
            seeds.update(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{part!r} in {text!r} is not a seed or a range like 0-24") from None
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r}")
    return sorted(seeds)


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (nan for no values)."""
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def scene_log_name(family: str, seed: int, method: str) -> str:
    """The file name of one scene's decision log in a run's ``decisions/`` folder."""
    return f"{family}-{seed:03d}-{method}.jsonl"


def latency_cells(method: str, latency: Latency) -> dict[str, Any]:
    """The row's latency columns: what the run simulated (empty for ``mpc``, which has no
    planner, and where the backend's own latency applies). ``latency`` comes resolved
    (``methods.resolve_latency``): an emergency latency wherever a decision one is set."""
    dec, emg = latency
    if method == BASELINE or (dec is None and emg is None):
        return {"latency_s": "", "emergency_latency_s": ""}
    return {"latency_s": "" if dec is None else dec, "emergency_latency_s": emg}


def error_row(method: str, family: str, seed: int, detail: str,
              latency: Latency = (None, None)) -> dict[str, Any]:
    row: dict[str, Any] = {c: math.nan for c in COLUMNS}
    row.update(family=family, seed=seed, method=method, outcome="error", collision=0, fail=1,
               off_route=0, route_overrides=0, decisions=0, fallbacks=0, steps=0, wall_s=0.0,
               detail=detail, stale_steps=0, stale_agent_steps=0, held_insertions=0, shadows=0,
               **latency_cells(method, latency))
    return row


_INT_COLUMNS = ("seed", "collision", "fail", "off_route", "decisions", "fallbacks", "steps",
                "route_overrides", "stale_steps", "stale_agent_steps", "held_insertions",
                "shadows")
_TEXT_COLUMNS = ("family", "method", "outcome", "detail", "latency_s", "emergency_latency_s")
_ADDED_COLUMNS = {"held_insertions": "0", "shadows": "0"}
"""Columns added after files were stored (``--replay-from`` of an older run): read as
this value where a file lacks them (the guard and the shadow did not exist)."""


def read_rows(path: Path, jobs: set[tuple[str, str, int]], *,
              latency: Latency = (None, None)) -> list[dict[str, Any]]:
    """The rows of an earlier ``results.csv`` that belong to ``jobs`` ((method, family,
    seed)), ran with the same simulated ``latency`` and did not end in ``error``, typed as
    ``run_scene`` returns them (latency cells as text; a missing file: none). Raises
    ``ValueError`` / ``KeyError`` naming a malformed row."""
    return [row for _, row in _typed_rows(path)
            if row["outcome"] != "error" and _same_latency(row, latency)
            and (row["method"], row["family"], row["seed"]) in jobs]


def resume_rows(path: Path, jobs: set[tuple[str, str, int]], *,
                latency: Latency = (None, None)
                ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """``--resume``: (the rows of ``jobs`` to keep, as :func:`read_rows` reads them; the
    rows of other scenes, kept as they are, so a resumed run with a narrower selection
    loses nothing of the file). Raises ``ValueError`` naming the line where a scene of
    ``jobs`` ran at another simulated latency (mixing two latencies in one file would
    average them in one table row), and as :func:`read_rows` for a malformed file."""
    kept, others = [], []
    for line, row in _typed_rows(path):
        if (row["method"], row["family"], row["seed"]) not in jobs:
            others.append(row)
        elif not _same_latency(row, latency):
            want = latency_cells(row["method"], latency)
            raise ValueError(
                f"line {line}: {row['family']} seed {row['seed']} {row['method']} ran at "
                f"decision / emergency latency {row['latency_s'] or '-'} / "
                f"{row['emergency_latency_s'] or '-'} s, this run simulates "
                f"{want['latency_s'] or '-'} / {want['emergency_latency_s'] or '-'} s; "
                "resume with the same latency options or write to another --out")
        elif row["outcome"] != "error":
            kept.append(row)
    return kept, others


def _typed_rows(path: Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line, row) of a ``results.csv``, typed as ``run_scene`` returns rows (none for a
    missing file); ``ValueError`` / ``KeyError`` name a malformed line."""
    if not path.exists():
        return
    with open(path, newline="") as fh:
        for line, raw in enumerate(csv.DictReader(fh), start=2):
            raw = {**_ADDED_COLUMNS, **raw}
            missing = [c for c in COLUMNS if c not in raw]
            if missing:
                raise KeyError(f"line {line}: no column(s) {missing}")
            try:
                yield line, {c: raw[c] if c in _TEXT_COLUMNS
                             else int(raw[c]) if c in _INT_COLUMNS else float(raw[c])
                             for c in COLUMNS}
            except ValueError as exc:
                raise ValueError(f"line {line}: {exc}") from None


def _same_latency(row: dict[str, Any], latency: Latency) -> bool:
    """The row ran with the simulated ``latency`` this run writes."""
    want = latency_cells(row["method"], latency)
    return all(_same_cell(row[k], v) for k, v in want.items())


def _same_cell(text: str, value: Any) -> bool:
    """A latency cell read back from results.csv against the value this run writes."""
    if text == "" or value == "":
        return text == "" and value == ""
    return math.isclose(float(text), float(value))


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """``results.csv``, rows sorted by family, method, seed (written anew, atomically)."""
    ordered = sorted(rows, key=lambda r: (r["family"], r["method"], r["seed"]))
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(ordered)
    tmp.replace(path)
