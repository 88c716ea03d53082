"""``MultiSumoSim``: one SUMO episode with N egos ``ego_1 … ego_N`` moved by our own model.

The multi-vehicle counterpart of ``lmpc_bridge.sim.SumoSim`` (issue 18); the single-ego
class is not touched, so single-ego runs behave exactly as before. Per step: each running
ego's control is guard-clamped and integrated (kinematic bicycle, ``lmpc_bridge.dynamics``)
and the ego placed in SUMO (``moveToXY``, front bumper); ONE ``simulationStep()``; then per
ego: its context subscription (what it observes), its route progress, the collision check
with oriented boxes (ego-ego on the bridge's own poses, ego-other on SUMO's; SUMO detects
neither for moved vehicles), its target and the time limit.

Differences from ``SumoSim`` (documented in docs/MULTI.md):
- an ego that reached its target, or collided, is removed from SUMO and its outcome
  frozen (a collision between two egos ends both); the episode goes on until no ego runs;
- **deadlock**: when no running ego has moved (speed < ``DEADLOCK_SPEED_MPS``) for
  ``DEADLOCK_S`` while none has reached its target, the episode ends; the running egos'
  outcome is ``timeout`` with detail ``deadlock`` (their time counts the limit);
- SUMO places an ego on the closest lane of its ROUTE (``moveToXY`` ``keepRoute=1``, not
  2): in the taper before a one-lane section the other direction's lane lies 1.6 m away
  and SUMO put the ego there (its drivers then did not see it; narrow seed 6). The
  bridge's own pose stays exact; no route watch (``off_route``), no ``save_state``;
- the affected vehicles of ``ineff`` follow the same rules as for the single ego
  (``lmpc_bridge.participants``: follower, leader, yielding junction foe; other egos
  included);
- in an ego's observation the other egos carry the bridge's exact poses.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import libsumo
import traci.constants as tc

from lmpc_msgs_py.messages import (
    Agent,
    AgentArray,
    AgentSignals,
    Control,
    EgoState,
    EpisodeStatus,
    HistoryPoint,
    MapSnapshot,
    SignalStates,
)
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge.dynamics import EgoPose, clamp_control, step_bicycle
from lmpc_bridge.geometry import OrientedBox, boxes_overlap
from lmpc_bridge.insertion import InsertionGuard, guard_box
from lmpc_bridge.mapping import RouteGeometry, build_map, read_net
from lmpc_bridge.metrics import compute_metrics
from lmpc_bridge import sumo_rng
from lmpc_bridge.demand import refused_at_start, refused_warnings
from lmpc_bridge.multi_scene import EgoSpec, ego_scene, ego_specs
from lmpc_bridge.record import EpisodeRecord, StepRecord
from lmpc_bridge.scenarios import Scene, SceneError, build_scene
from lmpc_bridge.scenarios.base import check_sumo_path
from lmpc_bridge.shadow import EgoShadow, LaneShape, lane_shapes, shadow_id
from lmpc_bridge.participants import (
    MAX_AGENT_ACCEL_MPS2,
    PERSON_VARS,
    SIG_BRAKE,
    SIG_LEFT,
    SIG_RIGHT,
    VEHICLE_VARS,
    Seen,
    clip,
    convert,
    foes_query_ok,
    nearby_records,
    sumo_angle_from_yaw,
    yaw_from_sumo_angle,
)
from lmpc_bridge.sim import CONTROL_STALE_S, DT_S, SimError

DEADLOCK_S = 10.0
DEADLOCK_SPEED_MPS = 0.1


@dataclass
class EgoRun:
    """One ego of the episode: its task, map, integrated pose and record."""

    spec: EgoSpec
    scene: Scene
    map: MapSnapshot
    route: RouteGeometry
    pose: EgoPose
    seen: dict[str, Seen] = field(default_factory=dict)
    history: dict[str, deque] = field(default_factory=dict)
    lane: Optional[str] = None
    lane_pos_m: float = 0.0
    route_index: int = 0
    dist_to_target_m: float = 0.0
    steps: list[StepRecord] = field(default_factory=list)
    outcome: str = "running"
    detail: str = ""
    collided_with: Optional[str] = None
    reached_at_s: Optional[float] = None
    foes_query: bool = True
    """Ask SUMO for the ego's junction foes (``participants.foes_query_ok``)."""
    shadow: Optional[EgoShadow] = None
    """Its body on a second lane while it stands across two (``lmpc_bridge.shadow``)."""
    lane_shapes: dict[str, LaneShape] = field(default_factory=dict)

    @property
    def ego_id(self) -> str:
        return self.spec.ego_id

    @property
    def running(self) -> bool:
        return self.outcome == "running"


