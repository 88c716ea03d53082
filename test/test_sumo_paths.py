"""A work directory SUMO's tools cannot be given is refused when the simulation is made,
with an error naming the path (netconvert / sumo split file options at ',')."""
from __future__ import annotations

from pathlib import Path

import pytest

from lmpc_bridge.multi_sim import MultiSumoSim
from lmpc_bridge.scenarios import SceneError
from lmpc_bridge.sim import SumoSim


@pytest.mark.parametrize("make", [SumoSim, MultiSumoSim])
def test_a_work_dir_with_a_comma_is_refused_by_name(tmp_path: Path, make) -> None:
    bad = tmp_path / "runs,2026"
    with pytest.raises(SceneError, match=r"runs,2026.*contains ','"):
        make(work_dir=bad)
    make(work_dir=tmp_path / "runs_2026")  # the same without the comma is taken


def test_run_graph_refuses_such_a_run_dir_before_any_node_starts(tmp_path: Path) -> None:
    from lmpc_scripts import run_graph

    run_dir = tmp_path / "a,b"
    summary = run_graph.run(run_graph.parse_args(
        ["--scenario", "usi", "--seed", "0", "--quiet", "--run-dir", str(run_dir)]))
    assert summary["outcome"] == "error"
    assert f"the run directory '{run_dir}' contains ','" in str(summary["detail"])
    assert "no node was started" in str(summary["detail"])
    assert not list(run_dir.glob("*.log"))  # no node log
