"""The ``replay`` backend: answers from a recorded decision log, so a run with an LLM can
be repeated exactly without the LLM.

The log is the planner's JSON-lines decision log (``PlannerCore``, one record per
decision with its ``attempts``: stage, ``prompt_sha256``, tokens, latency, raw output,
error kind). Each recorded call is answered once, chosen by

1. the sha256 of the request's prompt (the same prompt -> the same recorded call, in
   recorded order when one prompt was asked more than once);
2. (``match: hash_or_stamp``) else the next unused call recorded for the same stamp,
   mode and stage (the prompt generator changed, but the situation is the same), and
   with ``stamp_window_s`` > 0 the unused call of that mode and stage nearest in stamp
   within the window (``near``; a replay through the ROS graph);
3. else, for a prompt seen before whose calls are used up, its last recorded call
   again (the same prompt gets the same answer).

A request with no answer comes back as ``error_kind="transport"`` naming the stamp,
stage and prompt hash, so the planner falls back as for any failed call.

What is repeated: the raw text (refused text is refused again, so re-asks and
fallbacks repeat), a recorded timeout / transport failure, the token counts, and the
latency. ``latency: report`` (default) answers at once and reports latencies whose sum
over a decision's calls is exactly the recorded decision latency (all of it on the
decision's first call); it sets ``reports_latency = True``, and ``PlannerCore`` then takes
that sum as the decision's latency: the replayed decision takes effect at the recorded
sim time (an exact repeat). ``latency: sleep`` spends each call's recorded wall time
(capped just below the request's deadline, so a recorded timeout stays a timeout), so
the planner measures about the recorded decision latency; this is APPROXIMATE
(scheduling, prompt building: milliseconds when idle, tens of ms on a loaded machine).
"""
from __future__ import annotations

import hashlib
import json
import re
import threading
import time
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from lmpc_llm_planner.backends.base import BackendError, BackendReply, DecisionRequest
from lmpc_llm_planner.config import ReplayConfig

SOURCE_RE = re.compile(r"^(rules|replay|mock|llm:[\w.:/\-]{1,96})$")
"""Sources a replayed decision may carry (``fallback`` is the planner's, not a backend's)."""
SLEEP_MARGIN_S = 0.005
"""A recorded call is never slept past ``deadline - margin``."""


@dataclass(frozen=True)
class RecordedCall:
    """One backend call of the recorded log."""

    index: int
    """Position in the log (calls in recorded order)."""
    position: int
    """Position among the calls of its decision (0 = first)."""
    decision_latency_s: float
    """The recorded decision's ``latency_s`` (all its calls, as reported)."""
    stamp_ms: int
    mode: str
    stage: str
    prompt_sha256: str
    raw_output: Optional[str]
    error_kind: Optional[str]
    error: str
    latency_s: float
    tokens_in: int
    tokens_out: int
    revisit_s: Optional[float] = None
    """The recorded reply's ``revisit_s`` (the planner then asks again at the same time)."""

    def reply(self, latency_s: float) -> BackendReply:
        if self.raw_output is None:
            kind = "timeout" if self.error_kind == "timeout" else "transport"
            return BackendReply(text=None, latency_s=latency_s, error_kind=kind,
                                error=self.error or kind)  # verbatim: it goes into the re-ask
        return BackendReply(text=self.raw_output, latency_s=latency_s,
                            tokens_in=self.tokens_in, tokens_out=self.tokens_out,
                            revisit_s=self.revisit_s)


@dataclass(frozen=True)
class ReplayLog:
    """A decision log read for replay."""

    calls: tuple[RecordedCall, ...]
    sources: Counter[str]
    """Backend sources of the recorded decisions (no fallbacks)."""
    skipped_lines: int
    """Lines that were not a decision record (blank, broken JSON, scene errors)."""


def _int(value: Any) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else 0


def _float(value: Any) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    return float(value) if ok and 0.0 <= value < 1e6 else 0.0


def load_replay_log(path: str | Path) -> ReplayLog:
    """Read the recorded calls of a JSON-lines decision log.

    Raises :class:`BackendError` when the file cannot be read or holds no call.
    """
    file = Path(path)
    try:
        lines = file.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise BackendError(f"replay backend: cannot read decision log {file}: {exc}") from None
    calls: list[RecordedCall] = []
    sources: Counter[str] = Counter()
    skipped = 0
    for line in lines:
        try:
            rec = json.loads(line)
            attempts = rec["attempts"]
            stamp_ms = int(round(float(rec["stamp_s"]) * 1000.0))
            mode = str(rec["mode"])
            if not isinstance(attempts, list) or not attempts:
                raise ValueError("no attempts")
            parsed = [
                RecordedCall(
                    index=len(calls) + i,
                    position=i,
                    decision_latency_s=_float(rec.get("latency_s")),
                    stamp_ms=stamp_ms,
                    mode=mode,
                    stage=str(a["stage"]),
                    prompt_sha256=str(a["prompt_sha256"]),
                    raw_output=a["raw_output"] if isinstance(a.get("raw_output"), str) else None,
                    error_kind=a.get("error_kind"),
                    error=str(a.get("error") or ""),
                    latency_s=_float(a.get("latency_s")),
                    tokens_in=_int(a.get("tokens_in")),
                    tokens_out=_int(a.get("tokens_out")),
                    revisit_s=_float(a.get("revisit_s")) or None,
                )
                for i, a in enumerate(attempts)
            ]
        except (ValueError, KeyError, TypeError, AttributeError):
            skipped += 1
            continue
        calls.extend(parsed)
        source = rec.get("source")
        if isinstance(source, str) and SOURCE_RE.match(source):
            sources[source] += 1
    if not calls:
        raise BackendError(
            f"replay backend: {file} holds no recorded backend call ({skipped} lines skipped); "
            "point replay.log_path at a planner decisions.jsonl"
        )
    return ReplayLog(calls=tuple(calls), sources=sources, skipped_lines=skipped)


