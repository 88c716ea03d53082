"""Config loading and refusal of bad files."""
from pathlib import Path

import pytest
import yaml

from lmpc_msgs_py.messages import WeightLevels
from lmpc_mpc.config import DEFAULT_CONFIG_PATH, MpcConfigError, load_mpc_config


def _write(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "mpc.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _default() -> dict:
    return yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())


def test_default_config_loads_with_neutral_intervals() -> None:
    cfg = load_mpc_config()
    lo, hi = cfg.decision_space.accel_intervals_mps2[cfg.decision_space.neutral_accel_index]
    assert lo <= 0.0 <= hi
    lo, hi = cfg.decision_space.steer_intervals_rad[cfg.decision_space.neutral_steer_index]
    assert lo <= 0.0 <= hi
    a, d = cfg.decision_space.bias_for(0, cfg.decision_space.neutral_steer_index)
    assert a == pytest.approx(sum(cfg.decision_space.accel_intervals_mps2[0]) / 2)
    assert d == pytest.approx(0.0)


def test_weights_follow_levels() -> None:
    cfg = load_mpc_config()
    hi = cfg.decision_space.weights_for(WeightLevels(safety="high", action="low"))
    base = cfg.decision_space.weights_for(None)
    assert hi.safety.w_saf > base.safety.w_saf
    assert hi.action.w_accel < base.action.w_accel


def test_bias_index_out_of_range_is_refused() -> None:
    cfg = load_mpc_config()
    with pytest.raises(IndexError, match="accel_index"):
        cfg.decision_space.bias_for(len(cfg.decision_space.accel_intervals_mps2), 0)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(horizon="thirty"), "horizon"),
    (lambda d: d.update(bogus=1), "bogus"),
    (lambda d: d.update(solver="osqp"), "solver"),
    (lambda d: d.update(dt_s=float("nan")), "dt_s"),
])
def test_bad_config_names_the_field(tmp_path: Path, mutate, field: str,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # the file's own value is under test: no LMPC_MPC_SOLVER override from the caller
    monkeypatch.delenv("LMPC_MPC_SOLVER", raising=False)
    data = _default()
    mutate(data)
    with pytest.raises(MpcConfigError, match=field.replace(".", r"\.")):
        load_mpc_config(_write(tmp_path, data))


def test_unreadable_and_non_mapping_files(tmp_path: Path) -> None:
    with pytest.raises(MpcConfigError, match="cannot read"):
        load_mpc_config(tmp_path / "missing.yaml")
    p = tmp_path / "list.yaml"
    p.write_text("- 1\n- 2\n")
    with pytest.raises(MpcConfigError, match="mapping"):
        load_mpc_config(p)


def _space_file(tmp_path: Path, name: str, mutate) -> Path:
    from lmpc_msgs_py.vocabulary import DEFAULT_SPACE_PATH

    data = yaml.safe_load(DEFAULT_SPACE_PATH.read_text())
    mutate(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_decision_space_is_not_written_in_the_mpc_config(tmp_path: Path) -> None:
    data = _default()
    data["accel_intervals_mps2"] = [[-1.0, 0.0], [0.0, 1.0]]  # the pre-issue-15 home
    with pytest.raises(MpcConfigError, match="decision-space file"):
        load_mpc_config(_write(tmp_path, data))


def test_decision_space_file_relative_to_the_config_and_checked(tmp_path: Path) -> None:
    _space_file(tmp_path, "space.yaml",
                lambda d: d["weight_pool"]["safety"]["high"].update(w_saf=2000.0))
    cfg = load_mpc_config(_write(tmp_path, {**_default(), "decision_space_file": "space.yaml"}))
    assert cfg.decision_space.weight_pool.safety.high.w_saf == 2000.0
    assert cfg.decision_space.source == str(tmp_path / "space.yaml")
    assert cfg.decision_space.space_hash != load_mpc_config().decision_space.space_hash
    _space_file(tmp_path, "bad.yaml", lambda d: d["weight_pool"]["safety"].pop("high"))
    with pytest.raises(MpcConfigError, match=r"decision_space_file.*weight_pool\.safety\.high"):
        load_mpc_config(_write(tmp_path, {**_default(), "decision_space_file": "bad.yaml"}))
