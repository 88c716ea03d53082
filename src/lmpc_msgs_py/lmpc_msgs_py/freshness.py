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


@dataclass
class SequenceGate:
    """Accepts a message only if its ``seq`` is newer than every one seen before.

    A publisher that restarts begins again at 0; a ``seq`` of 0 after a gap
    resets the gate, so a restarted bridge is accepted (its stamps restart too).
    """

    topic: str
    last_seq: Optional[int] = None
    refused: int = field(default=0)

    def check(self, seq: int) -> None:
        """Raise :class:`StaleMessage` for a duplicate or backwards ``seq``."""
        last = self.last_seq
        if last is not None and seq <= last and seq != 0:
            self.refused += 1
            what = "duplicate" if seq == last else f"goes backwards ({seq} after {last})"
            raise StaleMessage(self.topic, "seq", what)
        self.last_seq = seq

    def reset(self) -> None:
        self.last_seq = None


def is_stale(stamp_s: float, now_s: float, bound_s: float) -> bool:
    """True when ``stamp_s`` lies more than ``bound_s`` before ``now_s``."""
    # 1e-9: stamps are multiples of dt, so 1.3 - 1.0 must not count as more than 0.3.
    return now_s - stamp_s > bound_s + 1e-9
