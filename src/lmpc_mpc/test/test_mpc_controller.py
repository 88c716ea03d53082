"""Solver and controller on synthetic observations (closed loop with the same bicycle)."""
import math
from typing import Callable, Sequence

import numpy as np
import pytest

from lmpc_msgs_py.messages import Agent, BezierTrajectory, Decision, WeightLevels
from lmpc_mpc import synthetic as S
from lmpc_mpc.closeness import closeness
from lmpc_mpc.config import load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.solver import MpcSolver

CFG = load_mpc_config()


@pytest.fixture(scope="module")
def solver() -> MpcSolver:
    return MpcSolver(CFG)


def _run(ctrl: MpcController, m, x0, steps: int,
         agents: Callable[[float], Sequence[Agent]] = lambda t: ()):
    log = S.closed_loop(ctrl, m, x0, steps, agents)
    for _, _, ctl in log:
        assert math.isfinite(ctl.accel_mps2) and math.isfinite(ctl.steer_rad)
    return log


def _ctrl(solver: MpcSolver) -> MpcController:
    solver.reset()
    return MpcController(CFG, solver=solver)


def test_solution_respects_bounds(solver: MpcSolver) -> None:
    log = _run(_ctrl(solver), S.four_way_junction(), (1.6, -40.0, math.pi / 2, 6.0), 60)
    veh = _ctrl(solver).vehicle
    steers = [c.steer_rad for _, _, c in log]
    for _, x, c in log:
        assert -veh.max_decel_mps2 - 1e-6 <= c.accel_mps2 <= veh.max_accel_mps2 + 1e-6
        assert abs(c.steer_rad) <= veh.max_steer_rad + 1e-6
        assert 0.0 <= x[3] <= veh.max_speed_mps + 1e-6
        assert c.mode == "baseline"
    rate = np.abs(np.diff(steers)) / CFG.dt_s
    assert rate.max() <= veh.max_steer_rate_radps + 1e-3
    assert max(abs(s) for s in steers) > 0.1  # it did turn


def test_straight_road_reaches_speed_limit_smoothly(solver: MpcSolver) -> None:
    m = S.straight_road(speed_mps=12.0)
    log = _run(_ctrl(solver), m, (10.0, -4.8, 0.0, 0.0), 110)
    v = np.array([x[3] for _, x, _ in log])
    acc = np.array([c.accel_mps2 for _, _, c in log])
    assert v[-1] == pytest.approx(12.0, abs=0.4)
    assert v.max() < 12.5
    assert np.abs(np.diff(acc)).max() < 1.0  # no bang-bang
    assert all(abs(x[1] + 4.8) < 0.2 for _, x, _ in log)


def test_stopped_car_ahead_ego_stops_behind_with_gap(solver: MpcSolver) -> None:
    m = S.straight_road()
    car = S.agent("car1", x_m=80.0, y_m=-4.8, yaw_rad=0.0, lane_id="E0_0")
    log = _run(_ctrl(solver), m, (10.0, -4.8, 0.0, 10.0), 120, lambda t: [car])
    x_end = log[-1][1]
    gap = 80.0 - x_end[0] - 4.5  # box to box
    assert x_end[3] < 0.3
    assert 0.8 < gap < 6.0
    assert all(abs(x[1] + 4.8) < 0.5 for _, x, _ in log)  # braked, did not swerve


def test_oncoming_crossing_car_ego_waits(solver: MpcSolver) -> None:
    m = S.four_way_junction()

    def oncoming(t: float) -> list[Agent]:
        y = 40.0 - 10.0 * t
        return [S.agent("on", x_m=-1.6, y_m=y, yaw_rad=-math.pi / 2, v_mps=10.0,
                        lane_id="N_in_0" if y > 8.0 else ":J_3_0")]

    # 90 steps: since the stop counts from the physical zone (``_BRAKE_INTO_GAP``) the
    # ego no longer commits while creeping at the zone's edge with the car still in the
    # junction (it did at 4.0 s, car at y = 0); it goes ~0.8 s later
    log = _run(_ctrl(solver), m, (1.6, -25.0, math.pi / 2, 3.0), 90, oncoming)
    gaps = [math.hypot(x[0] - a.x_m, x[1] - a.y_m)
            for (t, x, _) in log for a in oncoming(t + CFG.dt_s)]
    assert min(gaps) > 2.5  # boxes never touch (it passes in its own lane)
    # until the car has passed the conflict point (its lane at y ~ -0.8), the ego
    # stays out of the oncoming lane (x > 0)
    for t, x, _ in log:
        if -2.0 <= 40.0 - 10.0 * t <= 8.0:
            assert x[0] > 0.0
    # it yields once, in time: no commit-then-emergency-brake flip-flop (before the hard
    # yield of issue 23 it braked at -5.4, went on at +2.1, then braked at -6 m/s^2)
    assert min(c.accel_mps2 for _, _, c in log) > -4.5
    assert log[-1][1][0] < -1.5 and log[-1][1][2] > 2.0  # and then it turns left


