"""The ``adp`` method (docs/RL.md, "ADP"): registered, a missing network is one line, and
the shipped network drives one scene deterministically (numpy only, no JAX)."""
from __future__ import annotations

from pathlib import Path

import pytest

from lmpc_bridge.evaluation.scenes import RunSettings, run_scene
from lmpc_scripts import method_adp, methods
from lmpc_scripts.method_rl import POLICY_DIR_ENV


def test_adp_is_a_registered_method() -> None:
    assert methods.METHODS["adp"].factory == "lmpc_scripts.method_adp:build"
    assert "adp" in methods.list_methods()


def test_a_missing_network_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(POLICY_DIR_ENV, str(tmp_path))
    with pytest.raises(FileNotFoundError, match="no ADP network .*adp.npz"):
        method_adp.make_controller()


def test_the_shipped_network_drives_one_scene_deterministically(tmp_path: Path) -> None:
    assert method_adp.adp_path(method_adp.DEFAULT_POLICY_DIR).is_file()
    settings = RunSettings(work_dir=str(tmp_path / "work"))
    rows = [run_scene("adp", "usi", 10003, settings, methods.build, methods.prepare)
            for _ in range(2)]
    assert rows[0]["outcome"] != "error", rows[0]["detail"]
    assert rows[0]["steps"] > 10
    same = ("outcome", "time_s", "ineff", "pen_acc", "pen_dist", "overall_cost", "steps",
            "detail")
    assert [rows[0][k] for k in same] == [rows[1][k] for k in same]
    assert "adp: network adp.npz" in rows[0]["detail"]
