"""Generated C (``lmpc_mpc.codegen``): the compiled problem drives the closed loop exactly
like the interpreted one (to the last bit); ``auto`` uses a compiled entry only when the
cache has one, ``build`` makes it, ``off`` never uses it; the command compiles a config's
problem sizes; a failed compile leaves the interpreted problem running."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lmpc_mpc import codegen, solver_cache
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcSolver

# two sizes keep the compiling short (~5 s); the lead-car scene needs the 2-slot one
CFG = load_mpc_config().model_copy(update={"agent_slot_sizes": (0, 2), "max_agents": 2})


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "solvers"
    monkeypatch.setenv(solver_cache.CACHE_ENV, str(folder))
    return folder


def _run(mode: str) -> tuple[np.ndarray, set[int]]:
    """Closed loop behind a slower car: controls and states per step, and the slot
    counts that ran as generated C."""
    cfg = CFG.model_copy(update={"codegen": mode})
    solver = MpcSolver(cfg)
    controls, states = S.follow_lead_car(MpcController(cfg, solver=solver), 30, cfg.dt_s)
    assert states[-1][3] < 9.5  # it slowed behind the lead: the solver did real work
    return np.array([u + x for u, x in zip(controls, states)]), solver.generated_sizes()


def test_generated_c_drives_exactly_like_the_interpreted_problem(cache: Path) -> None:
    interpreted, none = _run("auto")  # nothing compiled yet: auto runs interpreted
    assert none == set()
    compiled, sizes = _run("build")
    assert sizes == {0, 2}  # compiled on first use (the controller warms up both sizes)
    assert np.array_equal(interpreted, compiled)  # every control and state, to the last bit
    again, sizes = _run("auto")  # now the cache has it: auto uses it
    assert sizes == {0, 2} and np.array_equal(interpreted, again)
    _, sizes = _run("off")
    assert sizes == set()


def test_the_command_compiles_every_size_of_a_config(
        cache: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg_file = tmp_path / "mpc.yaml"
    cfg_file.write_text("horizon: 10\nagent_slot_sizes: [0, 2]\nmax_agents: 2\n")
    assert codegen.main(["--config", str(cfg_file)]) == 0
    assert "2 of 2 problem sizes as generated C" in capsys.readouterr().out
    cfg = load_mpc_config(cfg_file)
    solver = MpcSolver(cfg)  # auto: both from the cache, nothing compiled now
    solver.warm_up()
    assert solver.generated_sizes() == {0, 2}


def test_a_failed_compile_leaves_the_interpreted_problem(
        cache: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(codegen, "FLAGS", ("--no-such-flag",))
    solver = MpcSolver(CFG.model_copy(update={"codegen": "build", "horizon": 10}))
    assert solver.compiled(2).solver.name() == "mpc"
    assert solver.generated_sizes() == set()
    assert "compiling the MPC's functions failed" in caplog.text


def test_the_command_names_a_bad_config(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    cfg_file = tmp_path / "mpc.yaml"
    cfg_file.write_text("horizon: 1\n")
    with pytest.raises(SystemExit) as exc:
        codegen.main(["--config", str(cfg_file)])
    assert exc.value.code == 2 and "horizon" in capsys.readouterr().err
