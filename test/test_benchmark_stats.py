"""The planner figures (``lmpc_bridge.evaluation.decisions``): from decision logs, and
tokens / latency rows from kept requests, on hand-made inputs counted by hand."""
from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from lmpc_bridge.evaluation.decisions import (
    decision_stats,
    latency_row,
    stats_md,
    token_rows,
)


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


def _req(mode: str, estimate: int, prompt: str, *, agents: int = 2,
         retry: str | None = None) -> Any:
    return SimpleNamespace(mode=mode, tokens_estimate=estimate, prompt=prompt,
                           retry_error=retry, scene=SimpleNamespace(agents=[0] * agents))


class _CharTokenizer:
    """One token per two bytes of the prompt."""

    def tokenize(self, text: bytes, add_bos: bool) -> list[int]:
        assert add_bos is False
        return [0] * (len(text) // 2)


def test_token_rows_per_family_and_mode_first_asks_only() -> None:
    eoa = [_req("normal", 10, "a" * 40, agents=3), _req("normal", 30, "b" * 80),
           _req("normal", 99, "c" * 400, retry="prose")]  # a re-ask: not counted
    usi = [_req("emergency", 5, "d" * 20, agents=1), _req("normal", 20, "e" * 60)]
    rows = token_rows([("eoa", eoa), ("usi", usi), ("eoa", [_req("normal", 50, "f" * 100)])],
                      None)
    assert [(r["family"], r["mode"], r["prompts"]) for r in rows] == [
        ("eoa", "normal", 3), ("usi", "normal", 1), ("usi", "emergency", 1)]
    assert rows[0]["estimate_median"] == 30 and rows[0]["estimate_max"] == 50
    assert rows[0]["agents_max"] == 3 and "smollm2_median" not in rows[0]
    with_real = token_rows([("eoa", eoa)], _CharTokenizer())[0]
    assert with_real["smollm2_median"] == 30 and with_real["smollm2_max"] == 40
    assert with_real["chars_per_token"] == 2.0


def test_latency_row_and_an_empty_backend() -> None:
    row = latency_row("rules", [0.1, 0.2, 0.6], identical_runs="2/2")
    assert row["backend"] == "rules" and row["calls"] == 3
    assert row["mean_s"] == 0.3 and row["median_s"] == 0.2
    assert 0.2 < row["p95_s"] <= 0.6 and row["identical_runs"] == "2/2"
    empty = latency_row("openai", [])
    assert empty["calls"] == 0
    assert all(math.isnan(empty[k]) for k in ("mean_s", "p95_s", "median_s"))
