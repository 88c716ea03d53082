"""The learned planners' methods ``dqn`` / ``ppo`` / ``sac`` (``scripts/method_rl.py``) and
``scripts/train_rl.py`` (docs/RL.md). The methods need numpy only; the training smoke
runs need skrl[jax] (the ``rl`` extra, not in the ``test`` extra: it adds ~640 MB of JAX,
flax, TensorBoard and tensorstore), so they skip without it."""
from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from graphkit import REPO, scripts_module

from lmpc_bridge.evaluation.scenes import RunSettings, run_scene
from lmpc_bridge.rl_obs import obs_size
from lmpc_scripts import method_rl, methods

BENCH = REPO / "scripts" / "benchmark.py"
TRAIN = REPO / "scripts" / "train_rl.py"


def random_policy(algo: str, seed: int = 0) -> method_rl.NumpyPolicy:
    rng = np.random.default_rng(seed)
    out = 9 if algo == "dqn" else 2
    sizes = (obs_size(), 16, out)
    layers = tuple((rng.normal(0, 0.5, (a, b)).astype(np.float32),
                    rng.normal(0, 0.1, b).astype(np.float32))
                   for a, b in zip(sizes[:-1], sizes[1:]))
    return method_rl.NumpyPolicy(algo=algo, layers=layers, meta={"k_agents": 8, "test": True})


def test_a_saved_policy_loads_back_exactly(tmp_path: Path) -> None:
    for algo in ("dqn", "ppo", "sac"):
        pol = random_policy(algo)
        pol.save(tmp_path / f"{algo}.npz")
        back = method_rl.load_policy(tmp_path / f"{algo}.npz")
        assert back.algo == algo and back.meta["test"] is True
        x = np.linspace(-1, 1, obs_size()).astype(np.float32)
        assert np.array_equal(back.forward(x), pol.forward(x))
        act = back.act(x)
        assert 0 <= act < 9 if algo == "dqn" else (np.abs(act) <= 1).all()


def test_missing_or_bad_policy_files_get_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no saved policy .*train_rl.py"):
        method_rl.load_policy(tmp_path / "nope.npz")
    (tmp_path / "bad.npz").write_text("not a zip")
    with pytest.raises(ValueError, match="not a saved policy"):
        method_rl.load_policy(tmp_path / "bad.npz")
    out = subprocess.run([sys.executable, str(BENCH), "--families", "usi", "--seeds", "0",
                          "--methods", "dqn", "--policy-dir", str(tmp_path), "--out",
                          str(tmp_path / "run")], capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"benchmark: no saved policy {tmp_path / 'dqn-usi.npz'}: train it "
        "(scripts/train_rl.py --install) or give --policy-dir"]


def test_the_learned_methods_are_registered() -> None:
    for algo in ("dqn", "ppo", "sac"):
        assert methods.METHODS[algo].factory == "lmpc_scripts.method_rl:build"


