"""The MPC controller of the in-process contract (docs/ARCHITECTURE.md), no ROS.

``on_decision`` stores decisions; ``compute`` turns one observation into one
``Control``. The decision-timing rule lives here, in one place, for the node and
the benchmark alike: a decision stamped ``t0`` is in force from the first
observation with ``t >= t0 + max(latency_s, dt)`` until ``t0 + ttl_s``; the
newest applicable one wins. Without one the controller runs the paper's MPC
baseline (normal weights, every agent in range attended, route reference,
closest-heading predictions, zero bias).

Fallbacks (RELIABILITY.md): a failed solve uses the shifted previous plan for
``shifted_plan_steps`` steps, then brakes at ``vehicle.safe_brake_mps2``, the
steer ramped towards 0 at the steer-rate limit; stale ego / agents brake at once. A
solve over the wall-time budget is a failure only in realtime operation
(``realtime=True`` or ``enforce_time_budget`` in the config); in sync / benchmark
runs it is counted (``over_budget``) and used, so the same observations give the same
controls however loaded the machine is.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np

from lmpc_msgs_py.messages import Agent, Control, ControlMode, Decision, EgoState, PosePoint
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams
from lmpc_msgs_py.vocabulary import space_mismatch
from lmpc_mpc.closeness import closeness, must_attend
from lmpc_mpc.config import MpcConfig
from lmpc_mpc.mirrors import OWN_SUFFIX
from lmpc_mpc.prediction import baseline_candidate
from lmpc_mpc.reference import (
    REFERENCE_DS_M,
    ReferencePathError,
    _path_geometry,
    _Polyline,
    bezier_points,
    candidates_for_pose,
    closest_heading,
    lane_at,
    reference_path_points,
    route_candidate,
    route_path,
    route_progress,
    sharp_turn_near,
    sharp_turn_path,
    timed_reference,
)
from lmpc_mpc.lead_in import lead_in, turned_away
from lmpc_mpc.route_guard import RouteLeave, leaves_route
from lmpc_mpc.solver import MpcProblem, MpcSolver, Obstacle
from lmpc_mpc.crossing import _HEDGE_APART_M, CrossingRules
from lmpc_mpc.stale import StaleRecord, StaleVerdict
from lmpc_mpc.stop_line import STOP_MARGIN_M as _STOP_MARGIN_M
from lmpc_mpc.stop_line import stop_distance_m

_TIME_EPS_S = 1e-6
_DECISION_MEMORY = 8
_Points = tuple[tuple[float, float], ...]
_CANDIDATE_REUSE_S = 0.5
"""An agent's closest-heading candidate is rebuilt at most this often (sim time) while
the agent stays on the same lane; in between its forecast runs along the kept curve
from the agent's current position (building candidates was ~1 ms per agent per step)."""
_REBUILDS_PER_STEP = 3
"""At most this many expired agent curves are rebuilt per step (the oldest first; new
agents and curves older than twice ``_CANDIDATE_REUSE_S`` always), so agents seen
together do not all expire in the same step (that made p99 spikes)."""
_ON_ROUTE_M = 2.0
_ON_ROUTE_RAD = math.radians(45.0)
"""A decision curve ending this close to the route, heading along it, is continued along
the route (``MpcController._decision_curve``)."""


@dataclass(frozen=True)
class ControllerStats:
    """Counters of the controller (the node puts them on its diagnostics)."""

    steps: int
    solver_failures: int
    fallbacks: int
    shifted: int
    brakes: int
    stale_inputs: int
    floor_additions: int
    """Agent-steps the per-step safety floor attended that the decision in force did not."""
    hedged: int
    """Agent-steps a close agent was kept clear of along both the decision's prediction
    and the MPC's own forecast (they differed by more than ``_HEDGE_APART_M`` within the
    last ``safety_floor_hold_s``)."""
    over_budget: int
    """Successful solves slower than ``time_budget_s`` (wall); failures only in realtime."""
    mode: str
    route_overrides: int = 0
    """Decisions whose chosen candidate left the ego's route where the route goes on
    elsewhere (``route_guard``): the MPC tracked the route reference instead."""
    stale_steps: int = 0
    """Steps on which the decision in force was found stale for some agent (``lmpc_mpc.stale``)."""
    stale_agent_steps: int = 0
    """Agent-steps an agent was re-attended with the MPC's own forecast (stale check)."""
    go_refused: int = 0
    """Steps on which a decision's "go" bias was refused (the MPC's crossing rule yields)."""
    brake_refused: int = 0
    """Steps on which a decision's braking was not executed on a roundabout with a car
    closing in from behind (``StaleVerdict.brake_refused_for``)."""
    refused_decisions: int = 0
    """Decisions refused on arrival: made in another decision space (their ``space_hash``
    is not this MPC's) or with an interval index outside this space."""


@dataclass(frozen=True)
class ControllerSnapshot:
    """``MpcController.snapshot``: the controller's own state and its solver's warm start."""

    state: dict
    solver: tuple


_REENTRY_AHEAD_M = 12.0
_REENTRY_RAD = math.radians(30.0)
"""The path point this far ahead lies more than this off the ego's heading: the decision's
steer bias is replaced by the path's own (``MpcController._problem``)."""
_SHARP_ON_ROUTE_M = 3.0
"""The sharp-turn reference is for an ego on its route: farther off, the usual one."""


