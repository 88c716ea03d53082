"""ROS 2 node ``mpc_controller``: a thin wrapper around :class:`MpcController`.

One control per received ego state, once agents and signals with the same stamp
are in (or after a short wall wait, then the newest ones), and - sync barrier -
once the decision named by ``ego_state.required_decision_id`` has arrived (up to
1 s wall, then it goes on and counts it). Watchdog: if ``/clock`` does not move
for 2 s wall, it says so once and publishes nothing that moves the car; if the bridge
has then left the graph for ``bridge_gone_exit_s`` (default 10 s) the node exits.
"""
from __future__ import annotations

import signal
import time
from typing import Optional

import rclpy
from nav_msgs.msg import Path
from geometry_msgs.msg import Point, PoseStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from visualization_msgs.msg import Marker, MarkerArray

from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import LmpcNode, run_node
from lmpc_msgs_py.messages import AgentArray, Control, Decision, EgoState, MapSnapshot, \
    SignalStates
from lmpc_msgs_py.observation import Observation
from lmpc_mpc.config import MpcConfigError, load_mpc_config
from lmpc_mpc.controller import MpcController
from lmpc_mpc.mirrors import MirrorLine, agent_lines, candidate_lines
from lmpc_mpc.reference import index_map

PAIR_WAIT_S = 0.2
"""Wall time to wait for agents / signals of the ego state's stamp before using the newest."""
BARRIER_WAIT_S = 1.0
UNMATCHED_WAIT_S = 10.0
"""Sync barrier: how long to wait for a required decision while no decision writer has
matched this node's reader yet. Such a decision cannot have arrived: the planner published
it (transient local) before DDS discovery had matched the two, and it is delivered on the
match, which took over 1 s on a loaded CI machine (the first two decisions of an episode
arrived together at ~5 s of sim and were both too late: test_graph_instruction failed)."""
CLOCK_WATCHDOG_S = 2.0
TICK_S = 0.01
HOLD_STALE_S = 0.35
"""A coordination hold message older than this (sim) vs the ego state is not applied."""


