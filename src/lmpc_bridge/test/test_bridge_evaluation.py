"""The evaluation library (``lmpc_bridge.evaluation``): it stays inside the bridge's arrow,
and its Table I on a hand-made summary."""
from __future__ import annotations

import csv
import os
import subprocess
import sys
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from lmpc_bridge.evaluation.executors import make_executor

from lmpc_bridge.evaluation.rows import (COLUMNS, error_row, latency_cells, parse_seeds, read_rows,
                                         resume_rows, write_rows)
from lmpc_bridge.evaluation.table import aggregate, table2_md, table_md


def test_the_evaluation_library_imports_neither_the_planner_nor_the_mpc() -> None:
    code = ("import sys\n"
            "import lmpc_bridge.evaluation.scenes, lmpc_bridge.evaluation.rows\n"
            "import lmpc_bridge.evaluation.replay, lmpc_bridge.evaluation.table\n"
            "import lmpc_bridge.evaluation.decisions, lmpc_bridge.evaluation.executors\n"
            "print(sorted(m for m in sys.modules if m.startswith(('lmpc_mpc', "
            "'lmpc_llm_planner', 'lmpc_scripts', 'ray'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]", out


def test_the_pool_executor_yields_every_result_and_a_dead_worker_as_its_exception() -> None:
    with make_executor("pool", 2) as ex:
        assert sorted(ex.results(abs, [(-3,), (2,), (-1,)])) == [(0, 3), (1, 2), (2, 1)]
    with make_executor("pool", 1) as ex:
        (index, result), = list(ex.results(os._exit, [(3,)]))
    assert index == 0 and isinstance(result, BrokenProcessPool)
    with pytest.raises(ValueError, match="unknown executor 'dask'; choose from pool, ray"):
        make_executor("dask", 1)


def _row(family: str, method: str, seed: int, oc: float, *, outcome: str = "reached",
         ) -> dict:
    return {"family": family, "method": method, "seed": seed, "outcome": outcome,
            "collision": int(outcome == "collision"), "fail": int(outcome == "timeout"),
            "off_route": 0, "ineff": 1.0, "time_s": 10.0, "pen_acc": 0.5, "pen_dist": 0.25,
            "overall_cost": oc, "stale_steps": 0, "steps": 100}


def test_table_i_puts_mpc_first_and_gives_each_method_its_change_against_it() -> None:
    rows = [_row("usi", "lmpc-rules", 0, 90.0),
            _row("usi", "lmpc-rules", 1, 70.0, outcome="collision"),
            _row("usi", "mpc", 0, 100.0), _row("usi", "mpc", 1, 100.0)]
    summary = aggregate(rows)
    assert list(summary["usi"]) == ["mpc", "lmpc-rules"]
    assert summary["usi"]["lmpc-rules"]["collisions"] == 1
    assert summary["usi"]["lmpc-rules"]["oc_change_vs_mpc"] == -0.2
    lines = table_md(summary).splitlines()
    assert lines[0].startswith("| Scenario | Method | Coll. |") and lines[1] == "|---" * 11 + "|"
    assert lines[2] == "| USI | mpc | 0 | 0 | 0 | 1.0 | 10.0 | 0.50 | 0.25 | 100.0 |  |"
    assert lines[3].endswith("| 80.0 | -20.0% |"), lines[3]


def test_latency_cells_are_empty_for_the_baseline_and_where_nothing_is_simulated() -> None:
    assert latency_cells("mpc", (2.5, 1.5)) == {"latency_s": "", "emergency_latency_s": ""}
    assert latency_cells("lmpc-rules", (None, None))["latency_s"] == ""
    assert latency_cells("lmpc-rules", (2.5, 1.5)) == {"latency_s": 2.5,
                                                       "emergency_latency_s": 1.5}
    assert parse_seeds("0,3,5-7") == [0, 3, 5, 6, 7]


def test_table_ii_lists_the_ablation_rows_in_the_papers_order() -> None:
    rows = [_row(f, m, 0, oc) for f in ("usi", "rab") for m, oc in (
        ("lmpc-rules", 80.0), ("lmpc-rules-aw", 85.0), ("mpc", 100.0),
        ("lmpc-rules-enc", 95.0))]
    rows += [_row("si", "mpc", 0, 100.0), _row("si", "lmpc-rules", 0, 90.0)]  # no ablation
    lines = table2_md(aggregate(rows)).splitlines()
    assert lines[0].startswith("| Scenario | O^dy | Â & W | Method |")
    assert len(lines) == 2 + 8  # rab and usi, four rows each; si has no ablation run
    assert [ln.split(" | ")[1:4] for ln in lines[2:6]] == [
        ["×", "×", "mpc"], ["✓", "×", "lmpc-rules-enc"], ["×", "✓", "lmpc-rules-aw"],
        ["✓", "✓", "lmpc-rules"]]
    assert lines[2].startswith("| RAB |") and lines[6].startswith("| USI |")
    assert lines[3].endswith("| 95.0 |")
    assert table2_md(aggregate(rows[-2:])) == ""


def test_read_rows_of_a_file_written_before_held_insertions(tmp_path: Path) -> None:
    """An older results.csv (``--replay-from`` a stored run) lacks ``held_insertions``:
    read as 0; a file lacking any other column is refused, naming it."""
    row = error_row("mpc", "usi", 3, "x")
    row["outcome"], row["fail"] = "reached", 0
    row.update({c: 1.0 for c in COLUMNS if isinstance(row[c], float)})
    old = [c for c in COLUMNS if c != "held_insertions"]
    path = tmp_path / "results.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=old, extrasaction="ignore")
        w.writeheader()
        w.writerow(row)
    (got,) = read_rows(path, {("mpc", "usi", 3)})
    assert got["held_insertions"] == 0 and got["seed"] == 3
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=[c for c in old if c != "stale_steps"],
                           extrasaction="ignore")
        w.writeheader()
        w.writerow(row)
    with pytest.raises(KeyError, match="stale_steps"):
        read_rows(path, {("mpc", "usi", 3)})


