"""The paper's ablation (Table II): a decision maker that keeps one half of its answer.

The paper separates the scenario encoder (O^dy: attention, agent predictions, the ego's
reference choice) from the action bias and the weights (A_hat & W). :class:`AblatedBackend`
wraps another backend (the rules reasoner for ``lmpc-rules-enc`` / ``lmpc-rules-aw``)
and rewrites each of its answers before the planner validates it, so the decision log
shows what the MPC was really given:

- ``keep="encoding"`` (O^dy only): the answer's action guidance becomes the neutral
  intervals of the request's pools and every weight level ``normal`` (the baseline's
  weights). An emergency answer, which has no encoding, becomes all neutral too: its
  brake is part of A_hat.
- ``keep="action"`` (A_hat & W only): the answer's scenario encoding becomes the
  baseline's (:func:`baseline_encoding`: the route candidate, every offered agent
  attended, each predicted along the candidate closest to its heading); an emergency
  answer (no encoding: baseline attention already) is left as it is.

A reply's ``revisit_s`` (the rules asking to be asked again soon near a roundabout) is
part of A_hat: the rules plan their approach on braking at that next decision, which an
encoding-only answer cannot do, so ``keep="encoding"`` drops it (the period applies).

Works on both answer forms (single call and chained stages): it rewrites whichever of
``scenario_encoding`` / ``action_guidance`` / ``weight_adjustment`` a reply carries. A
reply that is not a JSON object is passed on unchanged (the planner refuses it as it
would the inner backend's).
"""
from __future__ import annotations

import dataclasses
import json
from typing import Literal, Optional

from lmpc_llm_planner.backends.base import Backend, BackendReply, DecisionRequest
from lmpc_llm_planner.scene import Scene
from lmpc_llm_planner.schema import MAX_REASONING_CHARS, ScenarioEncoding
from lmpc_msgs_py.vocabulary import neutral_index

Keep = Literal["encoding", "action"]
NORMAL_WEIGHTS = {"tracking": "normal", "action": "normal", "smoothness": "normal",
                  "safety": "normal"}


def baseline_encoding(scene: Scene, ego_trajectory: Optional[int] = None) -> ScenarioEncoding:
    """The scenario encoding the MPC baseline stands for: ``ego_trajectory`` (default the
    route candidate), every offered agent attended, each predicted along its candidate
    closest to its heading."""
    cand = scene.route_candidate_id if ego_trajectory is None else ego_trajectory
    return ScenarioEncoding(
        ego_trajectory=cand, attention=list(scene.agent_ids),
        agent_trajectories={v.id: v.closest_heading_id for v in scene.agents})


class AblatedBackend:
    """``inner``'s answers with one half replaced by the baseline's (module doc)."""

    def __init__(self, inner: Backend, keep: Keep) -> None:
        if keep not in ("encoding", "action"):
            raise ValueError(f"keep must be 'encoding' or 'action', got {keep!r}")
        self.inner = inner
        self.keep = keep
        self.name = inner.name  # the decisions' source stays the reasoner's
        self.rewritten = 0
        """Answers this wrapper changed."""

    def __getattr__(self, name: str) -> object:
        # reports_latency, reported_latency_s, hits ...: the inner backend's
        return getattr(self.inner, name)

    def complete(self, request: DecisionRequest) -> BackendReply:
        reply = self.inner.complete(request)
        if self.keep == "encoding" and reply.revisit_s is not None:
            reply = dataclasses.replace(reply, revisit_s=None)
        if not reply.ok or reply.text is None:
            return reply
        try:
            answer = json.loads(reply.text)
        except ValueError:
            return reply
        if not isinstance(answer, dict):
            return reply
        changed = self._rewrite(answer, request)
        if not changed:
            return reply
        self.rewritten += 1
        return dataclasses.replace(reply, text=json.dumps(answer))

    def _rewrite(self, answer: dict[str, object], request: DecisionRequest) -> bool:
        before = json.dumps(answer, sort_keys=True)
        if self.keep == "encoding":
            if "action_guidance" in answer:
                answer["action_guidance"] = {
                    "accel_interval": neutral_index(request.accel_intervals_mps2),
                    "steer_interval": neutral_index(request.steer_intervals_rad)}
            if "weight_adjustment" in answer:
                answer["weight_adjustment"] = dict(NORMAL_WEIGHTS)
        elif "scenario_encoding" in answer:
            answer["scenario_encoding"] = baseline_encoding(request.scene).model_dump()
        if json.dumps(answer, sort_keys=True) == before:
            return False
        if isinstance(answer.get("reasoning"), str):
            kept = "scenario encoding" if self.keep == "encoding" else "action bias and weights"
            answer["reasoning"] = (f"[ablation: only the {kept} kept] "
                                   + str(answer["reasoning"]))[:MAX_REASONING_CHARS]
        return True
