"""Whether an ``lmpc-replay`` row repeats the row the recorded run wrote for its scene."""
from __future__ import annotations

from typing import Any

REPEAT_OC_TOL = 2e-4
"""O.C. difference still counted as a repeat: rows round it to 4 decimals, and a
floating-point difference far below that can move the last digit (seen once in 50 scenes:
eoa seed 5, 395.9955 vs 395.9954, every prompt answered from the log)."""


def replay_check(rows: list[dict[str, Any]], recorded: list[dict[str, Any]],
                 recorded_method: str) -> list[str]:
    """One line per ``lmpc-replay`` row of ``rows``: whether it repeats the row of
    ``recorded`` (same family and seed, ``recorded_method``) exactly: every prompt
    answered from the log, the same outcome and time, O.C. within ``REPEAT_OC_TOL``.
    Resumed rows (read back from results.csv, without the prompt counts) are reported as
    not checked."""
    by_scene = {(r["family"], r["seed"]): r for r in recorded if r["method"] == recorded_method}
    lines = []
    for row in sorted((r for r in rows if r["method"] == "lmpc-replay"),
                      key=lambda r: (r["family"], r["seed"])):
        scene = f"{row['family']} seed {row['seed']}"
        old = by_scene.get((row["family"], row["seed"]))
        if row["outcome"] == "error":
            lines.append(f"{scene}: not checked ({row['detail']})")
        elif "replay_unmatched" not in row:
            lines.append(f"{scene}: not checked (row kept by --resume)")
        elif old is None:
            lines.append(f"{scene}: no recorded {recorded_method} row to compare with")
        else:
            same = (row["outcome"] == old["outcome"] and row["time_s"] == old["time_s"]
                    and abs(row["overall_cost"] - old["overall_cost"]) <= REPEAT_OC_TOL)
            verdict = "exact repeat" if same and row["replay_unmatched"] == 0 else "differs"
            lines.append(
                f"{scene}: {verdict}: {row['replay_unmatched']} of "
                f"{row['replay_unmatched'] + row['replay_answered']} prompt(s) not in the log; "
                f"{row['outcome']} t={row['time_s']}s O.C.={row['overall_cost']} vs recorded "
                f"{old['outcome']} t={old['time_s']}s O.C.={old['overall_cost']}")
    return lines
