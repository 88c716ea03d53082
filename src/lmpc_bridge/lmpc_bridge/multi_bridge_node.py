"""ROS 2 node `sumo_bridge` for a multi-ego scene (issue 18): N egos ``ego_1 … ego_N``.

The multi-ego counterpart of ``bridge_node.BridgeNode`` around
:class:`lmpc_bridge.multi_sim.MultiSumoSim` (the single-ego node is not changed; run_graph
starts this one when the scene has several egos). Each ego has its own topics under
``/<ego_id>/lmpc/`` (``lmpc_msgs_py.topics.topic``): map (latched), ego_state, agents,
signals, episode (latched: the ego's own outcome, published when IT ends), ego/odom; it
reads the ego's control, decision and planner status. One ``/clock``.

- ``sync``: step k+1 happens once every RUNNING ego's control for step k (and, with
  planners, each planner's status for step k) arrived. After ``control_timeout_s`` wall
  the step is taken with the controls there are: an ego whose control is missing brakes
  (bounded deceleration, ``MultiSumoSim.step`` with ``None``) and is counted late; the
  others drive on their controls. An ego whose MPC left the graph brakes every step
  without being waited for. A planner that is late (``planner_timeout_s``) or gone is not
  waited for (RELIABILITY.md, per ego).
- ``realtime``: steps paced by a wall timer; per ego the newest control not older than
  ``control_stale_s`` sim is applied, otherwise that ego brakes.

An ego that reached its target or collided leaves the episode (``MultiSumoSim``): its
topics fall silent after its final ``episode`` message; the episode ends when no ego
runs (or on a deadlock). ``run_dir/episode.json`` holds per-ego outcomes, metrics, late
controls and control latency (median / p99 / max) and the joint figures.
"""
from __future__ import annotations

import functools
import json
import sys
import time
from dataclasses import dataclass
from typing import Any, Literal, Optional

from nav_msgs.msg import Odometry
from pydantic import Field
from rosgraph_msgs.msg import Clock

from lmpc_bridge.bridge_node import (
    CONTROL_WAIT_STAGE,
    SCENE_ERROR_EXIT,
    BridgeBase,
    BridgeTiming,
    EgoInputs,
    _percentiles,
    _stamp,
    _StepTiming,
    control_for_step,
)
from lmpc_bridge.multi_sim import MultiSumoSim
from lmpc_bridge.scenarios import SceneError
from lmpc_bridge.sim import SimError
from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import JsonPublisher, run_node
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


class MultiBridgeConfig(BridgeTiming):
    """Parameters of the multi-ego bridge (``BridgeTiming`` plus these)."""

    scenario: str = "narrow"
    egos: int = Field(0, ge=0)
    """The number of egos the graph was started for (0: whatever the scene has); the
    bridge refuses a scene with another number."""
    coordination: Literal["none", "distributed", "central"] = "none"
    """With coordination, step 0 also waits until every planner and the coordinator are
    connected (their hold / directive publishers exist only then)."""


@dataclass(kw_only=True)
class _Ego(EgoInputs):
    """One ego's topics and inputs."""

    eid: str
    pub_map: JsonPublisher[MapSnapshot]
    pub_ego: JsonPublisher[EgoState]
    pub_agents: JsonPublisher[AgentArray]
    pub_signals: JsonPublisher[SignalStates]
    pub_episode: JsonPublisher[EpisodeStatus]
    pub_odom: object
    ended: bool = False


def _wait_stage(eid: str) -> str:
    return f"{CONTROL_WAIT_STAGE} {eid}"


