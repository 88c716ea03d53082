"""The method registry: the one composition root that knows every package.

Each method name maps to a factory that builds its planner and controller for a scene
(``lmpc_bridge.evaluation.scenes.SceneSpec`` -> ``Wiring``). Every script that runs
in-process episodes (benchmark.py, planner_stats.py, instruction_probe.py, render.py)
builds them here; ``benchmark.py --list-methods`` prints the registry. Adding a method:
docs/ARCHITECTURE.md, "Adding a method".
"""
from __future__ import annotations

import importlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

from lmpc_bridge.evaluation.rows import Latency, scene_log_name
from lmpc_bridge.evaluation.scenes import SceneSpec, Wiring


@dataclass(frozen=True)
class Method:
    """A registry entry: its name, one line for ``--list-methods`` and its factory, a
    function or ``"module:function"`` (imported when the method first runs, so a method
    in a module of its own may import this one and heavy dependencies stay unloaded)."""

    name: str
    summary: str
    factory: Callable[[SceneSpec], Wiring] | str

    def build(self, spec: SceneSpec) -> Wiring:
        factory = self.factory
        if isinstance(factory, str):
            module, _, name = factory.partition(":")
            factory = getattr(importlib.import_module(module), name)
        return factory(spec)


_SOLVER: Any = None  # one compiled MPC solver per process (building all sizes takes ~1.5 s)


def prepare() -> None:
    """Compile and warm up this process's MPC solver (``run_scenes`` calls it once per
    worker, before the first scene's wall time starts)."""
    global _SOLVER
    if _SOLVER is None:
        from lmpc_mpc.config import load_mpc_config
        from lmpc_mpc.solver import MpcSolver

        _SOLVER = MpcSolver(load_mpc_config())
        _SOLVER.warm_up()


def make_controller() -> Any:
    """The MPC controller of every method, on this process's solver, reset: no warm start
    carried over from the previous episode."""
    from lmpc_mpc.config import load_mpc_config
    from lmpc_mpc.controller import MpcController

    prepare()
    _SOLVER.reset()
    return MpcController(load_mpc_config(), solver=_SOLVER)


def resolve_latency(decision_s: Optional[float], emergency_s: Optional[float]) -> Latency:
    """(decision, emergency) latency with the emergency default filled in: min(decision,
    ``DEFAULT_EMERGENCY_LATENCY_S``), the paper's short emergency path."""
    if decision_s is not None and emergency_s is None:
        from lmpc_llm_planner.config import DEFAULT_EMERGENCY_LATENCY_S

        emergency_s = min(decision_s, DEFAULT_EMERGENCY_LATENCY_S)
    return (decision_s, emergency_s)


def make_planner(method: str, instruction: Optional[str] = None, *,
                 log_path: Optional[Path] = None, replay_log: Optional[Path] = None,
                 replay_of: str = "lmpc-local", latency: Latency = (None, None),
                 planner_config: Optional[Path] = None, backend: Any = None) -> Any:
    """The planner core of an ``lmpc-*`` method; ``instruction`` reaches it as the user's
    text through ``PlannerCore.on_instruction``, as the node's ``/lmpc/instruction``
    subscription does; ``log_path``: its JSON-lines decision log. ``lmpc-replay`` answers
    from ``replay_log`` (prompts matched by hash only) with the planner settings of the
    method that recorded it, ``replay_of``. ``latency``: (decision, emergency) latency to
    simulate, s (None: the config's), see ``lmpc_llm_planner.config.latency_overrides``.
    ``planner_config``: the planner YAML of the LLM methods instead of the packaged one
    (``lmpc-local``: its own ``planner_local.yaml``); the method still names the backend.
    ``backend``: a backend object used instead of the one the config names."""
    from lmpc_llm_planner.backends import make_backend
    from lmpc_llm_planner.config import (
        LOCAL_CONFIG_PATH,
        latency_overrides,
        load_planner_config,
    )
    from lmpc_llm_planner.planner import PlannerCore
    from lmpc_msgs_py.vocabulary import load_decision_space

    backend_name = method.removeprefix("lmpc-")
    overrides: dict[str, Any] = {"backend": backend_name}
    settings_of = backend_name
    if backend_name == "replay":
        if replay_log is None:
            raise ValueError("lmpc-replay needs the recorded decision log of the scene")
        # Hash only: a prompt the recording never saw is a miss (and a fallback decision),
        # never a look-alike answer, so "0 unmatched" means the decisions were the recorded ones.
        overrides["replay"] = {"log_path": str(replay_log), "match": "hash"}
        settings_of = replay_of.removeprefix("lmpc-")
    # The small local model needs its own config (a deadline it can meet on a small CPU,
    # a simulated latency: config/planner_local.yaml says why), or every call times out.
    path = planner_config if planner_config is not None else (
        LOCAL_CONFIG_PATH if settings_of == "local" else None)
    if latency != (None, None):
        base = load_planner_config(path, overrides=overrides)
        overrides.update(latency_overrides(*latency, period_s=base.period_s, ttl_s=base.ttl_s))
    config = load_planner_config(path, overrides=overrides)
    core = PlannerCore(config, backend if backend is not None else make_backend(config),
                       load_decision_space(), log_path=log_path)
    if instruction:
        core.on_instruction(instruction)
    return core


