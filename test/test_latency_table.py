"""``scripts/latency_table.py``: the latency table and plot from benchmark summaries
(hand-made here, so the expected cells are known)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from lmpc_scripts import latency_table


def _summary(folder: Path, latency: float | None, si_oc: float, si_coll: int,
             period: float | None = None) -> Path:
    folder.mkdir(parents=True)
    row = {"scenes": 25, "collisions": si_coll, "fails": 0, "overall_cost": si_oc,
           "stale_scenes": 3, "stale_steps": 40}
    (folder / "summary.json").write_text(json.dumps({
        "decision_latency_s": latency, "planning_period_s": period, "partial": None,
        "families": {"si": {"lmpc-rules": row},
                     "usi": {"mpc": dict(row), "lmpc-rules": dict(row, overall_cost=100.0)}}}))
    return folder


def test_table_and_plot_per_latency(tmp_path: Path) -> None:
    runs = latency_table.load([_summary(tmp_path / "b", 2.5, 150.0, 1),
                               _summary(tmp_path / "a", 0.0, 120.0, 0)])
    assert list(runs) == [(0.0, 2.5), (2.5, 2.5)]  # sorted, whatever the folder order
    table = latency_table.table_md(runs)
    assert "| SI | 0 | 2.5 | 25 | 0 | 0 | 120.0 |  | 3 / 40 |" in table
    assert "| SI | 2.5 | 2.5 | 25 | 1 | 0 | 150.0 | +25.0% | 3 / 40 |" in table
    png = tmp_path / "latency.png"
    latency_table.plot(runs, png)
    assert png.stat().st_size > 5000


def test_a_run_without_a_latency_is_the_rules_own_zero_else_refused(tmp_path: Path) -> None:
    # no --decision-latency: the backend's own latency, 0 for the rules reasoner (the
    # Table I run of ``make bench`` is the 0 s row); for another backend it is unknown
    folder = _summary(tmp_path / "plain", None, 120.0, 0)
    assert list(latency_table.load([folder])) == [(0.0, 2.5)]
    with pytest.raises(ValueError, match="plain.*--decision-latency"):
        latency_table.load([folder], method="mpc")


def test_planning_periods_are_a_second_axis_against_the_packaged_default(
        tmp_path: Path) -> None:
    runs = latency_table.load([_summary(tmp_path / "p5", 0.0, 180.0, 0, period=5.0),
                               _summary(tmp_path / "l0", None, 120.0, 0),
                               _summary(tmp_path / "p1", 0.0, 90.0, 2, period=1.0),
                               _summary(tmp_path / "l2", 2.5, 150.0, 1)])
    assert list(runs) == [(0.0, 1.0), (0.0, 2.5), (0.0, 5.0), (2.5, 2.5)]
    table = latency_table.table_md(runs)
    assert "| SI | 0 | 1 | 25 | 2 | 0 | 90.0 | -25.0% |" in table
    assert "| SI | 0 | 5 | 25 | 0 | 0 | 180.0 | +50.0% |" in table
    png = tmp_path / "cadence.png"
    latency_table.plot(runs, png)  # two columns: latency and period
    assert png.stat().st_size > 5000
    with pytest.raises(ValueError, match="second run at latency 0 s, period 5 s"):
        latency_table.load([tmp_path / "p5", _summary(tmp_path / "p5b", 0.0, 1.0, 0, 5.0)])