def _decision(ego_xy, *, stamp_s: float, latency_s: float = 0.0, ttl_s: float = 5.0,
              accel_idx: int = 0, levels: WeightLevels = WeightLevels(action="high")
              ) -> Decision:
    cps = tuple((ego_xy[0] + d, ego_xy[1]) for d in (0.0, 20.0, 40.0, 60.0))
    return Decision(stamp_s=stamp_s, seq=1, decision_id=f"d{stamp_s}", source="mock",
                    latency_s=latency_s, ttl_s=ttl_s,
                    ego_trajectory=BezierTrajectory(candidate_id=0, control_points=cps),
                    accel_interval=accel_idx,
                    steer_interval=CFG.decision_space.neutral_steer_index,
                    weights=levels, space_hash=CFG.decision_space.space_hash)


def test_braking_decision_stops_and_holds_then_expires(solver: MpcSolver) -> None:
    m = S.straight_road()
    ctrl = _ctrl(solver)
    ctrl.on_decision(_decision((10.0, -4.8), stamp_s=0.0, latency_s=0.5, ttl_s=6.0))
    log = _run(ctrl, m, (10.0, -4.8, 0.0, 10.0), 90)
    modes = [c.mode for _, _, c in log]
    assert modes[:5] == ["baseline"] * 5  # not before t0 + latency
    assert modes[5] == "decision" and log[5][2].decision_id == "d0.0"
    v = {round(t, 1): x[3] for t, x, _ in log}
    pos = {round(t, 1): x[0] for t, x, _ in log}
    assert v[3.0] < 5.0 and v[5.9] < 0.6  # braking hard, then (nearly) standing
    assert pos[5.9] - pos[4.5] < 1.5  # holding, not creeping on
    assert modes[-1] == "baseline"  # expired at t0 + ttl


def test_stale_agents_brake(solver: MpcSolver) -> None:
    ctrl = _ctrl(solver)
    m = S.straight_road()
    ego = S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=8.0, stamp_s=5.0, seq=50)
    ctl = ctrl.compute(S.observation(m, ego, agents_stamp_s=4.0))
    assert ctl.mode == "brake" and "stale" in ctl.solver_status
    assert ctl.accel_mps2 == pytest.approx(-ctrl.vehicle.safe_brake_mps2)
    ctl = ctrl.compute(S.observation(m, ego), now_s=6.0)
    assert ctl.mode == "brake"

    # a stale input while steering: the brake straightens the wheel no faster than the
    # steer-rate limit (a jump to 0 was clamped and flagged by the bridge's guard)
    veh = ctrl.vehicle
    rate = veh.max_steer_rate_radps * CFG.dt_s
    for steer, expected in ((0.5, 0.5 - rate), (-0.5, -0.5 + rate), (rate / 2, 0.0)):
        turning = ego.model_copy(update={"steer_rad": steer})
        ctl = ctrl.compute(S.observation(m, turning), now_s=6.0)
        assert ctl.mode == "brake" and ctl.steer_rad == pytest.approx(expected)
        assert abs(ctl.steer_rad - steer) <= rate + 1e-12


def test_tiny_time_budget_fails_safely() -> None:
    cfg = CFG.model_copy(update={"time_budget_s": 1e-6, "enforce_time_budget": True})
    ctrl = MpcController(cfg)
    m = S.straight_road()
    modes = []
    for k in range(6):
        ego = S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=5.0, stamp_s=k * 0.1, seq=k)
        obs = S.observation(m, ego)
        ctl = ctrl.compute(obs)
        modes.append(ctl.mode)
        assert math.isfinite(ctl.accel_mps2) and ctl.accel_mps2 < 0.0
    assert set(modes) == {"brake"}
    assert ctrl.stats().solver_failures == 6
    problem, _, _ = ctrl._problem(obs, None)
    res = ctrl.solver.solve(problem)
    assert not res.success and "budget" in res.status and np.all(np.isfinite(res.predicted))


def test_time_budget_only_counted_when_not_realtime() -> None:
    """Sync / benchmark runs: a slow solve is counted, not failed (results must not
    depend on wall time)."""
    cfg = CFG.model_copy(update={"time_budget_s": 1e-6})
    ctrl = MpcController(cfg, realtime=False)
    m = S.straight_road()
    for k in range(3):
        ego = S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=5.0, stamp_s=k * 0.1, seq=k)
        ctl = ctrl.compute(S.observation(m, ego))
        assert ctl.mode == "baseline"
    st = ctrl.stats()
    assert st.solver_failures == 0 and st.over_budget == 3


def test_braking_bias_is_followed_at_its_rate(solver: MpcSolver) -> None:
    """The strongest braking interval from 3 m/s: the MPC brakes at about its midpoint
    (it used to spread ~1 m/s^2 over the horizon: v >= 0 made the constant bias
    infeasible and the quadratic cost preferred the spread)."""
    m = S.straight_road()
    ctrl = _ctrl(solver)
    ctrl.on_decision(_decision((10.0, -4.8), stamp_s=0.0, latency_s=0.0,
                               levels=WeightLevels(action="high")))
    ego = S.ego_state(x_m=10.0, y_m=-4.8, yaw_rad=0.0, v_mps=3.0, stamp_s=0.1, seq=1)
    ctl = ctrl.compute(S.observation(m, ego))
    want = CFG.decision_space.bias_for(0, CFG.decision_space.neutral_steer_index)[0]
    assert ctl.mode == "decision"
    assert ctl.accel_mps2 < 0.8 * want  # at least 80 % of the asked deceleration


