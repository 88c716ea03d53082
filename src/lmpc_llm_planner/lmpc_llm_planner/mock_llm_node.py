"""``mock_llm`` node: replaces the planner in tests with scripted decisions.

Parameters: ``script_file`` (YAML or JSON, see ``mock_script.py``), ``period_s``
(re-issue period, 2.5), ``ttl_s`` (5.0), ``decision_space_file`` ('' = packaged
default), ``ego_id``, ``use_sim_time``. Publishes
like the planner: the decision (when the script says so) then the status.
"""
from __future__ import annotations

import sys
from typing import Any, Optional

from rcl_interfaces.msg import ParameterDescriptor

from lmpc_msgs_py.base_node import run_node
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.decision_node import DecisionNode
from lmpc_llm_planner.mock_script import MockPlanner, load_mock_script


class MockLlmNode(DecisionNode):
    def __init__(self) -> None:
        super().__init__("mock_llm")
        desc = ParameterDescriptor
        self.declare_parameter("script_file", "", desc(description="YAML / JSON script"))
        self.declare_parameter("period_s", 2.5, desc(description="re-issue period (sim s)"))
        self.declare_parameter("ttl_s", 5.0, desc(description="decision time to live (s)"))
        self.declare_parameter("decision_space_file", "", desc(
            description="decision-space YAML ('' = default; the MPC must use the same)"))
        path = self.get_parameter("script_file").value
        if not path:
            raise SystemExit("mock_llm: parameter 'script_file' is required "
                             "(--ros-args -p script_file:=path/to/script.yaml)")
        self.mock = MockPlanner(
            load_mock_script(path),
            load_decision_space(self.get_parameter("decision_space_file").value or None),
            period_s=float(self.get_parameter("period_s").value),
            ttl_s=float(self.get_parameter("ttl_s").value),
        )
        self.core = self.mock
        self.start()

    def core_counters(self) -> dict[str, Any]:
        return {"scripted_decisions": self.mock.decisions}


def main(args: Optional[list[str]] = None) -> int:
    return run_node(MockLlmNode, args)


if __name__ == "__main__":
    sys.exit(main())
