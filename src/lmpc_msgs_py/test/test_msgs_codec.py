"""Codec refusals of RELIABILITY.md "Inputs that must be refused", one case each."""
from __future__ import annotations

import json

import pytest

from lmpc_msgs_py import (
    ALL_MESSAGES,
    BezierTrajectory,
    Control,
    Decision,
    DecodeError,
    EgoState,
    EpisodeMetrics,
    EpisodeStatus,
    SequenceGate,
    StaleMessage,
    decode,
    encode,
    is_stale,
)
from lmpc_msgs_py.codec import MAX_PAYLOAD_BYTES
from lmpc_msgs_py.freshness import RESYNC_AFTER

TOPIC = "/lmpc/ego_state"


def ego(**over: object) -> EgoState:
    fields: dict[str, object] = dict(
        stamp_s=1.5, seq=15, x_m=10.0, y_m=-4.0, yaw_rad=0.3, v_mps=8.0, a_mps2=-0.5,
        steer_rad=0.05, lane_id="E0_0", lane_pos_m=12.0, dist_to_target_m=80.0,
    )
    fields.update(over)
    return EgoState(**fields)  # type: ignore[arg-type]


def ego_dict(**over: object) -> dict[str, object]:
    data = json.loads(encode(ego()))
    data.update(over)
    return data


def refused(text: str, cls: type = EgoState) -> DecodeError:
    with pytest.raises(DecodeError) as info:
        decode(text, cls, topic=TOPIC)
    err = info.value
    assert err.topic == TOPIC
    assert str(err).startswith(f"dropped message on {TOPIC}: field '{err.field}': ")
    return err


def test_round_trip_keeps_every_field() -> None:
    msg = ego()
    text = encode(msg)
    assert json.loads(text)["schema"] == "lmpc/EgoState@1"
    assert decode(text, EgoState, topic=TOPIC) == msg


@pytest.mark.parametrize(
    "text, reason_part",
    [
        ("this is not json", "not valid JSON"),
        ('{"schema": "lmpc/EgoState@1", "seq": 1', "not valid JSON"),  # truncated
        ("", "empty string"),
        ("   ", "empty string"),
        ("[1, 2, 3]", ""),
    ],
)
def test_refuses_non_json_truncated_empty(text: str, reason_part: str) -> None:
    err = refused(text)
    assert reason_part in err.reason


def test_refuses_very_large_string() -> None:
    err = refused(" " * 10 + "x" * (MAX_PAYLOAD_BYTES + 1))
    assert "exceeds" in err.reason


def test_refuses_wrong_schema_name_and_version() -> None:
    err = refused(json.dumps(ego_dict(schema="lmpc/EgoState@2")))
    assert err.field == "schema" and "lmpc/EgoState@2" in err.reason
    err = refused(json.dumps(ego_dict(schema="lmpc/Control@1")))
    assert err.field == "schema"


def test_refuses_missing_schema_and_missing_field() -> None:
    data = ego_dict()
    del data["schema"]
    assert refused(json.dumps(data)).field == "schema"
    data = ego_dict()
    del data["v_mps"]
    err = refused(json.dumps(data))
    assert err.field == "v_mps" and "required" in err.reason.lower()


def test_refuses_extra_field_and_wrong_type() -> None:
    assert refused(json.dumps(ego_dict(bogus=1))).field == "bogus"
    assert refused(json.dumps(ego_dict(v_mps="8.0"))).field == "v_mps"
    assert refused(json.dumps(ego_dict(seq=1.5))).field == "seq"
    assert refused(json.dumps(ego_dict(lane_id=7))).field == "lane_id"


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity", "1e309"])
def test_refuses_nan_inf_overflow(literal: str) -> None:
    text = encode(ego()).replace('"x_m":10.0', f'"x_m":{literal}')
    assert literal in text
    err = refused(text)
    assert err.field in ("x_m", "<payload>")


@pytest.mark.parametrize(
    "field, value",
    [("v_mps", 200.0), ("steer_rad", 3.0), ("a_mps2", 50.0), ("a_mps2", -50.0), ("v_mps", -1.0)],
)
def test_refuses_physically_absurd_values(field: str, value: float) -> None:
    assert refused(json.dumps(ego_dict(**{field: value}))).field == field


