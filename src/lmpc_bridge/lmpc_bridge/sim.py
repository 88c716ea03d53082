"""``SumoSim``: one SUMO episode driven through libsumo, with the ego moved by our own model.

Per step: guard-clamp the control, integrate the ego's kinematic bicycle, place
the ego in SUMO (``vehicle.moveToXY`` with ``keepRoute=2``, front bumper, SUMO
angle), ``simulationStep()``, then check collisions with oriented boxes (SUMO
does not detect every collision of an externally moved vehicle), whether the ego
left its route (``route_watch``: outcome ``off_route``), the target and the time
limit, and append to the per-step record.

The ego stays a normal SUMO vehicle, so other drivers' car following and
junction logic see it (SUMO derives its speed from the displacement).
Observations come from one context subscription around the ego (vehicles and
persons within the sensing range) and carry only observable data (DESIGN §3).

libsumo runs one simulation per process: one ``SumoSim`` per process, and
:meth:`close` before another ``reset``/``start`` (``reset`` does it for you).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

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
    LinkSignal,
    MapSnapshot,
    SignalStates,
)
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vehicle import DEFAULT_VEHICLE, VehicleParams

from lmpc_bridge import demand as traffic
from lmpc_bridge import sumo_rng
from lmpc_bridge.dynamics import EgoPose, clamp_control, step_bicycle
from lmpc_bridge.geometry import OrientedBox, boxes_overlap
from lmpc_bridge.insertion import InsertionGuard, guard_box
from lmpc_bridge.mapping import RouteGeometry, build_map, read_net
from lmpc_bridge.metrics import compute_metrics
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
from lmpc_bridge.record import EpisodeRecord, StepRecord
from lmpc_bridge.route_watch import RouteWatch
from lmpc_bridge.scenarios import Scene, build_scene
from lmpc_bridge.scenarios.base import check_sumo_path
from lmpc_bridge.shadow import EgoShadow, LaneShape, lane_shapes

DT_S = 0.1
EGO_ID = "ego"
CONTROL_STALE_S = 0.3
"""A control stamped more than this before the current step counts as late (RELIABILITY)."""
Outcome = Literal["running", "reached", "collision", "timeout", "off_route", "error"]


@dataclass(frozen=True)
class SimState:
    """A saved episode of :class:`SumoSim` (``save_state`` / ``load_state``): the SUMO state
    file and the bridge's own state at that step."""

    path: Path
    scene: Any
    step_index: int
    pose: EgoPose
    seen: dict[str, Any]
    history: dict[str, tuple[HistoryPoint, ...]]
    ego_lane: str | None
    ego_lane_pos_m: float
    route_index: int
    dist_to_target_m: float
    signals: tuple[LinkSignal, ...]
    steps: tuple[StepRecord, ...]
    outcome: str
    detail: str
    collided_with: str | None
    reached_at_s: float | None
    max_time_s: float
    guard: InsertionGuard | None = None
    """The held vehicles (not in SUMO's state) and the hold count at that step."""
    shadow: EgoShadow | None = None
    """The ego's shadow (its vehicle is in SUMO's state; where it stands is here)."""


class SimError(RuntimeError):
    """The simulation cannot do what was asked (not started, episode over, SUMO failure)."""


@dataclass(frozen=True)
class StepInfo:
    """What one :meth:`SumoSim.step` did."""

    step_index: int
    time_s: float
    outcome: Outcome
    clamped: bool
    late: bool
    applied_accel_mps2: float
    applied_steer_rad: float
    collided_with: str | None = None


