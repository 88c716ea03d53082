"""Planner figures: from the scenes' decision logs (``decisions/*.jsonl`` of a run:
``decision_stats``, ``stats_md``) and from the requests a tool kept along episodes
(``token_rows``: tokens per decision; ``latency_row``: latency per backend call)."""
from __future__ import annotations

import json
import math
import re
import statistics
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

from lmpc_bridge.evaluation.rows import percentile
from lmpc_bridge.evaluation.table import markdown

_LOG_NAME = re.compile(r"^(?P<family>.+)-(?P<seed>\d{3,})-(?P<method>lmpc-[a-z]+)\.jsonl$")


def decision_stats(log_dir: Path) -> dict[str, dict[str, dict[str, Any]]]:
    """Per family, method and decision mode, from the scenes' decision logs: decisions,
    fallbacks, the share answered validly at the first attempt, the measured backend
    latency (wall, median / p95 / max; a backend run with a fixed simulated latency
    still logs the measured one) and the tokens in / out (median, max in)."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for path in sorted(Path(log_dir).glob("*.jsonl")):
        m = _LOG_NAME.match(path.name)
        if m is None:
            continue
        for line in path.read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                if rec.get("kind") == "mpc_stale_check":
                    continue  # the MPC's record of a decision, not a planner decision
                groups.setdefault((m["family"], m["method"], rec.get("mode", "normal")),
                                  []).append(rec)
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (family, method, mode), recs in sorted(groups.items()):
        lat = [float(r["measured_latency_s"]) for r in recs if r.get("attempts")]
        first_ok = [r for r in recs if r.get("attempts") and
                    r["attempts"][0].get("error_kind") is None]
        asked = [r for r in recs if r.get("attempts")]
        fallbacks = sum(1 for r in recs if (r.get("decision") or {}).get("source") == "fallback")
        tok_in = [int(r["tokens_in"]) for r in asked]
        tok_out = [int(r["tokens_out"]) for r in asked]
        out.setdefault(family, {}).setdefault(method, {})[mode] = {
            "decisions": len(recs), "fallbacks": fallbacks,
            "valid_first_answer": round(len(first_ok) / len(asked), 4) if asked else math.nan,
            "latency_s_median": round(statistics.median(lat), 3) if lat else math.nan,
            "latency_s_p95": round(percentile(lat, 0.95), 3),
            "latency_s_max": round(max(lat), 3) if lat else math.nan,
            "tokens_in_median": statistics.median(tok_in) if tok_in else math.nan,
            "tokens_in_max": max(tok_in) if tok_in else math.nan,
            "tokens_out_median": statistics.median(tok_out) if tok_out else math.nan,
        }
    return out


def stats_md(stats: dict[str, dict[str, dict[str, Any]]]) -> str:
    """The planner figures: one row a family, method and decision mode."""
    rows = [[family.upper(), method, mode, f"{a['decisions']}", f"{a['fallbacks']}",
             f"{a['valid_first_answer']:.0%}",
             f"{a['latency_s_median']:.2f} / {a['latency_s_p95']:.2f} / "
             f"{a['latency_s_max']:.2f}",
             f"{a['tokens_in_median']:.0f} / {a['tokens_in_max']:.0f}",
             f"{a['tokens_out_median']:.0f}"]
            for family, methods in stats.items() for method, modes in methods.items()
            for mode, a in modes.items()]
    return markdown(["Scenario", "Method", "Mode", "Decisions", "Fallbacks", "Valid 1st",
                     "Latency med / p95 / max s", "Tokens in med / max", "Tokens out med"],
                    rows)


def latency_row(name: str, values: Sequence[float], **extra: Any) -> dict[str, Any]:
    """Backend ``name``'s calls: count, mean, p95 and median latency in s (4 digits),
    then ``extra``."""
    return {"backend": name, "calls": len(values),
            "mean_s": round(statistics.fmean(values), 4) if values else math.nan,
            "p95_s": round(percentile(values, 0.95), 4),
            "median_s": round(statistics.median(values), 4) if values else math.nan,
            **extra}


def token_rows(requests: Iterable[tuple[str, Sequence[Any]]],
               tokenizer: Optional[Any]) -> list[dict[str, Any]]:
    """Tokens per decision, one row a family (in order of appearance) and mode, from
    (family, planner requests) pairs; first asks only (re-asks quote the error).

    The planner's estimate (``tokens_estimate``) always; with a llama.cpp ``tokenizer``
    also the real token count of the prompt text and the characters per token."""
    pairs = list(requests)
    rows = []
    for family in dict.fromkeys(f for f, _ in pairs):
        reqs = [r for f, sel in pairs if f == family for r in sel if r.retry_error is None]
        for mode in ("normal", "emergency"):
            sel = [r for r in reqs if r.mode == mode]
            if not sel:
                continue
            est = [r.tokens_estimate for r in sel]
            row: dict[str, Any] = {
                "family": family, "mode": mode, "prompts": len(sel),
                "agents_max": max(len(r.scene.agents) for r in sel),
                "estimate_median": statistics.median(est), "estimate_max": max(est)}
            if tokenizer is not None:
                real = [len(tokenizer.tokenize(r.prompt.encode("utf-8"), add_bos=False))
                        for r in sel]
                row.update(smollm2_median=statistics.median(real), smollm2_max=max(real),
                           chars_per_token=round(sum(len(r.prompt) for r in sel)
                                                 / max(1, sum(real)), 2))
            rows.append(row)
    return rows
