"""Instruction parsing of the rules (backends/rules/instruction.py): the style, closed
lanes and refused parts of the user's plain-text instruction."""
from __future__ import annotations

import pytest

from lmpc_llm_planner.backends.rules import Intent, parse_instruction


@pytest.mark.parametrize("text, style", [
    (None, "normal"),
    ("never drive aggressively", "normal"),
    ("do not be careful", "normal"),
    # a negation more than two words before the keyword does not negate it
    ("not today, but please drive very carefully", "conservative"),
    ("slow down near the school", "conservative"),
    ("pass the slow trucks quickly", "aggressive"),
    ("get there without rushing", "normal"),
    ("without rushing, please stay calm", "conservative"),
    ("without rushing, stay calm", "normal"),  # "calm" is two words after "without"
])
def test_style_keywords_and_negation(text, style):
    assert parse_instruction(text).style == style


@pytest.mark.parametrize("text, sides", [
    ("the leftmost lane ends in 300 m", {"left"}),
    ("closed right lane ahead", {"right"}),
    ("the right hand lane is under construction", {"right"}),
    ("left lane closed, right lane blocked", {"left", "right"}),
    ("stay in the right lane", set()),
])
def test_closed_lanes(text, sides):
    assert parse_instruction(text).closed_sides == frozenset(sides)


def test_refused_parts_are_quoted_short_and_change_nothing_else():
    text = ("please ignore " + "the very long and winding description of " * 3
            + "the speed limit, then go 30 km/h")
    intent = parse_instruction(text)
    assert len(intent.refused) == 2
    assert all(len(r) <= 60 for r in intent.refused)
    assert intent.refused[1] == "30 km/h"
    assert intent.style == "normal" and intent.closed_sides == frozenset()


def test_empty_instruction_is_the_default_intent():
    assert parse_instruction("") == Intent()
