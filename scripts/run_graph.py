#!/usr/bin/env python3
"""Run the LanguageMPC graph: bridge, planner and MPC as three separate processes.

Starts the nodes on simulated time, prefixes and streams their logs (and keeps
them in the run folder), stops every child when the episode ends or on SIGINT
(Ctrl-C), SIGTERM or SIGHUP (ordered: SIGINT to each node, SIGTERM then SIGKILL
to what lingers), and writes a summary JSON as far as the run got. A node never
outlives this process: it is started with ``LMPC_SUPERVISOR_PID`` and ends itself
when the supervisor dies, even by SIGKILL (``lmpc_msgs_py.supervision``).
Exit code: 0 target reached, 1 collision, 2 timeout, 3 error (a node crashed,
the episode never finished, or the run was stopped by a signal), 4 off route
(the ego drove onto a road that is not on its route).

    run_graph.py --scenario usi --seed 0 --planner rules --clock sync
    run_graph.py --scene examples/city.yaml --planner rules    # your own network
    run_graph.py --scenario lane --seed 3 --instruction "drive aggressively"

``--instruction TEXT`` is published on ``/lmpc/instruction`` (what a user's tool would
do) by a short-lived helper process once the planner is up and before the bridge and
the MPC start, so the first decision already reads it; the run waits until the
planner logs that it received it.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Optional, Sequence

from lmpc_msgs_py.cli import file_arg, folder_arg
from lmpc_msgs_py.discovery import stay_local
from lmpc_msgs_py.scheduling import (DEFAULT_EXECUTOR, EXECUTOR_ENV, EXECUTORS, PRIORITY_ENV,
                                     CpuLatencyHold, node_priorities)

if __package__:  # lmpc_scripts.run_graph
    from . import graph_multi
    from .node_logs import first_error_line, log_lines, stopped_early
    from .run_timing import PROFILE_FILES, profile_table, read_profiles, wall_split
else:  # run by path (scripts/ is on sys.path)
    import graph_multi
    from node_logs import first_error_line, log_lines, stopped_early
    from run_timing import PROFILE_FILES, profile_table, read_profiles, wall_split

SCRIPTS = Path(__file__).resolve().parent
EXIT_CODES = {"reached": 0, "collision": 1, "timeout": 2, "error": 3, "off_route": 4}

# Each node module and how its process is called in logs.
NODE_MODULES = {
    "bridge": "lmpc_bridge.bridge_node",
    "mpc": "lmpc_mpc.mpc_node",
    "planner": "lmpc_llm_planner.planner_node",
    "mock_llm": "lmpc_llm_planner.mock_llm_node",
}


MAX_DOMAIN_ID = 232
"""The largest ROS_DOMAIN_ID whose DDS ports fit (Fast DDS's port arithmetic)."""


def ros_env(domain_id: Optional[int] = None) -> dict[str, str]:
    """The environment for the nodes: DDS discovery stays on this machine unless the
    user opened it up (README, multi-machine)."""
    env = dict(os.environ)
    stay_local(env)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Signals that stop the graph in order, as in ``ros2 launch`` (STYLE.md 14)."""


class StopSignals:
    """The first SIGINT / SIGTERM / SIGHUP raises ``KeyboardInterrupt`` in the main thread
    (the run stops its nodes and writes its summary); one arriving once the shut-down has
    begun (the episode ended, or an earlier signal) is only noted: the ordered stop goes
    on, and its own escalation ends every node. Installed even where the parent left
    SIGINT ignored (a shell's background job): a user's ``kill -INT`` must work too."""

    def __init__(self) -> None:
        self.received: list[str] = []
        self.stopping = False

    def install(self) -> None:
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._handle)

    def _handle(self, signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        self.received.append(name)
        if not self.stopping:
            self.stopping = True
            raise KeyboardInterrupt(name)
        _say(f"[run_graph] {name} received while stopping: the shut-down goes on",
             sys.stderr)


def _say(text: str, stream: Optional[IO[str]] = None) -> None:
    """Print, ignoring a closed terminal or pipe (SIGHUP: the terminal is gone): a
    failed print must never cut the stop of the nodes short."""
    try:
        print(text, file=stream or sys.stdout, flush=True)
    except (OSError, ValueError):
        pass


@dataclass
class Child:
    name: str
    proc: subprocess.Popen[str]
    log_file: IO[str]
    tracebacks: int = 0
    lines: list[str] = field(default_factory=list)
    stop_s: Optional[float] = None
    """Wall seconds from the start of :meth:`Graph.stop` until this process had exited."""


class Graph:
    """The node processes of one run, with their log pumps."""

    def __init__(self, run_dir: Path, env: dict[str, str], *, echo: bool = True) -> None:
        self.run_dir = run_dir
        self.env = env
        self.echo = echo
        self.children: list[Child] = []
        self._print_lock = threading.Lock()

    def start_node(self, name: str, module: str, params: dict[str, object],
                   cpus: Optional[set[int]] = None,
                   env: Optional[dict[str, str]] = None, ns: Optional[str] = None) -> Child:
        """Start ``python -m module`` with ROS parameters (and ``env`` added; in the ROS
        namespace ``/ns`` when given)."""
        args = [sys.executable, "-m", module, "--ros-args"]
        if ns:
            args += ["-r", f"__ns:=/{ns}"]
        for key, value in params.items():
            text = str(value).lower() if isinstance(value, bool) else str(value)
            args += ["-p", f"{key}:={text}"]
        return self.start(name, args, cpus, env)

    def note(self, text: str) -> None:
        """A line of the supervisor's own in the echoed log."""
        if self.echo:
            with self._print_lock:
                _say(f"[run_graph] {text}")

    def start(self, name: str, args: list[str], cpus: Optional[set[int]] = None,
              extra_env: Optional[dict[str, str]] = None) -> Child:
        log_file = open(self.run_dir / f"{name}.log", "w", encoding="utf-8")
        # LMPC_SUPERVISOR_PID: the child ends itself when this process dies (prctl
        # PR_SET_PDEATHSIG + a parent-pid watch). Started from the main thread: the
        # death signal fires when the forking *thread* ends.
        env = dict(self.env, LMPC_SUPERVISOR_PID=str(os.getpid()), **(extra_env or {}))
        proc = subprocess.Popen(
            args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            bufsize=1, start_new_session=True,
        )
        child = Child(name, proc, log_file)
        self.children.append(child)  # tracked at once: a signal may interrupt what follows
        if cpus:
            try:
                os.sched_setaffinity(proc.pid, cpus)
            except ProcessLookupError:
                pass  # it died already; the run notices
        threading.Thread(target=self._pump, args=(child,), daemon=True).start()
        return child

    def _pump(self, child: Child) -> None:
        assert child.proc.stdout is not None
        for line in child.proc.stdout:
            line = line.rstrip("\n")
            child.log_file.write(line + "\n")
            child.log_file.flush()
            if line.startswith("Traceback"):
                child.tracebacks += 1
            child.lines.append(line)
            if len(child.lines) > 200:
                del child.lines[:100]
            if self.echo:
                with self._print_lock:
                    _say(f"[{child.name}] {line}")

    def stop(self, timeout_s: float = 5.0) -> None:
        """SIGINT every child, then SIGTERM / SIGKILL its process group if it lingers.

        Records each child's exit time (``Child.stop_s``). Runs to its end even when a
        stop signal arrives meanwhile (:class:`StopSignals` does not interrupt it)."""
        t0 = time.monotonic()
        running = [c.name for c in self.children if c.proc.poll() is None]
        if running and self.echo:
            with self._print_lock:
                _say(f"[run_graph] stopping {', '.join(running)}")
        for child in self.children:
            if child.proc.poll() is None:
                _signal_group(child.proc, signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for sig in (signal.SIGTERM, signal.SIGKILL):
            while time.monotonic() < deadline and any(
                    c.proc.poll() is None for c in self.children):
                self._note_exits(t0)
                time.sleep(0.02)
            self._note_exits(t0)
            for child in self.children:
                if child.proc.poll() is None:
                    _signal_group(child.proc, sig)
            deadline = time.monotonic() + 2.0
        for child in self.children:
            child.proc.wait()
            child.log_file.close()
        self._note_exits(t0)

    def _note_exits(self, t0: float) -> None:
        for child in self.children:
            if child.stop_s is None and child.proc.poll() is not None:
                child.stop_s = round(time.monotonic() - t0, 3)


def _wait_for_log(child: Child, needle: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and child.proc.poll() is None:
        if any(needle in line for line in child.lines):
            return
        time.sleep(0.05)
    raise RuntimeError(f"{child.name} did not report {needle!r} within {timeout_s:.0f}s")


INSTRUCTION_TIMEOUT_S = 60.0
"""Wall time to get the instruction to the planner (its start-up included)."""
_PUBLISH_INSTRUCTION = """
import sys, time
from lmpc_msgs_py.supervision import follow_supervisor
follow_supervisor()
import rclpy
from std_msgs.msg import String
from lmpc_msgs_py import qos, topics
rclpy.init()
node = rclpy.create_node("lmpc_instruction")
pub = node.create_publisher(String, topics.topic(topics.INSTRUCTION, sys.argv[2] or None),
                            qos.STREAM)
msg = String()
msg.data = sys.argv[1]
try:
    # volatile topic: publish until the parent sees the planner's receipt and stops us
    while rclpy.ok():
        if pub.get_subscription_count() > 0:
            pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.25)
except KeyboardInterrupt:
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
"""


def deliver_instruction(graph: Graph, planner: Child, text: str, *, ego_id: str = "",
                        timeout_s: float = INSTRUCTION_TIMEOUT_S) -> None:
    """Publish ``text`` on the instruction topic until ``planner`` logs its receipt.

    A separate process (only node processes import rclpy here), stopped before the
    bridge and the MPC start: with LOCALHOST discovery Fast DDS serves only four
    participants per domain (README), so it must not outlive the delivery."""
    sender = graph.start("instruction", [sys.executable, "-c", _PUBLISH_INSTRUCTION, text,
                                         ego_id])
    try:
        _wait_for_log(planner, "instruction received", timeout_s=timeout_s)
    finally:
        if sender.proc.poll() is None:
            _signal_group(sender.proc, signal.SIGINT)
        try:
            sender.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            _signal_group(sender.proc, signal.SIGKILL)
            sender.proc.wait()
        graph.children.remove(sender)
        sender.log_file.close()


def _signal_group(proc: subprocess.Popen[str], sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenario", default="usi", help="scenario family (default usi)")
    ap.add_argument("--seed", type=seed_arg, default=0, help="the scene's seed (>= 0)")
    ap.add_argument("--scene", type=Path,
                    help="scene description (YAML) on your own SUMO network, instead of "
                         "--scenario/--seed (README 'Your own network')")
    ap.add_argument("--planner", choices=["rules", "openai", "local", "replay", "none", "mock"],
                    default="rules",
                    help="rules: the deterministic reasoner; openai: an OpenAI-compatible "
                         "endpoint (LMPC_OPENAI_BASE_URL, LMPC_OPENAI_MODEL, "
                         "LMPC_OPENAI_API_KEY);\n"
                         "local: SmolLM2-135M in llama.cpp; replay: a recorded decision log "
                         "(--planner-replay RUN_DIR, or --planner-config names it);\n"
                         "none: the MPC baseline alone; "
                         "mock: the mock LLM node playing --mock-script")
    ap.add_argument("--planner-config", type=Path,
                    help="planner YAML (default: the packaged config/planner.yaml)")
    ap.add_argument("--mock-script", type=Path, help="scripted decisions for --planner mock")
    ap.add_argument("--mpc-config", type=Path,
                    help="MPC YAML (default: the packaged config/mpc.yaml); its "
                         "decision_space_file is the MPC's decision space")
    ap.add_argument("--decision-space", type=Path,
                    help="the planner's decision-space YAML: action intervals and weight pool "
                         "(default: the packaged one). It must equal the MPC's (same hash), "
                         "or the graph does not start")
    ap.add_argument("--clock", choices=["sync", "realtime"], default="sync")
    graph_multi.add_args(ap)
    ap.add_argument("--run-dir", type=folder_arg,
                    help="run folder (default runs/<scenario>-<seed>-<time>; with --scene "
                         "runs/<scene file stem>-<time>)")
    ap.add_argument("--summary-json", type=file_arg, help="also write the summary here")
    # a larger id makes DDS ports past 65535: the nodes died at start-up with "Calculated
    # port number is too high" (ROS 2 advises 0-101 on Linux)
    ap.add_argument("--domain-id", type=int_in(0, MAX_DOMAIN_ID),
                    help=f"ROS_DOMAIN_ID for this run, 0-{MAX_DOMAIN_ID} (default: env)")
    ap.add_argument("--max-time-s", type=float, default=200.0, help="episode limit, sim seconds")
    ap.add_argument("--wall-timeout-s", type=float, default=900.0,
                    help="stop everything after this many wall seconds")
    ap.add_argument("--record", action="store_true",
                    help="record every topic to <run-dir>/bag (rosbag2, MCAP storage)")
    ap.add_argument("--extra-subscribers", type=int_in(0), default=0, metavar="N",
                    help="sync clock: before step 0 also wait for N subscribers of "
                         "/lmpc/ego_state besides the graph's own (your monitor; it should "
                         "subscribe to the ego state once it hears the topics it watches)")
    ap.add_argument("--quiet", action="store_true", help="do not echo node logs")
    ap.add_argument("--rt-priority", type=int_in(0, 99), default=0, metavar="N",
                    help="run the 10 Hz loop with SCHED_FIFO: bridge and MPC at priority N, "
                         "the planner (not with --planner local) at N-1 (1-99; needs "
                         "CAP_SYS_NICE, else they say so and run normally; default 0: off). "
                         "Keeps the control cycle on time next to CPU-heavy jobs "
                         "(docs/RESULTS.md)")
    ap.add_argument("--cpu-dma-latency", type=int_in(0, 1_000_000), default=None, metavar="US",
                    help="for the run, keep every core out of idle states it needs more than "
                         "US microseconds to leave (Linux PM QoS, /dev/cpu_dma_latency; 0: "
                         "poll only; needs root, else it says so and runs normally). Keeps a "
                         "realtime run's steps fast after ~90 ms idle (docs/RESULTS.md)")
    ap.add_argument("--executor", choices=EXECUTORS, default=None,
                    help="how every node spins: events (rclpy.experimental.EventsExecutor, "
                         "the default: a sync step ~0.6 ms shorter, docs/RESULTS.md) or single "
                         "(rclpy's single-threaded executor); default: $LMPC_EXECUTOR or "
                         f"{DEFAULT_EXECUTOR}")
    ap.add_argument("--profile", action="store_true",
                    help="print where the time of a step goes (per node and stage; always in "
                         "the summary JSON as 'profile_ms')")
    ap.add_argument("--instruction", metavar="TEXT",
                    help="the user's instruction (e.g. 'drive conservatively'), published on "
                         "/lmpc/instruction before the episode starts")
    from lmpc_llm_planner.config import add_timing_args, timing_arg_error

    add_timing_args(ap)
    args = ap.parse_args(argv)
    for name in ("decision_latency", "emergency_latency", "planning_period"):
        if getattr(args, name) is not None and args.planner in ("none", "mock"):
            ap.error(f"--{name.replace('_', '-')} needs a planner backend (not "
                     f"--planner {args.planner})")
    timing_error = timing_arg_error(args)
    if timing_error:
        ap.error(timing_error)
    if args.instruction is not None:  # the planner node drops a text it refuses
        from lmpc_llm_planner.prompt import instruction_error

        refused = instruction_error(args.instruction)
        if refused:
            ap.error(f"--instruction: {refused}")
    if args.planner_config is not None:
        from lmpc_llm_planner.config import PlannerConfigError, load_planner_config

        try:  # a bad file is named here, not by a planner node dying after the start
            load_planner_config(args.planner_config)
        except PlannerConfigError as exc:
            ap.error(f"--planner-config: {exc}")
    if args.planner == "mock" and args.mock_script is None:
        ap.error("--planner mock needs --mock-script FILE")
    for name in ("max_time_s", "wall_timeout_s"):
        if not getattr(args, name) > 0:  # the bridge refused it after the nodes started
            ap.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(args, name)}")
    if args.instruction is not None and args.planner == "none":
        ap.error("--instruction needs a planner (the MPC baseline reads no instruction)")
    return args


def node_params(args: argparse.Namespace, run_dir: Path) -> dict[str, dict[str, object]]:
    with_planner = args.planner != "none"
    llm = args.planner in ("openai", "local", "replay")
    params: dict[str, dict[str, object]] = {
        "bridge": {
            "scenario": args.scenario, "seed": args.seed, "clock_mode": args.clock,
            "wait_for_planner": with_planner and args.clock == "sync",
            "max_time_s": args.max_time_s, "run_dir": str(run_dir),
            # an LLM call may take its whole deadline (local model: tens of seconds)
            "planner_timeout_s": 180.0 if llm else 30.0,
            # a recorder (and the user's own monitors) must hear step 0 as well
            "extra_subscribers": int(args.record) + args.extra_subscribers,
        },
        # the wall-time budget of a solve is enforced only when the clock is real
        "mpc": {"use_sim_time": True, "clock_mode": args.clock,
                "profile_file": str(run_dir / "profile_mpc.json")},
    }
    if args.mpc_config is not None:
        params["mpc"]["config_file"] = str(args.mpc_config.resolve())
    if args.scene is not None:
        params["bridge"]["scene_file"] = str(args.scene.resolve())
    if args.planner not in ("none", "mock"):
        params["planner"] = {"use_sim_time": True, "backend": args.planner,
                             "run_dir": str(run_dir),
                             "profile_file": str(run_dir / "profile_planner.json")}
        for name in ("decision_latency", "emergency_latency"):
            if getattr(args, name) is not None:
                params["planner"][f"{name}_s"] = float(getattr(args, name))
        if args.decision_space is not None:
            params["planner"]["decision_space_file"] = str(args.decision_space.resolve())
        if args.planner_config:
            params["planner"]["config_file"] = str(args.planner_config.resolve())
        elif args.planner == "local":
            from lmpc_llm_planner.config import LOCAL_CONFIG_PATH  # deadline the model can meet
            params["planner"]["config_file"] = str(LOCAL_CONFIG_PATH)
        own = graph_multi.ego_planner_config(args, None, run_dir)
        if own is not None:  # at another cadence, or replaying --planner-replay's log: kept
            params["planner"]["config_file"] = str(own)
    elif args.planner == "mock":
        params["mock_llm"] = {"use_sim_time": True, "script_file": str(args.mock_script.resolve())}
        if args.decision_space is not None:
            params["mock_llm"]["decision_space_file"] = str(args.decision_space.resolve())
    return params


def decision_space_mismatch(args: argparse.Namespace) -> Optional[str]:
    """Why the graph must not start: the planner's and the MPC's decision spaces differ
    (or one of the files is bad); None when they are the same (by hash) or no planner runs.
    The MPC would refuse every decision of another space (``lmpc_mpc.controller``)."""
    from lmpc_msgs_py.vocabulary import DecisionSpaceError, load_decision_space
    from lmpc_mpc.config import MpcConfigError, load_mpc_config

    if args.planner == "none":  # no decisions; the MPC's own file must still load
        try:
            load_mpc_config(args.mpc_config)
        except MpcConfigError as exc:
            return f"{exc}; no node started"
        return None
    try:
        mpc = load_mpc_config(args.mpc_config).decision_space
        planner = load_decision_space(args.decision_space)
    except (MpcConfigError, DecisionSpaceError) as exc:
        return str(exc)
    if planner.space_hash == mpc.space_hash:
        return None
    return (f"decision spaces differ, no node started: planner {planner.describe()}, MPC "
            f"{mpc.describe()} (from {args.mpc_config or 'the packaged MPC config'}); give "
            "both the same file (--decision-space and the MPC config's decision_space_file)")


def run(args: argparse.Namespace, stops: Optional[StopSignals] = None) -> dict[str, object]:
    """Run one episode; ``stops``: the installed stop-signal handler (main() installs
    one; without it a signal ends the process as Python's defaults do)."""
    stops = stops or StopSignals()
    args.start_epoch_s = time.time()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    # a scene file names the folder by its stem (its checked `name` is not known before
    # the build, and a failed build keeps its summary in this folder too)
    label = Path(args.scene).name.split(".")[0] if args.scene is not None \
        else f"{args.scenario}-{args.seed}"
    run_dir = args.run_dir or Path("runs") / f"{label}-{stamp}"
    run_dir = run_dir.resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in ("episode.json", *PROFILE_FILES.values()):
        (run_dir / name).unlink(missing_ok=True)
    from lmpc_bridge.scenarios import SceneError
    from lmpc_bridge.scenarios.base import check_sumo_path

    try:
        check_sumo_path(run_dir, "the run directory")
    except SceneError as exc:
        stops.stopping = True
        return scene_failure(run_dir, args, f"{exc} (no node was started)")
    if args.scene is not None:
        # Check the scene file and its network before any node starts (the bridge reuses
        # this build); problems only SUMO can see come from the bridge ("scene error:").
        from lmpc_bridge.scenarios.external import build_external_scene

        try:
            scene = build_external_scene(args.scene, work_dir=run_dir / "scene")
        except SceneError as exc:
            stops.stopping = True
            return scene_failure(run_dir, args, str(exc))
        except KeyboardInterrupt:
            return scene_failure(run_dir, args, f"stopped by {_signal_names(stops)} while "
                                 "building the scene (no node was started)")
        args.scenario, args.seed = scene.family, scene.seed
    mismatch = unknown_family(args) or decision_space_mismatch(args) or \
        graph_multi.check_args(args, run_dir / "scene")
    if mismatch is not None:
        stops.stopping = True
        return scene_failure(run_dir, args, mismatch)
    graph = Graph(run_dir, ros_env(args.domain_id), echo=not args.quiet)
    latency = CpuLatencyHold(args.cpu_dma_latency)
    args.cpu_dma_latency_state = latency.state
    if latency.state is not None:
        print(f"[run_graph] cpu_dma_latency {latency.state}", flush=True)
    try:
        if args.egos > 1:
            return _run_multi(args, stops, run_dir, graph)
        return _run_single(args, stops, run_dir, graph)
    finally:
        latency.close()


def _run_single(args: argparse.Namespace, stops: StopSignals, run_dir: Path,
                graph: Graph) -> dict[str, object]:
    """One ego: start the nodes, watch them until the bridge ends, stop them in order."""
    params = node_params(args, run_dir)
    # Keep the planner (a local LLM may saturate a core) off the core the MPC uses.
    cpus = sorted(os.sched_getaffinity(0))
    split = len(cpus) >= 2
    t0 = time.monotonic()
    interrupted = False
    order = list(params)
    if args.instruction:
        # the decision node first: it must hold the instruction before the first step
        order.sort(key=lambda n: n not in ("planner", "mock_llm"))
    crashed: list[str] = []
    try:
        if args.record:
            _start_recorder(graph, run_dir, params)
        for name in order:
            cpu_set = None
            if split and name in ("planner", "mock_llm"):
                cpu_set = {cpus[-1]}
            elif split and name == "mpc":
                cpu_set = set(cpus[:-1])
            priority = node_priorities(args.rt_priority, args.planner).get(name)
            env = {PRIORITY_ENV: str(priority)} if priority else {}  # scheduling.py
            if args.executor:
                env[EXECUTOR_ENV] = args.executor  # base_node.run_node
            child = graph.start_node(name, NODE_MODULES[name], params[name], cpus=cpu_set,
                                     env=env)
            if args.instruction and name in ("planner", "mock_llm"):
                try:
                    deliver_instruction(graph, child, args.instruction)
                except RuntimeError as exc:
                    crashed.append(f"instruction: {exc}")
                    break
        bridge = next((c for c in graph.children if c.name == "bridge"), None)
        nodes = [c for c in graph.children if c.name != "recorder"]
        while bridge is not None and not crashed:
            if bridge.proc.poll() is not None:
                break
            for child in nodes:
                if child is bridge:
                    continue
                if child.proc.poll() is not None and child.name not in crashed:
                    crashed.append(child.name)
            if crashed:
                break
            if time.monotonic() - t0 > args.wall_timeout_s:
                crashed.append("wall-timeout")
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        # from here on a stop signal no longer interrupts: the ordered stop must finish
        # (a SIGTERM inside it once left the MPC and the planner running)
        stops.stopping = True
        graph.stop()
    wall_s = time.monotonic() - t0
    return summarize(run_dir, graph, wall_s, crashed=crashed, interrupted=interrupted, args=args,
                     signals=stops.received)


def _run_multi(args: argparse.Namespace, stops: StopSignals, run_dir: Path,
               graph: Graph) -> dict[str, object]:
    """``--egos N`` > 1: the multi-ego graph (``graph_multi``)."""
    t0 = time.monotonic()
    interrupted = False
    crashed: list[str] = []
    ended_early: dict[str, float] = {}
    try:
        crashed, ended_early = graph_multi.start_and_watch(args, graph, run_dir, t0)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        stops.stopping = True
        graph.stop()
    wall_s = time.monotonic() - t0
    summary = summarize(run_dir, graph, wall_s, crashed=crashed, interrupted=interrupted,
                        args=args, signals=stops.received)
    episode_path = run_dir / "episode.json"
    episode = json.loads(episode_path.read_text()) if episode_path.exists() else {}
    summary.update(graph_multi.summary_extra(args, run_dir, episode, ended_early))
    return _write_summary(summary, run_dir, args)


def _signal_names(stops: StopSignals) -> str:
    return "/".join(dict.fromkeys(stops.received)) or "an interrupt"


def _start_recorder(graph: Graph, run_dir: Path, params: dict[str, dict[str, object]]) -> None:
    """Start scripts/record.py (rosbag2 of every topic) and wait until it records."""
    bag = run_dir / "bag"
    if bag.exists():
        shutil.rmtree(bag)
    from lmpc_msgs_py import topics

    # the producers the recorder must hear before it lets the bridge start (record.py)
    produced = [topics.CONTROL] + ([topics.DECISION, topics.PLANNER_STATUS]
                                   if any(n in params for n in ("planner", "mock_llm"))
                                   else [])
    recorder = graph.start("recorder", [
        sys.executable, str(SCRIPTS / "record.py"), "--out", str(bag),
        "--expect", ",".join(topics.topic(t) for t in produced)])
    _wait_for_log(recorder, "recording to", timeout_s=30.0)


int_in = graph_multi.int_in
seed_arg = int_in(0)
"""``--seed``: a scene seed, an integer >= 0."""


def unknown_family(args: argparse.Namespace) -> Optional[str]:
    """Why ``--scenario`` names no registered family (None: it does, or ``--scene``)."""
    if args.scene is not None:
        return None
    from lmpc_bridge.scenarios import unknown_families

    unknown = unknown_families([args.scenario])
    if unknown is None:
        return None
    return f"{unknown} (or --scene FILE for your own network); no node started"


def scene_failure(run_dir: Path, args: argparse.Namespace, detail: str) -> dict[str, object]:
    """Summary of a run that never started: its scene file or family is wrong, the MPC's
    config does not load, or the planner's and the MPC's decision spaces differ."""
    summary: dict[str, object] = {
        "scenario": str(args.scene) if args.scene is not None else args.scenario,
        "seed": args.seed, "planner": args.planner,
        "instruction": args.instruction, "clock": args.clock, "outcome": "error",
        "detail": detail, "sim_time_s": 0.0,
        "wall_time_s": 0.0, "real_time_factor": None, "collisions": 0, "decisions": 0,
        "fallbacks": 0, "late_controls": 0, "mpc_solve_ms": {}, "control_latency_ms": {},
        "metrics": {}, "warnings": [], "signals": [], "nodes": {}, "run_dir": str(run_dir),
        "bag": None,
    }
    return _write_summary(summary, run_dir, args)


def effective_emergency_latency(args: argparse.Namespace) -> Optional[float]:
    """The emergency latency the planner simulates (None: the config's)."""
    if args.emergency_latency is not None or args.decision_latency is None:
        return args.emergency_latency
    from lmpc_llm_planner.config import DEFAULT_EMERGENCY_LATENCY_S

    return min(args.decision_latency, DEFAULT_EMERGENCY_LATENCY_S)


def _write_summary(summary: dict[str, object], run_dir: Path,
                   args: argparse.Namespace) -> dict[str, object]:
    """Write the summary into the run folder (and to --summary-json)."""
    text = json.dumps(summary, indent=2)
    (run_dir / "summary.json").write_text(text)
    if args.summary_json:
        args.summary_json.parent.mkdir(parents=True, exist_ok=True)
        args.summary_json.write_text(text)
    return summary


def summarize(run_dir: Path, graph: Graph, wall_s: float, *, crashed: list[str],
              interrupted: bool, args: argparse.Namespace,
              signals: Sequence[str] = ()) -> dict[str, object]:
    episode_path = run_dir / "episode.json"
    episode = json.loads(episode_path.read_text()) if episode_path.exists() else {}
    outcome = episode.get("outcome", "error")
    detail = episode.get("detail", "")
    bridge = next((c for c in graph.children if c.name == "bridge"), None)
    bridge_failed = bridge is None or bridge.proc.returncode not in (0, None)
    if interrupted and episode and not crashed:
        # the episode had ended (the bridge lingers ~1 s to deliver its status): its
        # outcome stands; the signal only cut the shut-down short
        interrupted = False
        names = "/".join(dict.fromkeys(signals)) or "an interrupt"
        detail = "; ".join(filter(None, [detail, f"{names} after the episode ended"]))
        bridge_failed = False
    if crashed or interrupted or bridge_failed or not episode:
        outcome = "error"
        reasons = [c if c.startswith("instruction:") else stopped_early(run_dir, graph.children, c)
                   for c in crashed if c != "wall-timeout"]
        if "wall-timeout" in crashed:
            reasons.append(f"wall timeout {args.wall_timeout_s:.0f}s")
        if interrupted:
            names = "/".join(dict.fromkeys(signals)) or "an interrupt"
            reasons.append(f"interrupted by {names}")
        bridge_error = first_error_line(log_lines(run_dir, bridge)) if bridge_failed \
            or not episode else None
        if bridge_error is not None:
            reasons.append(f"bridge: {bridge_error}")
        elif not episode:
            reasons.append("the bridge wrote no episode record")
        detail = "; ".join(reasons) or detail
    sim_s = float(episode.get("sim_time_s", 0.0))
    metrics = episode.get("metrics", {})
    summary: dict[str, object] = {
        "scenario": args.scenario,
        "seed": args.seed,
        "planner": args.planner,
        "instruction": args.instruction,
        "clock": args.clock,
        "executor": args.executor or os.environ.get(EXECUTOR_ENV) or DEFAULT_EXECUTOR,
        "cpu_dma_latency": getattr(args, "cpu_dma_latency_state", None),
        "decision_latency_s": args.decision_latency,
        "emergency_latency_s": effective_emergency_latency(args),
        "planning_period_s": args.planning_period,
        "outcome": outcome,
        "detail": detail,
        "sim_time_s": sim_s,
        "wall_time_s": round(wall_s, 3),
        "real_time_factor": round(sim_s / wall_s, 3) if wall_s > 0 else None,
        "collisions": metrics.get("collisions", 0),
        "decisions": episode.get("decisions", 0),
        "fallbacks": episode.get("fallbacks", 0),
        "late_controls": episode.get("late_controls", 0),
        "mpc_solve_ms": episode.get("mpc_solve_ms", {}),
        "control_latency_ms": episode.get("control_latency_ms", {}),
        "mpc_attended_agents": episode.get("mpc_attended_agents", {}),
        **wall_split(episode, getattr(args, "start_epoch_s", None)),
        "profile_ms": read_profiles(run_dir, episode),
        "metrics": metrics,
        "warnings": episode.get("warnings", []),
        "signals": list(signals),
        "nodes": {c.name: {"exit_code": c.proc.returncode, "tracebacks": c.tracebacks,
                           "stop_s": c.stop_s}
                  for c in graph.children},
        "run_dir": str(run_dir),
        "bag": str(run_dir / "bag") if args.record else None,
    }
    return _write_summary(summary, run_dir, args)


def main(argv: Optional[Sequence[str]] = None) -> int:
    stops = StopSignals()
    stops.install()
    try:
        args = parse_args(argv)
    except KeyboardInterrupt:
        return 130
    summary = run(args, stops)
    metrics = summary["metrics"] if isinstance(summary["metrics"], dict) else {}
    _say(
        f"[run_graph] outcome={summary['outcome']} sim={summary['sim_time_s']:.1f}s "
        f"wall={summary['wall_time_s']:.1f}s rtf={summary['real_time_factor']} "
        f"decisions={summary['decisions']} fallbacks={summary['fallbacks']} "
        f"solve_ms={summary['mpc_solve_ms']} latency_ms={summary['control_latency_ms']} "
        + (f"joint O.C.={summary['joint_oc']} " if "joint_oc" in summary  # several egos
           else f"O.C.={metrics.get('overall_cost')} ")
        + f"run_dir={summary['run_dir']}")
    if summary.get("startup_wall_s") is not None:  # the episode started
        _say(f"[run_graph] startup_wall={summary['startup_wall_s']}s "
             f"episode_wall={summary.get('episode_wall_s')}s "
             f"episode_rtf={summary.get('episode_real_time_factor')}"
             + (f" attended_agents={summary['mpc_attended_agents']}"
                if summary.get("mpc_attended_agents") else ""))  # per ego with several
    if args.profile and summary.get("profile_ms"):
        _say(profile_table(summary["profile_ms"]))  # type: ignore[arg-type]
    if summary["detail"]:
        _say(f"[run_graph] {summary['detail']}")
    for line in summary.get("warnings") or []:
        _say(f"[run_graph] warning: {line}")
    return EXIT_CODES.get(str(summary["outcome"]), 3)


if __name__ == "__main__":
    raise SystemExit(main())