def test_route_reference_off_path_points_along_the_route(solver: MpcSolver) -> None:
    """Stopped beside its path inside the junction, with SUMO naming another internal
    lane: the baseline reference still runs forward along the left turn."""
    m = S.four_way_junction(ego_turn="l")
    ctrl = _ctrl(solver)
    # on the left-turn arc (centre (-8, -8), r 9.6), 1.2 m outside it, heading along it
    ang = math.radians(30.0)
    r = 9.6 + 1.2
    x, y = -8.0 + r * math.cos(ang), -8.0 + r * math.sin(ang)
    ego = S.ego_state(x_m=x, y_m=y, yaw_rad=ang + math.pi / 2, v_mps=0.0,
                      lane_id=":J_0_0", route_index=1)
    ctrl.compute(S.observation(m, ego))
    path = ctrl.reference_path
    d = path[min(len(path) - 1, 20)] - path[0]
    heading = math.atan2(d[1], d[0])
    assert abs(math.remainder(heading - (ang + math.pi / 2), 2 * math.pi)) < math.radians(45)
    assert path[-1][0] < -20.0  # it ends out on W_out_0, not back on S_in_0


def test_facing_away_from_the_path_gets_a_lead_in() -> None:
    from lmpc_mpc.lead_in import lead_in as _lead_in
    path = np.column_stack([np.zeros(50), np.linspace(0.0, 49.0, 50)])  # north
    out = _lead_in(path, 0.0, 0.0, -math.pi / 2)  # ego faces south
    d = out[2] - out[0]
    # it starts along the ego's heading, then bends round towards the path
    assert d[1] < 0.0 and abs(d[0]) < abs(d[1])
    assert out[-1][1] == pytest.approx(49.0)
    same = _lead_in(path, 0.0, 0.0, math.pi / 2)  # already along it: unchanged
    assert same is path


class _CountingSolver(MpcSolver):
    """The real solver, counting the controller's "the problem jumped" signals."""

    reconverged_at: list[int]

    def reconverge(self) -> None:
        self.reconverged_at.append(self.solves)
        super().reconverge()

    def solve(self, problem):  # type: ignore[no-untyped-def]
        self.solves += 1
        return super().solve(problem)


def test_a_decision_taking_effect_or_expiring_makes_the_solver_reconverge() -> None:
    counting = _CountingSolver(CFG)
    counting.reconverged_at, counting.solves = [], 0
    ctrl = MpcController(CFG, solver=counting)
    ctrl.on_decision(_decision((10.0, -4.8), stamp_s=0.0, latency_s=0.5, ttl_s=2.0))
    log = _run(ctrl, S.straight_road(), (10.0, -4.8, 0.0, 10.0), 30)
    modes = [c.mode for _, _, c in log]
    switches = [k for k in range(len(modes)) if k == 0 or modes[k] != modes[k - 1]]
    # first solve (baseline), the decision at 0.5 s, its expiry at 2.0 s: nothing else
    assert switches == [0, 5, 20]
    assert counting.reconverged_at == switches[1:]  # the first solve is a cold start anyway


def test_safety_floor_attends_a_close_agent_the_decision_left_out(solver: MpcSolver) -> None:
    """A decision in force that attends nobody (a weak LLM; or made before the car was
    there) must not blind the MPC: a standing car ahead in the lane is attended once its
    TTC or distance is under the floor, and the ego stops behind it; a car in the other
    lane far ahead, moving away, stays out of the problem (beyond what both drive in the
    floor's 3 s reach). With the floor off, the same run hits the car."""
    m = S.straight_road()
    stopped = S.agent("stopped", x_m=80.0, y_m=-4.8, yaw_rad=0.0, lane_id="E0_0")

    def away(t: float) -> Agent:
        return S.agent("away", x_m=110.0 + 14.0 * t, y_m=-1.6, yaw_rad=0.0, v_mps=14.0,
                       lane_id="E0_1")

    def drive(config) -> tuple[list, MpcController]:
        solver.reset()
        ctrl = MpcController(config, solver=solver)
        keep = _decision((10.0, -4.8), stamp_s=0.0, ttl_s=30.0,
                         accel_idx=CFG.decision_space.neutral_accel_index, levels=WeightLevels())
        ctrl.on_decision(keep.model_copy(update={"ego_trajectory": BezierTrajectory(
            candidate_id=0, control_points=((10.0, -4.8), (100.0, -4.8), (190.0, -4.8)))}))
        return _run(ctrl, m, (10.0, -4.8, 0.0, 10.0), 70, lambda t: [stopped, away(t)]), ctrl

    def min_gap_m(log) -> float:
        return min(closeness(S.ego_state(x_m=float(x[0]), y_m=float(x[1]),
                                         yaw_rad=float(x[2]), v_mps=float(x[3])),
                             stopped).gap_m for _, x, _ in log)

    log, ctrl = drive(CFG)
    # in force from t0 + dt to the end (shifted: a failed solve while braking hard)
    assert all(c.mode in ("decision", "shifted") for _, _, c in log[1:])
    assert "stopped" not in log[1][2].attended  # 70 m away at 10 m/s: TTC 6.5 s
    assert all("away" not in c.attended for _, _, c in log[1:])
    first = next(k for k, (_, _, c) in enumerate(log) if k > 0 and "stopped" in c.attended)
    # once added it stays (held) until the ego is past it
    assert all("stopped" in c.attended for _, x, c in log[first:] if x[0] < 80.0)
    assert ctrl.stats().floor_additions > 0
    assert min_gap_m(log) > 0.5 and log[-1][1][3] < 1.5
    # (the stale-decision check off too: it would re-attend the car on the path)
    blind, ctrl = drive(CFG.model_copy(update={"safety_floor_dist_m": 0.0,
                                               "safety_floor_ttc_s": 0.0,
                                               "safety_floor_reach_s": 0.0,
                                               "stale_decision_check": False}))
    assert all(c.attended == () for _, _, c in blind[1:]) and ctrl.stats().floor_additions == 0
    assert min_gap_m(blind) == 0.0


