"""The MPC's one validated configuration (STYLE.md 4), loaded once from YAML.

:class:`MpcConfig` holds the horizon, the solver choice, the safety-distance and
freshness parameters, and the decision space (``lmpc_msgs_py.vocabulary``: the
action intervals whose midpoints are the bias ``A_hat`` and the weight pool), read
from the file ``decision_space_file`` names. The planner loads the same space from
``lmpc_msgs_py.vocabulary`` (not from this module); a Decision carries the space's
hash and :class:`~lmpc_mpc.controller.MpcController` refuses one from another space.
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

import os

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lmpc_msgs_py.vocabulary import (  # noqa: F401  (re-exported: their old home)
    ActionWeights,
    DecisionSpace,
    DecisionSpaceError,
    LevelSet,
    ResolvedWeights,
    SafetyWeights,
    SmoothnessWeights,
    TrackingWeights,
    WeightPool,
    load_decision_space,
)
from lmpc_msgs_py.yamlfile import field_path, first_field_error, read_mapping

DEFAULT_CONFIG_PATH = Path(__file__).resolve().parent / "config" / "mpc.yaml"
SOLVER_ENV = "LMPC_MPC_SOLVER"
"""Environment variable that overrides the config's ``solver`` (benchmarks pick the
solver this way without a config file of their own)."""

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


_SPACE_KEYS = ("weight_pool", "accel_intervals_mps2", "steer_intervals_rad")
"""Keys of the decision space (before issue 15 they were in the MPC config)."""


class MpcConfigError(ValueError):
    """The MPC configuration file is missing, unreadable or invalid (names the field)."""


class MpcConfig(BaseModel):
    """Everything the MPC needs besides the vehicle (see ``config/mpc.yaml``)."""

    model_config = _STRICT

    horizon: int = Field(30, ge=2, le=200)
    """Number of control steps N in the horizon."""
    dt_s: float = Field(0.1, gt=0.0, le=1.0)
    """Step length of the model and the control loop [s]."""
    solver: Literal["fatrop", "ipopt", "sqp_rti"] = "fatrop"
    """``fatrop`` (default) / ``ipopt``: the NLP solved to tolerance by FATROP (stage-wise)
    or IPOPT (general, slower); ``sqp_rti``: real-time iteration, one Gauss-Newton QP per
    step from the shifted previous solution (``lmpc_mpc.rti``), with FATROP answering
    every step the RTI does not deliver (``rti_fallback``; docs/lmpc_mpc.md, "The
    hybrid"). The environment variable ``LMPC_MPC_SOLVER`` overrides the file (see
    :func:`load_mpc_config`)."""
    codegen: Literal["auto", "build", "off"] = "auto"
    """The NLP's functions as generated C (``lmpc_mpc.codegen``; the same iterates to the
    bit, FATROP ~15 % faster): ``auto`` uses a compiled problem the solver cache holds
    (``python -m lmpc_mpc.codegen`` makes them; ``make demo`` / ``test`` / ``bench`` run
    it) and the interpreted one otherwise; ``build`` compiles a missing one on first use
    (2-15 s a problem size); ``off`` never."""
    rti_iterations: int = Field(1, ge=1, le=50)
    """``sqp_rti``: at most this many Gauss-Newton SQP steps per control step from a warm
    start. The first step is always taken; another only while the last one moved a
    planned control by more than ``rti_step_accel_mps2`` / ``rti_step_steer_rad`` (the
    guess was far from the new optimum: a jump of the reference or of the active
    obstacles). 1 (default) = the plain one-step RTI: the extra full steps have no
    globalisation and can hop to another local optimum (usi seed 3, docs/lmpc_mpc.md)."""
    rti_step_accel_mps2: float = Field(0.5, gt=0.0, le=10.0)
    """``sqp_rti``: a warm step that changed a planned acceleration by more than this
    is followed by another (up to ``rti_iterations``)."""
    rti_step_steer_rad: float = Field(0.05, gt=0.0, le=1.0)
    """``sqp_rti``: the same for a planned steer angle."""
    rti_max_move_accel_mps2: float = Field(3.0, gt=0.0, le=20.0)
    """``sqp_rti``: a warm step that moves a planned acceleration anywhere in the horizon
    by more than this is not trusted (the linearisation was far from the problem: dev
    seed rab 107 mpc swung +3 / -3.5 / +3 m/s^2 and steered into the ring's entry lane);
    see ``rti_fallback``."""
    rti_max_move_steer_rad: float = Field(0.3, gt=0.0, le=2.0)
    """``sqp_rti``: the same for a planned steer angle."""
    rti_fallback: bool = True
    """``sqp_rti``: a step the RTI does not deliver (its QP failed or gave non-finite
    numbers, a cold or reconverge iteration still moving a control by more than
    ``rti_step_*``, a warm step moving one by more than ``rti_max_move_*``) is solved by
    FATROP from the same warm start and parameters (the hybrid of docs/lmpc_mpc.md); off:
    such a step is a failed solve (shifted plan, then the brake)."""
    retry_solver: Literal["ipopt", "none"] = "none"
    """``ipopt``: a FATROP solve that does not converge (iteration cap, a failed line
    search) or gives non-finite numbers is solved once more by IPOPT from the same warm
    start and parameters; its solution, if it converges, is the step's (the solve time
    counts both; in realtime within the same ``time_budget_s``). ``none`` (default): such
    a step is a failed solve (shifted plan, then the brake). IPOPT converges on most steps
    FATROP gives up on (7 of 8 of ``sac`` on si 100-109) but sometimes to another local
    optimum (a hard swerve against the decision's bias): measured, it cut Table I's
    fallback steps by ~90 % and put one published style scene off its route, so it is
    opt-in (docs/lmpc_mpc.md, "A second solver for a failed solve")."""
    retry_max_move_accel_mps2: float = Field(3.0, gt=0.0, le=20.0)
    """``retry_solver``: a rescued plan that moves a planned acceleration anywhere in the
    horizon by more than this from the shifted previous plan is not trusted (the step
    fails as without a retry); the RTI's ``rti_max_move_accel_mps2``, not tuned."""
    retry_max_move_steer_rad: float = Field(0.3, gt=0.0, le=2.0)
    """``retry_solver``: the same for a planned steer angle."""
    rti_cold_iterations: int = Field(5, ge=1, le=50)
    """``sqp_rti``: steps from a cold start (first step, after a failure or a reset),
    where the guess is a plain roll-out and one step is not enough."""
    rti_qp_solver: Literal["hpipm"] = "hpipm"
    """``sqp_rti``: the structured QP solver (HPIPM ships in the CasADi wheel; FATROP's
    QP interface was far slower, see docs/lmpc_mpc.md)."""
    time_budget_s: float = Field(0.05, gt=0.0, le=10.0)
    """Wall time one solve may take [s]. A slower solve counts as a failure only when
    ``enforce_time_budget`` is on; otherwise it is counted (``over_budget``) and used."""
    enforce_time_budget: bool = False
    """Realtime operation: a solve over ``time_budget_s`` (wall) is a failure. Off in
    sync / benchmark runs, so results depend on the deterministic iteration cap only
    (same seed, same numbers) and not on how loaded the machine is. The node sets it
    from its ``clock_mode`` parameter."""
    max_iterations: int = Field(60, ge=1, le=10000)
    """Iteration cap of the NLP solver per solve; for ``sqp_rti`` the QP solver's
    iteration cap per Gauss-Newton step (a QP that needs more is a failed solve)."""
    decision_space_file: str = ""
    """The decision-space YAML (intervals and weight pool, ``lmpc_msgs_py.vocabulary``);
    '' = the packaged ``lmpc_msgs_py/config/decision_space.yaml``; a relative path is
    taken from the MPC config's directory. The planner must load the same file."""
    decision_space: DecisionSpace
    """The space itself, loaded from ``decision_space_file`` by :func:`load_mpc_config`
    (not written in the MPC config: the intervals and levels have one home)."""
    lateral_weight_factor: float = Field(10.0, ge=1.0, le=1000.0)
    """The lateral position error to the reference weighs this many times W_x."""
    reference_accel_mps2: float = Field(1.5, gt=0.0, le=10.0)
    """Acceleration the reference speed profile assumes from the current speed [m/s^2]."""
    reference_lat_accel_mps2: float = Field(2.5, gt=0.0, le=10.0)
    """Lateral acceleration bound that caps the reference speed in curves [m/s^2]."""
    lookahead_m: float = Field(60.0, gt=5.0, le=500.0)
    """Length of the reference candidates ahead of a vehicle [m]."""
    safety_gap_m: float = Field(2.0, ge=0.0, le=50.0)
    """Standstill gap between boxes in the desired distance d_hat [m]."""
    safety_headway_s: float = Field(1.0, ge=0.0, le=10.0)
    """Time headway of d_hat = gap + headway * v + half-lengths (agents ahead only) [s]."""
    safety_lateral_gap_m: float = Field(0.6, ge=0.0, le=10.0)
    """Side clearance between boxes; with the half-widths it scales the lateral axis [m]."""
    sensing_range_m: float = Field(80.0, gt=0.0, le=1000.0)
    """Agents within this distance are attended in baseline mode [m]."""
    safety_floor_dist_m: float = Field(12.0, ge=0.0, le=200.0)
    """Per-step safety floor: with a decision in force, an agent it does not attend that
    is closer than this (centre to centre) is attended anyway, with the baseline
    prediction. The planner applies the same floor when it decides; this one holds
    between decisions, on the current observation (an agent the decision never saw, or
    one that came close since) [m]."""
    safety_floor_ttc_s: float = Field(4.0, ge=0.0, le=60.0)
    """Per-step safety floor: the same for an agent whose time to collision
    (``lmpc_mpc.closeness``) is below this [s]."""
    safety_floor_reach_s: float = Field(3.0, ge=0.0, le=30.0)
    """Per-step safety floor: also attended, an agent closer than ``safety_floor_dist_m``
    plus what it and the ego can drive in this time (the horizon, 30 x 0.1 s: it could
    reach the ego's plan) [s]. 0: distance and TTC only."""
    safety_floor_hold_s: float = Field(3.0, ge=0.0, le=60.0)
    """An agent the per-step floor added stays attended this long after it last met the
    floor's test (sim time): the constant-velocity TTC of a car ahead vanishes while the
    ego swerves round it, and dropping the car mid-swerve let the plan turn back into it [s]."""
    stale_decision_check: bool = True
    """Check the decision in force against the current state on every step (issue 23,
    ``lmpc_mpc.stale``): re-attend agents it dropped or mispredicted that are on the ego's
    path, refuse its "go" while the MPC's own crossing rule yields. False: the decision
    is applied as it came (for measuring what the check costs)."""
    max_agents: int = Field(20, ge=0, le=100)
    """Most obstacle slots one problem holds (agents plus a red-light stop line); the
    nearest are kept."""
    agent_slot_sizes: tuple[int, ...] = (5, 10, 20)
    """Compiled problem sizes (agent slots); the smallest that fits is used."""
    shifted_plan_steps: int = Field(3, ge=0, le=50)
    """Steps the shifted previous plan is used after a solver failure, then brake."""
    stale_after_s: float = Field(0.3, gt=0.0, le=10.0)
    """Ego / agents older than this (sim time) are stale: the controller brakes [s]."""

    @model_validator(mode="after")
    def _check(self) -> "MpcConfig":
        if not self.agent_slot_sizes or list(self.agent_slot_sizes) != sorted(
            self.agent_slot_sizes
        ):
            raise ValueError("agent_slot_sizes: must be a non-empty ascending list")
        if self.agent_slot_sizes[-1] < self.max_agents:
            raise ValueError(
                f"agent_slot_sizes: largest ({self.agent_slot_sizes[-1]}) must hold "
                f"max_agents ({self.max_agents})"
            )
        return self


def load_mpc_config(path: str | Path | None = None) -> MpcConfig:
    """Load and validate the MPC config (``None``: the packaged ``config/mpc.yaml``).

    ``LMPC_MPC_SOLVER`` (if set and not empty) replaces the file's ``solver``;
    ``sqp_rti:K`` also sets ``rti_iterations`` to K (as ``bench_mpc --solvers``).
    Raises :class:`MpcConfigError` naming the file, the field and the reason.
    """
    file = Path(path) if path is not None and str(path) != "" else DEFAULT_CONFIG_PATH
    data = read_mapping(file, what="MPC config", error=MpcConfigError)
    override = os.environ.get(SOLVER_ENV, "").strip()
    if override:
        name, sep, steps = override.partition(":")
        data = {**data, "solver": name}
        if sep:
            if name != "sqp_rti" or not steps.isdigit():
                raise MpcConfigError(
                    f"{SOLVER_ENV}={override!r}: expected a solver name or sqp_rti:K (K >= 1)")
            data["rti_iterations"] = int(steps)
    if "decision_space" in data or any(k in data for k in _SPACE_KEYS):
        raise MpcConfigError(
            f"MPC config {file}: the intervals and the weight pool are not set here but in "
            "the decision-space file (field 'decision_space_file', lmpc_msgs_py.vocabulary)")
    space_file = str(data.get("decision_space_file") or "")
    if space_file and not Path(space_file).is_absolute():
        space_file = str(file.parent / space_file)
    try:
        data = {**data, "decision_space": load_decision_space(space_file or None)}
    except DecisionSpaceError as exc:
        raise MpcConfigError(f"MPC config {file}: field 'decision_space_file': {exc}") from None
    try:
        return MpcConfig.model_validate(data)
    except ValidationError as exc:
        text = first_field_error("MPC config", file, exc)
        if override and field_path(exc.errors(include_url=False)[0]) == "solver":
            text += f" (set by the environment variable {SOLVER_ENV})"
        raise MpcConfigError(text) from None
