"""ROS 2 node `sumo_bridge`: steps SUMO, publishes the world, applies controls.

A thin wrapper around :class:`lmpc_bridge.sim.SumoSim` (all simulation logic
lives there). Two clock modes (DESIGN §2, docs/ARCHITECTURE.md):

- ``sync`` (default): lock-step. Step k+1 happens only once the control for
  step k (and, with a planner, the planner's status for step k) arrived; a
  control more than ``control_timeout_s`` wall late is counted late and the ego
  brakes for that step.
- ``realtime``: steps paced by a 10 Hz wall timer; the newest control that is
  not older than ``control_stale_s`` sim is applied, otherwise the ego brakes.

The bridge is the clock source (``/clock``) and runs on wall time itself.
"""
from __future__ import annotations

import functools
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional, TypeVar

import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from nav_msgs.msg import Odometry
from pydantic import BaseModel, ConfigDict, Field
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from lmpc_bridge.scenarios import SceneError
from lmpc_bridge.sim import SimError, SumoSim
from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import LmpcNode, run_node
from lmpc_msgs_py.messages import (
    AgentArray,
    Control,
    Decision,
    EgoState,
    EpisodeStatus,
    MapSnapshot,
    PlannerStatus,
    SignalStates,
)
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.profiling import percentiles


class BridgeTiming(BaseModel):
    """Parameters every bridge node has (single- and multi-ego), mapped once from ROS
    parameters."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = Field(0, ge=0)
    clock_mode: Literal["sync", "realtime"] = "sync"
    wait_for_planner: bool = False
    """Sync mode: also wait for the planner's status of each step (set when a planner runs)."""
    control_timeout_s: float = Field(1.0, gt=0)
    """Sync mode: wall seconds to wait for a step's control before counting it late."""
    planner_timeout_s: float = Field(30.0, gt=0)
    """Sync mode: wall seconds to wait for the planner's status (longer than its LLM deadline)."""
    control_stale_s: float = Field(0.3, gt=0)
    """Realtime mode: a control older than this (sim) is not applied."""
    startup_timeout_s: float = Field(0.0, ge=0)
    """Realtime mode: wall seconds to wait for the MPC (and planner) before step 0, then
    start anyway (the ego brakes until a control arrives). 0 (default): start at once,
    as a real vehicle's clock would; the ego brakes while the MPC compiles its solver."""
    max_time_s: float = Field(200.0, gt=0)
    run_dir: str = ""
    progress_period_s: float = Field(5.0, gt=0)
    """Sim seconds between progress log lines."""
    linger_s: float = Field(1.0, ge=0)
    """Wall seconds to keep serving after the episode ended (final status delivery)."""


class BridgeConfig(BridgeTiming):
    """Parameters of the (single-ego) bridge node."""

    scenario: str = "usi"
    extra_subscribers: int = Field(0, ge=0)
    """Sync mode: further subscribers of the ego state to wait for before step 0 (a recorder)."""
    ego_id: str = ""
    scene_file: str = ""
    """A scene description (YAML, README "Your own network") instead of scenario / seed;
    its own max_time_s applies."""


C = TypeVar("C", bound=BaseModel)


def declare_config(node: Node, cls: type[C]) -> C:
    """``cls`` from the node's ROS parameters, one declared per field (its default and
    docstring as the parameter's default and description)."""
    values = {}
    for name, info in cls.model_fields.items():
        desc = ParameterDescriptor(description=(info.description or name))
        values[name] = node.declare_parameter(name, info.default, desc).value
    return cls(**values)


@dataclass
class _StepTiming:
    published_wall_s: float
    control_wall_s: Optional[float] = None
    """When the first control for the step arrived (None: none yet)."""


@dataclass
class _RunStats:
    decisions: dict[str, str] = field(default_factory=dict)  # id -> source
    solve_ms: list[float] = field(default_factory=list)
    attended: list[float] = field(default_factory=list)  # agents in the MPC's problem
    late_controls: int = 0
    control_modes: dict[str, int] = field(default_factory=dict)