def test_decision_curve_is_continued_along_the_lane(solver: MpcSolver) -> None:
    """Past the end of a (short) decision curve the reference follows the lane, not the
    ego's heading: the ego, 20 m beyond a 20 m curve and pointing 0.2 rad off the lane,
    gets a reference that stays in its lane over the whole horizon."""
    m = S.straight_road()
    ctrl = _ctrl(solver)
    short = _decision((10.0, -4.8), stamp_s=0.0, ttl_s=10.0,
                      accel_idx=CFG.decision_space.neutral_accel_index, levels=WeightLevels())
    ctrl.on_decision(short.model_copy(update={"ego_trajectory": BezierTrajectory(
        candidate_id=0, control_points=((10.0, -4.8), (20.0, -4.8), (30.0, -4.8)))}))
    ego = S.ego_state(x_m=50.0, y_m=-4.8, yaw_rad=0.2, v_mps=12.0, stamp_s=1.0, seq=10)
    ctl = ctrl.compute(S.observation(m, ego))
    assert ctl.mode == "decision"
    ref = ctrl.reference_states
    assert ref[-1, 0] > 75.0  # it runs on ~30 m beyond the curve's end
    assert np.all(np.abs(ref[5:, 1] + 4.8) < 0.5)  # in the lane, not along yaw 0.2


def test_safety_floor_reach_attends_a_car_keeping_pace_in_the_next_lane(
        solver: MpcSolver) -> None:
    """A car 25 m behind in the next lane at the ego's speed never closes in (no TTC), yet
    it is where a lane change goes: within the floor's reach (12 m + 3 s of both speeds)
    it is attended; with the reach off it is not."""
    m = S.straight_road()
    pacer = S.agent("pacer", x_m=25.0, y_m=-1.6, yaw_rad=0.0, v_mps=10.0, lane_id="E0_1")
    ego = S.ego_state(x_m=50.0, y_m=-4.8, yaw_rad=0.0, v_mps=10.0, stamp_s=1.0, seq=10)
    blind = _decision((50.0, -4.8), stamp_s=0.0, ttl_s=10.0,
                      accel_idx=CFG.decision_space.neutral_accel_index, levels=WeightLevels())
    for reach_s, attended in ((3.0, True), (0.0, False)):
        solver.reset()
        ctrl = MpcController(CFG.model_copy(update={"safety_floor_reach_s": reach_s}),
                             solver=solver)
        ctrl.on_decision(blind)
        ctl = ctrl.compute(S.observation(m, ego, [pacer]))
        assert ctl.mode == "decision" and ("pacer" in ctl.attended) == attended


