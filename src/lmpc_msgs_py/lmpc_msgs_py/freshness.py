"""Order and staleness checks for received messages (RELIABILITY.md).

A :class:`SequenceGate` per topic refuses duplicates and sequence numbers that
go backwards; :func:`is_stale` says whether a stamp is older than a bound.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional


class StaleMessage(Exception):
    """Refused for order or age: the message is valid but must not be used."""

    def __init__(self, topic: str, field_name: str, reason: str) -> None:
        super().__init__(f"dropped message on {topic}: field '{field_name}': {reason}")
        self.topic = topic
        self.field = field_name
        self.reason = reason


RESYNC_AFTER = 5
"""Consecutive refusals after which the gate follows the stream it keeps refusing."""


@dataclass
class SequenceGate:
    """Accepts a message only if its ``seq`` is newer than every one seen before.

    A publisher that restarts begins again at 0: a ``seq`` of 0 always passes and
    resets the gate (a restarted bridge is followed at once; a forged or replayed 0
    carries an old stamp, which the staleness check then refuses). A single forged or
    corrupted message with a huge ``seq`` would otherwise block the real stream for
    good: after :data:`RESYNC_AFTER` consecutive refusals the gate re-synchronises on
    the stream that keeps arriving (a lone bad ``seq`` costs 4 messages).
    """

    topic: str
    last_seq: Optional[int] = None
    refused: int = field(default=0)
    resyncs: int = field(default=0)
    _run: int = field(default=0, repr=False)

    def check(self, seq: int) -> None:
        """Raise :class:`StaleMessage` for a duplicate or backwards ``seq``."""
        last = self.last_seq
        if last is not None and seq <= last and seq != 0:
            self._run += 1
            if self._run < RESYNC_AFTER:
                self.refused += 1
                what = "duplicate" if seq == last else f"goes backwards ({seq} after {last})"
                raise StaleMessage(self.topic, "seq", what)
            self.resyncs += 1
        self._run = 0
        self.last_seq = seq

    def reset(self) -> None:
        self.last_seq = None
        self._run = 0


def is_stale(stamp_s: float, now_s: float, bound_s: float) -> bool:
    """True when ``stamp_s`` lies more than ``bound_s`` before ``now_s``."""
    # 1e-9: stamps are multiples of dt, so 1.3 - 1.0 must not count as more than 0.3.
    return now_s - stamp_s > bound_s + 1e-9