@pytest.mark.parametrize("algo", ["dqn", "ppo"])
def test_a_shipped_policy_drives_one_scene_deterministically(
        algo: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    random_policy(algo, seed=3).save(tmp_path / f"{algo}-usi.npz")
    monkeypatch.setenv(method_rl.POLICY_DIR_ENV, str(tmp_path))
    settings = RunSettings(work_dir=str(tmp_path / "work"), log_dir=str(tmp_path / "logs"))
    rows = [run_scene(algo, "usi", 10003, settings, methods.build, methods.prepare)
            for _ in range(2)]
    assert rows[0]["outcome"] != "error", rows[0]["detail"]
    assert rows[0]["decisions"] > 0  # it decided, through the MPC
    same = ("outcome", "time_s", "ineff", "pen_acc", "pen_dist", "overall_cost", "decisions",
            "steps", "detail")
    assert [rows[0][k] for k in same] == [rows[1][k] for k in same]
    assert f"{algo}: {rows[0]['decisions']} decisions" in rows[0]["detail"]


SHIPPED_DIR = REPO / "policies"


def test_the_shipped_policies_load_with_their_provenance() -> None:
    # the learned planners' files (<algo>-<family>.npz; policies/adp.npz is the ADP
    # network, test_adp_method.py)
    shipped = sorted(p for p in SHIPPED_DIR.glob("*-*.npz")
                     if p.stem.split("-")[0] in method_rl.ALGOS)
    assert (SHIPPED_DIR / "dqn-usi.npz") in shipped
    for path in shipped:
        algo, family = path.stem.split("-", 1)
        pol = method_rl.load_policy(path)
        assert (pol.algo, pol.meta["family"]) == (algo, family), path.name
        # trained on the training range only, with its provenance
        first, last = (int(s) for s in pol.meta["scene_seeds"].split("-"))
        assert pol.meta["seed"] >= 10000 and first >= 10000 and last >= first
        assert pol.meta["steps"] > 0 and pol.meta["train_wall_s"] > 0
        assert len(pol.meta["commit"]) == 40 and pol.meta["versions"]["skrl"] != "absent"
        assert pol.meta["command"].startswith("train_rl.py --algo " + algo)
        out = pol.forward(np.zeros(obs_size(pol.k_agents), np.float32))
        assert out.shape == ((9,) if algo == "dqn" else (2,))
        assert np.isfinite(out).all()


def test_the_shipped_dqn_policy_drives_one_scene_deterministically(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The committed policies/dqn-usi.npz (numpy only: no JAX in CI), twice on one
    training scene: it decides, and the two rows are equal to the last digit."""
    monkeypatch.setenv(method_rl.POLICY_DIR_ENV, str(SHIPPED_DIR))
    settings = RunSettings(work_dir=str(tmp_path / "work"), log_dir=str(tmp_path / "logs"))
    rows = [run_scene("dqn", "usi", 10003, settings, methods.build, methods.prepare)
            for _ in range(2)]
    assert rows[0]["outcome"] != "error", rows[0]["detail"]
    assert rows[0]["decisions"] > 0  # not the neutral action throughout
    same = ("outcome", "time_s", "ineff", "pen_acc", "pen_dist", "overall_cost", "decisions",
            "steps", "detail")
    assert [rows[0][k] for k in same] == [rows[1][k] for k in same]


def test_actions_map_to_the_decision_spaces_intervals() -> None:
    planner = method_rl.ActionPlanner("continuous")
    space = planner.space
    assert planner.is_neutral(np.zeros(2))
    assert not planner.is_neutral(np.array([0.0, 0.5]))  # 1.75 m to the left
    assert not planner.is_neutral(np.array([-0.5, 0.0]))  # -2.5 m/s2
    intervals = space.accel_intervals_mps2
    for a in np.linspace(-1, 1, 41) * method_rl.ACCEL_SCALE_MPS2:
        i = planner.accel_index(float(a))
        lo, hi = intervals[i]
        # beyond the outermost intervals: the outermost one
        assert lo <= a <= hi or (i == 0 and a < lo) or (i == len(intervals) - 1 and a > hi)
    disc = method_rl.ActionPlanner("discrete")
    assert disc.is_neutral(method_rl.NEUTRAL_DISCRETE)
    n = space.neutral_accel_index
    assert [disc.accel_index(s) for s in method_rl.ACCEL_STEPS] == [n - 1, n, n + 1]


def test_shifted_moves_the_reference_sideways_but_not_its_start() -> None:
    from lmpc_msgs_py.messages import BezierTrajectory

    traj = BezierTrajectory(candidate_id=0, control_points=((0.0, 0.0), (10.0, 0.0),
                                                            (20.0, 0.0)), label="ahead")
    left = method_rl.shifted(traj, 2.0)
    assert left.control_points == ((0.0, 0.0), (10.0, 2.0), (20.0, 2.0))


def test_stored_next_observations_are_the_finished_episodes_last_ones() -> None:
    """The vector env autoresets in the same step: a finished environment's next
    observation is the new episode's first; the transition must store the old episode's
    last (``final_obs``), or a truncated episode bootstraps from the wrong state."""
    train_rl = scripts_module("train_rl")  # its helpers need numpy only
    nxt = np.array([[1.0, 1.0], [2.0, 2.0]], np.float32)
    final = np.array([None, np.array([9.0, 8.0], np.float32)], dtype=object)
    info = {"final_obs": final, "_final_obs": np.array([False, True])}
    stored = train_rl._stored_next(nxt, info, np.array([False, True]))
    np.testing.assert_array_equal(stored, [[1.0, 1.0], [9.0, 8.0]])
    np.testing.assert_array_equal(nxt, [[1.0, 1.0], [2.0, 2.0]])  # not changed in place
    assert train_rl._stored_next(nxt, {}, np.array([False, False])) is nxt


def test_train_refuses_seeds_below_the_training_range() -> None:
    out = subprocess.run([sys.executable, str(TRAIN), "--algo", "dqn", "--family", "usi",
                          "--steps", "10", "--seed", "3"], capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "train_rl: --seed 3: training uses seeds >= 10000 only (0-24 are the published "
        "test scenes, 100-124 the development seeds)"]


@pytest.mark.skipif(importlib.util.find_spec("skrl") is None,
                    reason="skrl[jax] not installed (the rl extra; not in the test extra)")
@pytest.mark.slow
@pytest.mark.parametrize("algo", ["dqn", "ppo", "sac"])
def test_training_smoke_run_writes_curve_and_policy(algo: str, tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, str(TRAIN), "--algo", algo, "--family", "usi",
                          "--steps", "300", "--seed", "10000", "--envs", "2",
                          "--eval-scenes", "1", "--no-progress", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "curve.csv").open()))
    assert all(r["outcome"] in ("reached", "collision", "timeout", "off_route", "error", "cap")
               for r in rows)
    assert (tmp_path / "curve.png").stat().st_size > 0
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert prov["steps"] == 300 and prov["versions"]["skrl"] != "absent"
    assert prov["train_cap"] is None  # the default: only the 200 s cap
    held_out = list(csv.DictReader((tmp_path / "eval.csv").open()))
    pairs = [(r["scene_seed"], r["driver"]) for r in held_out]
    assert pairs == [("10200", "policy"), ("10200", "mpc")]
    assert prov["eval_mpc_reached"] + prov["eval_policy_reached"] <= 2
    pol = method_rl.load_policy(tmp_path / "policy.npz")
    assert pol.algo == algo and pol.meta["commit"] == prov["commit"]
    assert pol.forward(np.zeros(obs_size(), np.float32)).shape == ((9,) if algo == "dqn"
                                                                   else (2,))