def test_close_agent_is_kept_clear_of_along_the_mpc_forecast_too(
        solver: MpcSolver, monkeypatch: pytest.MonkeyPatch) -> None:
    """A weak planner attends the slow car ahead (3 m/s) but predicts it to change to
    the left lane (SmolLM2 on eoa). It stays in the ego's lane. The MPC keeps clear of
    both the decision's prediction and its own lane-following forecast of a close agent,
    so the ego slows behind it; taking the prediction at face value (hedge off) runs
    into it."""
    from lmpc_mpc import controller as C
    from lmpc_msgs_py.messages import AgentPrediction

    m = S.straight_road()

    def slow(t: float) -> Agent:
        return S.agent("slow", x_m=50.0 + 3.0 * t, y_m=-4.8, yaw_rad=0.0, v_mps=3.0,
                       lane_id="E0_0")

    leaves = AgentPrediction(agent_id="slow", trajectory=BezierTrajectory(
        candidate_id=1, control_points=((50.0, -4.8), (56.0, -4.8), (58.0, -1.6),
                                        (64.0, -1.6)), label="change to the left lane"))
    keep = _decision((10.0, -4.8), stamp_s=0.0, ttl_s=30.0,
                     accel_idx=CFG.decision_space.neutral_accel_index, levels=WeightLevels())
    keep = keep.model_copy(update={
        "ego_trajectory": BezierTrajectory(candidate_id=0, control_points=(
            (10.0, -4.8), (100.0, -4.8), (190.0, -4.8))),
        "attention": ("slow",), "agent_predictions": (leaves,)})

    def drive(config=CFG) -> tuple[list, MpcController]:
        solver.reset()
        ctrl = MpcController(config, solver=solver)
        ctrl.on_decision(keep)
        return _run(ctrl, m, (10.0, -4.8, 0.0, 12.0), 80, lambda t: [slow(t)]), ctrl

    def min_gap_m(log) -> float:
        return min(closeness(S.ego_state(x_m=float(x[0]), y_m=float(x[1]),
                                         yaw_rad=float(x[2]), v_mps=float(x[3])),
                             slow(t + CFG.dt_s)).gap_m for t, x, _ in log)

    log, ctrl = drive()
    assert all(c.mode in ("decision", "shifted") for _, _, c in log[1:])
    assert ctrl.stats().hedged > 0
    assert "slow#own" in ctrl.agent_predictions
    assert min_gap_m(log) > 1.0
    monkeypatch.setattr(C, "_HEDGE_APART_M", math.inf)
    # (the stale-decision check off too: it would add the own forecast the same way)
    blind, ctrl = drive(CFG.model_copy(update={"stale_decision_check": False}))
    assert ctrl.stats().hedged == 0
    assert min_gap_m(blind) == 0.0


def test_a_go_that_became_unsafe_before_taking_effect_is_refused(solver: MpcSolver) -> None:
    """Issue 23. The planner looked at t = 0 (no one coming) and said "go" (accelerate,
    left turn, attend nobody); with a 2.5 s latency the decision takes effect at 2.5 s.
    Meanwhile a car has appeared in the oncoming lane (at 1 s), reaching the ego's turn
    path within the horizon. The stale check, on the current state with the MPC's own
    forecast, refuses the go while the MPC's crossing rule yields to the car: the bias
    is neutral, ``Control.stale`` and the stats say so, the ego stays out of the
    oncoming lane until the car has passed, then turns. Check off: the go is applied
    as it came (the ego speeds up towards the junction)."""
    from lmpc_mpc.reference import route_candidate

    m = S.four_way_junction()
    start = (1.6, -30.0, math.pi / 2, 0.0)
    turn = route_candidate(m, S.ego_state(x_m=start[0], y_m=start[1], yaw_rad=start[2]),
                           lookahead_m=CFG.lookahead_m)
    go = _decision(start[:2], stamp_s=0.0, latency_s=2.5, ttl_s=30.0,
                   accel_idx=len(CFG.decision_space.accel_intervals_mps2) - 1)
    go = go.model_copy(update={"ego_trajectory": BezierTrajectory(
        candidate_id=turn.candidate_id, control_points=turn.control_points),
        "attention": ()})
    assert CFG.decision_space.bias_for(go.accel_interval, go.steer_interval)[0] > 1.0

    def oncoming(t: float) -> list[Agent]:
        if t < 1.0:
            return []  # not there when the planner looked
        y = 48.0 - 10.0 * (t - 1.0)
        return [S.agent("on", x_m=-1.6, y_m=y, yaw_rad=-math.pi / 2, v_mps=10.0,
                        lane_id="N_in_0" if y > 8.0 else ":J_3_0")]

    def drive(check: bool) -> tuple[list, MpcController]:
        cfg = CFG.model_copy(update={"stale_decision_check": check})
        solver.reset()
        ctrl = MpcController(cfg, solver=solver)
        ctrl.on_decision(go)
        return _run(ctrl, m, start, 110, oncoming), ctrl

    def mean_accel(log, times: set[float]) -> float:
        return float(np.mean([c.accel_mps2 for t, _, c in log if round(t, 1) in times]))

    log, ctrl = drive(True)
    refused = [(t, c) for t, _, c in log if "go" in c.stale]
    assert refused and all(c.decision_id == go.decision_id for _, c in refused)
    assert 2.5 - 1e-9 <= min(t for t, _ in refused) < 3.0  # once in force, not before
    assert all("on" in c.stale for _, c in refused)
    st = ctrl.stats()
    assert st.go_refused == len(refused) and st.stale_steps >= st.go_refused
    assert ctrl.stale_log[go.decision_id].go_refused_steps == st.go_refused
    for t, x, _ in log:  # out of the oncoming lane while the car is near the crossing
        if any(-6.0 < a.y_m < 25.0 for a in oncoming(t + CFG.dt_s)):
            assert x[0] > 0.0
    assert log[-1][1][0] < -3.0  # and it turned once the car had passed
    blind, ctrl = drive(False)
    assert ctrl.stats().stale_steps == 0 and all(not c.stale for _, _, c in blind)
    first = {round(t, 1) for t, _ in refused[:5]}  # the go applied there: harder
    assert mean_accel(blind, first) > mean_accel(log, first) + 0.3


