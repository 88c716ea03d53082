"""``llm_planner`` node: a thin ROS wrapper around :class:`PlannerCore`.

Parameters (mapped once into ``PlannerConfig``): ``config_file`` ('' = packaged
default), ``backend`` ('' = from the file), ``ego_id`` ('' = single ego),
``run_dir`` (decision log at ``run_dir/decisions.jsonl`` when set),
``decision_space_file`` (the intervals and weight pool, '' = packaged default; the MPC
must load the same file, it refuses Decisions of another space),
``decision_latency_s`` / ``emergency_latency_s`` (a simulated latency, < 0 = from
the file; ``config.latency_overrides``), and ROS's own ``use_sim_time``. Multi-ego graphs
(issue 18): ``coordination`` (``none`` | ``distributed`` | ``central``), ``ego_ids`` (the
graph's egos, comma-separated), ``on_silence`` (``coordination_wiring.py``).
Topics and timing: see ``decision_node.py``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType

from lmpc_msgs_py.base_node import run_node
from lmpc_msgs_py.messages import Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.backends import make_backend
from lmpc_llm_planner.config import latency_overrides, load_planner_config
from lmpc_llm_planner.coordination_wiring import CoordinationWiring
from lmpc_llm_planner.decision_node import DecisionNode
from lmpc_llm_planner.planner import PlannerCore


class PlannerNode(DecisionNode):
    """Requests LLM decisions on sim time and publishes them with the sync status."""

    def __init__(self) -> None:
        super().__init__("llm_planner")
        desc = ParameterDescriptor
        self.declare_parameter("config_file", "", desc(description="planner YAML ('' = default)"))
        self.declare_parameter("backend", "", desc(description="backend override ('' = file)"))
        self.declare_parameter("run_dir", "", desc(description="run folder for decisions.jsonl"))
        self.declare_parameter("decision_space_file", "", desc(
            description="decision-space YAML: intervals and weight pool ('' = default; the "
                        "MPC must use the same)"))
        overrides: dict[str, Any] = {}
        backend = self.get_parameter("backend").value
        if backend:
            overrides["backend"] = backend
        run_dir = self.get_parameter("run_dir").value
        if run_dir:
            overrides["decision_log"] = str(Path(run_dir) / "decisions.jsonl")
        for name in ("decision_latency_s", "emergency_latency_s"):
            self.declare_parameter(name, -1.0, desc(
                description=f"simulated {name.split('_')[0]} latency, s (< 0: from the file)"))
        latency = tuple(v if v >= 0.0 else None for v in (
            float(self.get_parameter("decision_latency_s").value),
            float(self.get_parameter("emergency_latency_s").value)))
        config_file = self.get_parameter("config_file").value or None
        if latency != (None, None):
            base = load_planner_config(config_file, overrides=overrides)
            overrides.update(latency_overrides(latency[0], latency[1], period_s=base.period_s,
                                               ttl_s=base.ttl_s))
        config = load_planner_config(config_file, overrides=overrides)
        space = load_decision_space(self.get_parameter("decision_space_file").value or None)
        self.planner = PlannerCore(config, make_backend(config), space)
        self.core = self.planner
        self.coordination = self._coordination(space)
        self.start()
        self.get_logger().info(
            f"backend={config.backend} stages={config.stages} period={config.period_s} s "
            f"latency={config.fixed_latency_s} s emergency={config.emergency_latency_s} s "
            f"ttl={config.ttl_s} s decision space {space.describe()} "
            f"log={config.decision_log or 'off'}"
        )

    def _coordination(self, space: Any) -> Optional[CoordinationWiring]:
        """Multi-ego graphs (issue 18): the coordination topics, when asked for."""
        desc = ParameterDescriptor
        mode = self.declare_parameter("coordination", "none", desc(
            description="none | distributed | central (multi-ego graphs, docs/MULTI.md)")).value
        ego_ids = [e for e in str(self.declare_parameter("ego_ids", "", desc(
            description="the graph's egos, comma-separated (multi-ego graphs)")).value
        ).split(",") if e]
        on_silence = self.declare_parameter("on_silence", "distributed", desc(
            description="central mode, coordinator silent: distributed | none")).value
        if mode in ("", "none"):
            return None
        if not self.ego_id:
            raise ValueError(f"coordination {mode!r} needs the parameter ego_id")
        wiring = CoordinationWiring(self, ego_id=self.ego_id, ego_ids=ego_ids or [self.ego_id],
                                    mode=mode, space=space, on_silence=on_silence,
                                    wall_clock=Clock(clock_type=ClockType.STEADY_TIME),
                                    on_peer=lambda: self._try_pending(force=False))
        self.get_logger().info(f"coordination {mode} among {', '.join(sorted(wiring.link.known))}")
        return wiring

    def destroy_node(self) -> None:
        """Also write the coordination's counters to ``run_dir/coordination.json``."""
        run_dir = self.get_parameter("run_dir").value
        if self.coordination is not None and run_dir:
            try:
                (Path(run_dir) / "coordination.json").write_text(json.dumps(
                    {**self.coordination.link.stats(),
                     "assembly_wait_expired": self.counters["assembly_wait_expired"]},
                    indent=1))
            except OSError as exc:
                self.get_logger().warning(f"could not write coordination.json: {exc}")
        super().destroy_node()

    def inputs_ready(self, obs: Observation) -> bool:
        return self.coordination is None or self.coordination.ready(obs)

    def before_decide(self, obs: Observation) -> Observation:
        if self.coordination is None:
            return obs
        acted = self.coordination.before(obs)
        self.planner.on_command(self.coordination.command_text(obs.stamp_s))  # prompt text
        return acted

    def after_decide(self, decision: Optional[Decision],
                     obs: Observation) -> Optional[Decision]:
        return decision if self.coordination is None else self.coordination.after(decision, obs)

    def core_counters(self) -> dict[str, Any]:
        out = dict(self.planner.counters.as_dict())
        if self.coordination is not None:
            out.update(self.coordination.counters())
        return out


def main(args: Optional[list[str]] = None) -> int:
    return run_node(PlannerNode, args)


if __name__ == "__main__":
    sys.exit(main())