def test_resume_keeps_the_rows_of_other_scenes_and_refuses_another_latency(
        tmp_path: Path) -> None:
    """``--resume`` with a narrower selection keeps the file's other rows (it once dropped
    them when it rewrote results.csv); an error row of the selection runs again; a scene
    of the selection recorded at another simulated latency is refused, naming its line."""
    def row(method: str, family: str, seed: int, outcome: str = "reached",
            latency: tuple = (None, None)) -> dict:
        r = error_row(method, family, seed, "x", latency)
        r.update({c: 1.0 for c in COLUMNS if isinstance(r[c], float)})
        r.update(latency_cells(method, latency))
        r["outcome"], r["fail"] = outcome, int(outcome == "error")
        return r

    at_1_5 = (1.5, 1.5)
    path = tmp_path / "results.csv"
    write_rows(path, [row("lmpc-oracle", "rab", 0, latency=at_1_5),
                      row("lmpc-oracle", "si", 0, latency=at_1_5),
                      row("lmpc-oracle", "si", 1, "error", at_1_5), row("mpc", "si", 0)])
    jobs = {("lmpc-oracle", "si", s) for s in (0, 1, 2)}
    kept, others = resume_rows(path, jobs, latency=at_1_5)
    assert [(r["family"], r["seed"]) for r in kept] == [("si", 0)]
    assert sorted((r["method"], r["family"]) for r in others) == [
        ("lmpc-oracle", "rab"), ("mpc", "si")]
    assert others[0]["latency_s"] == "1.5"  # kept as written, whatever its latency
    with pytest.raises(ValueError, match=r"line \d: si seed 0 lmpc-oracle ran at .*1\.5"):
        resume_rows(path, jobs, latency=(2.5, 1.5))