def controller_cells(controller: Any, log_path: Optional[Path]) -> dict[str, Any]:
    """The MPC's row cells; its stale-decision checks go to the scene's decision log."""
    cstats = controller.stats()
    if log_path is not None and controller.stale_log:
        # the MPC's stale-decision check, per decision it overrode (lmpc_mpc.stale), next
        # to the planner's records of those decisions
        with log_path.open("a", encoding="utf-8") as fh:
            for rec in controller.stale_log.values():
                fh.write(json.dumps({"kind": "mpc_stale_check", **rec.as_dict()}) + "\n")
    # decisions whose candidate left the route: the MPC followed the route instead
    return {"route_overrides": cstats.route_overrides, "stale_steps": cstats.stale_steps,
            "stale_agent_steps": cstats.stale_agent_steps}


def build_mpc(spec: SceneSpec) -> Wiring:
    """The MPC baseline: no planner (the instruction is ignored)."""
    controller = make_controller()
    return Wiring(None, controller, lambda log: controller_cells(controller, log))


def build_lmpc(spec: SceneSpec) -> Wiring:
    """LanguageMPC: the planner core with the backend the method names, and the MPC."""
    planner = make_planner(spec.method, spec.instruction, log_path=spec.log_path,
                           latency=spec.latency, planner_config=spec.planner_config,
                           backend=spec.backend)
    controller = make_controller()
    return Wiring(planner, controller, lambda log: controller_cells(controller, log))


def build_ablation(spec: SceneSpec) -> Wiring:
    """``lmpc-rules-enc`` / ``lmpc-rules-aw``: the rules reasoner with only its scenario
    encoding, or only its action bias and weights, kept (the paper's Table II;
    ``lmpc_llm_planner.backends.ablation``)."""
    from lmpc_llm_planner.backends.ablation import AblatedBackend

    planner = make_planner("lmpc-rules", spec.instruction, log_path=spec.log_path,
                           latency=spec.latency, planner_config=spec.planner_config,
                           backend=spec.backend)
    keep = {"lmpc-rules-enc": "encoding", "lmpc-rules-aw": "action"}[spec.method]
    planner.backend = AblatedBackend(planner.backend, keep)  # type: ignore[arg-type]
    controller = make_controller()
    return Wiring(planner, controller, lambda log: controller_cells(controller, log))