@dataclass
class EgoInputs:
    """What the bridge receives for one ego and steps on: its newest control, how far its
    planner has got, the decision its next observation names (sync barrier), the wall
    times of each step's publication and control, and the run's statistics."""

    latest_control: Optional[Control] = None
    planner_stamp_s: float = -1.0
    required_decision_id: Optional[str] = None
    timing: dict[int, _StepTiming] = field(default_factory=dict)
    stats: _RunStats = field(default_factory=_RunStats)

    def take_control(self, msg: Control, dt_s: float) -> None:
        timing = self.timing.get(round(msg.stamp_s / dt_s))
        if timing is not None and timing.control_wall_s is None:
            timing.control_wall_s = time.monotonic()
        if self.latest_control is None or msg.stamp_s >= self.latest_control.stamp_s:
            self.latest_control = msg

    def take_status(self, msg: PlannerStatus) -> None:
        self.planner_stamp_s = max(self.planner_stamp_s, msg.stamp_s)
        if msg.last_decision_id is not None:
            self.required_decision_id = msg.last_decision_id

    def applied(self, k: int, control: Optional[Control]) -> Optional[_StepTiming]:
        """Count step ``k``'s control (None: late, the ego brakes); its timing when the
        control arrived (for the control-cycle stages), else None."""
        if control is None:
            self.stats.late_controls += 1
        else:
            self.stats.solve_ms.append(control.solve_time_ms)
            self.stats.attended.append(float(len(control.attended)))
            modes = self.stats.control_modes
            modes[control.mode] = modes.get(control.mode, 0) + 1
        timing = self.timing.pop(k, None)
        if timing is None or timing.control_wall_s is None or control is None:
            return None
        return timing


def _percentiles(values: list[float]) -> dict[str, Optional[float]]:
    if not values:
        return {"median": None, "p99": None, "max": None}
    stats = percentiles(values)
    return {key: stats[key] for key in ("median", "p99", "max")}


CONTROL_WAIT_STAGE = "wait: control (transport + MPC)"
"""The profile stage of the control cycle: EgoState published -> its Control received."""


def _wait_percentiles(profile: dict[str, dict[str, float]]) -> dict[str, Optional[float]]:
    """The control cycle's median / p99 / max (ms) from the profile (None: no sample)."""
    stats = profile.get(CONTROL_WAIT_STAGE)
    if stats is None:
        return {"median": None, "p99": None, "max": None}
    return {key: stats[key] for key in ("median", "p99", "max")}


def _stamp(t_s: float) -> TimeMsg:
    sec = int(math.floor(t_s))
    return TimeMsg(sec=sec, nanosec=int(round((t_s - sec) * 1e9)) % 1_000_000_000)


def odometry(state: EgoState, child_frame_id: str) -> Odometry:
    """The ego's pose and speed as ``nav_msgs/Odometry`` in the map frame (RViz)."""
    odom = Odometry()
    odom.header.stamp = _stamp(state.stamp_s)
    odom.header.frame_id = "map"
    odom.child_frame_id = child_frame_id
    odom.pose.pose.position.x = state.x_m
    odom.pose.pose.position.y = state.y_m
    odom.pose.pose.orientation.z = math.sin(state.yaw_rad / 2.0)
    odom.pose.pose.orientation.w = math.cos(state.yaw_rad / 2.0)
    odom.twist.twist.linear.x = state.v_mps
    return odom


def control_for_step(ctl: Optional[Control], sim_time_s: float, cfg: BridgeTiming
                     ) -> Optional[Control]:
    """The control to apply at ``sim_time_s``: sync, the one stamped with this step;
    realtime, the newest one not older than ``control_stale_s``; None: brake."""
    if ctl is None:
        return None
    if cfg.clock_mode == "sync":
        return ctl if abs(ctl.stamp_s - sim_time_s) < 1e-6 else None
    stale = sim_time_s - ctl.stamp_s > cfg.control_stale_s + 1e-9
    return None if stale else ctl


