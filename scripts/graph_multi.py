"""The multi-ego graph of ``run_graph.py --egos N`` (issue 18, docs/MULTI.md).

One bridge (``lmpc_bridge.multi_bridge_node``) drives ``ego_1 … ego_N``; each ego has one
MPC and (unless ``--planner none``) one planner process, started in the ROS namespace
``/<ego_id>`` with ``ego_id`` set, so their node names are ``/<ego_id>/mpc_controller``,
``/<ego_id>/llm_planner`` and their topics ``/<ego_id>/lmpc/...``. With ``--coordination
central`` a ``coordinator`` process (``lmpc_llm_planner.coordinator_node``, backend
``--coordinator-backend``) joins; with ``distributed`` the planners resolve among
themselves. The coordinator is the one process allowed to end early: the egos fall back
(``coordination/link.py``) and the run goes on (the summary says when it ended).

Planners: ``rules``, ``none`` and the LLM backends ``openai`` / ``local`` / ``replay``
(each ego's planner reads its command in force as prompt text; its decision log is
``<run_dir>/<ego_id>/decisions.jsonl``). ``--planner replay --planner-replay DIR``: each
ego replays ``DIR/<ego_id>/decisions.jsonl`` of a finished multi-ego run. The LLM
coordinator's calls go to ``<run_dir>/coordinator.jsonl``; ``--coordinator-backend replay
--coordinator-replay FILE`` answers from such a log.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Optional

MULTI_FAMILIES = ("narrow", "usi-multi", "merge")
"""Families whose scenes carry several egos (``params["egos"]``), as
``lmpc_scripts.multi.MULTI_FAMILIES`` (not imported: it pulls in the methods registry,
which the graph's start-up does not need; test_graph_multi checks they agree)."""
COORDINATION = ("none", "distributed", "central")
MULTI_PLANNERS = ("rules", "openai", "local", "replay", "none")
"""The planners of a multi-ego graph (``mock``, the scripted mock LLM node, has no
coordination: refused)."""
COORDINATOR_BACKENDS = ("rules", "openai", "local", "replay")
LLM_PLANNERS = ("openai", "local", "replay")
PEER_WAIT_SYNC_S = 2.0
"""Sync clock, ``distributed``: wall s a planner waits for its peers' statuses of its step
(default 0.2 s). A planner that died costs its peers this per step until it has been
silent for 0.5 s sim (5 steps, ~10 s wall), then it no longer takes part."""


def int_in(lo: int, hi: Optional[int] = None) -> Any:
    """An argparse ``type``: ``lmpc_msgs_py.cli.int_arg(lo, hi)``, imported when an
    argument is parsed (the launcher imports no package before it has to: start-up)."""

    def parse(text: str) -> int:
        from lmpc_msgs_py.cli import int_arg

        return int_arg(lo, hi)(text)

    return parse


def add_args(ap: argparse.ArgumentParser) -> None:
    """run_graph's options of a multi-ego graph."""
    ap.add_argument("--egos", type=int_in(1), metavar="N",
                    help="controlled vehicles ego_1..ego_N, one MPC and one planner process "
                         "each under /ego_k/lmpc/... (default: the family's; 1 = today's "
                         "single-ego graph under /lmpc/...; docs/MULTI.md)")
    ap.add_argument("--coordination", choices=COORDINATION, default="none",
                    help="several egos: none (independent), distributed (the planners "
                         "resolve shared conflicts by a fixed rule set), central (a "
                         "coordinator node sends directives)")
    ap.add_argument("--planner-replay", type=Path, metavar="DIR",
                    help="--planner replay: the finished run folder whose decision log the "
                         "planner replays (DIR/decisions.jsonl; several egos: "
                         "DIR/ego_k/decisions.jsonl for ego_k)")
    ap.add_argument("--coordinator-backend", choices=COORDINATOR_BACKENDS, default="rules",
                    help="--coordination central: rules (the fixed rule set), openai / local "
                         "(an LLM; endpoint and model as the planner's: the openai / local "
                         "section of --coordinator-config and LMPC_OPENAI_BASE_URL / "
                         "LMPC_OPENAI_MODEL / LMPC_OPENAI_API_KEY; its calls logged to "
                         "<run-dir>/coordinator.jsonl), replay (--coordinator-replay)")
    ap.add_argument("--coordinator-config", type=Path, metavar="YAML",
                    help="planner YAML whose openai / local settings the LLM coordinator "
                         "uses (default: --planner-config, else the packaged one; local: "
                         "planner_local.yaml)")
    ap.add_argument("--coordinator-replay", type=Path, metavar="LOG",
                    help="--coordinator-backend replay: a coordinator.jsonl of an earlier run")


def scene_egos(family: str, seed: int, work_dir: Path) -> int:
    """How many egos the scene of ``family`` / ``seed`` has (1: a single-ego family)."""
    if family not in MULTI_FAMILIES:
        return 1
    from lmpc_bridge.multi_scene import ego_specs
    from lmpc_bridge.scenarios import build_scene

    return len(ego_specs(build_scene(family, seed, work_dir=work_dir)))


def check_args(args: argparse.Namespace, work_dir: Path) -> Optional[str]:
    """Fill ``args.egos`` (from the family when not given); why the run cannot go, or None.
    ``args.egos`` 1 is today's single-ego graph."""
    if args.scene is not None:
        if (args.egos or 1) != 1 or args.coordination != "none":
            return "--egos / --coordination need a multi-ego family (--scenario), not --scene"
        args.egos = 1
        return _single_ego_flags(args, work_dir.parent)
    try:
        n = scene_egos(args.scenario, args.seed, work_dir)
    except Exception as exc:  # noqa: BLE001 - a scene that cannot be built: one line
        return f"scene {args.scenario}/{args.seed}: {exc}"
    if args.egos is None:
        args.egos = n
    if args.egos != 1 and args.egos != n:
        return (f"--egos {args.egos}: scene {args.scenario}/{args.seed} has {n} ego(s) "
                f"(--egos 1 runs ego_1 alone)")
    if args.egos == 1:
        if args.coordination != "none":
            return f"--coordination {args.coordination} needs several egos (--egos {n})"
        return _single_ego_flags(args, work_dir.parent)
    if args.planner not in MULTI_PLANNERS:
        return (f"--planner {args.planner}: a multi-ego graph runs the planners "
                f"{', '.join(MULTI_PLANNERS)} (the mock LLM node has no coordination; "
                "--planner openai against a test server instead)")
    if args.coordination != "none" and args.planner == "none":
        return f"--coordination {args.coordination} needs a planner (--planner rules)"
    for flag, value in (("--record", args.record), ("--instruction", args.instruction),
                        ("--extra-subscribers", args.extra_subscribers)):
        if value:
            return f"{flag} is not supported with several egos yet"
    return _replay_flags(args, work_dir.parent) or _coordinator_flags(args)


def _replay_flags(args: argparse.Namespace, run_dir: Path) -> Optional[str]:
    """``--planner replay`` / ``--planner-replay DIR``: DIR is a finished run folder (not
    this run's) with the decision log of every ego (one ego: ``DIR/decisions.jsonl``);
    one ego may instead name its log in ``--planner-config`` (``replay.log_path``)."""
    if args.planner_replay is not None and args.planner != "replay":
        return "--planner-replay needs --planner replay"
    if args.planner != "replay":
        return None
    if args.planner_replay is None:
        if args.egos != 1:
            return ("--planner replay with several egos needs --planner-replay DIR (a "
                    "finished multi-ego run folder with DIR/ego_k/decisions.jsonl)")
        from lmpc_llm_planner.config import PlannerConfigError, load_planner_config

        try:
            log_path = load_planner_config(args.planner_config).replay.log_path
        except PlannerConfigError:
            return None  # run_graph names the bad file
        return None if log_path else (
            "--planner replay needs --planner-replay DIR (a finished run folder with "
            "DIR/decisions.jsonl) or a --planner-config whose replay.log_path names a log")
    if args.planner_replay.resolve() == run_dir.resolve():
        return "--planner-replay must be another run folder than --run-dir (its logs are read)"
    for eid in ego_ids(args.egos) if args.egos != 1 else [None]:
        log = replay_log(args.planner_replay, eid)
        if not log.is_file():
            return f"--planner-replay: {log} does not exist (the decision log of " \
                   f"{eid or 'the ego'})"
    return None


def replay_log(run_dir: Path, eid: Optional[str]) -> Path:
    """The decision log of ``eid`` in a finished run folder (None: a single-ego run's)."""
    return run_dir / eid / "decisions.jsonl" if eid else run_dir / "decisions.jsonl"


def _coordinator_flags(args: argparse.Namespace) -> Optional[str]:
    backend = args.coordinator_backend
    if backend != "rules" and args.coordination != "central":
        return (f"--coordinator-backend {backend} needs --coordination central (only "
                "central runs a coordinator)")
    if args.coordinator_replay is not None and backend != "replay":
        return "--coordinator-replay needs --coordinator-backend replay"
    if args.coordinator_config is not None and backend not in ("openai", "local"):
        return "--coordinator-config needs --coordinator-backend openai or local"
    if backend == "replay" and (args.coordinator_replay is None
                                or not args.coordinator_replay.is_file()):
        return ("--coordinator-backend replay needs --coordinator-replay LOG, an existing "
                f"coordinator.jsonl (got {args.coordinator_replay})")
    return None


def _single_ego_flags(args: argparse.Namespace, run_dir: Path) -> Optional[str]:
    """A multi-ego option given to a single-ego run: why not (None: none given); the
    replay flags."""
    for flag, given, needs in (
            ("--coordinator-backend", args.coordinator_backend != "rules",
             "several egos and --coordination central"),
            ("--coordinator-config", args.coordinator_config is not None,
             "several egos and --coordination central"),
            ("--coordinator-replay", args.coordinator_replay is not None,
             "several egos and --coordination central")):
        if given:
            return f"{flag} needs {needs}"
    return _replay_flags(args, run_dir)


def ego_ids(n: int) -> list[str]:
    return [f"ego_{k + 1}" for k in range(n)]


def node_specs(args: argparse.Namespace, run_dir: Path
               ) -> list[tuple[str, str, dict[str, object], Optional[str]]]:
    """(name, module, parameters, namespace) of every node, in start order (the bridge
    last: it waits for the others anyway)."""
    ids = ego_ids(args.egos)
    with_planner = args.planner != "none"
    specs: list[tuple[str, str, dict[str, object], Optional[str]]] = []
    if args.coordination == "central":
        specs.append(("coordinator", "lmpc_llm_planner.coordinator_node",
                      coordinator_params(args, run_dir, ids), None))
    for eid in ids:
        mpc: dict[str, object] = {"use_sim_time": True, "clock_mode": args.clock,
                                  "ego_id": eid,
                                  "profile_file": str(run_dir / f"profile_mpc_{eid}.json")}
        if args.mpc_config is not None:
            mpc["config_file"] = str(args.mpc_config.resolve())
        specs.append((f"mpc_{eid}", "lmpc_mpc.mpc_node", mpc, eid))
        if with_planner:
            ego_dir = run_dir / eid
            ego_dir.mkdir(parents=True, exist_ok=True)
            planner: dict[str, object] = {
                "use_sim_time": True, "backend": args.planner, "run_dir": str(ego_dir),
                "ego_id": eid, "ego_ids": ",".join(ids), "coordination": args.coordination,
                "profile_file": str(run_dir / f"profile_planner_{eid}.json")}
            if args.clock == "sync" and args.coordination == "distributed":
                # the bridge waits for every planner: a peer's status is late, not lost
                # (its 0.2 s default ran out under CI load and the egos resolved on the
                # statuses of different steps)
                planner["assembly_wait_s"] = PEER_WAIT_SYNC_S
            config = ego_planner_config(args, eid, ego_dir)
            if config is not None:
                planner["config_file"] = str(config)
            if args.decision_space is not None:
                planner["decision_space_file"] = str(args.decision_space.resolve())
            for name in ("decision_latency", "emergency_latency"):
                if getattr(args, name) is not None:
                    planner[f"{name}_s"] = float(getattr(args, name))
            specs.append((f"planner_{eid}", "lmpc_llm_planner.planner_node", planner, eid))
    specs.append(("bridge", "lmpc_bridge.multi_bridge_node", {
        "scenario": args.scenario, "seed": args.seed, "egos": args.egos,
        "clock_mode": args.clock, "wait_for_planner": with_planner and args.clock == "sync",
        "max_time_s": args.max_time_s, "run_dir": str(run_dir),
        # an LLM call may take its whole deadline (local model: tens of seconds)
        "planner_timeout_s": 180.0 if args.planner in LLM_PLANNERS else 30.0,
        "coordination": args.coordination}, None))
    return specs


def coordinator_params(args: argparse.Namespace, run_dir: Path, ids: list[str]
                       ) -> dict[str, object]:
    """The coordinator node's parameters: its backend, the planner YAML of an LLM
    backend's settings, its call log (``coordinator.jsonl``) or the log it replays."""
    params: dict[str, object] = {
        "use_sim_time": True, "ego_ids": ",".join(ids), "backend": args.coordinator_backend,
        "profile_file": str(run_dir / "profile_coordinator.json"),
        "stats_file": str(run_dir / "coordinator.json")}
    if args.coordinator_backend in ("openai", "local"):
        config = args.coordinator_config or args.planner_config
        if config is None and args.coordinator_backend == "local":
            from lmpc_llm_planner.config import LOCAL_CONFIG_PATH

            config = LOCAL_CONFIG_PATH
        if config is not None:
            params["config_file"] = str(Path(config).resolve())
        params["log_file"] = str(run_dir / "coordinator.jsonl")
    elif args.coordinator_backend == "replay":
        params["replay_log"] = str(args.coordinator_replay.resolve())
    return params


def ego_planner_config(args: argparse.Namespace, eid: Optional[str], ego_dir: Path
                       ) -> Optional[Path]:
    """The planner YAML of ``eid`` (None: the single ego; returns None for the packaged
    one): ``--planner-config`` (``local``: planner_local.yaml), written to
    ``ego_dir/planner_config.yaml`` when the ego needs its own copy (``--planning-period``;
    ``--planner-replay``: its own log)."""
    from lmpc_llm_planner.config import LOCAL_CONFIG_PATH

    base = args.planner_config or (LOCAL_CONFIG_PATH if args.planner == "local" else None)
    replay = args.planner == "replay" and args.planner_replay is not None
    if args.planning_period is None and not replay:
        return None if base is None else Path(base).resolve()
    import yaml

    from lmpc_llm_planner.config import (
        DEFAULT_CONFIG_PATH,
        PlannerConfigError,
        cadence_config,
    )
    from lmpc_msgs_py.yamlfile import read_mapping

    if args.planning_period is not None:
        data = cadence_config(args.planning_period, base)
    else:
        data = read_mapping(Path(base or DEFAULT_CONFIG_PATH), what="planner config",
                            error=PlannerConfigError)
    if replay:
        log = replay_log(args.planner_replay, eid).resolve()
        # stamps may shift by a step or two in the graph (ReplayConfig.stamp_window_s)
        data["replay"] = {**(data.get("replay") or {}), "log_path": str(log),
                          "stamp_window_s": 0.5}
    out = ego_dir / "planner_config.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def may_end_early(name: str) -> bool:
    """The coordinator may crash or be killed: the egos fall back, the run goes on."""
    return name == "coordinator"


def profiles(run_dir: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for path in sorted(run_dir.glob("profile_*.json")):
        try:
            out[path.stem[len("profile_"):]] = json.loads(path.read_text())["stages_ms"]
        except (OSError, ValueError, KeyError):
            continue
    return out


def _read_json(path: Path) -> Optional[dict[str, Any]]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def summary_extra(args: argparse.Namespace, run_dir: Path, episode: dict[str, Any],
                  ended_early: dict[str, float]) -> dict[str, object]:
    """The multi-ego keys of the summary: per ego (no records), the joint figures."""
    egos = {eid: {k: v for k, v in e.items() if k != "metrics"}
            | {"overall_cost": e.get("metrics", {}).get("overall_cost"),
               "time_s": e.get("metrics", {}).get("time_s")}
            for eid, e in episode.get("egos", {}).items()}
    for eid, e in egos.items():
        e["coordination"] = _read_json(run_dir / eid / "coordination.json")
    return {
        "egos": egos, "n_egos": args.egos, "coordination": args.coordination,
        "coordinator": _read_json(run_dir / "coordinator.json"),
        "deadlock": episode.get("deadlock"), "ego_collisions": episode.get("ego_collisions"),
        "clear_s": episode.get("clear_s"), "joint_oc": episode.get("joint_oc"),
        "ended_early": ended_early,
        "profile_ms": profiles(run_dir) | ({"bridge": episode["profile_ms"]}
                                           if episode.get("profile_ms") else {}),
    }


def start_and_watch(args: argparse.Namespace, graph: Any, run_dir: Path, t0: float
                    ) -> tuple[list[str], dict[str, float]]:
    """Start the nodes (``graph``: run_graph's ``Graph``) and watch them until the bridge
    ends: the names of nodes that stopped early (and ``wall-timeout``), and when (wall s
    after the start) a node allowed to end early did. ``KeyboardInterrupt`` propagates."""
    import os
    import time

    cpus = sorted(os.sched_getaffinity(0))
    split = len(cpus) >= 2
    for name, module, params, ns in node_specs(args, run_dir):
        cpu_set = None  # as the single-ego graph: planners on the last core, MPCs off it
        if split and name.startswith("planner_"):
            cpu_set = {cpus[-1]}
        elif split and name.startswith("mpc_"):
            cpu_set = set(cpus[:-1])
        graph.start_node(name, module, params, cpus=cpu_set, ns=ns)
    crashed: list[str] = []
    ended_early: dict[str, float] = {}
    bridge = next(c for c in graph.children if c.name == "bridge")
    while bridge.proc.poll() is None:
        for child in graph.children:
            if child is bridge or child.proc.poll() is None:
                continue
            if may_end_early(child.name):
                if child.name not in ended_early:
                    ended_early[child.name] = round(time.monotonic() - t0, 3)
                    graph.note(f"{child.name} ended (exit {child.proc.returncode}): the egos "
                               "fall back to their own coordination")
            elif child.name not in crashed:
                crashed.append(child.name)
        if crashed:
            break
        if time.monotonic() - t0 > args.wall_timeout_s:
            crashed.append("wall-timeout")
            break
        time.sleep(0.05)
    return crashed, ended_early
