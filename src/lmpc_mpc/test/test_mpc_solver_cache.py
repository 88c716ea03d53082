"""The on-disk solver cache (``lmpc_mpc.solver_cache``): a loaded problem drives exactly
like a built one, a hit skips the build, other inputs get other entries, a broken entry
is rebuilt, ``off`` disables it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lmpc_mpc import solver_cache
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcSolver

CFG = load_mpc_config()


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "solvers"
    monkeypatch.setenv(solver_cache.CACHE_ENV, str(folder))
    return folder


def _run(steps: int = 30) -> np.ndarray:
    """Closed loop behind a slower car (test_mpc_oracle's golden scene): controls, states."""
    ctrl = MpcController(CFG, solver=MpcSolver(CFG))
    controls, states = S.follow_lead_car(ctrl, steps, CFG.dt_s)
    rows = [u + x for u, x in zip(controls, states)]
    assert rows[-1][5] < 9.5  # it slowed behind the lead: the solver did real work
    return np.array(rows)


def test_a_loaded_solver_drives_exactly_like_a_built_one(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    built = _run()
    entries = sorted(p.name for p in cache.iterdir())
    assert entries and all(p.endswith((".casadi", ".npz")) for p in entries)
    assert not [p for p in entries if ".tmp" in p]

    def no_build(self: MpcSolver, n_slots: int) -> None:
        raise AssertionError(f"built size {n_slots} although it is cached")

    monkeypatch.setattr(MpcSolver, "_build", no_build)
    loaded = _run()
    assert np.array_equal(built, loaded)  # to the last digit


def test_other_inputs_get_other_entries(cache: Path) -> None:
    MpcSolver(CFG).compiled(5)
    n = len(list(cache.glob("*.casadi")))
    MpcSolver(CFG.model_copy(update={"horizon": CFG.horizon - 5})).compiled(5)
    MpcSolver(CFG, solver="ipopt").compiled(5)
    MpcSolver(CFG).compiled(10)
    assert len(list(cache.glob("*.casadi"))) == n + 3


def test_a_broken_entry_is_rebuilt(cache: Path, caplog: pytest.LogCaptureFixture) -> None:
    MpcSolver(CFG).compiled(5)
    (entry,) = cache.glob("*.casadi")
    entry.write_text("not a casadi function")
    ctrl = MpcController(CFG, solver=MpcSolver(CFG))
    assert ctrl.solver.compiled(5).solver.name() == "mpc"
    assert "unreadable" in caplog.text and entry.name in caplog.text
    assert solver_cache.load(entry.stem) is not None  # written again


def test_off_disables_the_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(solver_cache.CACHE_ENV, "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    MpcSolver(CFG).compiled(5)
    assert solver_cache.cache_dir() is None and not any(tmp_path.iterdir())


def test_a_loaded_rti_drives_exactly_like_a_built_one(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The RTI's QP data function comes from the cache (its HPIPM solver is made anew:
    that interface does not deserialise) and gives the same controls to the last digit."""
    rti = CFG.model_copy(update={"solver": "sqp_rti"})

    def run() -> np.ndarray:
        ctrl = MpcController(rti, solver=MpcSolver(rti))
        controls, states = S.follow_lead_car(ctrl, 30, rti.dt_s)
        assert states[-1][3] < 9.5  # it slowed behind the lead
        return np.array([u + x for u, x in zip(controls, states)])

    built = run()
    assert len(list(cache.glob("*.casadi"))) >= 1

    def no_build(self: object, *args: object) -> None:
        raise AssertionError("built the RTI data although it is cached")

    monkeypatch.setattr("lmpc_mpc.rti.RtiQp._build", no_build)
    assert np.array_equal(built, run())


def test_a_hybrid_solvers_nlp_is_its_fatrop_fallbacks(cache: Path) -> None:
    """``compiled()`` of the hybrid ``sqp_rti`` (there is no "sqp_rti" NLP plugin) is the
    NLP of the FATROP solver that answers the steps its RTI does not deliver."""
    hybrid = MpcSolver(CFG, solver="sqp_rti")
    comp = hybrid.compiled(5)
    assert comp is hybrid._nlp_fallback().compiled(5)
    assert comp.solver.name() == "mpc" and hybrid._nlp_fallback().solver_name == "fatrop"