class BridgeBase(LmpcNode):
    """What the single- and the multi-ego bridge share: the configuration and the run
    folder, the start-up (step 0 once every participant is connected; realtime: or after
    ``startup_timeout_s``), the step-cycle bookkeeping and the linger after the end.
    Subclasses build the simulation and define ``_ready_to_start``, ``_publish_step``,
    ``_sync_watchdog``, ``_realtime_tick`` and ``_diagnostics``."""

    def __init__(self, config_cls: type[BridgeTiming]) -> None:
        super().__init__("sumo_bridge")
        self.cfg = declare_config(self, config_cls)
        self.exit_code = 0
        run_dir = Path(self.cfg.run_dir) if self.cfg.run_dir else Path(tempfile.mkdtemp("-lmpc"))
        run_dir.mkdir(parents=True, exist_ok=True)
        self.run_dir = run_dir
        self.started = False
        self.finished = False
        self.next_progress_s = 0.0
        self.waiting_since = time.monotonic()
        self.finished_wall_s = 0.0
        self.step0_epoch_s: Optional[float] = None
        self.last_publish_wall_s: Optional[float] = None

    def _start_timers(self, dt_s: float) -> None:
        if self.cfg.clock_mode == "sync":
            self.create_timer(0.02, self._sync_watchdog)
        else:
            self.create_timer(dt_s, self._realtime_tick)
        self.create_timer(1.0, self._diagnostics)

    def _ready_to_start(self) -> Optional[str]:
        """None when every participant is connected, else what we wait for."""
        raise NotImplementedError

    def _publish_step(self) -> None:
        raise NotImplementedError

    def _sync_watchdog(self) -> None:
        raise NotImplementedError

    def _realtime_tick(self) -> None:
        raise NotImplementedError

    def _diagnostics(self) -> None:
        raise NotImplementedError

    def _ended(self) -> bool:
        """True once the episode has ended (the caller then does nothing else); shuts
        rclpy down ``linger_s`` after the end (the final status has been delivered)."""
        if not self.finished:
            return False
        if time.monotonic() - self.finished_wall_s >= self.cfg.linger_s:
            rclpy.try_shutdown()
        return True

    def _starting(self) -> bool:
        """True before and at step 0 (the caller then does nothing else): waits for the
        participants (realtime: at most ``startup_timeout_s``), then publishes step 0."""
        if self.started:
            return False
        missing = self._ready_to_start()
        waited = time.monotonic() - self.waiting_since
        realtime = self.cfg.clock_mode == "realtime"
        if missing is not None and (not realtime or waited < self.cfg.startup_timeout_s):
            if waited > 2.0:
                self.log_event("startup", f"waiting for {missing}", level="info")
            return True
        if missing is None:
            self.get_logger().info("all participants connected: starting the episode")
        elif self.cfg.startup_timeout_s > 0.0:
            self.get_logger().warn(f"starting without {missing} after "
                                   f"{self.cfg.startup_timeout_s:.0f} s wall")
        self.started = True
        self._publish_step()
        return True

    def _step_published(self) -> None:
        """Book-keeping of a step's publication: the step cycle, the wall time of step 0."""
        now = time.monotonic()
        if self.last_publish_wall_s is not None:
            self.stage_times.add("step cycle (publish to publish)",
                                 (now - self.last_publish_wall_s) * 1e3)
        else:
            self.step0_epoch_s = time.time()
        self.last_publish_wall_s = now

    def _mark_finished(self) -> None:
        self.finished = True
        self.finished_wall_s = time.monotonic()

    def _try_sync_step(self) -> None:
        raise NotImplementedError

    # -- inputs of one ego -----------------------------------------------------------------
    def _on_control(self, ego: EgoInputs, msg: Control) -> None:
        if self.finished:
            return
        ego.take_control(msg, self.sim_dt_s)
        if self.cfg.clock_mode == "sync":
            self._try_sync_step()

    def _on_decision(self, ego: EgoInputs, msg: Decision) -> None:
        ego.stats.decisions.setdefault(msg.decision_id, msg.source)

    def _on_planner_status(self, ego: EgoInputs, msg: PlannerStatus) -> None:
        ego.take_status(msg)
        if self.cfg.clock_mode == "sync" and not self.finished:
            self._try_sync_step()

    @property
    def sim_dt_s(self) -> float:
        raise NotImplementedError

    @staticmethod
    def publish_odom_mirror(pub: Any, ego: EgoState, child_frame: str) -> None:
        """The ego's Odometry mirror for ROS tools, built only when someone listens (~0.07
        ms a step), as the MPC's RViz mirrors; a subscriber gets it from the next step on."""
        if pub.get_subscription_count():
            pub.publish(odometry(ego, child_frame))