def test_a_go_is_refused_while_a_car_ahead_holds_the_reference(solver: MpcSolver) -> None:
    """Issue 23 (usi 5 at a 2.5 s latency). A "go" decided on an empty road takes effect
    behind a car that has stopped in the ego's lane meanwhile. The reference is held
    behind the car; a go bias against it made the MPC steer round the car (off the road).
    The check refuses the go while the car holds the reference: ``Control.stale`` names
    it, the ego stops behind it in its lane. Check off: the go pushes the ego on harder
    and it leaves its lane to pass."""
    m = S.straight_road()
    start = (10.0, -4.8, 0.0, 8.0)
    go = _decision(start[:2], stamp_s=0.0, latency_s=2.5, ttl_s=30.0,
                   accel_idx=len(CFG.decision_space.accel_intervals_mps2) - 1)
    go = go.model_copy(update={"attention": ()})
    assert CFG.decision_space.bias_for(go.accel_interval, go.steer_interval)[0] > 1.0

    def stopped(t: float) -> list[Agent]:
        # it stopped there after the planner looked
        return [] if t < 1.0 else [S.agent("car", x_m=70.0, y_m=-4.8, yaw_rad=0.0,
                                           lane_id="E0_0")]

    def drive(check: bool) -> tuple[list, MpcController]:
        solver.reset()
        ctrl = MpcController(CFG.model_copy(update={"stale_decision_check": check}),
                             solver=solver)
        ctrl.on_decision(go)
        return _run(ctrl, m, start, 100, stopped), ctrl

    log, ctrl = drive(True)
    refused = [c for t, _, c in log if "go" in c.stale]
    assert refused and all("car" in c.stale for c in refused)
    assert ctrl.stats().go_refused == len(refused)
    end = log[-1][1]
    assert end[3] < 0.5 and 0.5 < 70.0 - end[0] - 4.5 < 8.0  # stopped behind the car
    assert all(abs(x[1] + 4.8) < 0.6 for _, x, _ in log)  # in its lane throughout
    blind, _ = drive(False)
    assert max(abs(x[1] + 4.8) for _, x, _ in blind) > 0.6 and \
        max(c.accel_mps2 for t, _, c in blind if t >= 2.5) > \
        max(c.accel_mps2 for t, _, c in log if t >= 2.5) + 0.3


def test_standing_agent_beside_the_path_gets_no_headway(solver: MpcSolver) -> None:
    """Issue 21: in a tight turn out of a junction, a car standing at the stop line of the
    opposite lane of the road turned into sits nearly dead ahead in the frame of the turn's
    tangent; with the time headway on it the ego stopped in the junction for good. A
    standing agent whose forecast stays laterally clear of the path is flagged ``beside``
    (no headway in the solver); one standing on the path, or a moving one beside it, is
    not."""
    from lmpc_mpc.controller import _Polyline
    from lmpc_mpc.solver import Obstacle

    ctrl = _ctrl(solver)
    ctrl._ego_v_mps, ctrl._now_s = 2.0, 0.0
    # a quarter turn to the left (radius 8 m) from heading east to north, then north
    th = np.linspace(0.0, math.pi / 2, 30)
    path = np.vstack([np.c_[8.0 * np.sin(th), 8.0 - 8.0 * np.cos(th)],
                      np.c_[np.full(20, 8.0), np.linspace(8.5, 40.0, 20)]])
    n = CFG.horizon

    def still(x: float, y: float) -> np.ndarray:
        return np.tile([x, y], (n + 1, 1))

    obstacles = [Obstacle("beside", still(11.2, 14.0), 4.5, 1.8),   # opposite lane, 3.2 m over
                 Obstacle("on", still(8.0, 20.0), 4.5, 1.8),        # standing in the path
                 Obstacle("moving", np.c_[np.full(n + 1, 11.2),
                                          np.linspace(30.0, 10.0, n + 1)], 4.5, 1.8)]
    ctrl._lead_limits(_Polyline.of(path), obstacles, [0.0, 0.0, 7.0])
    assert ctrl._beside == {0}


def test_beside_obstacle_has_no_headway_in_the_safety_zone(solver: MpcSolver) -> None:
    from dataclasses import replace

    from lmpc_mpc.obstacles import Obstacle, obstacle_rows

    n = CFG.horizon
    ob = Obstacle("car", np.tile([20.0, 3.2], (n + 1, 1)), 4.5, 1.8)
    ref = np.c_[np.linspace(0.0, 30.0, n + 1), np.zeros(n + 1), np.zeros(n + 1),
                np.full(n + 1, 10.0)]
    yaw = np.zeros(n + 1)
    for flag, want in ((False, CFG.safety_headway_s), (True, 0.0)):
        prob = _headway_problem(replace(ob, beside=flag), ref)
        rows = obstacle_rows(prob.obstacles, ref, yaw, config=solver.config,
                             vehicle=solver.vehicle)
        assert rows[0, 0, 3] == pytest.approx(want)


def _headway_problem(ob, ref):
    from lmpc_mpc.solver import MpcProblem

    n = CFG.horizon
    return MpcProblem(x0=(0.0, 0.0, 0.0, 10.0), u_prev=(0.0, 0.0), u_prev2=(0.0, 0.0),
                      reference=ref, reference_curvature_1pm=np.zeros(n + 1),
                      weights=CFG.decision_space.weights_for(None), bias=(0.0, 0.0),
                      obstacles=(ob,))