def test_absurd_control_refused() -> None:
    ctl = Control(stamp_s=0.0, seq=0, accel_mps2=1.0, steer_rad=0.0, mode="baseline",
                  solver_status="ok", solve_time_ms=1.0)
    data = json.loads(encode(ctl))
    data["accel_mps2"] = -50.0
    assert refused(json.dumps(data), Control).field == "accel_mps2"


def test_decision_prediction_must_be_attended() -> None:
    traj = BezierTrajectory(candidate_id=0, control_points=((0.0, 0.0), (1.0, 0.0)))
    good = Decision(
        stamp_s=2.5, seq=1, decision_id="d1", source="rules", latency_s=0.01,
        ego_trajectory=traj, attention=("car1",), accel_interval=2, steer_interval=2,
        space_hash="0123456789abcdef",
    )
    assert decode(encode(good), Decision) == good
    data = json.loads(encode(good))
    data["agent_predictions"] = [{"agent_id": "ghost", "trajectory": data["ego_trajectory"]}]
    err = refused(json.dumps(data), Decision)
    assert "ghost" in err.reason
    data = json.loads(encode(good))
    data["source"] = "somebody"
    assert refused(json.dumps(data), Decision).field == "source"


def test_every_message_is_frozen_and_strict() -> None:
    for cls in ALL_MESSAGES:
        cfg = cls.model_config
        assert cfg.get("extra") == "forbid" and cfg.get("frozen") is True
        assert cfg.get("allow_inf_nan") is False
        assert cls.SCHEMA.startswith("lmpc/")
        assert cls.SCHEMA.endswith("@2" if cls in (EpisodeStatus, Decision) else "@1")
    with pytest.raises(Exception):
        ego().v_mps = 3.0  # type: ignore[misc]


def test_sequence_gate_refuses_duplicates_and_backwards() -> None:
    gate = SequenceGate("/lmpc/control")
    gate.check(0)
    gate.check(0)  # step 0 re-offered while discovery settles
    gate.check(1)
    gate.check(2)
    with pytest.raises(StaleMessage, match="duplicate"):
        gate.check(2)
    with pytest.raises(StaleMessage, match="backwards"):
        gate.check(1)
    gate.check(0)  # a restarted publisher begins again at 0 (staleness judges its stamp)
    gate.check(1)
    assert gate.refused == 2 and gate.resyncs == 0


def test_sequence_gate_survives_one_forged_huge_seq() -> None:
    gate = SequenceGate("/lmpc/control")
    gate.check(1)
    gate.check(10**12)  # forged / corrupted, but a valid message
    refused = 0
    for seq in range(2, 20):
        try:
            gate.check(seq)
        except StaleMessage:
            refused += 1
    assert refused == RESYNC_AFTER - 1 and gate.last_seq == 19


def test_staleness_bound() -> None:
    assert is_stale(1.0, 1.31, 0.3)
    assert not is_stale(1.0, 1.3, 0.3)


def test_episode_status_v2_carries_off_route_and_refuses_v1() -> None:
    status = EpisodeStatus(stamp_s=3.0, seq=30, scenario="short_lc", seed=0,
                           outcome="off_route", detail="left its route",
                           metrics=EpisodeMetrics(time_s=3.0))
    text = encode(status)
    assert decode(text, EpisodeStatus).outcome == "off_route"
    # a version-1 message (or a receiver's unknown outcome) is refused by name
    old = json.loads(text)
    old["schema"] = "lmpc/EpisodeStatus@1"
    with pytest.raises(DecodeError) as err:
        decode(json.dumps(old), EpisodeStatus, topic="/lmpc/episode")
    assert err.value.field == "schema" and "EpisodeStatus@2" in err.value.reason
    bad = json.loads(text)
    bad["outcome"] = "lost"
    with pytest.raises(DecodeError) as err:
        decode(json.dumps(bad), EpisodeStatus, topic="/lmpc/episode")
    assert err.value.field == "outcome"
