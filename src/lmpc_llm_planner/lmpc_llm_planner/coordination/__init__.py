"""Multi-vehicle joint control (issue 18): conflicts, statuses, the rule set, the
coordinator core and the per-episode coordination (docs/MULTI.md)."""
from lmpc_llm_planner.coordination.coordinator import (
    CoordinatorCore,
    RulesCoordinator,
    SilentCoordinator,
    make_coordinator_backend,
)
from lmpc_llm_planner.coordination.session import MODES, Coordination

__all__ = ["MODES", "Coordination", "CoordinatorCore", "RulesCoordinator",
           "SilentCoordinator", "make_coordinator_backend"]
