"""Instruction parsing: the user's plain-text instruction as an :class:`Intent` (keyword
rules, an APPROXIMATION of language understanding: no LLM here).

A style (conservative: longer gaps, safety high, no overtaking; aggressive: shorter
lane-change gaps, overtaking, late merges — never shorter turn gaps), closed lanes, and
refused parts (ignore a light, a speed figure), which change nothing."""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional

CONSERVATIVE_WORDS = re.compile(
    r"\b(careful|carefully|conservative|conservatively|cautious|cautiously|defensive"
    r"|defensively|safe|safely|calm|calmly|gentle|gently|relaxed"
    # "slow" asks for slow driving, "slow traffic / cars" describes others
    r"|slow(ly)?(?!\s+(traffic|cars?|leaders?|vehicles?|trucks?|lanes?)))\b", re.I)
AGGRESSIVE_WORDS = re.compile(r"\b(aggressive|aggressively|assertive|assertively|hurry|rush"
                              r"|rushing|fast|faster|quick|quickly|sporty|overtake|overtaking"
                              r"|late|urgent|urgently)\b", re.I)
CONSERVATIVE_PHRASES = re.compile(
    r"\b(take it easy|easy does it|no risks?|without (taking )?(any )?risks?"
    r"|(there is |i'm |i am )?(in )?no hurry|not in a hurry|don't rush|do not rush"
    r"|no rush)\b", re.I)
"""Conservative wording that a negation carries (checked before the words)."""
_NEGATION = re.compile(r"\b(not|don't|dont|never|no|avoid|without)\W+(\w+\W+){0,2}$", re.I)
CLOSED_LANE = re.compile(
    r"\b(?P<side>right|left)(?:most|-most| hand)?\s+lane\b[^.;!?]*?"
    r"\b(?:is|are|will be|gets)?\s*(?:closed|blocked|shut|under construction|"
    r"ends|ending)\b", re.I)
CLOSED_LANE_REV = re.compile(
    r"\b(?:closed|blocked|shut)\s+(?P<side>right|left)(?:most)?\s+lane\b", re.I)
UNSAFE_REQUEST = re.compile(
    r"\b(ignore|run|skip|disregard)\b[^.;!?]*\b(red|light|lights|signal|signals|rule|"
    r"rules|stop|sign|limit)\b|\b\d+(\.\d+)?\s*(m/s|mps|km/h|kmh|kph|mph)\b", re.I)


@dataclass(frozen=True)
class Intent:
    """What the rules take from the user's instruction (untrusted plain text).

    The instruction can only choose among options the rules offer anyway: the driving
    style (gaps, whether to overtake a slow leader, how early to change lanes) and lanes
    to avoid. Requests to break rules (ignore a light, a speed figure) are noted and
    ignored: signals, the speed limit and the configured pools are never changed."""

    style: str = "normal"
    """"conservative", "normal" or "aggressive"."""
    closed_sides: frozenset[str] = frozenset()
    """"right" / "left": the user says that lane (rightmost / leftmost) is closed ahead."""
    refused: tuple[str, ...] = ()
    """Parts of the instruction the rules will not follow (quoted in the reasoning)."""


def _mentions(pattern: re.Pattern[str], text: str) -> bool:
    """``pattern`` occurs in ``text`` without a negation just before it."""
    for m in pattern.finditer(text):
        if not _NEGATION.search(text[:m.start()]):
            return True
    return False


def parse_instruction(text: Optional[str]) -> Intent:
    """The user's instruction as an :class:`Intent`. Conservative wording wins over
    aggressive wording when both occur (the safer reading)."""
    if not text:
        return Intent()
    conservative = bool(CONSERVATIVE_PHRASES.search(text)) or \
        _mentions(CONSERVATIVE_WORDS, text)
    aggressive = _mentions(AGGRESSIVE_WORDS, text)
    style = "conservative" if conservative else "aggressive" if aggressive else "normal"
    sides = {m.group("side").lower() for m in CLOSED_LANE.finditer(text)}
    sides |= {m.group("side").lower() for m in CLOSED_LANE_REV.finditer(text)}
    refused = tuple(m.group(0)[:60] for m in UNSAFE_REQUEST.finditer(text))
    return Intent(style=style, closed_sides=frozenset(sides), refused=refused)
