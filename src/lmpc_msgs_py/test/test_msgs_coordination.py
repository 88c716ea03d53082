"""Coordination messages (issue 18): round trips and the refusals, one line naming the field."""
from __future__ import annotations

import json

import pytest

from lmpc_msgs_py import DecodeError, decode, encode
from lmpc_msgs_py.coordination import ConflictView, Directive, EgoStatus, SpeedBand

TOPIC = "/coordination/status"


def status(**over: object) -> EgoStatus:
    fields: dict[str, object] = dict(
        stamp_s=3.0, seq=30, ego_id="ego_1", route_index=1, dist_to_target_m=120.0,
        v_mps=7.5, intent="approach", decision_summary="rules: accel 3, attend ego_2",
        conflict=ConflictView(conflict_id="narrow:B2C|C2B", kind="narrow", via="AB_0",
                              dist_to_entry_m=20.0, dist_to_exit_m=85.0))
    fields.update(over)
    return EgoStatus(**fields)  # type: ignore[arg-type]


def directive(**over: object) -> Directive:
    fields: dict[str, object] = dict(
        stamp_s=3.0, seq=4, directive_id="c-4-ego_2", ego_id="ego_2",
        conflict_id="narrow:B2C|C2B", priority=1, command="yield",
        speed_band=SpeedBand(min_mps=0.0, max_mps=5.0), deadline_s=8.0, source="rules")
    fields.update(over)
    return Directive(**fields)  # type: ignore[arg-type]


def refused(data: dict[str, object], cls: type) -> DecodeError:
    with pytest.raises(DecodeError) as info:
        decode(json.dumps(data), cls, topic=TOPIC)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"dropped message on {TOPIC}: field '{info.value.field}': ")
    return info.value


@pytest.mark.parametrize("msg", [status(), status(intent="cruise", conflict=None), directive()])
def test_round_trip(msg: object) -> None:
    text = encode(msg)  # type: ignore[arg-type]
    assert decode(text, type(msg), topic=TOPIC) == msg  # type: ignore[arg-type]
    assert json.loads(text)["schema"] == type(msg).SCHEMA  # type: ignore[attr-defined]


def _dump(msg: object, **over: object) -> dict[str, object]:
    data = json.loads(encode(msg))  # type: ignore[arg-type]
    data.update(over)
    return data


@pytest.mark.parametrize("over,field", [
    ({"ego_id": "ego"}, "ego_id"),           # the single-ego id is not a multi-ego one
    ({"ego_id": "ego_0"}, "ego_id"),
    ({"ego_id": "car_1"}, "ego_id"),
    ({"v_mps": -1.0}, "v_mps"),
    ({"v_mps": 1e9}, "v_mps"),
    ({"dist_to_target_m": "far"}, "dist_to_target_m"),
    ({"intent": "overtake"}, "intent"),
    ({"intent": "wait", "conflict": None}, "conflict"),
    ({"decision_summary": "x" * 201}, "decision_summary"),
    ({"colour": "red"}, "colour"),
    ({"schema": "lmpc/EgoStatus@9"}, "schema"),
])
def test_status_refusals_name_the_field(over: dict[str, object], field: str) -> None:
    assert refused(_dump(status(), **over), EgoStatus).field == field


def test_status_refuses_exit_before_entry_and_nan() -> None:
    data = _dump(status())
    data["conflict"]["dist_to_exit_m"] = 5.0  # type: ignore[index]
    assert refused(data, EgoStatus).field == "conflict.dist_to_exit_m"
    text = encode(status()).replace('"v_mps":7.5', '"v_mps":NaN')
    with pytest.raises(DecodeError) as info:
        decode(text, EgoStatus, topic=TOPIC)
    assert info.value.field in ("v_mps", "<payload>")


@pytest.mark.parametrize("over,field", [
    ({"command": "overtake"}, "command"),
    ({"ego_id": "ego_1; rm"}, "ego_id"),
    ({"priority": -1}, "priority"),
    ({"deadline_s": 2.0}, "deadline_s"),
    ({"deadline_s": 3.0}, "deadline_s"),
    ({"speed_band": {"min_mps": 6.0, "max_mps": 5.0}}, "speed_band.max_mps"),
    ({"speed_band": {"max_mps": 99.0}}, "speed_band.max_mps"),
    ({"source": "someone"}, "source"),
    ({"conflict_id": ""}, "conflict_id"),
])
def test_directive_refusals_name_the_field(over: dict[str, object], field: str) -> None:
    assert refused(_dump(directive(), **over), Directive).field == field


def test_directive_without_schema_on_the_wire_is_refused() -> None:
    data = _dump(directive())
    del data["schema"]
    assert refused(data, Directive).field == "schema"


def test_topic_names_single_and_multi_ego() -> None:
    from lmpc_msgs_py import topics

    assert topics.topic(topics.EGO_STATE) == "/lmpc/ego_state"  # single ego: unchanged
    assert topics.topic(topics.EGO_STATE, "ego_2") == "/ego_2/lmpc/ego_state"
    assert topics.topic(topics.PLANNER_STATUS, "ego_1") == "/ego_1/lmpc/planner/status"
    assert topics.topic(topics.COORD_STATUS, "ego_1") == "/coordination/status"  # shared
    assert topics.topic(topics.CLOCK, "ego_1") == "/clock"
