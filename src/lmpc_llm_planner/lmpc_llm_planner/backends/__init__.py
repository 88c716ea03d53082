"""LLM backends behind one interface (:class:`~lmpc_llm_planner.backends.base.Backend`).

``make_backend(config)`` builds the one named by ``config.backend``:

- ``rules``: the deterministic traffic-rule reasoner (package ``rules/``);
- ``openai``: any OpenAI-compatible chat-completions endpoint (``openai.py``, stdlib HTTP);
- ``local``: an embedded llama.cpp model, SmolLM2-135M by default (``local.py``; needs the
  optional extra ``local``);
- ``replay``: answers from a recorded decision log (``replay.py``).
"""
from __future__ import annotations

import os
from typing import Mapping, Optional

from lmpc_llm_planner.backends.base import (
    Backend,
    BackendError,
    BackendReply,
    DecisionRequest,
)
from lmpc_llm_planner.config import PlannerConfig

__all__ = ["Backend", "BackendError", "BackendReply", "DecisionRequest", "make_backend"]

LOCAL_INSTALL_HINT = "pip install -e 'src/lmpc_llm_planner[local]'"


def make_backend(
    config: PlannerConfig, *, environ: Optional[Mapping[str, str]] = None
) -> Backend:
    """The backend named by ``config.backend``.

    ``environ`` (default ``os.environ``) supplies the ``openai`` backend's overrides and
    key. Raises :class:`BackendError` with an actionable message for a backend that
    cannot be built (missing optional dependency or model, missing replay log, bad URL).
    """
    name = config.backend
    if name == "rules":
        from lmpc_llm_planner.backends.rules import RulesBackend

        return RulesBackend(config.rules)
    if name == "openai":
        from lmpc_llm_planner.backends.openai import OpenAIBackend

        return OpenAIBackend.from_env(config.openai, os.environ if environ is None else environ)
    if name == "local":
        from lmpc_llm_planner.backends.local import LocalBackend

        return LocalBackend.from_config(config.local)
    if name == "replay":
        from lmpc_llm_planner.backends.replay import ReplayBackend

        return ReplayBackend.from_config(config.replay)
    raise BackendError(
        f"unknown backend {name!r}; choose one of rules, openai, local, replay"
    )
