"""LLM backends behind one interface (:class:`~lmpc_llm_planner.backends.base.Backend`)."""
from __future__ import annotations

from lmpc_llm_planner.backends.base import (
    Backend,
    BackendError,
    BackendReply,
    DecisionRequest,
)
from lmpc_llm_planner.config import PlannerConfig

__all__ = ["Backend", "BackendError", "BackendReply", "DecisionRequest", "make_backend"]


def make_backend(config: PlannerConfig) -> Backend:
    """The backend named by ``config.backend``."""
    if config.backend == "rules":
        from lmpc_llm_planner.backends.rules import RulesBackend

        return RulesBackend(config.rules)
    raise BackendError(
        f"backend {config.backend!r} is not available in this version; use 'rules'"
    )
