"""The MPC resolves a Decision in its own decision space and refuses one from another
(issue 15: one vocabulary, checked by hash), and the named parameter packer."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from lmpc_msgs_py.messages import BezierTrajectory, Decision, WeightLevels
from lmpc_msgs_py.vocabulary import DEFAULT_SPACE_PATH, load_decision_space
from lmpc_mpc import synthetic as S
from lmpc_mpc.config import DEFAULT_CONFIG_PATH, load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.model import N_W, CostParams
from lmpc_mpc.solver import MpcSolver


def _decision(space_hash: str, *, accel: int = 0, steer: int = 2, stamp_s: float = 0.0,
              decision_id: str = "d1") -> Decision:
    cps = ((10.0, -4.8), (30.0, -4.8), (50.0, -4.8), (70.0, -4.8))  # along straight_road
    return Decision(stamp_s=stamp_s, seq=1, decision_id=decision_id, source="mock",
                    latency_s=0.0, ttl_s=5.0,
                    ego_trajectory=BezierTrajectory(candidate_id=0, control_points=cps),
                    accel_interval=accel, steer_interval=steer,
                    weights=WeightLevels(safety="high"), space_hash=space_hash)


@pytest.fixture(scope="module")
def other_space_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A decision space whose strongest brake is -5 m/s^2 instead of -6 (one number
    changed) and an MPC config that loads it."""
    folder = tmp_path_factory.mktemp("space")
    data = yaml.safe_load(DEFAULT_SPACE_PATH.read_text())
    data["accel_intervals_mps2"][0] = [-5.0, -4.0]
    space = folder / "other_space.yaml"
    space.write_text(yaml.safe_dump(data))
    mpc = yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())
    mpc["decision_space_file"] = str(space)
    mpc_file = folder / "mpc.yaml"
    mpc_file.write_text(yaml.safe_dump(mpc))
    return space, mpc_file


def test_a_decision_of_another_space_is_refused_naming_both(other_space_files) -> None:
    space_file, mpc_file = other_space_files
    cfg = load_mpc_config(mpc_file)
    planner_space = load_decision_space()  # the planner's: the packaged file
    assert cfg.decision_space.space_hash != planner_space.space_hash
    ctrl = MpcController(cfg, solver=MpcSolver(cfg))
    refusal = ctrl.on_decision(_decision(planner_space.space_hash))
    assert refusal is not None and "\n" not in refusal
    assert planner_space.space_hash in refusal
    assert cfg.decision_space.space_hash in refusal and str(space_file) in refusal
    assert ctrl.stats().refused_decisions == 1
    assert ctrl.active_decision(1.0) is None  # baseline behaviour, not the decision
    # the same decision made in the MPC's own space is taken
    assert ctrl.on_decision(_decision(cfg.decision_space.space_hash)) is None
    assert ctrl.active_decision(1.0) is not None
    assert ctrl.stats().refused_decisions == 1


def test_an_index_outside_the_space_is_refused() -> None:
    cfg = load_mpc_config()
    ctrl = MpcController(cfg, solver=MpcSolver(cfg))
    n = len(cfg.decision_space.accel_intervals_mps2)
    refusal = ctrl.on_decision(_decision(cfg.decision_space.space_hash, accel=n))
    assert refusal is not None and f"accel {n} of {n}" in refusal
    assert ctrl.stats().refused_decisions == 1 and ctrl.active_decision(1.0) is None


def test_the_bias_is_resolved_by_the_mpc_from_the_indices() -> None:
    """The controller's bias is the midpoint of the decision's intervals in its space:
    a braking index brakes the ego at about that rate."""
    cfg = load_mpc_config()
    space = cfg.decision_space
    ctrl = MpcController(cfg, solver=MpcSolver(cfg))
    accel, steer = space.bias_for(1, space.neutral_steer_index)  # -3 m/s^2, straight
    assert ctrl.on_decision(_decision(space.space_hash, accel=1,
                                      steer=space.neutral_steer_index)) is None
    ego = S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=10.0, stamp_s=0.5, seq=1)
    ctl = ctrl.compute(S.observation(S.straight_road(), ego, ()))
    assert ctl.mode == "decision"
    assert accel == -3.0 and ctl.accel_mps2 < -1.0  # brakes towards the bias, not cruising
    assert ctl.predicted[-1].v_mps < 0.5 * ego.v_mps
    assert steer == 0.0


def test_cost_params_pack_by_name_in_slot_order() -> None:
    cfg = load_mpc_config()
    w = cfg.decision_space.weights_for(WeightLevels(safety="high", action="low"))
    c = CostParams.of(w, bias_steer_rad=0.1, lateral_factor=cfg.lateral_weight_factor)
    packed = c.pack()
    assert len(packed) == N_W == len(CostParams._fields) == 13  # the unused slot is gone
    slot = {name: i for i, name in enumerate(CostParams._fields)}
    assert packed[slot["w_saf"]] == w.safety.w_saf == 1500.0
    assert packed[slot["w_bias_accel"]] == w.action.w_accel
    assert packed[slot["bias_steer_rad"]] == 0.1
    assert packed[slot["lateral_factor"]] == cfg.lateral_weight_factor
    # the symbols side reads the same slots by the same names
    import casadi as ca

    sym = ca.SX.sym("w", N_W)
    named = CostParams.symbols(sym)
    f = ca.Function("f", [sym], [named.w_saf, named.bias_steer_rad])
    out = [float(v) for v in f(np.array(packed))]
    assert out == [w.safety.w_saf, 0.1]