class SumoSim:
    """One SUMO episode at a time, the ego integrated by the bridge (see module docstring)."""

    def __init__(self, *, vehicle: VehicleParams = DEFAULT_VEHICLE,
                 sensing_range_m: float = 80.0, history_s: float = 2.0, work_dir: Path,
                 traci: Any = libsumo, sumo_binary: str = "sumo",
                 extra_sumo_args: tuple[str, ...] = ()) -> None:
        self._vehicle = vehicle
        self._range_m = float(sensing_range_m)
        self._history_len = max(int(round(history_s / DT_S)), 1)
        self._work_dir = check_sumo_path(Path(work_dir), "the SUMO work directory")
        self._traci = traci
        self._binary = sumo_binary
        self._extra_args = tuple(extra_sumo_args)
        self._started = False
        self._scene: Scene | None = None
        self._map: MapSnapshot | None = None
        self._route: RouteGeometry | None = None
        self._watch: RouteWatch | None = None
        self._reset_state()

    def _reset_state(self) -> None:
        self._step_index = 0
        self._pose = EgoPose(0.0, 0.0, 0.0, 0.0)
        self._seen: dict[str, Seen] = {}
        self._history: dict[str, deque[HistoryPoint]] = {}
        self._ego_lane: str | None = None
        self._ego_lane_pos_m = 0.0
        self._route_index = 0
        self._dist_to_target_m = 0.0
        self._signals: tuple[LinkSignal, ...] = ()
        self._steps: list[StepRecord] = []
        self._outcome: Outcome = "running"
        self._detail = ""
        self._collided_with: str | None = None
        self._reached_at_s: float | None = None
        self._max_time_s = 200.0
        self._guard = InsertionGuard()
        self._shadow = EgoShadow(EGO_ID)
        self._lane_shapes: dict[str, LaneShape] = {}
        self._foes_query_ok = True
        self._refused_at_start: tuple[str, ...] = ()
        self._route_edges: set[str] | None = None
        self._tls_links: dict[tuple[str, int | None], list[tuple[Any, Any]]] | None = None
        self._rng_carry: dict[str, int] | None = {}
        """Per carried generator: its call count minus its draws since this simulation
        seeded it (:data:`lmpc_bridge.sumo_rng.CARRIED_RNGS`); ``save_state`` subtracts
        it. None: unknown."""

    # --- lifecycle ----------------------------------------------------------------------
    def reset(self, family: str, seed: int, *, max_time_s: float | None = None) -> Observation:
        """Build the scene, start SUMO, insert the ego; returns the observation at t = 0."""
        self.close()
        self._reset_state()
        scene = build_scene(family, seed, work_dir=self._work_dir)
        return self.reset_scene(scene, max_time_s=max_time_s)

    def reset_scene(self, scene: Scene, *, max_time_s: float | None = None) -> Observation:
        """Start SUMO on a built ``scene`` (a family's or an external one), insert the ego.

        ``scene.params["begin_s"]`` (external scenes) starts SUMO at that time
        (``--begin``) and ``scene.params["warmup_s"]`` runs it that long before the
        ego is inserted, so background traffic fills the network. Failures raise
        :class:`SimError` naming the problem (SUMO cannot load the net, the start
        overlaps a vehicle, SUMO refuses the ego) and leave SUMO closed.
        """
        self.close()
        self._reset_state()
        try:
            return self._start_scene(scene, max_time_s)
        except BaseException:
            self.close()  # nothing half-started stays running
            raise

    def _start_scene(self, scene: Scene, max_time_s: float | None) -> Observation:
        self._scene = scene
        self._max_time_s = scene.max_time_s if max_time_s is None else float(max_time_s)
        family, seed = scene.family, scene.seed
        t = self._traci
        cmd = [self._binary, "-n", str(scene.net_file), "-r", str(scene.route_file),
               "--step-length", f"{DT_S}", "--time-to-teleport", "-1",
               "--collision.action", "none",  # the bridge checks collisions itself
               "--seed", str(seed), "--no-step-log", "true", "--no-warnings", "true",
               "--duration-log.disable", "true",
               # a saved state (``save_state``) carries the random number generators and
               # full-precision positions and speeds: restoring it continues bit-identically
               # (without the precision option positions drift by ~1 mm; docs/BRANCHING.md)
               "--save-state.rng", "true", "--save-state.transportables", "true",
               "--save-state.precision", "17"]
        if scene.additional_files:
            cmd += ["-a", ",".join(str(p) for p in scene.additional_files)]
        begin_s = float(scene.params.get("begin_s", 0.0))
        if begin_s > 0.0:
            cmd += ["--begin", f"{begin_s:g}"]
        cmd += list(self._extra_args)
        self._cmd = list(cmd)
        for attempt in range(2):
            try:
                t.start(cmd)
            except Exception as exc:  # noqa: BLE001 - libsumo raises its own types
                raise SimError(f"SUMO cannot load scene {family}/{seed} (net "
                               f"{scene.net_file}, routes {scene.route_file}, additional "
                               f"{[str(p) for p in scene.additional_files]}): {exc}") from None
            self._started = True
            # a fresh simulation: the static generators' counts go on from the last one's
            # (see sumo_rng.CARRIED_RNGS); unknown, a restart finds them (once, before any step)
            known = t is not libsumo or sumo_rng.counts_at_close() is not None
            self._rng_carry = (None if not known else {} if t is not libsumo
                               else dict(sumo_rng.counts_at_close() or {}))
            if known or attempt:
                break
            self.close()
        warmup_steps = int(round(float(scene.params.get("warmup_s", 0.0)) / DT_S))
        for _ in range(warmup_steps):
            t.simulationStep()
        if warmup_steps:
            self._check_start_free(scene)
        t.vehicle.add(EGO_ID, "r_ego", typeID="ego_type", depart="now",
                      departLane=str(scene.ego_depart_lane),
                      departPos=f"{scene.ego_depart_pos_m:.3f}",
                      departSpeed=f"{scene.ego_depart_speed_mps:.3f}")
        # The bridge moves the ego; SUMO must not brake or change lanes on its own.
        t.vehicle.setSpeedMode(EGO_ID, 0)
        t.vehicle.setLaneChangeMode(EGO_ID, 0)
        t.simulationStep()  # inserts the ego (and the background traffic departing at 0)
        if EGO_ID not in t.vehicle.getIDList():
            # SUMO refuses an insertion at speed that would need emergency braking (e.g. a
            # slow vehicle 20 m ahead, family eoa). The bridge sets the ego's speed itself
            # (our pose), so insert it standing; SUMO derives its speed from the next move.
            t.vehicle.remove(EGO_ID)
            t.vehicle.add(EGO_ID, "r_ego", typeID="ego_type", depart="now",
                          departLane=str(scene.ego_depart_lane),
                          departPos=f"{scene.ego_depart_pos_m:.3f}", departSpeed="0")
            t.vehicle.setSpeedMode(EGO_ID, 0)
            t.vehicle.setLaneChangeMode(EGO_ID, 0)
            t.simulationStep()
        if EGO_ID not in t.vehicle.getIDList():
            raise SimError(f"scene {family}/{seed}: SUMO did not insert the ego (blocked)")
        self._t0_s = float(t.simulation.getTime())  # our t = 0 is SUMO's first step
        # (after a warm-up, vehicles departing at 0 may have come and gone)
        self._refused_at_start = traffic.refused_at_start(
            scene.route_file, present=t.vehicle.getIDList(),
            pending=t.simulation.getPendingVehicles()) if not warmup_steps else ()
        self._subscribe()
        net = read_net(scene.net_file)
        self._map, self._route = build_map(scene, net=net)
        self._lane_shapes = lane_shapes(self._map.lanes)
        self._watch = RouteWatch.of_net(net, scene.ego_route_edges)
        self._foes_query_ok = foes_query_ok(net, scene.ego_route_edges)
        fx, fy = t.vehicle.getPosition(EGO_ID)
        yaw = yaw_from_sumo_angle(t.vehicle.getAngle(EGO_ID))
        half = self._vehicle.length_m / 2.0
        self._pose = EgoPose(x_m=fx - half * math.cos(yaw), y_m=fy - half * math.sin(yaw),
                             yaw_rad=yaw, v_mps=scene.ego_depart_speed_mps)
        self._refresh()
        ego_box = OrientedBox(self._pose.x_m, self._pose.y_m, yaw, self._vehicle.length_m,
                              self._vehicle.width_m)
        for s in sorted(self._seen.values(), key=lambda s: s.id):
            if boxes_overlap(ego_box, s.box()):
                raise SimError(f"scene {family}/{seed}: the ego's start overlaps {s.kind} "
                               f"{s.id!r} at ({s.x_m:.1f}, {s.y_m:.1f}): choose another start "
                               f"position or warm-up time")
        return self.observe()

    def _subscribe(self) -> None:
        """The context subscriptions around the ego the observations come from."""
        t = self._traci
        t.vehicle.subscribeContext(EGO_ID, tc.CMD_GET_VEHICLE_VARIABLE, self._range_m,
                                   list(VEHICLE_VARS))
        t.vehicle.subscribeContext(EGO_ID, tc.CMD_GET_PERSON_VARIABLE, self._range_m,
                                   list(PERSON_VARS))

    # --- branching ----------------------------------------------------------------------
    def save_state(self, path: Path) -> "SimState":
        """The episode as it is now: SUMO's state (``simulation.saveState`` with its random
        number generators, written to ``path``) and the bridge's own (ego pose, what was
        seen, histories, route progress, the per-step record, the outcome). ``load_state``
        continues from it, in this process (libsumo: one simulation per process)."""
        if not self._started or self._map is None:
            raise SimError("simulation not running: nothing to save")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._traci.simulation.saveState(str(path))
        self._correct_rng_counts(path)
        return SimState(
            path=path, scene=self._scene, step_index=self._step_index, pose=self._pose,
            seen=dict(self._seen),
            history={k: tuple(v) for k, v in self._history.items()},
            ego_lane=self._ego_lane, ego_lane_pos_m=self._ego_lane_pos_m,
            route_index=self._route_index, dist_to_target_m=self._dist_to_target_m,
            signals=self._signals, steps=tuple(self._steps),
            outcome=self._outcome, detail=self._detail, collided_with=self._collided_with,
            reached_at_s=self._reached_at_s, max_time_s=self._max_time_s,
            guard=self._guard.copy(), shadow=self._shadow.copy())

    def _correct_rng_counts(self, path: Path) -> None:
        """The saved counts of the static generators as draws since this simulation's
        seed (:func:`lmpc_bridge.sumo_rng.correct_counts`)."""
        if self._rng_carry is None:
            raise SimError("cannot save an exact state: SUMO's random number generator "
                           "counts of this process are unknown (docs/BRANCHING.md)")
        try:
            sumo_rng.correct_counts(path, self._rng_carry)
        except ValueError as exc:
            raise SimError(str(exc)) from None

    def load_state(self, state: "SimState") -> None:
        """Go back to ``state`` (from :meth:`save_state` of this episode): SUMO restarts on
        the saved state (``--load-state``), the ego's speed / lane-change modes and the
        context subscriptions are set again, and the bridge's state is restored."""
        if not self._started or self._scene is not state.scene:
            raise SimError("load_state: the state belongs to another episode (or SUMO is not "
                           "running): branch within one episode, in the process that saved it")
        t = self._traci
        if t is libsumo:
            sumo_rng.forget_counts()  # the restored simulation's close() notes them again
        # SUMO restarted on the state, not ``simulation.loadState`` into the running one: the
        # saved generator states are draw counts, which loadState applies as a discard on
        # the running generators instead of on freshly seeded ones, so the background
        # traffic's dawdling diverged from the first step (docs/BRANCHING.md). A restart on
        # a family scene takes ~15 ms.
        cmd = [a for i, a in enumerate(self._cmd)
               if a != "--begin" and (i == 0 or self._cmd[i - 1] != "--begin")]
        t.close()
        self._started = False
        try:
            t.start(cmd + ["--load-state", str(state.path)])
        except Exception as exc:  # noqa: BLE001 - libsumo raises its own types
            raise SimError(f"SUMO cannot load the saved state {state.path}: {exc}") from None
        self._started = True
        # loading set every generator's count to the state's (its draws since the seed):
        # nothing carried any more (no draw comes before the state's <rngState>, measured)
        self._rng_carry = {}
        if EGO_ID in t.vehicle.getIDList():
            # the ego's modes and the context subscriptions are TraCI settings, not state
            t.vehicle.setSpeedMode(EGO_ID, 0)
            t.vehicle.setLaneChangeMode(EGO_ID, 0)
            self._subscribe()
        self._step_index = state.step_index
        self._pose = state.pose
        self._seen = dict(state.seen)
        self._history = {k: deque(v, maxlen=self._history_len)
                         for k, v in state.history.items()}
        self._ego_lane, self._ego_lane_pos_m = state.ego_lane, state.ego_lane_pos_m
        self._route_index = state.route_index
        self._dist_to_target_m = state.dist_to_target_m
        self._signals = state.signals
        self._steps = list(state.steps)
        self._outcome, self._detail = state.outcome, state.detail
        self._collided_with, self._reached_at_s = state.collided_with, state.reached_at_s
        self._max_time_s = state.max_time_s
        self._guard = state.guard.copy() if state.guard is not None else InsertionGuard()
        self._shadow = state.shadow.copy() if state.shadow is not None else EgoShadow(EGO_ID)
        self._shadow.restore(t)

    def _check_start_free(self, scene: Scene) -> None:
        """After the warm-up: SimError when a vehicle occupies the ego's start slot."""
        t = self._traci
        lane_id = f"{scene.ego_route_edges[0]}_{scene.ego_depart_lane}"
        front = scene.ego_depart_pos_m
        back = front - self._vehicle.length_m
        for vid in t.lane.getLastStepVehicleIDs(lane_id):
            v_front = float(t.vehicle.getLanePosition(vid))
            v_back = v_front - float(t.vehicle.getLength(vid))
            if v_front > back - 1.0 and v_back < front + 1.0:
                raise SimError(
                    f"scene {scene.family}/{scene.seed}: the ego's start (lane {lane_id}, "
                    f"front at {front:.1f} m) overlaps vehicle {vid!r} (front at "
                    f"{v_front:.1f} m) after the {scene.params.get('warmup_s')} s warm-up: "
                    f"choose another start position or warm-up time")

    def close(self) -> None:
        """Stop SUMO (safe to call twice). With libsumo, first note the static random
        number generators' call counts, which the next simulation of this process starts
        from (:data:`lmpc_bridge.sumo_rng.CARRIED_RNGS`)."""
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
    def map(self) -> MapSnapshot:
        if self._map is None:
            raise SimError("no map: call reset(family, seed) first")
        return self._map

    @property
    def dt_s(self) -> float:
        """Simulation step (s): SUMO's step length and the ego integration step."""
        return DT_S

    @property
    def vehicle(self) -> VehicleParams:
        return self._vehicle

    @property
    def time_s(self) -> float:
        return round(self._step_index * DT_S, 6)

    @property
    def step_index(self) -> int:
        return self._step_index

    @property
    def pose(self) -> EgoPose:
        """The ego's integrated state (box centre)."""
        return self._pose

    # --- observation --------------------------------------------------------------------
    def _refresh(self) -> None:
        """Read the context subscription, update histories, ego lane, route progress, signals."""
        t = self._traci
        results = t.vehicle.getContextSubscriptionResults(EGO_ID) or {}
        seen: dict[str, Seen] = {}
        now = self.time_s
        for vid, vals in results.items():
            if tc.VAR_POSITION not in vals:
                continue  # e.g. a person type's entry (libsumo merges domains)
            if vid in self._guard.held or vid == self._shadow.vehicle_id:
                continue  # inserted into the ego and taken out again; the ego's own shadow
            if vid == EGO_ID:
                lane = vals.get(tc.VAR_LANE_ID) or None
                self._ego_lane = lane
                self._ego_lane_pos_m = float(vals.get(tc.VAR_LANEPOSITION, 0.0))
                continue
            seen[vid] = convert(vid, vals)
        self._seen = seen
        for vid, s in seen.items():
            hist = self._history.setdefault(vid, deque(maxlen=self._history_len))
            hist.append(HistoryPoint(t_s=now, x_m=s.x_m, y_m=s.y_m,
                                     v_mps=clip(s.v_mps, 0.0, 70.0)))
        for vid in list(self._history):
            if vid not in seen:
                del self._history[vid]  # out of range: history restarts when seen again
        route = self._route
        if route is not None:
            self._route_index = route.index_of(self._ego_lane, previous_index=self._route_index)
            on_route = (self._ego_lane is not None
                        and route.index_of(self._ego_lane, previous_index=0) == self._route_index)
            if on_route or self._step_index == 0:
                self._dist_to_target_m = max(
                    route.dist_to_target_m(self._route_index, self._ego_lane_pos_m)
                    + self._vehicle.length_m / 2.0, 0.0)
            else:
                # SUMO mapped the ego to a lane off its route (keepRoute=2 picks the nearest
                # lane, e.g. a crossing internal lane): dead-reckon the route distance.
                self._dist_to_target_m = max(self._dist_to_target_m - self._pose.v_mps * DT_S,
                                             0.0)
        self._signals = self._read_signals()

    def _read_signals(self) -> tuple[LinkSignal, ...]:
        """Signal-controlled links ahead on the ego route (none at an unsignalized junction)."""
        try:
            upcoming = self._traci.vehicle.getNextTLS(EGO_ID)
        except Exception:  # noqa: BLE001 - the ego may be off the network (keepRoute=2)
            return ()
        links = []
        route = self._route
        if self._route_edges is None:
            self._route_edges = set() if route is None else {
                lane_id.rsplit("_", 1)[0] for lane_id in route.lane_ids}
        route_edges = self._route_edges
        if self._tls_links is None:
            # (tls, link index) -> [(lane, successor)] once per map: the per-step lookup must
            # not scan every lane of a big map.
            self._tls_links = {}
            for lane in self.map.lanes:
                for succ in lane.successors:
                    if succ.tls_id is not None:
                        self._tls_links.setdefault((succ.tls_id, succ.link_index), []).append(
                            (lane, succ))
        for tls_id, link_index, distance, state in upcoming:
            from_lane = to_lane = None
            for lane, succ in self._tls_links.get((tls_id, link_index), ()):
                # SUMO reports the link of the lane the ego is on, which may be a
                # parallel lane of a route edge (before a lane change): match edges.
                if route is None or lane.edge_id in route_edges:
                    from_lane, to_lane = lane.id, succ.to_lane
            if from_lane is None or to_lane is None:
                continue
            try:
                switch_s = max(float(self._traci.trafficlight.getNextSwitch(tls_id))
                               - float(self._traci.simulation.getTime()), 0.0)
            except Exception:  # noqa: BLE001
                switch_s = None
            links.append(LinkSignal(tls_id=tls_id, link_index=int(link_index),
                                    from_lane=from_lane, to_lane=to_lane,
                                    state=state if state in "rygGsuoO" else "off",
                                    time_to_switch_s=switch_s,
                                    distance_m=max(float(distance), 0.0)))
        return tuple(links)

    def observe(self, *, required_decision_id: str | None = None) -> Observation:
        """The observation of the current step (stamp = time_s, seq = step_index)."""
        if self._map is None:
            raise SimError("no episode: call reset(family, seed) first")
        now, seq = self.time_s, self._step_index
        p = self._pose
        ego = EgoState(
            stamp_s=now, seq=seq, x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad,
            v_mps=clip(p.v_mps, 0.0, 70.0),
            a_mps2=clip(p.a_mps2, -MAX_AGENT_ACCEL_MPS2, MAX_AGENT_ACCEL_MPS2),
            steer_rad=p.steer_rad, length_m=self._vehicle.length_m,
            width_m=self._vehicle.width_m, lane_id=self._ego_lane,
            lane_pos_m=max(self._ego_lane_pos_m, 0.0), route_index=self._route_index,
            dist_to_target_m=self._dist_to_target_m,
            required_decision_id=required_decision_id,
        )
        agents = tuple(
            Agent(id=s.id, kind=s.kind, x_m=s.x_m, y_m=s.y_m, yaw_rad=s.yaw_rad,
                  v_mps=clip(s.v_mps, 0.0, 70.0), a_mps2=s.a_mps2, length_m=s.length_m,
                  width_m=s.width_m, lane_id=s.lane_id, lane_pos_m=max(s.lane_pos_m, 0.0),
                  signals=AgentSignals(left=bool(s.signals & SIG_LEFT),
                                       right=bool(s.signals & SIG_RIGHT),
                                       brake=bool(s.signals & SIG_BRAKE)),
                  history=tuple(self._history.get(s.id, ())))
            for s in sorted(self._seen.values(), key=lambda s: s.id)
        )
        return Observation(
            map=self._map,
            ego=ego,
            agents=AgentArray(stamp_s=now, seq=seq, sensing_range_m=self._range_m,
                              agents=agents),
            signals=SignalStates(stamp_s=now, seq=seq, links=self._signals),
        )

    # --- stepping -----------------------------------------------------------------------
    def step(self, control: Control | None) -> StepInfo:
        """Apply ``control`` (None = missing / late -> bounded braking) for one step of dt."""
        if not self._started or self._map is None:
            raise SimError("simulation not running: call reset(family, seed) first")
        if self._outcome != "running":
            raise SimError(f"episode is over ({self._outcome}); call reset() for a new one")
        late = control is None or control.stamp_s < self.time_s - CONTROL_STALE_S - 1e-9
        req_a = None if late else control.accel_mps2  # type: ignore[union-attr]
        req_s = None if late else control.steer_rad  # type: ignore[union-attr]
        guarded = clamp_control(req_a, req_s, prev_steer_rad=self._pose.steer_rad, dt_s=DT_S,
                                vehicle=self._vehicle)
        self._pose = step_bicycle(self._pose, guarded.accel_mps2, guarded.steer_rad, dt_s=DT_S,
                                  vehicle=self._vehicle)
        p = self._pose
        half = self._vehicle.length_m / 2.0
        ego_box = OrientedBox(p.x_m, p.y_m, p.yaw_rad, self._vehicle.length_m,
                              self._vehicle.width_m)
        t = self._traci
        try:
            t.vehicle.moveToXY(EGO_ID, "", -1, p.x_m + half * math.cos(p.yaw_rad),
                               p.y_m + half * math.sin(p.yaw_rad),
                               sumo_angle_from_yaw(p.yaw_rad), keepRoute=2)
            now = round((self._step_index + 1) * DT_S, 6)
            guard = {EGO_ID: guard_box(p.x_m, p.y_m, p.yaw_rad, self._vehicle.length_m,
                                       self._vehicle.width_m, p.v_mps)}
            if self._guard.held:
                self._guard.release_clear(t, guard, now_s=now)
            self._shadow.update(t, ego_box, p.v_mps, self._ego_lane, self._lane_shapes,
                                now_s=now)
            t.simulationStep()
            self._guard.hold_overlapping(t, guard, now_s=now,
                                         skip=(EGO_ID, self._shadow.vehicle_id))
        except Exception as exc:  # noqa: BLE001 - SUMO errors end the episode, not the process
            self._step_index += 1
            self._finish("error", f"SUMO failed: {exc}")
            return self._info(guarded, late)
        self._step_index += 1
        if EGO_ID not in t.vehicle.getIDList():
            self._finish("error", "SUMO removed the ego (left the network?)")
            return self._info(guarded, late)
        self._refresh()
        collided = None
        for s in sorted(self._seen.values(), key=lambda s: s.id):
            if boxes_overlap(ego_box, s.box()):
                collided = s.id
                break
        nearby = nearby_records(self._traci, EGO_ID, self._seen, ego_box,
                                foes_query=self._foes_query_ok)
        self._steps.append(StepRecord(
            step=self._step_index, t_s=self.time_s, x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad,
            v_mps=p.v_mps, a_mps2=p.a_mps2, steer_rad=p.steer_rad, lane_id=self._ego_lane,
            route_index=self._route_index, dist_to_target_m=self._dist_to_target_m,
            control_accel_mps2=req_a if req_a is not None and math.isfinite(req_a) else None,
            control_steer_rad=req_s if req_s is not None and math.isfinite(req_s) else None,
            applied_accel_mps2=guarded.accel_mps2, applied_steer_rad=guarded.steer_rad,
            clamped=guarded.clamped, late=late,
            decision_id=None if control is None else control.decision_id,
            control_mode=None if control is None else control.mode,
            solve_time_ms=None if control is None else control.solve_time_ms,
            nearby=nearby, collided_with=collided,
        ))
        off = None if self._watch is None else self._watch.check(self._ego_lane, p.x_m, p.y_m)
        if collided is not None:
            self._collided_with = collided
            self._finish("collision", f"ego box overlaps {collided!r}")
        elif off is not None:
            self._finish("off_route", off.detail())
        elif self._in_target():
            self._reached_at_s = self.time_s
            self._finish("reached", "")
        elif self.time_s >= self._max_time_s - 1e-9:
            self._finish("timeout", f"target not reached within {self._max_time_s:.0f} s")
        return self._info(guarded, late, collided)

    def _info(self, guarded: Any, late: bool, collided: str | None = None) -> StepInfo:
        return StepInfo(step_index=self._step_index, time_s=self.time_s, outcome=self._outcome,
                        clamped=guarded.clamped, late=late,
                        applied_accel_mps2=guarded.accel_mps2,
                        applied_steer_rad=guarded.steer_rad, collided_with=collided)

    def _finish(self, outcome: Outcome, detail: str) -> None:
        self._outcome = outcome
        self._detail = detail

    def _in_target(self) -> bool:
        target = self.scene.target
        p = self._pose
        if math.hypot(p.x_m - target.center[0], p.y_m - target.center[1]) <= target.radius_m:
            return True
        # Passing the target point on a target lane also counts (no skipping the circle).
        return (self._ego_lane in target.lane_ids
                and self._ego_lane_pos_m - self._vehicle.length_m / 2.0 >= target.lane_pos_m)

    # --- status and record --------------------------------------------------------------
    @property
    def outcome(self) -> Outcome:
        return self._outcome

    def _time_metric_s(self) -> float:
        if self._reached_at_s is not None:
            return self._reached_at_s
        if self._outcome in ("timeout", "off_route"):
            # off its route the ego never reaches the target: a failure counts the limit,
            # so leaving the route early never scores better than a timeout
            return self._max_time_s
        return self.time_s

    def status(self) -> EpisodeStatus:
        """Outcome so far with the metrics so far."""
        scene = self.scene
        return EpisodeStatus(
            stamp_s=self.time_s, seq=self._step_index, scenario=scene.family, seed=scene.seed,
            outcome=self._outcome, detail=self._detail[:1000],
            collided_with=self._collided_with,
            metrics=compute_metrics(self._steps, time_s=self._time_metric_s()),
        )

    def traffic_warnings(self) -> tuple[str, ...]:
        """External scenes: a line when no background vehicle departs in the simulated
        window, and one when fewer vehicles entered so far than the traffic files declare
        (:mod:`lmpc_bridge.demand`); for the families' scenes, a line naming the vehicles
        the scene starts with that SUMO refused at once (``demand.refused_at_start``). Call while
        SUMO runs."""
        scene = self.scene
        if "scene_file" not in scene.params:
            return traffic.refused_warnings(self._refused_at_start)
        window = traffic.Window(begin_s=float(scene.params.get("begin_s", 0.0)),
                                warmup_s=float(scene.params.get("warmup_s", 0.0)),
                                max_time_s=self._max_time_s)
        try:
            declared = traffic.declared_demand(scene.additional_files)
        except (OSError, ValueError) as exc:
            return (f"traffic files not checked: {exc}",)
        lines = traffic.window_warnings(declared, window)
        # a held vehicle counts once in SUMO's insertions per hold (it was inserted, then
        # taken out): the ego's insertion and the holds are not traffic that entered
        count = (traffic.read_entry_count(self._traci, ego_inserted=1 + self._guard.count
                                          + self._shadow.placements)
                 if self._started else None)
        if count is not None and not lines:
            lines += traffic.entry_warnings(declared, window, count)
        return tuple(lines)

    def last_step(self) -> StepRecord | None:
        """The newest step record (None before the first step): cheaper than
        ``record().steps[-1]``, which copies every step."""
        return self._steps[-1] if self._steps else None

    def record(self) -> EpisodeRecord:
        """The per-step record so far (``model_dump_json()`` for a file)."""
        scene = self.scene
        return EpisodeRecord(
            family=scene.family, seed=scene.seed, description=scene.description, dt_s=DT_S,
            max_time_s=self._max_time_s, target_center=scene.target.center,
            target_radius_m=scene.target.radius_m, outcome=self._outcome,
            reached_at_s=self._reached_at_s, collided_with=self._collided_with,
            held_insertions=self._guard.count, insertion_holds=self._guard.lines(),
            shadows=self._shadow.placements, shadow_log=tuple(self._shadow.log),
            steps=tuple(self._steps),
        )