class MpcNode(LmpcNode):
    """Subscribes map, ego_state, agents, signals, decision; publishes control and mirrors."""

    def __init__(self) -> None:
        super().__init__("mpc_controller")
        self.declare_parameter("config_file", "", ParameterDescriptor(
            description="MPC config YAML ('' = the packaged default)"))
        self.declare_parameter("ego_id", "", ParameterDescriptor(
            description="ego namespace ('' = single ego, topics under /lmpc)"))
        ego_id = self.get_parameter("ego_id").get_parameter_value().string_value
        self.ego_id = ego_id or None
        self.declare_bridge_gone_exit()
        self.declare_profile_output()
        self.declare_parameter("clock_mode", "", ParameterDescriptor(
            description="the bridge's clock mode: 'realtime' enforces the solver's wall-time "
                        "budget, 'sync' only counts overruns ('' = the config's "
                        "enforce_time_budget)"))
        path = self.get_parameter("config_file").get_parameter_value().string_value
        self.config = load_mpc_config(path or None)
        clock_mode = self.get_parameter("clock_mode").get_parameter_value().string_value
        if clock_mode not in ("", "sync", "realtime"):
            raise MpcConfigError(f"parameter clock_mode must be '', 'sync' or 'realtime', "
                                 f"got {clock_mode!r}")
        realtime = None if clock_mode == "" else clock_mode == "realtime"
        self.controller = MpcController(self.config, realtime=realtime)
        # build every compiled problem size now (~1.5 s), not inside the first steps
        self.controller.solver.warm_up()
        self._map: Optional[MapSnapshot] = None
        self._agents: dict[float, AgentArray] = {}
        self._signals: dict[float, SignalStates] = {}
        self._pending: list[tuple[EgoState, float]] = []  # (ego, wall time received)
        self._decision_ids: set[str] = set()
        self._barrier_given_up: dict[str, None] = {}
        """Decisions the sync barrier stopped waiting for (insertion-ordered, bounded)."""
        self._refusal: Optional[str] = None
        """Why the last refused decision was refused (diagnostics message), if any."""
        self._last_clock_s: Optional[float] = None
        self._last_clock_wall = time.monotonic()
        self._frozen = False
        self._seen_ego = False
        self._waiting_logged = False
        self._pub = self.json_publisher(Control, topics.CONTROL)
        self._ref_pub = self.create_publisher(Path, self.topic(topics.REFERENCE_PATH),
                                              lmpc_qos.MIRROR)
        self._pred_pub = self.create_publisher(Path, self.topic(topics.PREDICTED_PATH),
                                               lmpc_qos.MIRROR)
        self._cand_pub = self.create_publisher(MarkerArray, self.topic(topics.CANDIDATE_MARKERS),
                                               lmpc_qos.MIRROR)
        self._agent_pred_pub = self.create_publisher(
            MarkerArray, self.topic(topics.AGENT_PREDICTION_MARKERS), lmpc_qos.MIRROR)
        self.json_subscription(MapSnapshot, topics.MAP, self._on_map, lmpc_qos.LATCHED,
                               check_seq=False)
        self.json_subscription(EgoState, topics.EGO_STATE, self._on_ego)
        self.json_subscription(AgentArray, topics.AGENTS, self._on_agents)
        self.json_subscription(SignalStates, topics.SIGNALS, self._on_signals)
        self._decision_sub = self.json_subscription(Decision, topics.DECISION,
                                                    self._on_decision, lmpc_qos.DECISION_IN)
        self._holds: dict[float, AgentArray] = {}
        if self.ego_id:  # a multi-ego graph: the coordination's hold point (issue 18)
            self.json_subscription(AgentArray, topics.COORD_HOLD, self._on_hold)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(TICK_S, self._tick, clock=steady)
        self.create_timer(1.0, self._diagnostics, clock=steady)
        generated: set[int] = getattr(self.controller.solver, "generated_sizes", set)()
        self.get_logger().info(
            f"mpc_controller up: solver {self.config.solver} ({len(generated)} of "
            f"{len(self.config.agent_slot_sizes)} problem sizes as generated C), "
            f"horizon {self.config.horizon}, "
            f"decision space {self.config.decision_space.describe()}; "
            f"waiting for {self.topic(topics.MAP)} and {self.topic(topics.EGO_STATE)} "
            "(no control is published before both arrive)")

    # -- inputs --------------------------------------------------------------------------
    def _on_map(self, msg: MapSnapshot) -> None:
        self._map = msg
        with self.stage_times.stage("map lookups (once per map)"):
            index_map(msg)  # not in the first control step (~10 ms on a city map)

    def _on_ego(self, msg: EgoState) -> None:
        # a new ego state is the simulation advancing too (DDS does not order it
        # with /clock, and step 0 has /clock = 0, the same as "no clock yet")
        self._last_clock_wall = time.monotonic()
        if self._frozen:
            self.get_logger().info("simulation advancing again")
        self._frozen = False
        self._seen_ego = True
        self._pending.append((msg, time.monotonic()))
        self._tick()

    def _on_agents(self, msg: AgentArray) -> None:
        self._agents[msg.stamp_s] = msg
        self._trim(self._agents)
        self._tick()

    def _on_signals(self, msg: SignalStates) -> None:
        self._signals[msg.stamp_s] = msg
        self._trim(self._signals)
        self._tick()

    def _on_decision(self, msg: Decision) -> None:
        self._decision_ids.add(msg.decision_id)  # refused or not, the barrier saw it
        refusal = self.controller.on_decision(msg)
        if refusal is not None:
            # another decision space: the graph is miswired, say so loudly (throttled);
            # counted as a drop on the topic and as refused_decisions
            topic = self.topic(topics.DECISION)
            self.counters["dropped_messages"] += 1
            self.counters[f"dropped:{topic}"] += 1
            self._refusal = refusal
            self.log_event("decision_space", f"REFUSED decision {msg.decision_id} on {topic}: "
                           f"{refusal}", level="error")
        self._tick()

    def _on_hold(self, msg: AgentArray) -> None:
        self._holds[msg.stamp_s] = msg
        self._trim(self._holds)

    def _with_holds(self, agents: AgentArray, stamp_s: float) -> AgentArray:
        """``agents`` plus the virtual obstacles of the planner's newest hold message not
        after ``stamp_s`` and at most ``HOLD_STALE_S`` older (coordination_wiring.py)."""
        hold = self._newest(self._holds, stamp_s)
        if hold is None or not hold.agents or stamp_s - hold.stamp_s > HOLD_STALE_S + 1e-9:
            return agents
        self.counters["hold_steps"] += 1
        ids = {a.id for a in agents.agents}
        extra = tuple(a for a in hold.agents if a.id not in ids)
        return agents.model_copy(update={"agents": tuple(sorted(
            (*agents.agents, *extra), key=lambda a: a.id))})

    @staticmethod
    def _trim(store: dict) -> None:
        for key in sorted(store)[:-20]:
            del store[key]

    def _clock_s(self) -> float:
        now = self.get_clock().now().nanoseconds * 1e-9
        if self._last_clock_s is None or now != self._last_clock_s:
            self._last_clock_s = now
            self._last_clock_wall = time.monotonic()
            if self._frozen:
                self.get_logger().info("simulation advancing again")
            self._frozen = False
        return now

    # -- the step ------------------------------------------------------------------------
    def _tick(self) -> None:
        now_s = self._clock_s()
        if time.monotonic() - self._last_clock_wall > CLOCK_WATCHDOG_S and self._seen_ego:
            if not self._frozen:
                self.get_logger().warn(
                    f"simulation not advancing (/clock still for {CLOCK_WATCHDOG_S:.0f} s "
                    "wall): publishing no control")
                self.counters["clock_frozen"] += 1
            self._frozen = True
            self._pending.clear()
            self.exit_if_bridge_gone(True)
            return
        if self._map is None or not self._pending:
            if self._pending and not self._waiting_logged:
                self.get_logger().info("waiting for the map on " + self.topic(topics.MAP))
                self._waiting_logged = True
            del self._pending[:-1]  # commands nothing until the map is there
            return
        while self._pending:
            ego, wall = self._pending[0]
            waited = time.monotonic() - wall
            agents = self._agents.get(ego.stamp_s)
            signals = self._signals.get(ego.stamp_s)
            if (agents is None or signals is None) and waited < PAIR_WAIT_S:
                return
            need = ego.required_decision_id
            if need is not None and need not in self._decision_ids \
                    and need not in self._barrier_given_up:
                matched = self._decision_sub.get_publisher_count() > 0
                if waited < (BARRIER_WAIT_S if matched else UNMATCHED_WAIT_S):
                    return
                # once per decision: the next steps name it too (until the planner's next
                # one), and waiting again on each would cost every step BARRIER_WAIT_S
                self.counters["barrier_timeouts"] += 1
                self._barrier_given_up[need] = None
                if len(self._barrier_given_up) > 64:
                    del self._barrier_given_up[next(iter(self._barrier_given_up))]
                self.log_event("barrier", f"decision {need!r} not received within "
                               f"{waited:.0f} s ({'a' if matched else 'no'} decision writer "
                               "matched); computing without it (not waiting for it again)")
            if agents is None:
                agents = self._newest(self._agents, ego.stamp_s)
                self.counters["unpaired_agents"] += 1
            if signals is None:
                signals = self._newest(self._signals, ego.stamp_s)
                self.counters["unpaired_signals"] += 1
            self._pending.pop(0)
            self.stage_times.add("wait: inputs paired (ego received to compute)",
                                 (time.monotonic() - wall) * 1e3)
            if agents is None:
                agents = AgentArray(stamp_s=max(0.0, ego.stamp_s - 1e3), seq=0)
            if signals is None:
                signals = SignalStates(stamp_s=ego.stamp_s, seq=0)
            if self._holds:
                agents = self._with_holds(agents, ego.stamp_s)
            self._compute(Observation(map=self._map, ego=ego, agents=agents, signals=signals),
                          now_s)

    @staticmethod
    def _newest(store: dict, stamp_s: float):
        older = [k for k in store if k <= stamp_s]
        return store[max(older)] if older else None

    def _compute(self, obs: Observation, now_s: float) -> None:
        t0 = time.perf_counter()
        ctl = self.controller.compute(obs, now_s=now_s if now_s > 0.0 else None)
        compute_ms = (time.perf_counter() - t0) * 1e3
        self.stage_times.add("solve", ctl.solve_time_ms)
        self.stage_times.add("controller without the solve (set-up, checks)",
                             max(0.0, compute_ms - ctl.solve_time_ms))
        if self.controller.route_override_note is not None:
            self.log_event("route", self.controller.route_override_note)
            self.controller.route_override_note = None
        if ctl.mode == "brake" and "stale" in ctl.solver_status:
            self.log_event("stale", f"braking: {ctl.solver_status}")
        if ctl.mode in ("shifted", "brake"):
            self.counters["fallbacks"] += 1
        self._pub.publish(ctl)
        with self.stage_times.stage("mirrors (paths, markers)"):
            self._publish_paths(obs)

    def _publish_paths(self, obs: Observation) -> None:
        """The reference and predicted paths, candidates and agent forecasts for RViz /
        a recorder: built only for topics someone subscribes to (they cost more than the
        solve: ~6 ms a step, docs/RESULTS.md "Where the time goes")."""
        stamp = self.get_clock().now().to_msg()
        for pub, pts in ((self._ref_pub, self.controller.reference_path),
                         (self._pred_pub, self.controller.predicted)):
            if pub.get_subscription_count() == 0:
                continue
            msg = Path()
            msg.header.frame_id = "map"
            msg.header.stamp = stamp
            if pts is not None:
                for row in pts[:: max(1, len(pts) // 100)]:
                    ps = PoseStamped()
                    ps.header = msg.header
                    ps.pose.position.x = float(row[0])
                    ps.pose.position.y = float(row[1])
                    msg.poses.append(ps)
            pub.publish(msg)
        self._publish_markers(obs, stamp)

    def _publish_markers(self, obs: Observation, stamp) -> None:
        """The candidates and the agents' predictions as MarkerArrays (frame ``map``).
        Each array starts with a DELETEALL so lines of agents gone out of view vanish."""
        ctl = self.controller
        if self._cand_pub.get_subscription_count() == 0 \
                and self._agent_pred_pub.get_subscription_count() == 0:
            return
        cands = candidate_lines(obs.map, obs.ego, lookahead_m=self.config.lookahead_m,
                                reference_path=ctl.reference_path,
                                reference_id=ctl.reference_id)
        preds = agent_lines(obs.agents.agents, ctl.agent_predictions,
                            horizon=self.config.horizon, dt_s=self.config.dt_s)
        for pub, lines in ((self._cand_pub, cands), (self._agent_pred_pub, preds)):
            arr = MarkerArray()
            clear = Marker()
            clear.header.frame_id = "map"
            clear.header.stamp = stamp
            clear.action = Marker.DELETEALL
            arr.markers.append(clear)
            arr.markers.extend(self._marker(line, stamp) for line in lines)
            pub.publish(arr)

    @staticmethod
    def _marker(line: MirrorLine, stamp) -> Marker:
        m = Marker()
        m.header.frame_id = "map"
        m.header.stamp = stamp
        m.ns = line.ns
        m.id = line.marker_id
        m.type = Marker.LINE_STRIP
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.scale.x = float(line.width_m)
        m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in line.rgba)
        m.text = line.label[:100]
        m.points = [Point(x=float(x), y=float(y), z=0.0) for x, y in line.points_m]
        return m

    def _diagnostics(self) -> None:
        self._clock_s()
        st = self.controller.stats()
        level = 0 if st.mode in ("decision", "baseline", "idle") else 1
        if self._frozen:
            level = 1
        if self._frozen:
            message = "simulation not advancing"
        elif not self._seen_ego:
            message = f"waiting for {self.topic(topics.EGO_STATE)}"
        else:
            message = f"mode {st.mode}"
        if self._refusal is not None:
            level, message = 2, f"decisions refused: {self._refusal}"
        self.publish_diagnostics(level, message,
                                 {"mode": st.mode, "steps": st.steps,
                                  "solver_failures": st.solver_failures,
                                  "fallbacks": st.fallbacks, "shifted": st.shifted,
                                  "brakes": st.brakes, "stale_inputs": st.stale_inputs,
                                  "floor_additions": st.floor_additions,
                                  "hedged": st.hedged,
                                  "route_overrides": st.route_overrides,
                                  "stale_steps": st.stale_steps,
                                  "stale_agent_steps": st.stale_agent_steps,
                                  "go_refused": st.go_refused,
                                  "brake_refused": st.brake_refused,
                                  "refused_decisions": st.refused_decisions,
                                  "decision_space": self.config.decision_space.describe(),
                                  "over_budget": st.over_budget})


def _sigterm(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def main(args: Optional[list[str]] = None) -> int:
    """Console script ``mpc_controller``."""
    signal.signal(signal.SIGTERM, _sigterm)
    try:
        return run_node(MpcNode, args)
    except MpcConfigError as exc:
        print(f"mpc_controller: {exc}")
        rclpy.try_shutdown()
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
