"""``bench_mpc.py`` (``lmpc_mpc.bench.main``) refuses what it cannot measure with one
argparse line naming the value: a horizon outside the MPC config's range crashed inside
CasADi (FATROP's "ng must have length N+1"), a negative agent count or zero steps ran and
printed nan ratios, a missing config file ended in a traceback."""
import pytest

from lmpc_mpc import bench


@pytest.mark.parametrize("argv, said", [
    (["--horizons", "0"], "argument --horizons: 0 must be within 2-200"),
    (["--horizons", "30", "201"], "argument --horizons: 201 must be within 2-200"),
    (["--agents", "-1"], "argument --agents: -1 must be >= 0"),
    (["--steps", "0"], "argument --steps: 0 must be >= 1"),
    (["--steps", "x"], "argument --steps: 'x' is not an integer"),
    (["--present", "-3"], "argument --present: -3 must be >= 0"),
    (["--config", "/no/such/mpc.yaml"], "--config: MPC config /no/such/mpc.yaml: cannot read"),
])
def test_bad_arguments_are_refused_before_anything_runs(argv, said, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        bench.main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err