class ReplayBackend:
    """Answers from a :class:`ReplayLog`; see the module docstring. Thread-safe."""

    def __init__(self, log: ReplayLog, config: Optional[ReplayConfig] = None) -> None:
        self.config = config or ReplayConfig()
        self.log = log
        self.name = "replay"
        self.reports_latency = self.config.latency == "report"
        """Replies carry the recorded latency (the decision's on its first call)."""
        if self.config.keep_source and log.sources:
            # The most frequent recorded source (ties: alphabetical, so it is repeatable).
            self.name = sorted(log.sources.items(), key=lambda kv: (-kv[1], kv[0]))[0][0]
        self._by_hash: dict[str, list[RecordedCall]] = defaultdict(list)
        self._by_situation: dict[tuple[int, str, str], list[RecordedCall]] = defaultdict(list)
        for call in log.calls:
            self._by_hash[call.prompt_sha256].append(call)
            self._by_situation[(call.stamp_ms, call.mode, call.stage)].append(call)
        self._used: set[int] = set()
        self._last_for_hash: dict[str, RecordedCall] = {}
        self._lock = threading.Lock()
        self.hits: Counter[str] = Counter()
        """How requests were answered: hash, stamp, near, repeat, miss."""

    @classmethod
    def from_config(cls, config: ReplayConfig) -> "ReplayBackend":
        if not config.log_path:
            raise BackendError(
                "replay backend: set replay.log_path to a recorded decisions.jsonl "
                "(e.g. runs/<run>/decisions.jsonl)"
            )
        return cls(load_replay_log(config.log_path), config)

    def find(self, request: DecisionRequest) -> tuple[Optional[RecordedCall], str]:
        """The recorded call answering ``request`` (marked used) and how it was found."""
        sha = hashlib.sha256(request.prompt.encode("utf-8")).hexdigest()
        key = (int(round(request.scene.obs.stamp_s * 1000.0)), request.mode, request.stage)
        with self._lock:
            found, how = self._first_unused(self._by_hash.get(sha, ())), "hash"
            if found is None and self.config.match == "hash_or_stamp":
                found, how = self._first_unused(self._by_situation.get(key, ())), "stamp"
                if found is None and self.config.stamp_window_s > 0.0:
                    found, how = self._nearest_unused(key), "near"
            if found is None and sha in self._last_for_hash:
                found, how = self._last_for_hash[sha], "repeat"
            if found is None:
                self.hits["miss"] += 1
                return None, "miss"
            self._used.add(found.index)
            self._last_for_hash[sha] = found
            self.hits[how] += 1
            return found, how

    def _first_unused(self, calls: Any) -> Optional[RecordedCall]:
        return next((c for c in calls if c.index not in self._used), None)

    def _nearest_unused(self, key: tuple[int, str, str]) -> Optional[RecordedCall]:
        """The unused call of ``key``'s mode and stage nearest to its stamp within
        ``stamp_window_s`` (ties: the earlier one), else None."""
        stamp_ms, mode, stage = key
        window_ms = self.config.stamp_window_s * 1000.0
        near = [(abs(k[0] - stamp_ms), k[0], c) for k, calls in self._by_situation.items()
                if k[1] == mode and k[2] == stage and abs(k[0] - stamp_ms) <= window_ms
                for c in calls if c.index not in self._used]
        return min(near, key=lambda t: (t[0], t[1], t[2].index))[2] if near else None

    # -- Backend ---------------------------------------------------------------------------
    def complete(self, request: DecisionRequest) -> BackendReply:
        """The recorded answer to ``request`` (or a transport error naming what is missing)."""
        t0 = time.perf_counter()
        call, _how = self.find(request)
        if call is None:
            sha = hashlib.sha256(request.prompt.encode("utf-8")).hexdigest()
            return BackendReply(
                text=None, latency_s=time.perf_counter() - t0, error_kind="transport",
                error=(f"replay: no recorded answer for stamp {request.scene.obs.stamp_s:.3f} s, "
                       f"mode {request.mode}, stage {request.stage}, prompt {sha[:12]}"),
            )
        if self.reports_latency:
            # The whole recorded decision latency on its first call, 0 on the others: their
            # sum is then exactly the recorded value (no floating-point remainder).
            return call.reply(call.decision_latency_s if call.position == 0 else 0.0)
        wait_s = min(call.latency_s, request.deadline_s - SLEEP_MARGIN_S)
        wait_s -= time.perf_counter() - t0
        if wait_s > 0.0:
            time.sleep(wait_s)
        return call.reply(time.perf_counter() - t0)
