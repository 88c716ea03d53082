"""The decision vocabulary (``lmpc_msgs_py.vocabulary``): one file, validated, hashed."""
import json
from pathlib import Path

import pytest
import yaml

from lmpc_msgs_py.messages import Decision, WeightLevels
from lmpc_msgs_py.vocabulary import (
    DEFAULT_SPACE_PATH,
    DecisionSpaceError,
    load_decision_space,
    space_mismatch,
)


def _default() -> dict:
    return yaml.safe_load(DEFAULT_SPACE_PATH.read_text())


def _write(tmp_path: Path, data: dict, name: str = "space.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_packaged_space_neutral_bands_bias_and_weights() -> None:
    space = load_decision_space()
    lo, hi = space.neutral_accel_band
    assert lo <= 0.0 <= hi and (lo, hi) == space.accel_intervals_mps2[space.neutral_accel_index]
    lo, hi = space.steer_intervals_rad[space.neutral_steer_index]
    assert lo <= 0.0 <= hi
    a_lo, a_hi = space.accel_intervals_mps2[0]
    assert space.bias_for(0, space.neutral_steer_index) == (0.5 * (a_lo + a_hi), 0.0)
    high = space.weights_for(WeightLevels(safety="high", action="low"))
    base = space.weights_for(None)
    assert high.safety.w_saf > base.safety.w_saf and high.action.w_accel < base.action.w_accel
    with pytest.raises(IndexError, match="steer_index 5 out of range 0..4"):
        space.bias_for(0, 5)


def test_hash_is_of_the_content_not_the_spelling(tmp_path: Path) -> None:
    """Comments, key order and number spelling do not change the hash; one number does."""
    packaged = load_decision_space()
    assert len(packaged.space_hash) == 16
    data = _default()
    reordered = {k: data[k] for k in reversed(list(data))}
    text = "# another comment\n" + yaml.safe_dump(reordered, sort_keys=False).replace(
        "1500.0", "1.5e3")
    (tmp_path / "same.yaml").write_text(text)
    same = load_decision_space(tmp_path / "same.yaml")
    assert same.space_hash == packaged.space_hash and same.source.endswith("same.yaml")
    data["weight_pool"]["action"]["high"]["w_accel"] = 10.5
    other = load_decision_space(_write(tmp_path, data))
    assert other.space_hash != packaged.space_hash
    line = space_mismatch(other, packaged.space_hash)
    assert line is not None and "\n" not in line
    assert packaged.space_hash in line and other.space_hash in line and other.source in line
    assert space_mismatch(packaged, packaged.space_hash) is None


@pytest.mark.parametrize("mutate, text", [
    (lambda d: d["weight_pool"]["safety"].pop("high"), r"weight_pool\.safety\.high"),
    (lambda d: d.update(steer_intervals_rad=[[0.1, 0.3], [0.3, 0.6]]), "contains 0"),
    (lambda d: d.update(accel_intervals_mps2=[[0.0, 1.0], [-1.0, 0.0]]), "sorted"),
    (lambda d: d.update(accel_intervals_mps2=[[-1.0, 1.0]]), "at least 2"),
    (lambda d: d["weight_pool"]["safety"]["low"].update(w_saf=float("nan")), "w_saf"),
    (lambda d: d.update(horizon=30), "horizon"),
])
def test_bad_space_names_file_and_field(tmp_path: Path, mutate, text: str) -> None:
    data = _default()
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(DecisionSpaceError, match=text) as err:
        load_decision_space(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(DecisionSpaceError, match="cannot read"):
        load_decision_space(tmp_path / "nope.yaml")


def test_decision_carries_the_hash_and_no_numbers() -> None:
    fields = Decision.model_fields
    assert "space_hash" in fields
    assert "accel_bias_mps2" not in fields and "steer_bias_rad" not in fields
    schema = json.dumps(Decision.model_json_schema())
    assert "lmpc/Decision@2" in schema