class MultiBridgeNode(BridgeBase):
    def __init__(self) -> None:
        super().__init__(MultiBridgeConfig)
        self.cfg: MultiBridgeConfig
        self.get_logger().info(f"building scene {self.cfg.scenario} seed {self.cfg.seed} "
                               f"({self.cfg.clock_mode} clock, several egos)")
        self.sim = MultiSumoSim(work_dir=self.run_dir / "scene")
        self.sim.reset(self.cfg.scenario, self.cfg.seed, max_time_s=self.cfg.max_time_s)
        for line in self.sim.traffic_warnings():  # a vehicle SUMO refused at the start
            self.get_logger().warning(f"traffic: {line}")
        if self.cfg.egos and self.cfg.egos != len(self.sim.egos):
            n = len(self.sim.egos)
            self.sim.close()
            raise SimError(f"scene {self.cfg.scenario}/{self.cfg.seed} has {n} egos, the graph "
                           f"was started for {self.cfg.egos}")
        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, lmpc_qos.CLOCK)
        self.egos: dict[str, _Ego] = {}
        for eid in self.sim.egos:
            ego = _Ego(
                eid=eid,
                pub_map=self.json_publisher(MapSnapshot, topics.MAP, lmpc_qos.LATCHED, ego=eid),
                pub_ego=self.json_publisher(EgoState, topics.EGO_STATE, ego=eid),
                pub_agents=self.json_publisher(AgentArray, topics.AGENTS, ego=eid),
                pub_signals=self.json_publisher(SignalStates, topics.SIGNALS, ego=eid),
                pub_episode=self.json_publisher(EpisodeStatus, topics.EPISODE,
                                                lmpc_qos.LATCHED, ego=eid),
                pub_odom=self.create_publisher(Odometry, topics.topic(topics.EGO_ODOM, eid),
                                               lmpc_qos.MIRROR))
            self.egos[eid] = ego
            self.json_subscription(Control, topics.CONTROL,
                                   functools.partial(self._on_control, ego), ego=eid)
            self.json_subscription(Decision, topics.DECISION,
                                   functools.partial(self._on_decision, ego), ego=eid)
            self.json_subscription(PlannerStatus, topics.PLANNER_STATUS,
                                   functools.partial(self._on_planner_status, ego), ego=eid)
            ego.pub_map.publish(self.sim.egos[eid].map)
        self._start_timers(self.sim.dt_s)
        self.get_logger().info(f"egos {', '.join(self.egos)}; run folder {self.run_dir}")

    @property
    def sim_dt_s(self) -> float:
        return self.sim.dt_s

    # -- per-ego state -------------------------------------------------------------------
    def _running(self) -> list[_Ego]:
        return [self.egos[eid] for eid in self.sim.running_ids()]

    def _control(self, ego: _Ego) -> Optional[Control]:
        return control_for_step(ego.latest_control, self.sim.time_s, self.cfg)

    def _planner_done(self, ego: _Ego) -> bool:
        return not self.cfg.wait_for_planner or ego.planner_stamp_s >= self.sim.time_s - 1e-6

    def _gone(self, ego: _Ego, name: str, what: str) -> bool:
        gone = self.count_publishers(topics.topic(name, ego.eid)) < 1
        if gone:
            self.log_event(f"{what}-gone:{ego.eid}", f"{ego.eid}: no publisher on "
                           f"{topics.topic(name, ego.eid)} ({what} left the graph): "
                           + ("that ego brakes each step, the others drive on"
                              if what == "mpc" else "stepping without waiting for it"))
        return gone

    # -- stepping ------------------------------------------------------------------------
    def _ready_to_start(self) -> Optional[str]:
        need = (2 if self.cfg.wait_for_planner else 1)
        for ego in self.egos.values():
            have = ego.pub_ego.subscription_count()
            if have < need:
                return f"subscribers of {ego.pub_ego.topic} ({have} of {need})"
            control = topics.topic(topics.CONTROL, ego.eid)
            if self.count_publishers(control) < 1:
                return f"a publisher on {control} (mpc_controller of {ego.eid})"
            status = topics.topic(topics.PLANNER_STATUS, ego.eid)
            if self.cfg.wait_for_planner and self.count_publishers(status) < 1:
                return f"a publisher on {status} (llm_planner of {ego.eid})"
            hold = topics.topic(topics.COORD_HOLD, ego.eid)
            if self.cfg.coordination != "none" and self.count_publishers(hold) < 1:
                return f"a publisher on {hold} (the coordination of {ego.eid}'s planner)"
        if self.cfg.coordination == "central" \
                and self.count_publishers(topics.COORD_DIRECTIVE) < 1:
            return f"a publisher on {topics.COORD_DIRECTIVE} (coordinator)"
        return None

    def _publish_step(self) -> None:
        t = self.sim.time_s
        self.pub_clock.publish(Clock(clock=_stamp(t)))
        self._step_published()
        sync = self.cfg.clock_mode == "sync"
        for ego in self._running():
            with self.stage_times.stage("observe"):
                obs = self.sim.observe(ego.eid, required_decision_id=ego.required_decision_id
                                       if sync else None)
            ego.timing[obs.ego.seq] = _StepTiming(published_wall_s=time.monotonic())
            ego.pub_ego.publish(obs.ego)
            ego.pub_agents.publish(obs.agents)
            ego.pub_signals.publish(obs.signals)
            self.publish_odom_mirror(ego.pub_odom, obs.ego, ego.eid)
        self.waiting_since = time.monotonic()
        if t >= self.next_progress_s:
            self.next_progress_s = t + self.cfg.progress_period_s
            parts = [f"{e.eid} v={self.sim.egos[e.eid].pose.v_mps:.1f}m/s "
                     f"dist={self.sim.egos[e.eid].dist_to_target_m:.1f}m"
                     for e in self._running()]
            self.get_logger().info(f"progress t={t:.1f}s " + "; ".join(parts))

    def _advance(self, controls: dict[str, Optional[Control]]) -> None:
        k = int(round(self.sim.time_s / self.sim.dt_s))
        for ego in self._running():
            control = controls.get(ego.eid)
            if control is None:
                self.log_event(f"late-control:{ego.eid}", f"{ego.eid}: no control for step {k} "
                               f"(t={self.sim.time_s:.1f}s): braking that ego at a bounded "
                               "deceleration")
            timing = ego.applied(k, control)
            if timing is not None and timing.control_wall_s is not None:
                ms = (timing.control_wall_s - timing.published_wall_s) * 1e3
                self.stage_times.add(CONTROL_WAIT_STAGE, ms)
                self.stage_times.add(_wait_stage(ego.eid), ms)
        with self.stage_times.stage("sim step"):
            self.sim.step(controls)
        for ego in self.egos.values():
            run = self.sim.egos[ego.eid]
            if not run.running and not ego.ended:
                ego.ended = True
                status = self.sim.status(ego.eid)
                ego.pub_episode.publish(status)
                self.get_logger().info(f"{ego.eid}: {status.outcome} at t={status.stamp_s:.1f}s "
                                       f"{status.detail}".rstrip())
        if not self.sim.running:
            self._finish()
        else:
            self._publish_step()

    def _try_sync_step(self) -> None:
        if not self.started or self.finished:
            return
        running = self._running()
        if all(self._control(e) is not None and self._planner_done(e) for e in running):
            self._advance({e.eid: self._control(e) for e in running})

    def _sync_watchdog(self) -> None:
        if self._ended() or self._starting():
            return
        waited = time.monotonic() - self.waiting_since
        first = self.sim.time_s <= 1e-9
        running = self._running()
        no_control = [e for e in running if self._control(e) is None
                      and (first or not self._gone(e, topics.CONTROL, "mpc"))]
        no_planner = [e for e in running if not self._planner_done(e)
                      and not self._gone(e, topics.PLANNER_STATUS, "planner")]
        if not no_control and not no_planner:
            self._advance({e.eid: self._control(e) for e in running})
        elif no_control and waited > self.cfg.control_timeout_s:
            if first:
                self._publish_step()  # discovery may still be settling: offer step 0 again
                return
            self._advance({e.eid: self._control(e) for e in running})
        elif not no_control and waited > self.cfg.planner_timeout_s:
            self.log_event("late-planner", f"planner status for t={self.sim.time_s:.1f}s "
                           f"missing from {', '.join(e.eid for e in no_planner)} after "
                           f"{self.cfg.planner_timeout_s:.0f}s wall: stepping on")
            self._advance({e.eid: self._control(e) for e in running})

    def _realtime_tick(self) -> None:
        if self._ended() or self._starting():
            return
        self._advance({e.eid: self._control(e) for e in self._running()})

    # -- end of episode ------------------------------------------------------------------
    def _finish(self) -> None:
        self._mark_finished()
        self._write_episode()

    def _write_episode(self) -> None:
        profile = self.stage_times.summary()
        per_ego: dict[str, dict[str, Any]] = {}
        for eid, ego in self.egos.items():
            st, run = self.sim.status(eid), self.sim.egos[eid]
            sources = list(ego.stats.decisions.values())
            wait = profile.get(_wait_stage(eid))
            per_ego[eid] = {
                "outcome": st.outcome, "detail": st.detail, "collided_with": st.collided_with,
                "reached_at_s": run.reached_at_s, "metrics": st.metrics.model_dump(),
                "decisions": len(sources),
                "fallbacks": sum(1 for s in sources if s == "fallback"),
                "late_controls": ego.stats.late_controls,
                "control_modes": ego.stats.control_modes,
                "mpc_solve_ms": _percentiles(ego.stats.solve_ms),
                "mpc_attended_agents": _percentiles(ego.stats.attended),
                "control_latency_ms": {k: None if wait is None else wait[k]
                                       for k in ("median", "p99", "max")},
            }
        outcomes = [e["outcome"] for e in per_ego.values()]
        ids = set(self.egos)
        ego_hits = {tuple(sorted((eid, e["collided_with"]))) for eid, e in per_ego.items()
                    if e["outcome"] == "collision" and e["collided_with"] in ids}
        reached = [e["reached_at_s"] for e in per_ego.values()]
        joint = "reached" if all(o == "reached" for o in outcomes) else \
            "collision" if "collision" in outcomes else \
            "error" if "error" in outcomes else "timeout"
        all_sources = [s for e in self.egos.values() for s in e.stats.decisions.values()]
        total_wait = profile.get(CONTROL_WAIT_STAGE)
        out = {
            "scenario": self.sim.scene.family, "seed": self.sim.scene.seed,
            "clock_mode": self.cfg.clock_mode, "egos": per_ego, "outcome": joint,
            "detail": "; ".join(f"{eid}: {e['outcome']} {e['detail']}".rstrip()
                                for eid, e in per_ego.items()),
            "deadlock": self.sim.deadlock,
            "ego_collisions": len(ego_hits),
            "clear_s": max(reached) if all(r is not None for r in reached) else None,
            "joint_oc": sum(e["metrics"]["overall_cost"] for e in per_ego.values()),
            "collided_with": None,
            "sim_time_s": self.sim.time_s,
            "metrics": {"collisions": sum(1 for o in outcomes if o == "collision")},
            "decisions": len(all_sources),
            "fallbacks": sum(1 for s in all_sources if s == "fallback"),
            "late_controls": sum(e.stats.late_controls for e in self.egos.values()),
            "mpc_solve_ms": _percentiles([v for e in self.egos.values()
                                          for v in e.stats.solve_ms]),
            "control_latency_ms": {k: None if total_wait is None else total_wait[k]
                                   for k in ("median", "p99", "max")},
            "dropped_messages": self.counters.get("dropped_messages", 0),
            "step0_epoch_s": self.step0_epoch_s, "end_epoch_s": time.time(),
            "profile_ms": profile,
            "warnings": [f"traffic: {line}" for line in self.sim.traffic_warnings()],
            "records": {eid: self.sim.record(eid).to_json() for eid in self.egos},
        }
        path = self.run_dir / "episode.json"
        path.write_text(json.dumps(out, indent=1))
        self.get_logger().info(f"episode ended: {joint} at t={self.sim.time_s:.1f}s; "
                               f"record written to {path}")

    def _diagnostics(self) -> None:
        mode = "finished" if self.finished else ("running" if self.started else "waiting")
        extra: dict[str, object] = {"sim_time_s": round(self.sim.time_s, 2),
                                    "egos": ",".join(self.egos)}
        for eid, ego in self.egos.items():
            extra[f"late_controls:{eid}"] = ego.stats.late_controls
        self.publish_diagnostics(0, mode, extra)

    def destroy_node(self) -> None:
        self.sim.close()
        super().destroy_node()


def main(args: Optional[list[str]] = None) -> int:
    try:
        return run_node(MultiBridgeNode, args)
    except (SceneError, SimError) as exc:
        print(f"scene error: {exc}", file=sys.stderr, flush=True)
        return SCENE_ERROR_EXIT


if __name__ == "__main__":
    raise SystemExit(main())
