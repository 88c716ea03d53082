"""The mock LLM's scripted decisions (logic of the mock_llm node, no ROS)."""
from __future__ import annotations

import json

import pytest

from lmpc_llm_planner.mock_script import (
    MockPlanner,
    MockScript,
    MockScriptError,
    load_mock_script,
)


def mid(intervals, i):
    return 0.5 * sum(intervals[i])


@pytest.fixture
def script_file(tmp_path):
    p = tmp_path / "script.yaml"
    p.write_text(
        "- {from_s: 0.0, preset: stop}\n"
        "- {from_s: 4.0, preset: go}\n"
        "- {from_s: 6.0, preset: baseline, accel_interval: 2, weights: {safety: high},"
        " attention: [car1, ghost]}\n"
    )
    return p


def run(mock, left_turn_map, obs_factory, oncoming_factory, t_end_s):
    out = []
    for k in range(int(round(t_end_s / 0.1)) + 1):
        obs = obs_factory(left_turn_map, stamp_s=k * 0.1, seq=k,
                          agents=[oncoming_factory("car1", y_m=30.0, v_mps=10.0)])
        d = mock.on_observation(obs)
        if d is not None:
            out.append(d)
    return out


def test_script_presets_and_reissue(script_file, mpc_config, left_turn_map, obs_factory,
                                    oncoming_factory):
    mock = MockPlanner(load_mock_script(script_file), mpc_config, period_s=2.5)
    ds = run(mock, left_turn_map, obs_factory, oncoming_factory, 8.0)
    assert [round(d.stamp_s, 2) for d in ds] == [0.0, 2.5, 4.0, 6.0]
    acc = mpc_config.accel_intervals_mps2
    stop, go, custom = ds[0], ds[2], ds[3]
    assert stop.accel_interval == min(range(len(acc)), key=lambda i: mid(acc, i))
    assert stop.steer_interval == mpc_config.neutral_steer_index
    assert (stop.weights.action, stop.weights.tracking) == ("high", "low")
    assert mid(acc, go.accel_interval) > 0.0
    assert set(go.weights.model_dump().values()) == {"normal"}
    assert custom.accel_interval == 2 and custom.weights.safety == "high"
    assert custom.attention == ("car1",)  # the unobserved id is left out
    assert all(d.source == "mock" for d in ds)
    assert stop.ego_trajectory.label.startswith("turn left")  # route candidate


def test_json_script_and_refusals(tmp_path, mpc_config):
    p = tmp_path / "s.json"
    p.write_text(json.dumps({"entries": [{"from_s": 1.0, "preset": "go"}]}))
    assert load_mock_script(p).entries[0].preset == "go"
    bad = tmp_path / "bad.yaml"
    bad.write_text("- {from_s: 0.0, preset: fly}\n")
    with pytest.raises(MockScriptError, match="preset"):
        load_mock_script(bad)
    with pytest.raises(MockScriptError, match="accel_interval 9"):
        MockPlanner(MockScript.model_validate({"entries": [{"from_s": 0, "accel_interval": 9}]}),
                    mpc_config)


def test_nothing_before_first_entry(mpc_config, left_turn_map, obs_factory):
    mock = MockPlanner(MockScript.model_validate({"entries": [{"from_s": 1.0}]}), mpc_config)
    assert mock.on_observation(obs_factory(left_turn_map, stamp_s=0.5)) is None
    assert mock.on_observation(obs_factory(left_turn_map, stamp_s=1.0)) is not None
