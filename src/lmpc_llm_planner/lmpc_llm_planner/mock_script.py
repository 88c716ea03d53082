"""Scripted decisions for tests (the logic of the ``mock_llm`` node; no ROS).

A script is a list of entries, each in force from ``from_s`` (sim time) until the
next one::

    - {from_s: 0.0, preset: stop}
    - {from_s: 8.0, preset: go}
    - {from_s: 12.0, accel_interval: 2, weights: {safety: high}, attention: [car1]}

Presets: ``stop`` = strongest braking interval, neutral steer, action "high",
tracking "low" (holds the ego still, e.g. before a junction); ``go`` = route
candidate, mildest accelerating interval, normal weights; ``baseline`` = neutral
bias, normal weights. Field overrides apply on top of the preset (default
``baseline``). Every agent in range is attended unless ``attention`` lists ids
(ids not observed at that moment are left out). Decisions are built through the
same translation code as the real planner, with source ``mock``.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal, Optional, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from lmpc_msgs_py.messages import Decision
from lmpc_msgs_py.observation import Observation
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.schema import (
    ActionGuidance,
    LlmDecision,
    ScenarioEncoding,
    WeightAdjustment,
)
from lmpc_llm_planner.validation import DecisionMeta, translate

Level = Literal["low", "normal", "high"]


class MockScriptError(ValueError):
    """The mock script is missing, malformed, or names an index outside the config."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class WeightOverrides(_Strict):
    tracking: Optional[Level] = None
    action: Optional[Level] = None
    smoothness: Optional[Level] = None
    safety: Optional[Level] = None


class MockEntry(_Strict):
    """One scripted decision, in force from ``from_s``."""

    from_s: float = Field(ge=0.0)
    preset: Literal["stop", "go", "baseline"] = "baseline"
    accel_interval: Optional[int] = Field(default=None, ge=0)
    steer_interval: Optional[int] = Field(default=None, ge=0)
    ego_trajectory: Optional[int] = Field(default=None, ge=0, le=2)
    """Index among the offered ego candidates; None = the route candidate."""
    weights: WeightOverrides = WeightOverrides()
    attention: Union[Literal["all"], list[str]] = "all"
    reasoning: str = Field(default="", max_length=2000)


class MockScript(_Strict):
    entries: tuple[MockEntry, ...] = Field(min_length=1)


def load_mock_script(path: str | Path) -> MockScript:
    """Read a YAML or JSON script (a list of entries, or ``{entries: [...]}``)."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
        data = json.loads(text) if file.suffix == ".json" else yaml.safe_load(text)
    except (OSError, json.JSONDecodeError, yaml.YAMLError) as exc:
        raise MockScriptError(f"cannot read mock script {file}: {exc}") from None
    if isinstance(data, list):
        data = {"entries": data}
    try:
        script = MockScript.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in err["loc"])
        raise MockScriptError(f"mock script {file}: field '{loc}': {err['msg']}") from None
    return MockScript(entries=tuple(sorted(script.entries, key=lambda e: e.from_s)))


def _mid(iv: tuple[float, float]) -> float:
    return 0.5 * (iv[0] + iv[1])


class MockPlanner:
    """``PlannerLike`` that answers from a script (see the module docstring)."""

    def __init__(
        self,
        script: MockScript,
        space: DecisionSpace,
        *,
        period_s: float = 2.5,
        ttl_s: float = 5.0,
        lookahead_m: float = 60.0,
    ) -> None:
        self.script = script
        self.space = space
        self.period_s = period_s
        self.ttl_s = ttl_s
        self.lookahead_m = lookahead_m
        self.decisions = 0
        self.last_decision: Optional[Decision] = None
        self._current: Optional[int] = None
        self._t_last: Optional[float] = None
        n_a, n_s = len(space.accel_intervals_mps2), len(space.steer_intervals_rad)
        for i, e in enumerate(script.entries):
            if e.accel_interval is not None and e.accel_interval >= n_a:
                raise MockScriptError(f"entry {i}: accel_interval {e.accel_interval} "
                                      f"out of range 0..{n_a - 1}")
            if e.steer_interval is not None and e.steer_interval >= n_s:
                raise MockScriptError(f"entry {i}: steer_interval {e.steer_interval} "
                                      f"out of range 0..{n_s - 1}")

    def on_instruction(self, text: str) -> None:
        """Instructions do not change a script."""

    def entry_at(self, t_s: float) -> Optional[int]:
        """Index of the entry in force at ``t_s`` (None before the first)."""
        idx = None
        for i, e in enumerate(self.script.entries):
            if e.from_s <= t_s + 1e-6:
                idx = i
        return idx

    def on_observation(self, obs: Observation) -> Optional[Decision]:
        """The scripted decision when the entry changes or ``period_s`` has passed."""
        t = obs.stamp_s
        idx = self.entry_at(t)
        if idx is None:
            return None
        if self._t_last is not None and t < self._t_last:
            self._t_last, self._current = None, None  # time went backwards: new episode
        if idx == self._current and self._t_last is not None \
                and t - self._t_last < self.period_s - 1e-6:
            return None
        self._current, self._t_last = idx, t
        decision = self.build(self.script.entries[idx], obs)
        self.decisions += 1
        self.last_decision = decision
        return decision

    def build(self, entry: MockEntry, obs: Observation) -> Decision:
        """Translate one entry for this observation."""
        cfg = self.space
        scene = build_scene(obs, lookahead_m=self.lookahead_m, max_agents=200)
        accel = cfg.accel_intervals_mps2
        levels: dict[str, Any] = {"tracking": "normal", "action": "normal",
                                  "smoothness": "normal", "safety": "normal"}
        a_idx = cfg.neutral_accel_index
        if entry.preset == "stop":
            a_idx = min(range(len(accel)), key=lambda i: (_mid(accel[i]), i))
            levels.update(tracking="low", action="high")
        elif entry.preset == "go":
            positive = [i for i, iv in enumerate(accel) if _mid(iv) > 0.0]
            if positive:
                a_idx = min(positive, key=lambda i: (_mid(accel[i]), i))
        levels.update({k: v for k, v in entry.weights.model_dump().items() if v is not None})
        ids = scene.agent_ids if entry.attention == "all" else tuple(
            a for a in dict.fromkeys(entry.attention) if a in scene.agent_ids
        )
        ego_idx = scene.route_candidate_id
        if entry.ego_trajectory is not None and entry.ego_trajectory < len(scene.ego_candidates):
            ego_idx = entry.ego_trajectory
        wire = LlmDecision(
            reasoning=entry.reasoning or f"scripted '{entry.preset}' from t={entry.from_s:g} s",
            scenario_encoding=ScenarioEncoding(
                ego_trajectory=ego_idx, attention=list(ids), agent_trajectories={},
            ),
            action_guidance=ActionGuidance(
                accel_interval=entry.accel_interval if entry.accel_interval is not None else a_idx,
                steer_interval=(
                    entry.steer_interval if entry.steer_interval is not None
                    else cfg.neutral_steer_index
                ),
            ),
            weight_adjustment=WeightAdjustment(**levels),
        )
        n = self.decisions + 1
        meta = DecisionMeta(
            decision_id=f"{int(round(obs.stamp_s * 1000))}-{n}", seq=n, source="mock",
            mode="normal", latency_s=0.0, tokens_in=0, tokens_out=0, ttl_s=self.ttl_s,
        )
        return translate(wire, scene=scene, space=cfg, meta=meta)