class MultiSumoSim:
    """N egos in one SUMO episode (see the module docstring)."""

    def __init__(self, *, vehicle: VehicleParams = DEFAULT_VEHICLE,
                 sensing_range_m: float = 80.0, history_s: float = 2.0, work_dir: Path,
                 traci: Any = libsumo, sumo_binary: str = "sumo") -> None:
        self._vehicle = vehicle
        self._range_m = float(sensing_range_m)
        self._history_len = max(int(round(history_s / DT_S)), 1)
        self._work_dir = check_sumo_path(Path(work_dir), "the SUMO work directory")
        self._traci = traci
        self._binary = sumo_binary
        self._started = False
        self._scene: Optional[Scene] = None
        self.egos: dict[str, EgoRun] = {}
        self._step_index = 0
        self._max_time_s = 200.0
        self._still_since_s: Optional[float] = 0.0
        self.deadlock = False
        self._guard = InsertionGuard()
        self._refused_at_start: tuple[str, ...] = ()

    # --- lifecycle ----------------------------------------------------------------------
    def reset(self, family: str, seed: int, *, max_time_s: float | None = None
              ) -> dict[str, Observation]:
        """Build the scene, start SUMO, insert every ego; the observations at t = 0."""
        self.close()
        scene = build_scene(family, seed, work_dir=self._work_dir)
        try:
            specs = ego_specs(scene)
        except SceneError as exc:
            raise SimError(str(exc)) from None
        self._scene = scene
        self._max_time_s = scene.max_time_s if max_time_s is None else float(max_time_s)
        self._step_index, self._still_since_s, self.deadlock = 0, 0.0, False
        self._guard = InsertionGuard()
        self.egos = {}
        t = self._traci
        cmd = [self._binary, "-n", str(scene.net_file), "-r", str(scene.route_file),
               "--step-length", f"{DT_S}", "--time-to-teleport", "-1",
               "--collision.action", "none", "--seed", str(seed), "--no-step-log", "true",
               "--no-warnings", "true", "--duration-log.disable", "true"]
        try:
            t.start(cmd)
        except Exception as exc:  # noqa: BLE001 - libsumo raises its own types
            raise SimError(f"SUMO cannot load scene {family}/{seed}: {exc}") from None
        self._started = True
        try:
            return self._insert(scene, specs)
        except BaseException:
            self.close()
            raise

    def _insert(self, scene: Scene, specs: tuple[EgoSpec, ...]) -> dict[str, Observation]:
        t = self._traci
        for spec in specs:
            self._add(spec, spec.depart_speed_mps)
        t.simulationStep()
        missing = [s for s in specs if s.ego_id not in t.vehicle.getIDList()]
        for spec in missing:  # as SumoSim: insert standing when SUMO refuses the speed
            try:  # (SUMO may have dropped it already: "will not be able to depart")
                t.vehicle.remove(spec.ego_id)
            except Exception:  # noqa: BLE001 - libsumo raises its own types
                pass
            self._add(spec, 0.0)
        if missing:
            t.simulationStep()
        # as SumoSim: a vehicle of the scene that SUMO refused at once (an error on stderr)
        self._refused_at_start = refused_at_start(
            scene.route_file, present=t.vehicle.getIDList(),
            pending=t.simulation.getPendingVehicles())
        net = read_net(scene.net_file)
        for spec in specs:
            if spec.ego_id not in t.vehicle.getIDList():
                raise SimError(f"scene {scene.family}/{scene.seed}: SUMO did not insert "
                               f"{spec.ego_id} (blocked)")
            view = ego_scene(scene, spec)
            mp, route = build_map(view, net=net)
            fx, fy = t.vehicle.getPosition(spec.ego_id)
            yaw = yaw_from_sumo_angle(t.vehicle.getAngle(spec.ego_id))
            half = self._vehicle.length_m / 2.0
            pose = EgoPose(x_m=fx - half * math.cos(yaw), y_m=fy - half * math.sin(yaw),
                           yaw_rad=yaw, v_mps=spec.depart_speed_mps)
            self.egos[spec.ego_id] = EgoRun(
                spec=spec, scene=view, map=mp, route=route, pose=pose,
                foes_query=foes_query_ok(net, spec.route_edges),
                shadow=EgoShadow(spec.ego_id),
                lane_shapes=lane_shapes(mp.lanes))
            for domain in (tc.CMD_GET_VEHICLE_VARIABLE, tc.CMD_GET_PERSON_VARIABLE):
                t.vehicle.subscribeContext(spec.ego_id, domain, self._range_m,
                                           list(VEHICLE_VARS if domain ==
                                                tc.CMD_GET_VEHICLE_VARIABLE else PERSON_VARS))
        for ego in self.egos.values():
            self._refresh(ego)
            hit = self._collision(ego)
            if hit is not None:
                raise SimError(f"scene {scene.family}/{scene.seed}: {ego.ego_id}'s start "
                               f"overlaps {hit!r}")
        return {eid: self.observe(eid) for eid in self.egos}

    def _add(self, spec: EgoSpec, speed_mps: float) -> None:
        t = self._traci
        t.vehicle.add(spec.ego_id, spec.route_id, typeID="ego_type", depart="now",
                      departLane=str(spec.depart_lane), departPos=f"{spec.depart_pos_m:.3f}",
                      departSpeed=f"{speed_mps:.3f}")
        t.vehicle.setSpeedMode(spec.ego_id, 0)
        t.vehicle.setLaneChangeMode(spec.ego_id, 0)

    def traffic_warnings(self) -> tuple[str, ...]:
        """A line naming each vehicle the scene starts with that SUMO refused at once
        (``demand.refused_at_start``; the scene runs without it)."""
        return refused_warnings(self._refused_at_start)

    def close(self) -> None:
        """Stop SUMO (``sumo_rng.close_simulation``, as ``SumoSim.close``: a single-ego
        branching run after this one must not start from stale generator counts)."""
        if self._started:
            try:
                sumo_rng.close_simulation(self._traci, self._work_dir)
            finally:
                self._started = False

    # --- properties ---------------------------------------------------------------------
    @property
    def scene(self) -> Scene:
        if self._scene is None:
            raise SimError("no scene: call reset(family, seed) first")
        return self._scene

    @property
    def time_s(self) -> float:
        return round(self._step_index * DT_S, 6)

    @property
    def dt_s(self) -> float:
        return DT_S

    @property
    def running(self) -> bool:
        return any(e.running for e in self.egos.values())

    def running_ids(self) -> tuple[str, ...]:
        return tuple(eid for eid, e in self.egos.items() if e.running)

    @property
    def _shadow_ids(self) -> set[str]:
        return {shadow_id(eid) for eid in self.egos}

    # --- observation --------------------------------------------------------------------
    def _refresh(self, ego: EgoRun) -> None:
        t = self._traci
        results = t.vehicle.getContextSubscriptionResults(ego.ego_id) or {}
        seen: dict[str, Seen] = {}
        for vid, vals in results.items():
            if tc.VAR_POSITION not in vals or vid in self._guard.held \
                    or vid in self._shadow_ids:
                continue  # (held: inserted onto an ego, taken out again; an ego's shadow)
            if vid == ego.ego_id:
                ego.lane = vals.get(tc.VAR_LANE_ID) or None
                ego.lane_pos_m = float(vals.get(tc.VAR_LANEPOSITION, 0.0))
                continue
            s = convert(vid, vals)
            other = self.egos.get(vid)
            if other is not None:  # another ego: the bridge's exact pose
                p = other.pose
                s = Seen(id=vid, kind="car", x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad,
                         v_mps=p.v_mps, a_mps2=clip(p.a_mps2, -MAX_AGENT_ACCEL_MPS2,
                                                    MAX_AGENT_ACCEL_MPS2),
                         length_m=self._vehicle.length_m, width_m=self._vehicle.width_m,
                         lane_id=s.lane_id, lane_pos_m=s.lane_pos_m, signals=s.signals,
                         v_max_mps=s.v_max_mps)
            seen[vid] = s
        ego.seen = seen
        now = self.time_s
        for vid, s in seen.items():
            hist = ego.history.setdefault(vid, deque(maxlen=self._history_len))
            hist.append(HistoryPoint(t_s=now, x_m=s.x_m, y_m=s.y_m,
                                     v_mps=clip(s.v_mps, 0.0, 70.0)))
        for vid in list(ego.history):
            if vid not in seen:
                del ego.history[vid]
        route = ego.route
        ego.route_index = route.index_of(ego.lane, previous_index=ego.route_index)
        on_route = (ego.lane is not None
                    and route.index_of(ego.lane, previous_index=0) == ego.route_index)
        if on_route or self._step_index == 0:
            ego.dist_to_target_m = max(route.dist_to_target_m(ego.route_index, ego.lane_pos_m)
                                       + self._vehicle.length_m / 2.0, 0.0)
        else:
            ego.dist_to_target_m = max(ego.dist_to_target_m - ego.pose.v_mps * DT_S, 0.0)

    def observe(self, ego_id: str, *, required_decision_id: str | None = None) -> Observation:
        """The observation of ``ego_id`` at the current step."""
        ego = self.egos.get(ego_id)
        if ego is None:
            raise SimError(f"unknown ego {ego_id!r}; egos: {', '.join(self.egos)}")
        now, seq, p = self.time_s, self._step_index, ego.pose
        state = EgoState(
            stamp_s=now, seq=seq, x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad,
            v_mps=clip(p.v_mps, 0.0, 70.0),
            a_mps2=clip(p.a_mps2, -MAX_AGENT_ACCEL_MPS2, MAX_AGENT_ACCEL_MPS2),
            steer_rad=p.steer_rad, length_m=self._vehicle.length_m,
            width_m=self._vehicle.width_m, lane_id=ego.lane,
            lane_pos_m=max(ego.lane_pos_m, 0.0), route_index=ego.route_index,
            dist_to_target_m=ego.dist_to_target_m, required_decision_id=required_decision_id)
        agents = tuple(
            Agent(id=s.id, kind=s.kind, x_m=s.x_m, y_m=s.y_m, yaw_rad=s.yaw_rad,
                  v_mps=clip(s.v_mps, 0.0, 70.0), a_mps2=s.a_mps2, length_m=s.length_m,
                  width_m=s.width_m, lane_id=s.lane_id, lane_pos_m=max(s.lane_pos_m, 0.0),
                  signals=AgentSignals(left=bool(s.signals & SIG_LEFT),
                                       right=bool(s.signals & SIG_RIGHT),
                                       brake=bool(s.signals & SIG_BRAKE)),
                  history=tuple(ego.history.get(s.id, ())))
            for s in sorted(ego.seen.values(), key=lambda s: s.id))
        return Observation(
            map=ego.map, ego=state,
            agents=AgentArray(stamp_s=now, seq=seq, sensing_range_m=self._range_m,
                              agents=agents),
            signals=SignalStates(stamp_s=now, seq=seq, links=()))

    # --- stepping -----------------------------------------------------------------------
    def step(self, controls: dict[str, Optional[Control]]) -> None:
        """Apply each running ego's control (missing / None / late: bounded braking)."""
        if not self._started or self._scene is None:
            raise SimError("simulation not running: call reset(family, seed) first")
        if not self.running:
            raise SimError("episode is over; call reset() for a new one")
        t = self._traci
        applied: dict[str, tuple[Any, Optional[Control], bool]] = {}
        for eid in self.running_ids():
            ego, control = self.egos[eid], controls.get(eid)
            late = control is None or control.stamp_s < self.time_s - CONTROL_STALE_S - 1e-9
            guarded = clamp_control(None if late else control.accel_mps2,  # type: ignore
                                    None if late else control.steer_rad,  # type: ignore
                                    prev_steer_rad=ego.pose.steer_rad, dt_s=DT_S,
                                    vehicle=self._vehicle)
            ego.pose = p = step_bicycle(ego.pose, guarded.accel_mps2, guarded.steer_rad,
                                        dt_s=DT_S, vehicle=self._vehicle)
            applied[eid] = (guarded, control, late)
            half = self._vehicle.length_m / 2.0
            try:
                t.vehicle.moveToXY(eid, "", -1, p.x_m + half * math.cos(p.yaw_rad),
                                   p.y_m + half * math.sin(p.yaw_rad),
                                   sumo_angle_from_yaw(p.yaw_rad), keepRoute=1)
            except Exception as exc:  # noqa: BLE001
                ego.outcome, ego.detail = "error", f"SUMO failed to move {eid}: {exc}"
        # every running ego's body: no vehicle is inserted onto it (lmpc_bridge.insertion)
        now = round((self._step_index + 1) * DT_S, 6)
        guard = {eid: guard_box(e.pose.x_m, e.pose.y_m, e.pose.yaw_rad,
                                self._vehicle.length_m, self._vehicle.width_m, e.pose.v_mps)
                 for eid, e in self.egos.items() if e.running}
        try:
            if self._guard.held:
                self._guard.release_clear(t, guard, now_s=now)
            for e in self.egos.values():
                if e.running and e.shadow is not None:
                    e.shadow.update(t, self._body(e.pose), e.pose.v_mps, e.lane, e.lane_shapes,
                                    now_s=now)
            t.simulationStep()
            self._guard.hold_overlapping(t, guard, now_s=now,
                                         skip={*self.egos, *self._shadow_ids})
        except Exception as exc:  # noqa: BLE001 - SUMO errors end the episode
            self._step_index += 1
            for e in self.egos.values():
                if e.running:
                    e.outcome, e.detail = "error", f"SUMO failed: {exc}"
            return
        self._step_index += 1
        present = set(t.vehicle.getIDList())
        for eid, (guarded, control, late) in applied.items():
            ego = self.egos[eid]
            if ego.running and eid not in present:
                ego.outcome, ego.detail = "error", "SUMO removed the ego (left the network?)"
            if ego.running:
                self._refresh(ego)
        for eid, (guarded, control, late) in applied.items():
            ego = self.egos[eid]
            if ego.running:
                self._record(ego, guarded, control, late)
        self._finish_step()

    def _body(self, pose: EgoPose) -> OrientedBox:
        """An ego's box at ``pose`` (box centre)."""
        return OrientedBox(pose.x_m, pose.y_m, pose.yaw_rad, self._vehicle.length_m,
                           self._vehicle.width_m)

    def _collision(self, ego: EgoRun) -> Optional[str]:
        box = self._body(ego.pose)
        for other in sorted(self.egos.values(), key=lambda e: e.ego_id):
            if other is ego or not other.running:
                continue  # a finished ego left SUMO
            if boxes_overlap(box, self._body(other.pose)):
                return other.ego_id
        for s in sorted(ego.seen.values(), key=lambda s: s.id):
            if s.id not in self.egos and boxes_overlap(box, s.box()):
                return s.id
        return None

    def _record(self, ego: EgoRun, guarded: Any, control: Optional[Control],
                late: bool) -> None:
        p = ego.pose
        box = self._body(p)
        hit = self._collision(ego)
        req_a = None if late or control is None else control.accel_mps2
        req_s = None if late or control is None else control.steer_rad
        ego.steps.append(StepRecord(
            step=self._step_index, t_s=self.time_s, x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad,
            v_mps=p.v_mps, a_mps2=p.a_mps2, steer_rad=p.steer_rad, lane_id=ego.lane,
            route_index=ego.route_index, dist_to_target_m=ego.dist_to_target_m,
            control_accel_mps2=req_a if req_a is not None and math.isfinite(req_a) else None,
            control_steer_rad=req_s if req_s is not None and math.isfinite(req_s) else None,
            applied_accel_mps2=guarded.accel_mps2, applied_steer_rad=guarded.steer_rad,
            clamped=guarded.clamped, late=late,
            decision_id=None if control is None else control.decision_id,
            control_mode=None if control is None else control.mode,
            solve_time_ms=None if control is None else control.solve_time_ms,
            nearby=nearby_records(self._traci, ego.ego_id, ego.seen, box,
                                  foes_query=ego.foes_query),
            collided_with=hit))
        if hit is not None:
            ego.outcome, ego.detail, ego.collided_with = "collision", \
                f"{ego.ego_id} box overlaps {hit!r}", hit
            other = self.egos.get(hit)
            if other is not None and other.running:
                other.outcome, other.detail, other.collided_with = "collision", \
                    f"{other.ego_id} box overlaps {ego.ego_id!r}", ego.ego_id
        elif self._in_target(ego):
            ego.outcome, ego.reached_at_s = "reached", self.time_s

    def _in_target(self, ego: EgoRun) -> bool:
        target, p = ego.spec.target, ego.pose
        if math.hypot(p.x_m - target.center[0], p.y_m - target.center[1]) <= target.radius_m:
            return True
        return (ego.lane in target.lane_ids
                and ego.lane_pos_m - self._vehicle.length_m / 2.0 >= target.lane_pos_m)

    def _finish_step(self) -> None:
        t = self._traci
        present = set(t.vehicle.getIDList())
        for ego in self.egos.values():
            if not ego.running and ego.ego_id in present:
                # through (or wrecked): out of the episode (its subscriptions first: libsumo
                # fails the next step on a subscription of a vehicle it no longer knows)
                for domain in (tc.CMD_GET_VEHICLE_VARIABLE, tc.CMD_GET_PERSON_VARIABLE):
                    t.vehicle.unsubscribeContext(ego.ego_id, domain, self._range_m)
                t.vehicle.remove(ego.ego_id)
            if not ego.running and ego.shadow is not None and ego.shadow.lane_id is not None:
                ego.shadow.take_out(t, self.time_s, f"{ego.ego_id} is out of the episode")
        running = [e for e in self.egos.values() if e.running]
        if not running:
            return
        moving = any(e.pose.v_mps >= DEADLOCK_SPEED_MPS for e in running)
        reached = any(e.outcome == "reached" for e in self.egos.values())
        if moving or reached:
            self._still_since_s = None
        elif self._still_since_s is None:
            self._still_since_s = self.time_s
        if self._still_since_s is not None and not reached \
                and self.time_s - self._still_since_s >= DEADLOCK_S - 1e-9:
            self.deadlock = True
            for e in running:
                e.outcome, e.detail = "timeout", (f"deadlock: no ego moved for "
                                                  f"{DEADLOCK_S:.0f} s")
        elif self.time_s >= self._max_time_s - 1e-9:
            for e in running:
                e.outcome, e.detail = "timeout", \
                    f"target not reached within {self._max_time_s:.0f} s"

    # --- status and record --------------------------------------------------------------
    def _time_metric_s(self, ego: EgoRun) -> float:
        if ego.reached_at_s is not None:
            return ego.reached_at_s
        if ego.outcome == "timeout":
            return self._max_time_s
        return ego.steps[-1].t_s if ego.steps else self.time_s

    def status(self, ego_id: str) -> EpisodeStatus:
        ego, scene = self.egos[ego_id], self.scene
        return EpisodeStatus(
            stamp_s=self.time_s, seq=self._step_index, scenario=scene.family, seed=scene.seed,
            outcome=ego.outcome, detail=ego.detail[:1000], collided_with=ego.collided_with,
            metrics=compute_metrics(ego.steps, time_s=self._time_metric_s(ego)))

    def record(self, ego_id: str) -> EpisodeRecord:
        ego, scene = self.egos[ego_id], self.scene
        return EpisodeRecord(
            family=scene.family, seed=scene.seed, description=scene.description, dt_s=DT_S,
            max_time_s=self._max_time_s, target_center=ego.spec.target.center,
            target_radius_m=ego.spec.target.radius_m, outcome=ego.outcome,
            reached_at_s=ego.reached_at_s, collided_with=ego.collided_with,
            held_insertions=self._guard.by_ego.get(ego_id, 0),
            insertion_holds=self._guard.lines(ego_id),
            shadows=0 if ego.shadow is None else ego.shadow.placements,
            shadow_log=() if ego.shadow is None else tuple(ego.shadow.log),
            steps=tuple(ego.steps))
