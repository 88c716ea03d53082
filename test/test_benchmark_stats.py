"""The benchmark's planner figures from decision logs (``lmpc_bridge.evaluation.decisions``), on
hand-made logs whose answers are counted by hand."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from lmpc_bridge.evaluation.decisions import decision_stats, stats_md


def _rec(mode: str, latency_s: float, first_error: str | None, *, source: str = "llm:x",
         tokens_in: int = 900, tokens_out: int = 100) -> dict:
    attempts = [{"error_kind": first_error}] + ([{"error_kind": None}] if first_error else [])
    return {"mode": mode, "measured_latency_s": latency_s, "tokens_in": tokens_in,
            "tokens_out": tokens_out, "attempts": attempts, "decision": {"source": source}}


def test_decision_stats_counts_validity_latency_and_tokens(tmp_path: Path) -> None:
    logs = tmp_path / "decisions"
    logs.mkdir()
    a = [_rec("normal", 8.0, None), _rec("normal", 10.0, "prose"),
         _rec("emergency", 6.0, None, tokens_in=600)]
    b = [_rec("normal", 12.0, None, tokens_in=1100),
         _rec("normal", 30.0, "timeout", source="fallback")]
    (logs / "usi-000-lmpc-local.jsonl").write_text("\n".join(json.dumps(r) for r in a))
    (logs / "usi-001-lmpc-local.jsonl").write_text("\n".join(json.dumps(r) for r in b) + "\n")
    (logs / "notes.txt").write_text("not a log")
    stats = decision_stats(logs)
    normal = stats["usi"]["lmpc-local"]["normal"]
    assert normal["decisions"] == 4 and normal["fallbacks"] == 1
    assert normal["valid_first_answer"] == pytest.approx(0.5)  # 2 of 4 first answers
    assert normal["latency_s_median"] == pytest.approx(11.0)
    assert normal["latency_s_p95"] == pytest.approx(30.0)  # nearest rank of 4 values
    assert normal["tokens_in_median"] == 900 and normal["tokens_in_max"] == 1100
    emergency = stats["usi"]["lmpc-local"]["emergency"]
    assert emergency["decisions"] == 1 and emergency["tokens_in_max"] == 600
    table = stats_md(stats)
    assert "| USI | lmpc-local | normal | 4 | 1 | 50% |" in table