def build_replay(spec: SceneSpec) -> Wiring:
    """``lmpc-replay``: the recorded run's decision log of the scene answers, with the
    recording method's planner settings; the row notes how many prompts it answered."""
    if spec.replay is None:
        raise ValueError("lmpc-replay needs --replay-from DIR (a finished run folder)")
    run_dir, recorded = spec.replay
    replay_log = Path(run_dir) / "decisions" / scene_log_name(spec.family, spec.seed, recorded)
    if not replay_log.is_file():
        raise FileNotFoundError(f"no recorded decision log {replay_log}")
    planner = make_planner(spec.method, spec.instruction, log_path=spec.log_path,
                           replay_log=replay_log, replay_of=recorded, latency=spec.latency,
                           planner_config=spec.planner_config, backend=spec.backend)
    controller = make_controller()

    def finish(log: Optional[Path]) -> dict[str, Any]:
        cells = controller_cells(controller, log)
        hits = planner.backend.hits
        cells["replay_unmatched"] = hits["miss"]
        cells["replay_answered"] = sum(hits.values()) - hits["miss"]
        cells["note"] = (f"replayed {replay_log.name}: {cells['replay_answered']} prompt(s) "
                         f"answered from it, {cells['replay_unmatched']} not in it")
        return cells

    return Wiring(planner, controller, finish)


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("mpc", "the MPC alone on the route, no planner (the paper's baseline)", build_mpc),
    Method("lmpc-rules", "LanguageMPC, decisions by the deterministic rules reasoner",
           build_lmpc),
    Method("lmpc-local", "LanguageMPC, decisions by the embedded SmolLM2 (llama.cpp; "
           "planner_local.yaml)", build_lmpc),
    Method("lmpc-openai", "LanguageMPC, decisions by an OpenAI-compatible chat server "
           "(OPENAI_* env or --planner-config)", build_lmpc),
    Method("lmpc-replay", "LanguageMPC, decisions replayed from a finished run's logs "
           "(--replay-from, --replay-of)", build_replay),
    Method("lmpc-rules-enc", "ablation: the rules reasoner's scenario encoding only "
           "(attention, predictions, reference; bias neutral, weights normal)",
           build_ablation),
    Method("lmpc-rules-aw", "ablation: the rules reasoner's action bias and weights only "
           "(baseline attention, predictions, route reference)", build_ablation),
    Method("dqn", "learned planner: a DQN policy (policies/dqn-<family>.npz or "
           "$LMPC_POLICY_DIR) choosing decisions for the MPC (docs/RL.md)",
           "lmpc_scripts.method_rl:build"),
    Method("ppo", "learned planner: a PPO policy (policies/ppo-<family>.npz or "
           "$LMPC_POLICY_DIR) choosing decisions for the MPC (docs/RL.md)",
           "lmpc_scripts.method_rl:build"),
    Method("sac", "learned planner: a SAC policy (policies/sac-<family>.npz or "
           "$LMPC_POLICY_DIR) choosing decisions for the MPC (docs/RL.md)",
           "lmpc_scripts.method_rl:build"),
    Method("adp", "the MPC with its solve replaced by the ADP network's forward pass "
           "(policies/adp.npz or $LMPC_POLICY_DIR; docs/RL.md, ADP)",
           "lmpc_scripts.method_adp:build"),
    Method("lmpc-oracle", "the best of <= 32 decisions per planning instant, each rolled "
           "out 8 s (--oracle-lookahead-s) in the scene itself, optionally followed by the "
           "rules (--oracle-continuation) (docs/ORACLE.md; tens of times slower)",
           "lmpc_scripts.method_oracle:build"),
)}
"""Every method by name, in ``--list-methods`` order."""

LLM_METHODS = tuple(n for n in METHODS if n.startswith("lmpc-")
                    and n not in ("lmpc-replay", "lmpc-oracle"))
"""The methods that can record the decision logs ``lmpc-replay`` repeats."""


def build(spec: SceneSpec) -> Wiring:
    """The planner and controller of ``spec.method`` for one scene (``run_scenes``'s
    factory). Raises ``KeyError`` naming an unknown method."""
    try:
        method = METHODS[spec.method]
    except KeyError:
        raise KeyError(f"unknown method {spec.method!r}; choose from "
                       f"{', '.join(METHODS)}") from None
    return method.build(spec)


def list_methods() -> str:
    """One line a method: its name and what it is."""
    width = max(len(n) for n in METHODS)
    return "\n".join(f"{m.name:<{width}}  {m.summary}" for m in METHODS.values()) + "\n"