def _oncoming_from(y0_m: float) -> Callable[[float], list[Agent]]:
    """A car southbound at 10 m/s on the oncoming lane (x = -1.6) from y = ``y0_m``."""
    def agents(t: float) -> list[Agent]:
        y = y0_m - 10.0 * t
        lane = "N_in_0" if y > 8.0 else (":J_3_0" if y > -8.0 else "S_out_0")
        return [S.agent("on", x_m=-1.6, y_m=y, yaw_rad=-math.pi / 2, v_mps=10.0,
                        lane_id=lane)]
    return agents


@pytest.mark.parametrize("y0_m", [45.0, 50.0])
def test_left_turn_from_a_stop_waits_for_a_car_beyond_the_horizon(
        solver: MpcSolver, y0_m: float) -> None:
    """The ego stands at the stop line to turn left (~5 s to clear the oncoming lane from
    rest); the oncoming car is 4.5-5 s away, beyond the 3 s horizon. The crossing rule
    looks past the horizon (``_ZONE_TAIL_STEPS``): the ego waits, without hard braking,
    and never stands in the oncoming lane while the car is near (si 24 at latency 0).
    With the look past the horizon off (``_ZONE_TAIL_STEPS`` = 0), it starts, meets the
    car's zone, brakes at -6 m/s^2 and commits in front of it; with the stop counted
    from the zone's margin (``_BRAKE_INTO_GAP`` = 0), an ego held at the zone's edge
    creeps a few cm in, is "unable to stop", commits in front of the car and brakes
    (both cases fail either way)."""
    agents = _oncoming_from(y0_m)
    log = _run(_ctrl(solver), S.four_way_junction(), (1.6, -10.5, math.pi / 2, 0.0), 105,
               agents)
    assert min(c.accel_mps2 for _, _, c in log) > -3.0
    for t, x, _ in log:
        car_y = agents(t + CFG.dt_s)[0].y_m
        if -8.0 <= car_y <= 12.0:  # the car near or in the junction
            assert x[0] > 0.5, (t, x, car_y)  # the ego out of its lane
    assert log[-1][1][0] < -3.0  # and then it turns left


def _first_step(solver: MpcSolver, agents: Sequence[Agent], *, ego_y_m: float,
                v_mps: float) -> tuple[MpcController, float]:
    """One step of a fresh controller: the ego northbound on S_in_0 (left turn ahead)."""
    ctrl = _ctrl(solver)
    ego = S.ego_state(x_m=1.6, y_m=ego_y_m, yaw_rad=math.pi / 2, v_mps=v_mps, stamp_s=0.0,
                      seq=0)
    ctl = ctrl.compute(S.observation(S.four_way_junction(), ego, agents))
    return ctrl, ctl.accel_mps2


def test_time_to_clear_a_turn_counts_the_slowing_for_the_curve(solver: MpcSolver) -> None:
    """12 m/s, 20 m before the stop line of a left turn; an oncoming car at 10 m/s meets
    the turn in ~3 s. At the approach speed the ego would clear its zone in ~2.2 s and
    would commit; slowing for the curve (the reference's lateral-acceleration cap) it
    needs ~4 s, so it yields (usi 117 at a 2.5 s latency, dev seeds: it turned in front
    of the car)."""
    car = S.agent("on", x_m=-1.6, y_m=30.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                  lane_id="N_in_0")
    ctrl, accel = _first_step(solver, [car], ego_y_m=-28.0, v_mps=12.0)
    assert ctrl._time_along(30.0) > 3.0  # at 12 m/s and more, 30 m would take < 2.5 s
    assert "on" in ctrl._yielded and "on" not in ctrl._committed
    assert accel < 0.0


def test_a_follower_closing_in_is_no_crossing_zone(solver: MpcSolver) -> None:
    """The same yield with a faster car close behind the ego in its lane: the follower
    enters the ego's path from behind; taken as a crossing agent, its zone (starting
    behind the ego) moved every other zone's start behind the ego, and the ego
    committed in front of the oncoming car."""
    car = S.agent("on", x_m=-1.6, y_m=30.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                  lane_id="N_in_0")
    follower = S.agent("follower", x_m=1.6, y_m=-38.0, yaw_rad=math.pi / 2, v_mps=15.0,
                       lane_id="S_in_0")
    ctrl, accel = _first_step(solver, [car, follower], ego_y_m=-28.0, v_mps=12.0)
    assert "follower" in ctrl.agent_predictions  # attended: the MPC keeps clear of it
    assert "on" in ctrl._yielded and not ctrl._committed