class BridgeNode(BridgeBase):
    def __init__(self) -> None:
        super().__init__(BridgeConfig)
        self.cfg: BridgeConfig
        if self.cfg.ego_id:
            self.ego_id = self.cfg.ego_id
        run_dir = self.run_dir
        self.sim = SumoSim(work_dir=run_dir / "scene")
        if self.cfg.scene_file:
            # imported here: it pulls in sumolib / traci, ~0.1 s of every other start-up
            from lmpc_bridge.scenarios.external import build_external_scene

            self.get_logger().info(
                f"building scene from {self.cfg.scene_file} ({self.cfg.clock_mode} clock)")
            scene = build_external_scene(self.cfg.scene_file, work_dir=run_dir / "scene")
            self.sim.reset_scene(scene)
            for line in self.sim.traffic_warnings():  # e.g. demand that starts hours later
                self.get_logger().warning(f"traffic: {line}")
        else:
            self.get_logger().info(
                f"building scene {self.cfg.scenario} seed {self.cfg.seed} "
                f"({self.cfg.clock_mode} clock)"
            )
            self.sim.reset(self.cfg.scenario, self.cfg.seed, max_time_s=self.cfg.max_time_s)

        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, lmpc_qos.CLOCK)
        self.pub_map = self.json_publisher(MapSnapshot, topics.MAP, lmpc_qos.LATCHED)
        self.pub_ego = self.json_publisher(EgoState, topics.EGO_STATE)
        self.pub_agents = self.json_publisher(AgentArray, topics.AGENTS)
        self.pub_signals = self.json_publisher(SignalStates, topics.SIGNALS)
        self.pub_episode = self.json_publisher(EpisodeStatus, topics.EPISODE, lmpc_qos.LATCHED)
        self.pub_odom = self.create_publisher(
            Odometry, self.topic(topics.EGO_ODOM), lmpc_qos.MIRROR)

        self.inputs = EgoInputs()
        self.json_subscription(Control, topics.CONTROL,
                               functools.partial(self._on_control, self.inputs))
        self.json_subscription(Decision, topics.DECISION,
                               functools.partial(self._on_decision, self.inputs))
        self.json_subscription(PlannerStatus, topics.PLANNER_STATUS,
                               functools.partial(self._on_planner_status, self.inputs))

        self.pub_map.publish(self.sim.map)
        self._start_timers(self.sim.dt_s)
        self.get_logger().info(f"run folder {self.run_dir}")

    @property
    def sim_dt_s(self) -> float:
        return self.sim.dt_s

    # -- stepping ------------------------------------------------------------------------
    def _ready_to_start(self) -> Optional[str]:
        """None when every participant is connected, else what we wait for."""
        need_subs = (2 if self.cfg.wait_for_planner else 1) + self.cfg.extra_subscribers
        have_subs = self.pub_ego.subscription_count()
        if have_subs < need_subs:
            return f"subscribers of {self.pub_ego.topic} ({have_subs} of {need_subs})"
        control, status = self.topic(topics.CONTROL), self.topic(topics.PLANNER_STATUS)
        if self.count_publishers(control) < 1:
            return f"a publisher on {control} (mpc_controller)"
        if self.cfg.wait_for_planner and self.count_publishers(status) < 1:
            return f"a publisher on {status} (llm_planner)"
        return None

    def _publish_step(self) -> None:
        # The decision barrier is a sync-mode device (docs/ARCHITECTURE.md): in realtime
        # mode a decision the MPC never received (it joined late, DDS lost it) would make
        # the MPC wait BARRIER_WAIT_S on every step until the next decision, so every
        # control would come too late. Realtime decisions act when they arrive.
        required = self.inputs.required_decision_id if self.cfg.clock_mode == "sync" else None
        times = self.stage_times
        with times.stage("observe"):
            obs: Observation = self.sim.observe(required_decision_id=required)
        t = obs.stamp_s
        self.pub_clock.publish(Clock(clock=_stamp(t)))
        self._step_published()
        self.inputs.timing[obs.ego.seq] = _StepTiming(published_wall_s=self.last_publish_wall_s)
        # the ego state last: the MPC and the planner pair the three by stamp and start on
        # the ego state, so they decode the agents while the bridge still publishes
        self.pub_agents.publish(obs.agents)
        self.pub_signals.publish(obs.signals)
        self.pub_ego.publish(obs.ego)
        with times.stage("publish odometry"):
            self._publish_odom(obs.ego)
        self.waiting_since = time.monotonic()
        if t >= self.next_progress_s:
            self.next_progress_s = t + self.cfg.progress_period_s
            self.get_logger().info(
                f"progress t={t:.1f}s v={obs.ego.v_mps:.1f}m/s "
                f"dist_to_target={obs.ego.dist_to_target_m:.1f}m "
                f"decisions={len(self.inputs.stats.decisions)}"
            )
            self.pub_episode.publish(self.sim.status())

    def _publish_odom(self, ego: EgoState) -> None:
        self.publish_odom_mirror(self.pub_odom, ego, "ego")

    def _control_for_current_step(self) -> Optional[Control]:
        return control_for_step(self.inputs.latest_control, self.sim.time_s, self.cfg)

    def _advance(self, control: Optional[Control]) -> None:
        k = self.sim.step_index
        if control is None:
            self.log_event("late-control", f"no control for step {k} (t={self.sim.time_s:.1f}s): "
                           "braking the ego at a bounded deceleration")
        timing = self.inputs.applied(k, control)
        if timing is not None and timing.control_wall_s is not None:
            self.stage_times.add(CONTROL_WAIT_STAGE,
                                 (timing.control_wall_s - timing.published_wall_s) * 1e3)
            self.stage_times.add("wait: after the control (planner status)",
                                 (time.monotonic() - timing.control_wall_s) * 1e3)
        with self.stage_times.stage("sim step"):
            self.sim.step(control)
        status = self.sim.status()
        if status.outcome != "running":
            self._finish(status)
        else:
            self._publish_step()

    def _planner_gone(self) -> bool:
        """The planner took part but left the graph (DDS dropped its publisher)."""
        gone = self.count_publishers(self.topic(topics.PLANNER_STATUS)) < 1
        if gone:
            self.log_event("planner-gone", "the planner left the graph: stepping without waiting "
                           "for it (the MPC falls back to baseline when its decision expires)")
        return gone

    def _controller_gone(self) -> bool:
        gone = self.count_publishers(self.topic(topics.CONTROL)) < 1
        if gone:
            self.log_event("mpc-gone", "no publisher on the control topic: the ego brakes at a "
                           "bounded deceleration each step, the simulation goes on")
        return gone

    def _planner_done(self) -> bool:
        if not self.cfg.wait_for_planner \
                or self.inputs.planner_stamp_s >= self.sim.time_s - 1e-6:
            return True
        return self._planner_gone()

    def _try_sync_step(self) -> None:
        if not self.started or self.finished:
            return
        if self._control_for_current_step() is None:
            return
        if not self._planner_done():
            return
        self._advance(self._control_for_current_step())

    def _sync_watchdog(self) -> None:
        if self._ended() or self._starting():
            return
        waited = time.monotonic() - self.waiting_since
        have_control = self._control_for_current_step() is not None
        if have_control:
            if self._planner_done():  # it may have left the graph meanwhile
                self._advance(self._control_for_current_step())
            elif waited > self.cfg.planner_timeout_s:
                self.log_event(
                    "late-planner", f"planner status for t={self.sim.time_s:.1f}s missing "
                    f"after {self.cfg.planner_timeout_s:.0f}s wall: stepping on")
                self._advance(self._control_for_current_step())
            return
        if self.sim.step_index > 0 and self._controller_gone():
            self._advance(None)
        elif waited > self.cfg.control_timeout_s:
            if self.sim.step_index == 0:
                # Discovery may still be settling: offer step 0 again rather than count it late.
                self._publish_step()
                return
            self._advance(None)

    def _realtime_tick(self) -> None:
        # before step 0 the participants are waited for as in sync mode (bounded by
        # startup_timeout_s): otherwise the ego brakes from its initial speed while the
        # MPC warms up
        if self._ended() or self._starting():
            return
        self._advance(self._control_for_current_step())

    # -- end of episode ------------------------------------------------------------------
    def _finish(self, status: EpisodeStatus) -> None:
        self._mark_finished()
        self.pub_episode.publish(status)
        self.get_logger().info(
            f"episode ended: {status.outcome} at t={status.stamp_s:.1f}s {status.detail}".rstrip()
        )
        self._write_episode(status)

    def _write_episode(self, status: EpisodeStatus) -> None:
        sources = list(self.inputs.stats.decisions.values())
        record = self.sim.record()
        warnings = [f"traffic: {line}" for line in self.sim.traffic_warnings()]
        for line in warnings:
            self.get_logger().warning(line)
        out = {
            "scenario": self.sim.scene.family,
            "seed": self.sim.scene.seed,
            "clock_mode": self.cfg.clock_mode,
            "outcome": status.outcome,
            "detail": status.detail,
            "collided_with": status.collided_with,
            "sim_time_s": status.stamp_s,
            "metrics": status.metrics.model_dump(),
            "decisions": len(sources),
            "fallbacks": sum(1 for s in sources if s == "fallback"),
            "late_controls": self.inputs.stats.late_controls,
            # vehicles SUMO inserted onto the ego's body, held back (lmpc_bridge.insertion)
            "held_insertions": record.held_insertions,
            # the ego stood across two lanes: its shadow on the second (lmpc_bridge.shadow)
            "shadows": record.shadows,
            "control_modes": self.inputs.stats.control_modes,
            "mpc_solve_ms": _percentiles(self.inputs.stats.solve_ms),
            "mpc_attended_agents": _percentiles(self.inputs.stats.attended),
            "control_latency_ms": _wait_percentiles(self.stage_times.summary()),
            "dropped_messages": self.counters.get("dropped_messages", 0),
            "step0_epoch_s": self.step0_epoch_s,
            "end_epoch_s": time.time(),
            "profile_ms": self.stage_times.summary(),
            "warnings": warnings,
            # a scene file's run is rebuilt from the file, not a family (render.py run)
            "scene_file": self.cfg.scene_file or None,
            "record": record.to_json(),
        }
        path = self.run_dir / "episode.json"
        path.write_text(json.dumps(out, indent=1))
        self.get_logger().info(f"episode record written to {path}")

    def _diagnostics(self) -> None:
        mode = "finished" if self.finished else ("running" if self.started else "waiting")
        self.publish_diagnostics(0, mode, {
            "sim_time_s": round(self.sim.time_s, 2),
            "late_controls": self.inputs.stats.late_controls,
            "decisions": len(self.inputs.stats.decisions),
        })

    def destroy_node(self) -> None:
        self.sim.close()
        super().destroy_node()


SCENE_ERROR_EXIT = 4
"""Exit code of the bridge when its scene cannot be built or started."""


def main(args: Optional[list[str]] = None) -> int:
    try:
        return run_node(BridgeNode, args)
    except (SceneError, SimError) as exc:
        # One clear line (the launcher shows it); SUMO is already closed by reset_scene.
        print(f"scene error: {exc}", file=sys.stderr, flush=True)
        return SCENE_ERROR_EXIT


if __name__ == "__main__":
    raise SystemExit(main())
