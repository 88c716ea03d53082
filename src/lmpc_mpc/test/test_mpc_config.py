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
    lo, hi = cfg.accel_intervals_mps2[cfg.neutral_accel_index]
    assert lo <= 0.0 <= hi
    lo, hi = cfg.steer_intervals_rad[cfg.neutral_steer_index]
    assert lo <= 0.0 <= hi
    a, d = cfg.bias_for(0, cfg.neutral_steer_index)
    assert a == pytest.approx(sum(cfg.accel_intervals_mps2[0]) / 2)
    assert d == pytest.approx(0.0)


def test_weights_follow_levels() -> None:
    cfg = load_mpc_config()
    hi = cfg.weights_for(WeightLevels(safety="high", action="low"))
    base = cfg.weights_for(None)
    assert hi.safety.w_saf > base.safety.w_saf
    assert hi.action.w_accel < base.action.w_accel


def test_bias_index_out_of_range_is_refused() -> None:
    cfg = load_mpc_config()
    with pytest.raises(IndexError, match="accel_index"):
        cfg.bias_for(len(cfg.accel_intervals_mps2), 0)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(horizon="thirty"), "horizon"),
    (lambda d: d.update(bogus=1), "bogus"),
    (lambda d: d["weight_pool"]["safety"].pop("high"), "weight_pool.safety.high"),
    (lambda d: d.update(solver="osqp"), "solver"),
    (lambda d: d.update(steer_intervals_rad=[[0.1, 0.3], [0.3, 0.6]]), "contains 0"),
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