def test_a_lane_change_into_a_closed_gap_is_refused(solver: MpcSolver) -> None:
    """Issue 23, lane changes executed late. The planner looked at t = 0 (the left lane
    free) and chose the lane change to E0_1; with a 2.5 s latency it takes effect at
    2.5 s. Meanwhile a faster car has come up in the left lane and is beside the ego.
    The stale check refuses the lane change (``Control.stale`` says ``lane_change`` and
    names the car) and the ego keeps its lane, for the rest of the decision; its speed
    guidance still applies. Check off: the ego moves into the left lane, into the car."""
    m = S.straight_road()
    start = (40.0, -4.8, 0.0, 10.0)
    cps = ((40.0, -4.8), (55.0, -4.8), (65.0, -1.6), (100.0, -1.6))
    change = _decision(start[:2], stamp_s=0.0, latency_s=2.5, ttl_s=30.0,
                       accel_idx=CFG.decision_space.neutral_accel_index)
    change = change.model_copy(update={"ego_trajectory": BezierTrajectory(
        candidate_id=1, control_points=cps)})

    def left_lane(t: float) -> list[Agent]:
        # 14 m/s in the left lane, 10 m behind the ego at t = 0: beside it at 2.5 s
        return [S.agent("fast", x_m=30.0 + 14.0 * t, y_m=-1.6, yaw_rad=0.0, v_mps=14.0,
                        lane_id="E0_1")]

    def drive(check: bool) -> tuple[list, MpcController]:
        cfg = CFG.model_copy(update={"stale_decision_check": check})
        solver.reset()
        ctrl = MpcController(cfg, solver=solver)
        ctrl.on_decision(change)
        return _run(ctrl, m, start, 60, left_lane), ctrl

    log, ctrl = drive(True)
    refused = [(t, c) for t, _, c in log if "lane_change" in c.stale]
    assert refused and 2.5 - 1e-9 <= min(t for t, _ in refused) < 2.7
    assert all("fast" in c.stale for _, c in refused)
    assert all(t >= 2.5 - 1e-9 for t, _ in refused)
    assert len(refused) == sum(1 for t, _, _ in log if t >= 2.5 - 1e-9)  # held
    assert ctrl.stale_log[change.decision_id].agents == ["fast"]
    assert all(abs(x[1] + 4.8) < 0.3 for _, x, _ in log)  # it kept its lane
    blind, _ = drive(False)
    # toward the car (the MPC's safety term alone stops it ~1 m short of the lane line)
    assert max(x[1] for _, x, _ in blind) > -4.0


def test_a_lane_change_with_the_gap_open_goes_ahead(solver: MpcSolver) -> None:
    """The same late lane change with the left-lane car 60 m behind at 12 m/s: the gap
    stays open, nothing is refused, the ego changes lanes."""
    cps = ((40.0, -4.8), (55.0, -4.8), (65.0, -1.6), (100.0, -1.6))
    change = _decision((40.0, -4.8), stamp_s=0.0, latency_s=2.5, ttl_s=30.0,
                       accel_idx=CFG.decision_space.neutral_accel_index)
    change = change.model_copy(update={"ego_trajectory": BezierTrajectory(
        candidate_id=1, control_points=cps)})
    ctrl = _ctrl(solver)
    ctrl.on_decision(change)
    log = _run(ctrl, S.straight_road(), (40.0, -4.8, 0.0, 10.0), 60, lambda t: [
        S.agent("far", x_m=-20.0 + 12.0 * t, y_m=-1.6, yaw_rad=0.0, v_mps=12.0,
                lane_id="E0_1")])
    assert not any("lane_change" in c.stale for _, _, c in log)
    assert log[-1][1][1] > -2.2  # in the left lane


def test_turned_off_the_path_steers_as_the_path_needs_not_at_the_bias(
        solver: MpcSolver) -> None:
    """The ego stands in the junction turned 45 deg right of the left turn it must make
    (after a dodge); the decision's steer guidance is "slight left" (0.19 rad, chosen for
    a normal approach). The way onto the turn lies > 30 deg off its heading, so the
    problem's steer bias is the path's own steer (curvature feedforward), not 0.19:
    held at the bias by the action term, the ego came back onto the route in a wide
    arc, off the road (usi 14 at a 2.5 s latency). On its lane, heading along it, the
    bias is the decision's."""
    from lmpc_mpc.reference import route_candidate

    m = S.four_way_junction()
    normal = S.ego_state(x_m=1.6, y_m=-12.0, yaw_rad=math.pi / 2)
    cand = route_candidate(m, normal, lookahead_m=CFG.lookahead_m)
    steer_idx = 3
    assert CFG.decision_space.bias_for(2, steer_idx)[1] == pytest.approx(0.19)
    dec = _decision((1.6, -12.0), stamp_s=0.0, ttl_s=30.0,
                    accel_idx=CFG.decision_space.neutral_accel_index)
    dec = dec.model_copy(update={
        "steer_interval": steer_idx,
        "ego_trajectory": BezierTrajectory(candidate_id=cand.candidate_id,
                                           control_points=cand.control_points)})

    def steer_bias(ego) -> float:
        ctrl = _ctrl(solver)
        ctrl.on_decision(dec)
        problem, _, _ = ctrl._problem(S.observation(m, ego), dec)
        return problem.bias[1]

    assert steer_bias(normal) == pytest.approx(0.19)
    turned = S.ego_state(x_m=2.5, y_m=-6.0, yaw_rad=math.pi / 2 - math.radians(45.0))
    assert steer_bias(turned) > 0.25  # the arc onto the turn (~0.29 rad)