def rebased_control_points(control_points: Sequence[Sequence[float]], x_m: float,
                           y_m: float) -> np.ndarray:
    """A decision curve's control points from where the ego is now: its position, then
    the points from the closest one ahead of it on.

    The first control point is where the ego was when the planner looked, a latency
    (2.5 s, ~35 m at speed) before the decision takes effect. Left in, that long leg
    weighs on the whole Bezier: a turn's curve bent early and cut the corner (0.8 m left
    of the approach lane's centre 3 m into the junction; usi seed 13 of ``lmpc-local``:
    the ego stopped with its nose in the oncoming lane and was hit). With fewer than two
    points ahead the control points are kept as they are."""
    cps = np.asarray(control_points, dtype=float)
    here = np.array([x_m, y_m])
    i = int(np.argmin(np.hypot(*(cps - here).T)))
    if i + 1 < len(cps) and float(np.dot(cps[i] - here, cps[i + 1] - cps[i])) < 0.0:
        i += 1  # the closest point is behind the ego: start from the next one
    if i == 0 or len(cps) - i < 2:
        return cps
    return np.vstack([here, cps[i:]])


class MpcController(CrossingRules):
    """LanguageMPC's low-level controller: one ``Control`` per observation."""

    def __init__(self, config: MpcConfig, vehicle: VehicleParams = DEFAULT_VEHICLE, *,
                 solver: Optional[MpcSolver] = None, realtime: Optional[bool] = None) -> None:
        """``realtime``: enforce the solver's wall-time budget (None: the config's
        ``enforce_time_budget``). Set it before the first solve: IPOPT's wall-time
        option is compiled in."""
        self.config = config
        self.vehicle = vehicle
        self.solver = solver if solver is not None else MpcSolver(config, vehicle)
        if realtime is not None:
            self.solver.enforce_time_budget = bool(realtime)
        self._decisions: list[Decision] = []
        self._seq = 0
        self._u_prev: Optional[tuple[float, float]] = None
        self._u_prev2: Optional[tuple[float, float]] = None
        self._plan: Optional[np.ndarray] = None
        self._plan_pred: Optional[np.ndarray] = None
        self._plan_age = 0
        self._counts = {"steps": 0, "solver_failures": 0, "fallbacks": 0, "shifted": 0,
                        "brakes": 0, "stale_inputs": 0, "floor_additions": 0,
                        "hedged": 0, "route_overrides": 0, "stale_steps": 0,
                        "stale_agent_steps": 0, "go_refused": 0, "brake_refused": 0,
                        "refused_decisions": 0}
        self._mode = "idle"
        self._solved_decision_id: Optional[str] = None
        self._ego_v_mps = 0.0
        self._now_s = 0.0
        self._committed: dict[str, float] = {}
        """Crossing agents the ego decided to pass ahead of -> sim time of the decision."""
        self._floor_until: dict[str, float] = {}
        """Agent id -> sim time until which the per-step safety floor keeps it attended."""
        self._hedge_until: dict[str, float] = {}
        """Agent id -> sim time until which the MPC's own forecast of it stays beside the
        decision's prediction of it (see ``_problem``; held ``safety_floor_hold_s``)."""
        self._curve: Optional[tuple[str, np.ndarray, Optional[RouteLeave]]] = None
        """(decision id, its sampled and continued reference curve, where its candidate
        leaves the route or None), see ``_decision_curve``."""
        self.route_override_note: Optional[str] = None
        """Set (one line) when a decision's candidate left the route and the MPC took the
        route reference instead; the node logs it and clears it."""
        self._agent_curves: dict[str, tuple[float, Optional[str], _Points]] = {}
        """Agent id -> (sim time built, lane id then, control points) of the baseline
        prediction curve (see ``_CANDIDATE_REUSE_S``)."""
        self._rebuilds_left = _REBUILDS_PER_STEP
        self._lane_change_refused: dict[str, tuple[str, ...]] = {}
        """Decision id -> agents its lane change was refused for (``_lane_change_kept``)."""
        self._zone_tail: dict[str, np.ndarray] = {}
        """Obstacle id -> its forecast beyond the horizon (``_zone_forecast``), this step."""
        self._timing: tuple = (None, 0.0, None)
        """(this step's path geometry, its speed cap, the timing profile ``_time_along``
        built)."""
        self._route_s: Optional[tuple[int, float, float]] = None
        """(id of the map, sim time, arc length) of the ego's last route progress: the
        baseline reference starts there or later (monotone, see ``route_progress``)."""
        self.reference_path: Optional[np.ndarray] = None
        """(M, 2) the reference path of the last step (for the visual mirror)."""
        self.reference_states: Optional[np.ndarray] = None
        """(N+1, 4) the time-parameterised reference of the last step."""
        self.predicted: Optional[np.ndarray] = None
        """(N+1, 4) the predicted ego states of the last step (x, y, yaw, v)."""
        self.agent_predictions: dict[str, np.ndarray] = {}
        """Attended agent id -> (N+1, 2) forecast the last problem used (visual mirror)."""
        self.reference_id: Optional[int] = None
        """The decision's candidate id of the last step (None: baseline route reference)."""
        self.stale = StaleVerdict()
        """What the stale-decision check found on the last step (``lmpc_mpc.stale``)."""
        self.stale_log: dict[str, StaleRecord] = {}
        """Decision id -> what the stale check did while it was in force (first / last
        sim time, steps, agents, go refused steps): for the decision log."""
        self._yielded: list[str] = []
        """Agents the crossing rule of the last ``_lead_limits`` call yielded to."""
        self._last_yield: tuple[float, frozenset[str]] = (-math.inf, frozenset())
        """(sim time, agents) the crossing rule yielded to on its last step with obstacles."""
        self._leaders: list[tuple[str, float]] = []
        """Agents followed as leaders on the last step, with the reference's limit behind
        them (the least over the horizon, m along the path)."""
        self._followers: list[str] = []
        """Agents on the last step coming onto the ego's path from behind, going its way
        (``_lead_limits``): a stop would be run into."""
        self._beside: set[int] = set()
        """Indices of this step's obstacles that stay beside the path (``_lead_limits``)."""

    # -- decisions -----------------------------------------------------------------------
    def on_decision(self, decision: Decision) -> Optional[str]:
        """Store a decision; it takes effect per the timing rule (see module doc).

        Returns why it was refused (one line naming both decision spaces, counted as
        ``refused_decisions``), or None when it was stored (or already known): a decision
        made in another decision space (``space_hash``) or with an interval index this
        space does not have never steers; the MPC keeps its baseline behaviour."""
        space = self.config.decision_space
        refusal = space_mismatch(space, decision.space_hash)
        if refusal is None and not (
                decision.accel_interval < len(space.accel_intervals_mps2)
                and decision.steer_interval < len(space.steer_intervals_rad)):
            refusal = (f"decision {decision.decision_id}: interval index out of range "
                       f"(accel {decision.accel_interval} of "
                       f"{len(space.accel_intervals_mps2)}, steer {decision.steer_interval} "
                       f"of {len(space.steer_intervals_rad)}) in {space.describe()}")
        if refusal is not None:
            self._counts["refused_decisions"] += 1
            return refusal
        if any(d.decision_id == decision.decision_id for d in self._decisions):
            return None
        self._decisions.append(decision)
        self._decisions.sort(key=lambda d: (d.stamp_s, d.seq))
        del self._decisions[:-_DECISION_MEMORY]
        return None

    def effective_from_s(self, decision: Decision) -> float:
        """Sim time from which ``decision`` may steer (the one timing rule)."""
        return decision.stamp_s + max(decision.latency_s, self.config.dt_s)

    def active_decision(self, t_s: float) -> Optional[Decision]:
        """The newest decision in force at sim time ``t_s``, or None (baseline)."""
        for d in reversed(self._decisions):
            if self.effective_from_s(d) - _TIME_EPS_S <= t_s < d.stamp_s + d.ttl_s:
                return d
        return None

    def stats(self) -> ControllerStats:
        """Counters so far and the mode of the last control."""
        return ControllerStats(mode=self._mode, over_budget=self.solver.over_budget,
                               **self._counts)

    def reset(self) -> None:
        """Forget decisions, plan and warm start (new episode)."""
        self._decisions.clear()
        self._u_prev = self._u_prev2 = None
        self._plan = self._plan_pred = None
        self._plan_age = 0
        self._committed.clear()
        self._last_yield = (-math.inf, frozenset())
        self._lane_change_refused.clear()
        self._floor_until.clear()
        self._hedge_until.clear()
        self._curve = None
        self.route_override_note = None
        self._agent_curves.clear()
        self._route_s = None
        self._solved_decision_id = None
        self.stale = StaleVerdict()
        self.stale_log.clear()
        self.solver.reset()

    # -- branching -----------------------------------------------------------------------
    _SHARED = ("config", "vehicle", "solver")

    def snapshot(self) -> "ControllerSnapshot":
        """Everything the next controls depend on: decisions, plan, warm start, the
        crossing commitments, safety-floor / hedge holds, cached curves, counters. The
        compiled solver and the configs are shared, not copied. ``restore`` of it makes the
        controller continue exactly as it would have from here (episode branching)."""
        own = {k: v for k, v in self.__dict__.items() if k not in self._SHARED}
        return ControllerSnapshot(copy.deepcopy(own), self.solver.warm_state())

    def restore(self, snap: "ControllerSnapshot") -> None:
        """Go back to a ``snapshot`` of this controller (the snapshot stays reusable)."""
        self.__dict__.update(copy.deepcopy(snap.state))
        self.solver.set_warm_state(snap.solver)

    # -- control -------------------------------------------------------------------------
    def compute(self, obs: Observation, *, now_s: Optional[float] = None) -> Control:
        """The control for ``obs`` (stamped like its ego state). Never NaN.

        ``now_s``: the current sim time (``/clock``) if known; an ego state older than
        ``stale_after_s`` relative to it brakes, as do agents older than the ego state.
        """
        self._counts["steps"] += 1
        self.stale = StaleVerdict()
        ego = obs.ego
        t = ego.stamp_s
        stale = None
        if now_s is not None and now_s - t > self.config.stale_after_s:
            stale = f"stale ego state ({now_s - t:.2f} s old)"
        elif t - obs.agents.stamp_s > self.config.stale_after_s:
            stale = f"stale agents ({t - obs.agents.stamp_s:.2f} s older than ego state)"
        if stale is not None:
            self._counts["stale_inputs"] += 1
            return self._brake(obs, stale, decision_id=None)
        decision = self.active_decision(t)
        try:
            problem, attended, ref_id = self._problem(obs, decision)
        except (ReferencePathError, ValueError) as exc:
            self._counts["fallbacks"] += 1
            return self._brake(obs, f"no reference: {exc}"[:200], decision_id=None)
        dec_id = decision.decision_id if decision is not None else None
        if dec_id != self._solved_decision_id:
            self.solver.reconverge()  # new weights / bias / attention: a jump, not a drift
            self._solved_decision_id = dec_id
        result = self.solver.solve(problem)
        mode: ControlMode = "decision" if decision is not None else "baseline"
        if result.success:
            u = result.u0
            if all(math.isfinite(v) for v in u):
                self._plan = result.controls
                self._plan_pred = result.predicted
                self._plan_age = 0
                self.predicted = result.predicted
                return self._emit(obs, u, mode, result.status, result.solve_time_s, dec_id,
                                  ref_id, attended, result.predicted)
        self._counts["solver_failures"] += 1
        self._counts["fallbacks"] += 1
        self._plan_age += 1
        shift_limit = min(self.config.shifted_plan_steps,
                          len(self._plan) - 1 if self._plan is not None else 0)
        if self._plan is not None and self._plan_age <= shift_limit:
            self._counts["shifted"] += 1
            u_s = self._plan[self._plan_age]
            pred = self._plan_pred[self._plan_age:] if self._plan_pred is not None else None
            self.predicted = pred
            a_s = float(u_s[0])
            if self.stale.go_refused_for and a_s > 0.0:
                # the crossing rule has just refused the decision's go: the old plan's
                # steer is kept, its acceleration is not (usi training 10095 accelerated
                # into the junction on a shifted go plan for three failed solves and
                # stopped with its nose in the oncoming lane; braking with the steer eased
                # to 0 left si 10076 +29 and usi 10032 in a worse place)
                a_s = 0.0
            return self._emit(obs, (a_s, float(u_s[1])), "shifted",
                              f"shifted plan ({result.status})"[:200], result.solve_time_s,
                              dec_id, ref_id, attended, pred)
        return self._brake(obs, f"brake ({result.status})"[:200], decision_id=dec_id,
                           solve_time_s=result.solve_time_s)

    # -- building the problem ------------------------------------------------------------
    def _problem(self, obs: Observation, decision: Optional[Decision]
                 ) -> tuple[MpcProblem, tuple[str, ...], Optional[int]]:
        cfg, veh = self.config, self.vehicle
        ego = obs.ego
        n = cfg.horizon
        ego_xy = np.array([ego.x_m, ego.y_m])
        ref_id: Optional[int]
        ref_acc = cfg.reference_accel_mps2
        ref_dec: Optional[float] = None
        ref_v_cap = veh.max_speed_mps
        # a candidate that leaves the route where the route goes on is not followed: the
        # route reference instead, with the decision's weights and speed guidance
        leave = self._route_leave(obs, decision) if decision is not None else None
        lane_change_refused: tuple[str, ...] = ()
        sharp = self._sharp_turn(obs)
        if sharp is not None:
            # near / in a junction turn sharper than 110 degrees: the route's own
            # centreline, whatever the decision's curve (see _sharp_turn)
            path = sharp
            ref_id = decision.ego_trajectory.candidate_id \
                if decision is not None and leave is None else None
        elif decision is not None and leave is None:
            pts = self._decision_curve(obs, decision)
            # the curve starts where the ego was when the planner looked: go on from
            # the closest point ahead of the ego now
            i = int(np.argmin(np.hypot(*(pts - ego_xy).T)))
            path = np.vstack([ego_xy, pts[i + 1:]]) if i + 1 < len(pts) else \
                np.vstack([ego_xy, ego_xy + [math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)]])
            ref_id = decision.ego_trajectory.candidate_id
            kept = self._lane_change_kept(obs, decision, path) \
                if cfg.stale_decision_check else None
            if kept is not None:
                # its target lane's gap closed: the own lane instead (crossing.py)
                path, lane_change_refused = kept
                ref_id = None
        else:
            cand = route_candidate(obs.map, ego, lookahead_m=cfg.lookahead_m,
                                   progress_m=self._progress(obs))
            path = cand.sample(200)
            ref_id = None
        if decision is not None:
            weights = cfg.decision_space.weights_for(decision.weights)
            bias = self._decision_bias(decision)
            if leave is not None or lane_change_refused:
                bias = (bias[0], 0.0)  # its steer bias belongs to the manoeuvre not taken
            # the action guidance shapes the reference's speed profile too: a braking
            # bias (below the neutral interval) brakes the reference to a stop at that
            # rate, a speeding-up bias raises its acceleration. Otherwise the tracking
            # term would fight the bias (our reading; the paper leaves it open).
            lo, hi = cfg.decision_space.neutral_accel_band
            if bias[0] < lo:
                ref_v_cap, ref_dec = 0.0, max(-bias[0], 0.5)
            elif bias[0] > hi:
                ref_acc = max(bias[0], ref_acc)
        else:
            weights = cfg.decision_space.weights_for(None)
            bias = (0.0, 0.0)
        if sharp is None or turned_away(path, ego.x_m, ego.y_m, ego.yaw_rad):
            path = lead_in(path, ego.x_m, ego.y_m, ego.yaw_rad)
        v_limit = veh.max_speed_mps
        lane = lane_at(obs.map, x_m=ego.x_m, y_m=ego.y_m, yaw_rad=ego.yaw_rad,
                       lane_id=ego.lane_id)
        if lane is not None:
            v_limit = min(v_limit, lane.speed_limit_mps)
        stop_at = self._stop_distance(obs)
        agents = self._attended(obs, decision)
        obstacles: list[Obstacle] = []
        slots = max(0, cfg.max_agents - (1 if stop_at is not None else 0))
        preds = {p.agent_id: p.trajectory.control_points
                 for p in (decision.agent_predictions if decision is not None else ())}
        self._rebuilds_left = _REBUILDS_PER_STEP
        self._zone_tail = {}
        t = ego.stamp_s
        # close agents with a prediction get the MPC's own forecast too (or still do)
        hedged = {a.id for a in agents[:slots] if a.id in preds and (
            self._close(ego, a) or self._hedge_until.get(a.id, -math.inf) >= t)}
        # oldest curves get the rebuilds of this step
        for ag in sorted(agents[:slots], key=lambda a: self._agent_curves.get(
                a.id, (-math.inf,))[0]):
            if (ag.id not in preds or ag.id in hedged) and ag.v_mps >= 0.05:
                self._baseline_curve(obs, ag)
        speeds: list[float] = []
        ego_in_junction = (obs.ego.lane_id or "").startswith(":")
        for ag in agents[:slots]:
            own = self._agent_curves[ag.id][2] if ag.v_mps >= 0.05 and (
                ag.id not in preds or ag.id in hedged) else None
            cps = preds.get(ag.id, own)
            fc = self._zone_forecast(ag.id, ag, cps, obs)
            obstacles.append(Obstacle(ag.id, fc, ag.length_m, ag.width_m,
                                      yaw_rad=ag.yaw_rad, junction=ego_in_junction or (
                                          ag.lane_id or "").startswith(":")))
            speeds.append(ag.v_mps)
            if ag.id in hedged:
                # a close agent is also kept clear of along the MPC's own forecast: the
                # decision's prediction of it is one hypothesis, not a licence (a weak
                # model's "the stopped car ahead changes lanes" let the ego drive into it)
                mine = self._zone_forecast(ag.id + OWN_SUFFIX, ag, own, obs)
                if float(np.max(np.hypot(*(mine - fc).T))) > _HEDGE_APART_M:
                    # held like the floor: an obstacle flickering in and out of the
                    # problem from step to step made the plan jump (a spider-net junction)
                    self._hedge_until[ag.id] = t + cfg.safety_floor_hold_s
                if self._hedge_until.get(ag.id, -math.inf) >= t:
                    self._counts["hedged"] += 1
                    obstacles.append(Obstacle(ag.id + OWN_SUFFIX, mine, ag.length_m,
                                              ag.width_m))
                    speeds.append(ag.v_mps)
        if len(self._agent_curves) > 4 * max(len(obs.agents.agents), 8):
            seen = {a.id for a in obs.agents.agents}
            self._agent_curves = {k: v for k, v in self._agent_curves.items() if k in seen}
            self._hedge_until = {k: v for k, v in self._hedge_until.items() if k in seen}
        # once a step: the reference's resampling, also the crossing rule's timing
        # (checked first: a bad path is "no reference: <what is wrong>" and a brake)
        geometry = _path_geometry(reference_path_points(path), REFERENCE_DS_M)
        line = geometry[0]
        # the lead limits only ask "is the agent on our path, and where": a polyline
        # through every 3rd point (~1 m apart) is within ~2 cm of the curve and makes
        # the projection of every predicted agent position 3x cheaper
        coarse = _Polyline.of(np.vstack([path[:-1:3], path[-1:]])) if len(path) > 7 else line
        self._ego_v_mps = ego.v_mps
        self._now_s = ego.stamp_s
        reattended: tuple[str, ...] = ()
        check = decision is not None and cfg.stale_decision_check
        if check:
            reattended = self._reattend_stale(obs, coarse, agents[:slots], preds, obstacles,
                                              speeds)
        self._timing = (geometry, v_limit, None)  # physical: not a decision's braking cap
        s_limit = self._lead_limits(coarse, obstacles, speeds)
        if self._beside:
            obstacles = [replace(ob, beside=True) if i in self._beside else ob
                         for i, ob in enumerate(obstacles)]
        refused: tuple[str, ...] = ()
        neutral_hi = cfg.decision_space.neutral_accel_band[1]
        held = self._held_by(ego.v_mps, ref_acc) if check and bias[0] > neutral_hi else ()
        if check and bias[0] > neutral_hi and (self._yielded or held):
            # the decision says go, the MPC's own crossing rule (on the current state)
            # yields, or the way ahead is taken (a leader holds the reference back within
            # the horizon): the gap the decision relied on has closed, and a go bias
            # against a held reference made the MPC steer round the car ahead (off the
            # road; usi 5 at 2.5 s). Neutral bias and reference acceleration; reference
            # curve and weights stay the decision's
            refused = tuple(dict.fromkeys(list(self._yielded) + list(held)))
            bias = (0.0, bias[1])
            ref_acc = cfg.reference_accel_mps2
        brake_refused: tuple[str, ...] = ()
        if check and bias[0] < cfg.decision_space.neutral_accel_band[0] and self._followers \
                and lane is not None and lane.roundabout:
            # a braking decision executed on the roundabout (made before the entry, "slow
            # to 5 m/s for the turn", it braked the reference to a stop on the ring) while a
            # car behind closes in on the ego's path: the ego stopped on the ring and was
            # run into (rab 101 at 1.5 s, rab 10034 at 5 s). Its own crossing rule and
            # leaders still brake it where something ahead asks for it
            brake_refused = tuple(dict.fromkeys(self._followers))
            bias = (0.0, bias[1])
            ref_v_cap, ref_dec = veh.max_speed_mps, None
        self._note_stale(decision, StaleVerdict(reattended=reattended, go_refused_for=refused,
                                                lane_change_refused_for=lane_change_refused,
                                                brake_refused_for=brake_refused))
        ref = timed_reference(path, v0_mps=ego.v_mps, v_max_mps=min(v_limit, ref_v_cap),
                              a_max_mps2=ref_acc, a_dec_mps2=ref_dec,
                              a_lat_max_mps2=cfg.reference_lat_accel_mps2, horizon=n,
                              dt_s=cfg.dt_s, stop_at_m=stop_at, s_limit_m=s_limit,
                              geometry=geometry)
        if decision is not None:
            # the ego stands / drives turned far off its path (after a dodge in a
            # junction): the decision's steer guidance was for another pose, and the
            # action term held the steer at it (0.19 rad for a "slight left" where the way
            # back needed ~0.5): the ego came back onto the route in a wide arc, off the
            # road (usi 119 / 106 at 2.5 s, dev). It steers as the path needs instead
            ahead = line.at(min(_REENTRY_AHEAD_M, line.length_m))[0]
            head = math.atan2(ahead[1] - ego.y_m, ahead[0] - ego.x_m)
            if abs(math.remainder(head - ego.yaw_rad, 2.0 * math.pi)) > _REENTRY_RAD:
                kappa = float(np.mean(ref.curvature_1pm[:10]))
                bias = (bias[0], float(np.clip(math.atan(veh.wheelbase_m * kappa),
                                               -veh.max_steer_rad, veh.max_steer_rad)))
        self.reference_path = ref.path
        self.reference_states = ref.states
        self.reference_id = ref_id
        self.agent_predictions = {ob.obstacle_id: ob.xy_m for ob in obstacles}
        if stop_at is not None:
            xy = line.at(stop_at + 0.5 * veh.length_m + _STOP_MARGIN_M)[0]
            obstacles.append(Obstacle("stop_line", np.tile(xy, (n + 1, 1)), 0.1, 3.0,
                                      virtual=True))
        u_prev = self._u_prev if self._u_prev is not None else (ego.a_mps2, ego.steer_rad)
        u_prev2 = self._u_prev2 if self._u_prev2 is not None else u_prev
        problem = MpcProblem(x0=(ego.x_m, ego.y_m, ego.yaw_rad, ego.v_mps), u_prev=u_prev,
                             u_prev2=u_prev2, reference=ref.states,
                             reference_curvature_1pm=ref.curvature_1pm, weights=weights,
                             bias=bias, bias_accel_mps2=self._bias_profile(
                                 bias[0], ref.states[:, 3], min(v_limit, ref_v_cap)),
                             obstacles=tuple(obstacles))
        return problem, tuple(a.id for a in agents[:slots]), ref_id

    def _bias_profile(self, bias_mps2: float, ref_v_mps: np.ndarray,
                      v_max_mps: float) -> Optional[np.ndarray]:
        """Per control step, the acceleration bias: a braking bias while the reference
        (braked at that rate) still moves, then the neutral interval's lower bound (a
        gentle hold that still pulls a creeping car to rest); a speeding-up bias until
        the reference reaches its top speed, then 0. Asking for -5 m/s^2 for all 3 s
        from 3 m/s is infeasible (v >= 0): the quadratic cost then made the MPC spread
        about -1 m/s^2 over the horizon instead of braking as asked."""
        lo, hi = self.config.decision_space.neutral_accel_band
        if lo <= bias_mps2 <= hi:
            return None
        v_next = ref_v_mps[1:]
        if bias_mps2 < lo:
            return np.where(v_next > 1e-3, bias_mps2, min(lo, 0.0))
        return np.where(v_next < v_max_mps - 0.1, bias_mps2, 0.0)

    def _sharp_turn(self, obs: Observation) -> Optional[np.ndarray]:
        """The route's own centreline (``sharp_turn_path``) when the ego's route has a
        junction turn sharper than ``SHARP_TURN_RAD`` within the lookahead ahead of it
        (or the ego is in it) and the ego is within ``_SHARP_ON_ROUTE_M`` of its route;
        else None (always None on a route without such a turn: nothing else changes).

        Why (issue 21, the random and spider nets): such a turn (~120 degrees through a
        ~4.4 m radius) is at the car's kinematic limit (~4.2 m at full steer). The Bezier
        references cut it; a decision's curve, fixed for its 2.5 s and rebased from a pose
        in the turn, curled back (its curvature then braked the reference to a stop, the
        car stood in the junction); and with the path point 6 m ahead more than 60
        degrees off the heading mid-turn, the lead-in replaced the rest of the turn by a
        6 m arc: the car ran wide onto the next road. On the centreline the reference's
        curvature speed cap brakes for the real radius, and the lead-in is only for an
        ego turned away from the path's start (``lead_in.turned_away``). A decision's candidate
        along the route is thereby followed through its lanes; its weights and speed
        guidance stay, and a lane change it asks for waits until past the turn."""
        route = route_path(obs.map)
        if route is None or not route.sharp_turns:
            return None
        s = self._progress(obs)
        look = self.config.lookahead_m
        if not sharp_turn_near(route, s, look) or s is None:
            return None
        on = route.line.at(s)[0]
        if math.hypot(obs.ego.x_m - on[0], obs.ego.y_m - on[1]) > _SHARP_ON_ROUTE_M:
            return None
        return sharp_turn_path(route, obs.ego.x_m, obs.ego.y_m, s, look)

    def _progress(self, obs: Observation) -> Optional[float]:
        """The ego's monotone progress along its route (None: no route in the map)."""
        prev = self._route_s
        previous = None
        if prev is not None and prev[0] == id(obs.map) and prev[1] <= obs.ego.stamp_s:
            previous = prev[2]
        s = route_progress(obs.map, obs.ego, previous_m=previous)
        self._route_s = None if s is None else (id(obs.map), obs.ego.stamp_s, s)
        return s

    def _baseline_curve(self, obs: Observation, ag: Agent) -> _Points:
        """The agent's closest-heading candidate, rebuilt when older than
        ``_CANDIDATE_REUSE_S`` (while this step's rebuilds last; always past twice that)
        or when the agent changed lanes (an approximation: in between, the curve starts
        where the agent was when it was built)."""
        t = obs.ego.stamp_s
        hit = self._agent_curves.get(ag.id)
        if hit is not None and hit[1] == ag.lane_id and 0.0 <= t - hit[0]:
            age = t - hit[0]
            if age < _CANDIDATE_REUSE_S or (self._rebuilds_left <= 0
                                            and age < 2.0 * _CANDIDATE_REUSE_S):
                return hit[2]
        self._rebuilds_left -= 1
        cps = baseline_candidate(obs.map, ag, lookahead_m=self.config.lookahead_m).control_points
        self._agent_curves[ag.id] = (t, ag.lane_id, cps)
        return cps

    def _decision_bias(self, decision: Decision) -> tuple[float, float]:
        """``A_hat``: the midpoints of the decision's intervals (this MPC's decision space,
        the one place indices become numbers), clipped to the vehicle's limits."""
        veh = self.vehicle
        accel, steer = self.config.decision_space.bias_for(decision.accel_interval,
                                                           decision.steer_interval)
        return (float(np.clip(accel, -veh.max_decel_mps2, veh.max_accel_mps2)),
                float(np.clip(steer, -veh.max_steer_rad, veh.max_steer_rad)))

    def _route_leave(self, obs: Observation, decision: Decision) -> Optional[RouteLeave]:
        """Where the decision's candidate leaves the route (``route_guard``), else None;
        checked once per decision, on the curve ``_decision_curve`` builds from it."""
        self._decision_curve(obs, decision)
        return None if self._curve is None else self._curve[2]

    def _decision_curve(self, obs: Observation, decision: Decision) -> np.ndarray:
        """The decision's reference curve, sampled, and continued past its end so that
        it covers the horizon however far the ego drives while the decision is in force:
        along the ego's route where the curve ends on it, else along the lanes (the
        closest-heading candidate from its end pose). Without the continuation the
        reference ran straight on beyond the curve's ~60 m: off the road on a bend once a
        decision had been in force a few seconds at speed (a 2.5 s latency plus a 2.5 s
        cadence is 5 s, 70 m at 14 m/s); closest-heading alone took the straight branch
        of a junction where the route turns (examples/city.yaml). Built once per
        decision, when it takes effect, from the ego's pose then (``rebased_control_points``).
        """
        if self._curve is not None and self._curve[0] == decision.decision_id:
            return self._curve[1]
        pts = bezier_points(rebased_control_points(
            decision.ego_trajectory.control_points, obs.ego.x_m, obs.ego.y_m), 200)
        # the candidate itself (not the continuation below) must stay on the route where
        # the route goes on: a junction choice of the wrong lane turns elsewhere
        leave = leaves_route(obs.map, pts)
        if leave is not None:
            self._counts["route_overrides"] += 1
            self.route_override_note = (
                f"decision {decision.decision_id}: candidate "
                f"{decision.ego_trajectory.candidate_id} leaves the route "
                f"{leave.along_m:.0f} m ahead ({leave.dist_m:.1f} m off it at "
                f"({leave.x_m:.1f}, {leave.y_m:.1f})): following the route instead")
        d = pts[-1] - pts[-2]
        yaw = math.atan2(d[1], d[0])
        ex, ey = float(pts[-1, 0]), float(pts[-1, 1])
        look = self.config.lookahead_m
        route = route_path(obs.map)
        more: Optional[np.ndarray] = None
        if route is not None:
            s, off, heading = route.line.project(ex, ey)
            if off < _ON_ROUTE_M and abs(math.remainder(heading - yaw, 2.0 * math.pi)) \
                    < _ON_ROUTE_RAD and s < route.line.length_m:
                more = route.line.at(np.linspace(s, s + look, 121))
        if more is None:
            cands = candidates_for_pose(obs.map, x_m=ex, y_m=ey, yaw_rad=yaw, lane_id=None,
                                        lookahead_m=look)
            more = closest_heading(cands, yaw).sample(200)
        pts = np.vstack([pts, more[1:]])
        self._curve = (decision.decision_id, pts, leave)
        return pts

    def _attended(self, obs: Observation, decision: Optional[Decision]) -> list[Agent]:
        ego = obs.ego
        seen = {a.id: a for a in obs.agents.agents}
        if decision is not None:
            # ids the decision names but no longer observed are ignored; the safety floor
            # adds whoever is close now, whatever the decision (made up to a TTL ago on
            # an older observation) says: a weak planner can make the car slow, never blind
            named = set(decision.attention)
            chosen = [seen[i] for i in decision.attention if i in seen]
            cfg = self.config
            for a in seen.values():
                if a.id not in named and self._close(ego, a):
                    self._floor_until[a.id] = ego.stamp_s + cfg.safety_floor_hold_s
            floor = [a for a in seen.values() if a.id not in named
                     and self._floor_until.get(a.id, -math.inf) >= ego.stamp_s]
            self._counts["floor_additions"] += len(floor)
            chosen += floor
            if len(self._floor_until) > 4 * max(len(seen), 8):
                self._floor_until = {k: v for k, v in self._floor_until.items() if k in seen}
        else:
            chosen = [a for a in seen.values()
                      if math.hypot(a.x_m - ego.x_m, a.y_m - ego.y_m)
                      <= self.config.sensing_range_m]
        chosen.sort(key=lambda a: math.hypot(a.x_m - ego.x_m, a.y_m - ego.y_m))
        return chosen

    def _close(self, ego: EgoState, agent: Agent) -> bool:
        """The safety floor's test now (``lmpc_mpc.closeness.must_attend``): such an agent
        can reach the ego's plan within the horizon, so the MPC keeps clear of its own
        forecast of it as well as of the decision's prediction (``_problem``)."""
        cfg = self.config
        return must_attend(closeness(ego, agent), ego_v_mps=ego.v_mps, agent_v_mps=agent.v_mps,
                           ttc_s=cfg.safety_floor_ttc_s, dist_m=cfg.safety_floor_dist_m,
                           reach_s=cfg.safety_floor_reach_s)

    def _stop_distance(self, obs: Observation) -> Optional[float]:
        """Arc length along the reference where the box centre must stop (red light)."""
        return stop_distance_m(obs, length_m=self.vehicle.length_m)

    # -- output --------------------------------------------------------------------------
    def _brake(self, obs: Observation, status: str, *, decision_id: Optional[str],
               solve_time_s: float = 0.0) -> Control:
        self._counts["brakes"] += 1
        self._plan = None
        self._plan_pred = None
        self.predicted = None
        return self._emit(obs, (-self.vehicle.safe_brake_mps2, self._straighten(obs)), "brake",
                          status, solve_time_s, decision_id, None, (), None)

    def _straighten(self, obs: Observation) -> float:
        """The brake's steer: towards 0 from the ego's current steer, no faster than the
        steer-rate limit allows in one step (the bridge's guard would clamp a jump to 0 to
        exactly this value and flag the control as clamped)."""
        delta = self.vehicle.max_steer_rate_radps * self.config.dt_s
        steer = obs.ego.steer_rad
        return min(max(0.0, steer - delta), steer + delta)

    def _emit(self, obs: Observation, u: tuple[float, float], mode: ControlMode, status: str,
              solve_time_s: float, decision_id: Optional[str], ref_id: Optional[int],
              attended: tuple[str, ...], predicted: Optional[np.ndarray]) -> Control:
        veh = self.vehicle
        a, d = u
        if not (math.isfinite(a) and math.isfinite(d)):
            a, d, mode, status = (-veh.safe_brake_mps2, self._straighten(obs), "brake",
                                  "non-finite control")
        a = float(np.clip(a, -veh.max_decel_mps2, veh.max_accel_mps2))
        d = float(np.clip(d, -veh.max_steer_rad, veh.max_steer_rad))
        self._u_prev2 = self._u_prev if self._u_prev is not None else (a, d)
        self._u_prev = (a, d)
        self._mode = mode
        pts: tuple[PosePoint, ...] = ()
        if predicted is not None and np.all(np.isfinite(predicted)):
            # plain floats (tolist): the same values as per-element numpy scalars, a
            # fraction of the time (this runs every control step)
            two_pi = 2 * math.pi
            pts = tuple(PosePoint(x_m=r[0], y_m=r[1], yaw_rad=math.remainder(r[2], two_pi),
                                  v_mps=min(max(r[3], -5.0), 70.0))
                        for r in predicted[:200, :4].tolist())
        solve_ms = float(min(max(solve_time_s * 1e3, 0.0), 1e6))
        ctl = Control(stamp_s=obs.ego.stamp_s, seq=self._seq, accel_mps2=a, steer_rad=d,
                      mode=mode, solver_status=status[:200], solve_time_ms=solve_ms,
                      decision_id=decision_id, reference_id=ref_id, attended=attended,
                      predicted=pts, stale=self.stale.labels())
        self._seq += 1
        return ctl
