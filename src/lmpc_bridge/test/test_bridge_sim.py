"""SumoSim against real SUMO (libsumo): observe / step / collisions / junction yielding.

libsumo runs one simulation per process; every test closes its sim (``reset``
closes the previous one as well).
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import libsumo
import pytest

from lmpc_msgs_py.messages import Control

from lmpc_bridge.geometry import OrientedBox, box_gap_m
from lmpc_bridge.sim import EGO_ID, SimError, SumoSim, sumo_angle_from_yaw


class RecordingTraci:
    """Passes everything to libsumo and records ``vehicle.moveToXY`` calls."""

    def __init__(self) -> None:
        self.moves: list[tuple[Any, ...]] = []
        outer = self

        class _Vehicle:
            def __getattr__(self, name: str) -> Any:
                return getattr(libsumo.vehicle, name)

            def moveToXY(self, *args: Any, **kwargs: Any) -> None:  # noqa: N802 (SUMO name)
                outer.moves.append((args, kwargs))
                libsumo.vehicle.moveToXY(*args, **kwargs)

        self.vehicle = _Vehicle()

    def __getattr__(self, name: str) -> Any:
        return getattr(libsumo, name)


def control(obs_stamp: float, accel: float, steer: float = 0.0) -> Control:
    return Control(stamp_s=obs_stamp, seq=int(round(obs_stamp * 10)), accel_mps2=accel,
                   steer_rad=steer, mode="baseline", solver_status="test", solve_time_ms=0.0)


@pytest.fixture
def sim(scene_dir: Path) -> Iterator[SumoSim]:
    s = SumoSim(work_dir=scene_dir)
    yield s
    s.close()


def test_observe_and_step_contract(scene_dir: Path) -> None:
    rec = RecordingTraci()
    sim = SumoSim(work_dir=scene_dir, traci=rec)
    try:
        obs = sim.reset("usi", 1)
        assert (obs.stamp_s, obs.ego.seq, sim.step_index) == (0.0, 0, 0)
        assert obs.ego.lane_id == obs.map.ego_route[0] and obs.ego.route_index == 0
        assert obs.ego.v_mps == pytest.approx(sim.scene.ego_depart_speed_mps)
        assert all(a.id != EGO_ID for a in obs.agents.agents)
        assert obs.agents.agents, "usi seed 1 has traffic within 80 m at t=0"
        assert obs.signals.links == ()  # unsignalized junction
        # the ego centre is half a length behind SUMO's front bumper
        fx, fy = libsumo.vehicle.getPosition(EGO_ID)
        assert math.hypot(fx - obs.ego.x_m, fy - obs.ego.y_m) == pytest.approx(2.25, abs=1e-6)
        # agents: centre = SUMO front - L/2 along the heading
        a = obs.agents.agents[0]
        ax, ay = libsumo.vehicle.getPosition(a.id)
        assert ax - a.x_m == pytest.approx(a.length_m / 2 * math.cos(a.yaw_rad), abs=1e-6)
        assert ay - a.y_m == pytest.approx(a.length_m / 2 * math.sin(a.yaw_rad), abs=1e-6)

        d0 = obs.ego.dist_to_target_m
        for _ in range(10):
            info = sim.step(control(sim.time_s, 1.0))
            obs = sim.observe(required_decision_id="d-1")
        assert info.outcome == "running" and not info.clamped and not info.late
        assert (obs.stamp_s, obs.ego.seq) == (pytest.approx(1.0), 10)
        assert obs.ego.required_decision_id == "d-1"
        assert obs.ego.dist_to_target_m < d0 - 5.0
        # the ego was placed with its front bumper and SUMO's angle, keepRoute=2
        args, kwargs = rec.moves[-1]
        p = sim.pose
        assert args[0] == EGO_ID and kwargs == {"keepRoute": 2}
        assert args[3] == pytest.approx(p.x_m + 2.25 * math.cos(p.yaw_rad))
        assert args[4] == pytest.approx(p.y_m + 2.25 * math.sin(p.yaw_rad))
        assert args[5] == pytest.approx(sumo_angle_from_yaw(p.yaw_rad))
        assert len(rec.moves) == 10
        # SUMO sees the ego where we put it
        fx, fy = libsumo.vehicle.getPosition(EGO_ID)
        assert (fx, fy) == (pytest.approx(args[3], abs=1e-3), pytest.approx(args[4], abs=1e-3))
        # histories grow to at most 2 s
        for _ in range(25):
            sim.step(control(sim.time_s, 0.0))
        hist = sim.observe().agents.agents[0].history
        assert 1 < len(hist) <= 20
        assert [h.t_s for h in hist] == sorted(h.t_s for h in hist)
    finally:
        sim.close()


def test_missing_late_and_nan_controls_brake(sim: SumoSim) -> None:
    sim.reset("usi", 2)
    v0 = sim.pose.v_mps
    info = sim.step(None)
    assert info.late and info.applied_accel_mps2 == -sim.vehicle.safe_brake_mps2
    info = sim.step(control(0.0, 1.0))  # stamp 0.0 at t = 0.1 ... still fresh (<= 0.3 s)
    assert not info.late
    sim.step(control(0.2, 1.0))
    sim.step(control(0.3, 1.0))
    info = sim.step(control(0.0, 1.0))  # now 0.4 s old: late
    assert info.late
    over = sim.step(control(sim.time_s, 14.0, 0.9))
    assert over.clamped and over.applied_accel_mps2 == sim.vehicle.max_accel_mps2
    assert sim.pose.v_mps < v0 + 1.0
    rec = sim.record()
    assert [s.late for s in rec.steps] == [True, False, False, False, True, False]
    assert sim.status().metrics.late_controls == 2
    assert json.loads(rec.model_dump_json())["steps"][0]["late"] is True


def test_collision_with_a_stopped_car_is_detected(sim: SumoSim) -> None:
    obs = sim.reset("usi", 2)
    lane = obs.ego.lane_id
    pos = libsumo.vehicle.getLanePosition(EGO_ID)
    libsumo.vehicle.add("blocker", "r_leader", typeID="bg", depart="now",
                        departLane=lane.rsplit("_", 1)[1], departPos=f"{pos + 50.0:.2f}",
                        departSpeed="0")
    libsumo.vehicle.setSpeed("blocker", 0.0)
    outcome = "running"
    for _ in range(150):
        outcome = sim.step(control(sim.time_s, 0.0)).outcome
        if outcome != "running":
            break
    status = sim.status()
    assert outcome == "collision" and status.outcome == "collision"
    assert status.collided_with == "blocker"
    assert status.metrics.collisions == 1
    with pytest.raises(SimError, match="episode is over"):
        sim.step(control(sim.time_s, 0.0))
    # the collision is geometric: at the step before, the boxes were apart
    steps = sim.record().steps
    before = next(n for n in steps[-2].nearby if n.id == "blocker")
    assert before.gap_m > 0.0 and steps[-1].collided_with == "blocker"


def _drive_into_junction_and_stand(sim: SumoSim, obs: Any) -> None:
    """Follow the route (pure pursuit) to a stop across the oncoming lane; ignore traffic."""
    from conftest import StandInController  # noqa: PLC0415 (test helper)

    ctl = StandInController(cruise_mps=12.0, turn_mps=6.0)
    ctl.must_wait = lambda *_: False  # type: ignore[method-assign]
    stopping = False
    while sim.outcome == "running":
        c = ctl.compute(obs)
        # across the oncoming lane (y > 0.5 inside the junction): brake to a stand
        stopping = stopping or (obs.ego.route_index >= 1 and obs.ego.y_m > 0.3)
        if stopping:
            c = control(obs.stamp_s, -6.0, c.steer_rad)
        sim.step(c)
        obs = sim.observe()
        if stopping and obs.ego.v_mps == 0.0:
            return
    raise AssertionError(f"episode ended before the ego stood in the junction: {sim.outcome}")


def test_oncoming_car_brakes_for_ego_standing_in_junction(sim: SumoSim) -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    obs = sim.reset("usi", 0)
    _drive_into_junction_and_stand(sim, obs)
    t_stand = sim.time_s
    assert sim.observe().ego.lane_id.startswith(":C_")  # on an internal junction lane
    hard_brakers: set[str] = set()
    stopped_near: set[str] = set()
    for _ in range(150):
        info = sim.step(control(sim.time_s, -6.0))
        assert info.outcome == "running", sim.status().detail
        for n in sim.record().steps[-1].nearby:
            if n.id.startswith("onc") and n.a_mps2 < -2.0:
                hard_brakers.add(n.id)
            if n.id.startswith("onc") and n.v_mps < 0.1 and n.gap_m < 10.0:
                stopped_near.add(n.id)
    assert sim.time_s > t_stand + 14.0
    assert hard_brakers, "no oncoming car braked for the ego in the junction"
    assert stopped_near, "no oncoming car came to a stop in front of the ego"
    ego = sim.pose
    ego_box = OrientedBox(ego.x_m, ego.y_m, ego.yaw_rad, 4.5, 1.8)
    for a in sim.observe().agents.agents:
        assert box_gap_m(ego_box, OrientedBox(a.x_m, a.y_m, a.yaw_rad, a.length_m,
                                              a.width_m)) > 0.0
    # the stopped oncoming car is 'yielding' to the ego -> counts for ineff
    last = sim.record().steps[-1]
    assert any(n.affected for n in last.nearby if n.id in stopped_near)


def test_sim_refuses_use_before_reset(scene_dir: Path) -> None:
    sim = SumoSim(work_dir=scene_dir)
    with pytest.raises(SimError, match="reset"):
        sim.step(None)
    with pytest.raises(SimError, match="reset"):
        sim.observe()
