"""scripts/bench_loop.py: the figures it takes from a run_graph summary and its table's
medians and ratios (the graph runs themselves are the graph tests' business)."""
from __future__ import annotations

import pytest

from lmpc_scripts import bench_loop


def _summary(episode_s: float, p99: float, outcome: str = "reached") -> dict:
    return {"outcome": outcome, "metrics": {"overall_cost": 102.7731},
            "startup_wall_s": 1.3, "episode_wall_s": episode_s,
            "episode_real_time_factor": round(22.6 / episode_s, 1),
            "control_latency_ms": {"median": 5.0, "p99": p99, "max": p99 + 1.0},
            "mpc_solve_ms": {"median": 1.8, "p99": 2.5},
            "profile_ms": {"bridge": {"step cycle (publish to publish)": {"median": 6.5}}}}


def test_figures_reads_the_summary_fields() -> None:
    row = bench_loop.figures(_summary(1.5, 7.0))
    assert row["episode_s"] == 1.5 and row["cycle_p99"] == 7.0 and row["cycle_max"] == 8.0
    assert row["step_ms"] == 6.5 and row["solve_p99"] == 2.5 and row["oc"] == 102.7731
    failed = bench_loop.figures({"outcome": "error", "metrics": {}})
    assert failed["outcome"] == "error" and failed["episode_s"] is None


def test_table_gives_medians_and_ratios_to_the_first_variant() -> None:
    runs = {"--executor events": [bench_loop.figures(_summary(e, p)) for e, p in
                                  ((1.4, 7.0), (1.5, 7.4), (1.6, 9.0))],
            "--executor single": [bench_loop.figures(_summary(e, p)) for e, p in
                                  ((1.8, 8.4), (1.7, 9.0), (2.1, 9.9))]}
    text = bench_loop.table(runs)
    assert "ratio --executor single / --executor events: episode_s 1.20, step_ms 1.00, " \
           "cycle_med 1.00, cycle_p99 1.22" in text
    med = [line for line in text.splitlines() if " med " in line]
    assert len(med) == 2 and "    1.500" in med[0] and "    1.800" in med[1]


def test_a_run_count_below_one_is_refused() -> None:
    with pytest.raises(SystemExit):
        bench_loop.parse_args(["--runs", "0"])


def test_a_variant_run_graph_refuses_ends_the_benchmark_with_its_error(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    code = bench_loop.main(["--runs", "1", "--variants", "--executor bogus",
                            "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 3
    assert "v0-run1 (--executor bogus): run_graph wrote no summary (exit 2)" in err
    assert "invalid choice: 'bogus'" in err
