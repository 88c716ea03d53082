"""The backend interface: one request in, one reply (text or a typed error) out.

A backend never raises for a bad call: a timeout or transport failure comes back
as ``BackendReply(error_kind=...)``. (The planner still guards the call, so a
backend that does raise is counted as a transport error, never a crash.)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, Optional, Protocol, runtime_checkable

from lmpc_msgs_py.messages import Decision
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.scene import Scene
from lmpc_llm_planner.schema import Stage

RequestMode = Literal["normal", "emergency"]
BackendErrorKind = Literal["timeout", "transport"]


class BackendError(RuntimeError):
    """A backend cannot be created (unknown name, missing model, bad settings)."""


class PreviousDecision(Decision):
    """The last decision as a backend sees it: the Decision plus its acceleration bias
    resolved in the planner's decision space (the rules reasoner's go / stop hysteresis
    reads ``accel_bias_mps2``). Never published: the Decision on the wire carries the
    interval index only, and the MPC resolves it."""

    accel_bias_mps2: float
    """Midpoint of the decision's acceleration interval [m/s^2]."""

    @classmethod
    def of(cls, decision: Decision, space: DecisionSpace) -> "PreviousDecision":
        accel, _ = space.bias_for(decision.accel_interval, decision.steer_interval)
        return cls.model_validate({**decision.model_dump(), "accel_bias_mps2": float(accel)})


@dataclass(frozen=True)
class DecisionRequest:
    """Everything a backend may use: the prompt and the structured inputs behind it.

    An LLM backend reads ``prompt`` (and may constrain its output with
    ``json_schema``); the rules backend reads the structured ``scene`` — the same
    inputs the prompt was made from.
    """

    prompt: str
    mode: RequestMode
    scene: Scene
    """Observation, offered ego / agent candidates (their indices are the answer's)."""
    accel_intervals_mps2: tuple[tuple[float, float], ...]
    steer_intervals_rad: tuple[tuple[float, float], ...]
    json_schema: Mapping[str, Any]
    """JSON schema the reply must match (structured output / grammar backends)."""
    stage: Stage = "all"
    prior_stages: Mapping[str, Any] = field(default_factory=dict)
    """Chained mode: the validated answers of the earlier stages (stage name -> object)."""
    instruction: Optional[str] = None
    """The user's plain-text instruction (untrusted; it only informs choices)."""
    previous: Optional[PreviousDecision] = None
    retry_error: Optional[str] = None
    """On a re-ask: why the previous reply was refused."""
    tokens_estimate: int = 0
    """Prompt size estimate (characters / chars_per_token)."""
    deadline_s: float = 8.0
    """Wall time the backend may take; a later reply is discarded by the planner."""
    expected_latency_s: Optional[float] = None
    """Sim time from the observation to the decision taking effect, as the planner expects
    it (``PlannerCore.latency_estimate_s``); None: not known. The rules use it to tell a
    decision that acts soon after its observation from a stale one (``ring_revisit_s``)."""

    @property
    def agent_ids(self) -> tuple[str, ...]:
        return self.scene.agent_ids


@dataclass(frozen=True)
class BackendReply:
    """The raw answer of one call: ``text`` or an ``error_kind`` (timeout / transport)."""

    text: Optional[str]
    latency_s: float
    tokens_in: int = 0
    tokens_out: int = 0
    error_kind: Optional[BackendErrorKind] = None
    error: str = ""
    truncated: bool = False
    """The server stopped at the output limit (``finish_reason: length``): the text is
    probably cut off, and the re-ask says so."""
    revisit_s: Optional[float] = None
    """The backend asks to be asked again this much sim time after the request, sooner
    than the planner's ``period_s`` (the rules approaching a roundabout's yield line:
    ``RulesConfig.ring_revisit_s``); None: at the planner's period. Logged with the call
    and replayed, so a replayed run requests at the same instants."""

    @property
    def ok(self) -> bool:
        return self.error_kind is None and self.text is not None


@runtime_checkable
class Backend(Protocol):
    """Answers decision requests with the decision JSON text (schema.py)."""

    name: str
    """Decision source of its decisions: ``rules``, ``replay``, ``llm:<model>``..."""

    def complete(self, request: DecisionRequest) -> BackendReply:
        """Answer ``request``; never raise for a failed call (return an error kind)."""
        ...
