"""The planner node's coordination topics (issue 18; rclpy only through the node it is given).

A planner of a multi-ego graph started with ``coordination`` ``distributed`` or
``central`` gets an :class:`~lmpc_llm_planner.coordination.link.EgoLink` and these topics:

- publishes its ``EgoStatus`` on the shared ``/coordination/status`` every step (before
  its decision and its planner status, so the peers and the coordinator hear it before
  the bridge steps on);
- publishes a last status, ``done``, when its ego's ``episode`` says the ego left the
  episode (the peers stop waiting for it);
- subscribes ``/coordination/status`` (the peers') and ``/coordination/directive``
  (the coordinator's). A directive out of schema is dropped by the codec, a directive
  for an unknown ego by the link: both counted as ``directives_refused`` (diagnostics)
  and logged (throttled);
- publishes, per step, the virtual obstacles its coordination put in its observation
  (the hold point of a ``yield``) on ``/<ego>/lmpc/coordination/hold`` for its MPC,
  which takes them into its own observation (``lmpc_mpc.mpc_node``). The MPC computes
  control k before the planner has processed observation k, so it acts on the hold of
  step k-1: the same one-step lag as a decision (docs/ARCHITECTURE.md timing rule).
"""
from __future__ import annotations

from typing import Any, Callable, Optional

from std_msgs.msg import String

from lmpc_msgs_py import qos as lmpc_qos
from lmpc_msgs_py import topics
from lmpc_msgs_py.base_node import JsonPublisher, LmpcNode
from lmpc_msgs_py.codec import DecodeError, decode
from lmpc_msgs_py.coordination import Directive, EgoStatus
from lmpc_msgs_py.messages import AgentArray, Decision, EpisodeStatus
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.coordination.link import EgoLink


class CoordinationWiring:
    """See the module docstring."""

    def __init__(self, node: LmpcNode, *, ego_id: str, ego_ids: list[str], mode: str,
                 space: DecisionSpace, wall_clock: Any, on_silence: str = "distributed",
                 on_peer: Optional[Callable[[], None]] = None) -> None:
        """``wall_clock``: an rclpy steady clock for the connect timer (the node's clock is
        sim time, and ``/clock`` starts only once the coordination is connected)."""
        self.node = node
        self._on_peer = on_peer
        self.link = EgoLink(ego_id, ego_ids, mode, space, on_silence=on_silence)
        self._status_pub = node.json_publisher(EgoStatus, topics.COORD_STATUS)
        self._hold_pub: Optional[JsonPublisher[AgentArray]] = None
        self._hold_seq = 0
        self._status_sub = node.json_subscription(EgoStatus, topics.COORD_STATUS,
                                                  self._on_status, shared=True)
        node.json_subscription(EpisodeStatus, topics.EPISODE, self._on_episode,
                               lmpc_qos.LATCHED, check_seq=False)
        self._directive_sub = node.create_subscription(
            String, topics.COORD_DIRECTIVE, self._on_directive, lmpc_qos.STREAM)
        self._connect_timer = node.create_timer(0.05, self._connect, clock=wall_clock)

    def _connect(self) -> None:
        """Create the hold publisher once this planner hears every ego's status publisher,
        its own status publisher is matched by every planner (and the coordinator), and,
        ``central``, it hears the coordinator's directive publisher: the bridge waits for
        the hold publishers before step 0, so no ego starts before its coordination is
        connected (DDS discovery can take seconds on a loaded machine)."""
        need_coordinator = self.link.mode == "central"
        readers = len(self.link.known) + (1 if need_coordinator else 0)
        if self._status_sub.get_publisher_count() < len(self.link.known) \
                or self._status_pub.subscription_count() < readers or (
                need_coordinator and self._directive_sub.get_publisher_count() < 1):
            return  # both sides of each match: a reader that sees a writer is not enough
        self._hold_pub = self.node.json_publisher(AgentArray, topics.COORD_HOLD)
        self._connect_timer.cancel()
        self.node.get_logger().info("coordination connected: every ego's status"
                                    + (" and the coordinator" if need_coordinator else ""))

    def _on_status(self, st: EgoStatus) -> None:
        self.link.on_status(st)
        if self._on_peer is not None and st.ego_id != self.link.ego_id:
            self._on_peer()  # the step this planner holds may be complete now

    def _on_episode(self, ep: EpisodeStatus) -> None:
        """This ego's episode ended: tell the peers (a ``done`` status), so none waits for
        a status of it that will not come."""
        status = self.link.leave(ep.stamp_s)
        if status is not None:
            self._status_pub.publish(status)

    def ready(self, obs: Observation) -> bool:
        """Publish this step's status (once); whether the peers' statuses are all in."""
        status = self.link.report(obs)
        if status is not None:
            self._status_pub.publish(status)
        return not self.link.waiting_for(obs.stamp_s)

    def _on_directive(self, raw: String) -> None:
        try:
            d = decode(raw.data, Directive, topic=topics.COORD_DIRECTIVE)
        except DecodeError as exc:
            self.node.count_drop(topics.COORD_DIRECTIVE, exc.field, exc.reason)
            self.link.refuse(f"field '{exc.field}': {exc.reason}")
        else:
            self.link.on_directive(d)
        self._drain()

    def _drain(self) -> None:
        for line in self.link.events:
            self.node.log_event(f"coordination:{line[:40]}", line)
        self.link.events.clear()

    def before(self, obs: Observation) -> Observation:
        status, acted = self.link.prepare(obs)
        if status is not None:
            self._status_pub.publish(status)
        holds = self.link.holds(obs, acted)
        if self._hold_pub is None:
            self.node.log_event("coordination:unconnected", "coordination not connected yet: "
                                "no hold published for the MPC")
            return acted
        self._hold_pub.publish(AgentArray(stamp_s=obs.stamp_s, seq=self._hold_seq,
                                          sensing_range_m=obs.agents.sensing_range_m,
                                          agents=holds))
        self._hold_seq += 1
        self._drain()
        return acted

    def after(self, decision: Optional[Decision], obs: Observation) -> Optional[Decision]:
        return self.link.shape(decision, obs)

    def command_text(self, now_s: float) -> Optional[str]:
        """The command in force for this ego in words (None: none), for an LLM planner's
        prompt (``PlannerCore.on_command``), as in-process."""
        cmd = self.link.ego.in_force(now_s)
        return None if cmd is None else cmd.text()

    def counters(self) -> dict[str, Any]:
        return {f"coordination_{k}" if not k.startswith("directives") else k: v
                for k, v in self.link.stats().items()}
