"""Helpers for graph tests: run the graph as a user would, one ROS domain per run."""
from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from lmpc_msgs_py.discovery import stay_local

REPO = Path(__file__).resolve().parents[1]
RUN_GRAPH = REPO / "scripts" / "run_graph.py"
TOPICS = REPO / "scripts" / "topics.py"

stay_local()


def scripts_module(name: str) -> Any:
    """``scripts/<name>.py`` of this checkout (the installed lmpc_scripts may be another's)."""
    import importlib

    sys.path.insert(0, str(REPO / "scripts"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(REPO / "scripts"))


_domains = itertools.count()


def next_domain_id() -> int:
    """A domain id of its own for each graph (parallel runs never cross-talk).

    Ids 1..100 are valid with Fast DDS' default port mapping; spread by pid so two
    pytest processes on one machine pick different ones. ``LMPC_TEST_DOMAINS=60-69``
    confines one pytest process to a range (people running tests side by side)."""
    span = os.environ.get("LMPC_TEST_DOMAINS")
    if span:
        low, high = (int(v) for v in span.split("-"))
        return low + next(_domains) % (high - low + 1)
    return 1 + (os.getpid() * 7 + next(_domains)) % 100


@dataclass
class GraphRun:
    returncode: int
    summary: dict[str, Any]
    episode: dict[str, Any]
    output: str
    crosstalk: list[str]
    """Node warnings about several publishers on a one-producer topic (another graph on
    the domain): a run that has any did not drive on its own data."""


def run_graph(tmp_path: Path, domain_id: int, *extra: str, timeout_s: float = 300) -> GraphRun:
    """Run scripts/run_graph.py to the end of the episode; return its summary and record."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    run_dir = tmp_path / "run"
    summary_path = tmp_path / "summary.json"
    cmd = [sys.executable, str(RUN_GRAPH), "--run-dir", str(run_dir), "--summary-json",
           str(summary_path), "--domain-id", str(domain_id), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=tmp_path)
    output = proc.stdout + proc.stderr
    if not summary_path.exists():
        raise AssertionError(
            f"run_graph wrote no summary (exit {proc.returncode}):\n{output[-4000:]}")
    summary = json.loads(summary_path.read_text())
    episode_path = run_dir / "episode.json"
    episode = json.loads(episode_path.read_text()) if episode_path.exists() else {}
    crosstalk = [line for log in sorted(run_dir.glob("*.log"))
                 for line in log.read_text(errors="replace").splitlines()
                 if "publishers on" in line]
    return GraphRun(proc.returncode, summary, episode, output, crosstalk)


def graph_processes(domain_id: int) -> list[int]:
    """Pids of node processes (``python -m lmpc_*``) running on ``domain_id``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"-m" in cmdline and any(a.startswith(b"lmpc_") for a in cmdline) and \
                f"ROS_DOMAIN_ID={domain_id}".encode() in environ:
            pids.append(int(entry.name))
    return pids


# -- node-level harness for fault tests (RELIABILITY.md) -------------------------------------
# run_graph() above runs a whole episode as a user would; the helpers below start single
# node processes (with ROS remaps), kill them, publish raw payloads into the graph and read
# the nodes' diagnostics — what the fault, refusal and injection tests need.

NODE_MODULES = {
    "bridge": "lmpc_bridge.bridge_node",
    "mpc": "lmpc_mpc.mpc_node",
    "planner": "lmpc_llm_planner.planner_node",
    "mock_llm": "lmpc_llm_planner.mock_llm_node",
}
FAULT_RELAY = REPO / "scripts" / "fault_relay.py"


def node_env(domain_id: int, **extra: str) -> dict[str, str]:
    """Environment of a node process on ``domain_id`` (loopback discovery, unbuffered)."""
    env = dict(os.environ)
    stay_local(env)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    env.update(extra)
    return env


@dataclass
class NodeProc:
    """One node process with its log file (stdout + stderr)."""

    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path

    def log(self) -> str:
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None


class NodeSet:
    """Node processes of one test, each logging to ``run_dir/<name>.log``.

    Use as a context manager: leaving it SIGINTs every process still running
    (SIGKILL after ``stop_timeout_s``), so no test leaves a node behind."""

    def __init__(self, run_dir: Path, domain_id: int) -> None:
        self.run_dir = run_dir
        self.domain_id = domain_id
        self.procs: dict[str, NodeProc] = {}
        run_dir.mkdir(parents=True, exist_ok=True)

    def __enter__(self) -> "NodeSet":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()

    def start(self, name: str, params: dict[str, object], *, module: str | None = None,
              remaps: dict[str, str] | None = None, env: dict[str, str] | None = None
              ) -> NodeProc:
        """Start ``python -m <module> --ros-args -p k:=v ... -r from:=to ...``."""
        args = [sys.executable, "-m", module or NODE_MODULES[name], "--ros-args"]
        for key, value in params.items():
            text = str(value).lower() if isinstance(value, bool) else str(value)
            args += ["-p", f"{key}:={text or repr('')}"]  # YAML '' for an empty string
        for src, dst in (remaps or {}).items():
            args += ["-r", f"{src}:={dst}"]
        return self.start_cmd(name, args, env=env)

    def start_cmd(self, name: str, args: list[str], *, env: dict[str, str] | None = None
                  ) -> NodeProc:
        log_path = self.run_dir / f"{name}.log"
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(args, env=node_env(self.domain_id, **(env or {})),
                                    stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, cwd=self.run_dir)
        node = NodeProc(name, proc, log_path)
        self.procs[name] = node
        return node

    def wait_for_log(self, name: str, needle: str, timeout_s: float) -> float:
        """Wall time (monotonic) when ``needle`` appeared in the node's log."""
        deadline = time.monotonic() + timeout_s
        node = self.procs[name]
        while time.monotonic() < deadline:
            if needle in node.log():
                return time.monotonic()
            if not node.alive():
                break
            time.sleep(0.05)
        raise AssertionError(f"{name} did not log {needle!r} within {timeout_s:.0f} s "
                             f"(alive={node.alive()}):\n{node.log()[-3000:]}")

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        try:
            os.killpg(self.procs[name].proc.pid, sig)
        except ProcessLookupError:
            pass

    def wait_exit(self, name: str, timeout_s: float) -> int:
        """Wait for ``name`` to exit; fail at once (with its log) if another node of
        the set died with an error meanwhile."""
        deadline = time.monotonic() + timeout_s
        node = self.procs[name]
        while time.monotonic() < deadline:
            code = node.proc.poll()
            if code is not None:
                return code
            for other in self.procs.values():
                rc = other.proc.poll()
                if other is not node and rc not in (None, 0, -signal.SIGKILL):
                    raise AssertionError(f"{other.name} exited with {rc} while waiting for "
                                         f"{name}:\n{other.log()[-3000:]}")
            time.sleep(0.1)
        raise AssertionError(f"{name} still running after {timeout_s:.0f} s:\n"
                             f"{node.log()[-2000:]}")

    def stop(self, name: str, timeout_s: float = 10.0) -> int:
        """SIGINT, then SIGKILL after ``timeout_s``; the exit code (negative: killed)."""
        node = self.procs[name]
        if node.alive():
            self.kill(name, signal.SIGINT)
        try:
            return node.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.kill(name, signal.SIGKILL)
            return node.proc.wait(timeout=5.0)

    def stop_all(self, timeout_s: float = 10.0) -> dict[str, int]:
        """SIGINT every running process once, then wait; SIGKILL what lingers."""
        for name, node in self.procs.items():
            if node.alive():
                self.kill(name, signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        codes = {}
        for name, node in self.procs.items():
            try:
                codes[name] = node.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.kill(name, signal.SIGKILL)
                codes[name] = node.proc.wait(timeout=5.0)
        return codes

    def tracebacks(self) -> dict[str, int]:
        """Python tracebacks per node log (a node that died of an exception)."""
        return {name: node.log().count("Traceback (most recent call last)")
                for name, node in self.procs.items()}


# rclpy 7.1.6 at interpreter exit, after the node shut down cleanly: the garbage
# collector finalises a Task whose __init__ never ran to the end and its __del__ fails.
# Printed as "Exception ignored in: <function Future.__del__ ...>"; not the node's code.
_RCLPY_TEARDOWN_NOISE = ("Exception ignored in: <function Future.__del__",
                         "AttributeError: 'Task' object has no attribute '_exception'")


def logs_with_tracebacks(run_dir: Path) -> dict[str, int]:
    """``{log file: number of tracebacks}`` for every ``*.log`` in ``run_dir`` with one
    (the known rclpy teardown message above excepted)."""
    out = {}
    for path in sorted(run_dir.glob("*.log")):
        text = path.read_text(encoding="utf-8", errors="replace")
        n = text.count("Traceback (most recent call last)")
        if all(line in text for line in _RCLPY_TEARDOWN_NOISE):
            n -= min(text.count(_RCLPY_TEARDOWN_NOISE[0]), text.count(_RCLPY_TEARDOWN_NOISE[1]))
        if n:
            out[path.name] = n
    return out


def bridge_params(run_dir: Path, *, scenario: str = "usi", seed: int = 0,
                  clock_mode: str = "realtime", max_time_s: float = 60.0,
                  wait_for_planner: bool = False, **extra: object) -> dict[str, object]:
    """Bridge parameters as run_graph.py sets them (plus ``extra``)."""
    return {"scenario": scenario, "seed": seed, "clock_mode": clock_mode,
            "wait_for_planner": wait_for_planner, "max_time_s": max_time_s,
            "run_dir": str(run_dir), **extra}


def read_episode(run_dir: Path) -> dict[str, Any]:
    path = run_dir / "episode.json"
    if not path.exists():
        raise AssertionError(f"no episode record in {run_dir}")
    return json.loads(path.read_text())


class Probe:
    """An in-process ROS participant of the test: publishes raw ``std_msgs/String``
    payloads, records topics and the latest diagnostics of every node.

    Its own rclpy context on ``domain_id``, spun by a background thread (single-threaded
    executor; MultiThreadedExecutor is broken in the PyPI wheels)."""

    def __init__(self, domain_id: int) -> None:
        import threading

        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("lmpc_test_probe", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.lock = threading.Lock()
        self.received: dict[str, list[tuple[float, Any]]] = {}
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.diag_messages: dict[str, str] = {}
        self._pubs: dict[str, Any] = {}
        self._subs: dict[str, Any] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - shutting down
                if self._stop:
                    return
                raise

    def _on_diag(self, msg: Any) -> None:
        with self.lock:
            for st in msg.status:
                self.diagnostics[st.name] = {kv.key: kv.value for kv in st.values}
                self.diag_messages[st.name] = st.message

    def diag(self, node_name: str) -> dict[str, str]:
        """Latest diagnostics values of the node named ``node_name`` (e.g. /sumo_bridge)."""
        with self.lock:
            return dict(self.diagnostics.get(node_name, {}))

    def diag_count(self, node_name: str, key: str) -> int:
        return int(float(self.diag(node_name).get(key, "0")))

    def listen(self, topic: str, msg_type: Any = None, qos: Any = None) -> None:
        """Record every message on ``topic`` as (wall monotonic time, message)."""
        from std_msgs.msg import String

        from lmpc_msgs_py import qos as lmpc_qos

        self.received.setdefault(topic, [])

        def cb(msg: Any, name: str = topic) -> None:
            with self.lock:
                self.received[name].append((time.monotonic(), msg))

        self._subs[topic] = self.node.create_subscription(
            msg_type or String, topic, cb, qos or lmpc_qos.STREAM)

    def messages(self, topic: str) -> list[tuple[float, Any]]:
        with self.lock:
            return list(self.received.get(topic, []))

    def publish(self, topic: str, text: str, qos: Any = None) -> None:
        """Publish ``text`` as a ``std_msgs/String`` on ``topic`` (raw: no validation)."""
        from std_msgs.msg import String

        from lmpc_msgs_py import qos as lmpc_qos

        pub = self._pubs.get(topic)
        if pub is None:
            # as the nodes publish (transient local, compatible with every reader: the
            # MPC reads decisions transient local, lmpc_qos.DECISION_IN)
            pub = self._pubs[topic] = self.node.create_publisher(
                String, topic, qos or lmpc_qos.PRODUCED)
        pub.publish(String(data=text))

    def wait_subscribers(self, topic: str, count: int, timeout_s: float) -> None:
        """Wait until ``topic`` (a topic this probe publishes) has ``count`` subscribers."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if topic in self._pubs and self._pubs[topic].get_subscription_count() >= count:
                return
            time.sleep(0.05)
        have = self._pubs[topic].get_subscription_count() if topic in self._pubs else 0
        raise AssertionError(f"{topic}: {have} subscribers after {timeout_s:.0f} s, "
                             f"expected {count}")

    def wait_publishers(self, topic: str, count: int, timeout_s: float) -> None:
        """Wait until this probe's subscription on ``topic`` (see :meth:`listen`) has matched
        ``count`` publishers. A short sync run can finish before discovery on a busy machine
        has matched a late subscriber, so tests that count messages wait for this first."""
        sub = self._subs[topic]
        self.wait_until(f"{count} publisher(s) on {topic}",
                        lambda: sub.get_publisher_count() >= count, timeout_s)

    def wait_until(self, what: str, pred: Any, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if pred():
                return
            time.sleep(0.05)
        raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> "Probe":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- a fake OpenAI-compatible LLM server with failure modes ----------------------------------
FAKE_LLM_MODES = ("valid", "delay", "hang", "garbage", "fenced", "two_objects",
                  "unknown_action", "ghost", "nan", "empty", "crash")


def fake_llm_reply(mode: str, request: dict[str, Any]) -> str:
    """The decision text a fake model answers in ``mode`` to a chat-completions request.

    ``valid``: neutral choices (route candidate 0, neutral intervals of the default MPC
    config, normal weights) in the shape the request's schema asks for (the emergency
    form has no ``scenario_encoding``); with a coordinator's ``yield`` command in the
    prompt (multi-ego graphs) the braking interval [-4, -2] m/s^2 instead. A coordinator's
    request (a ``verdicts`` schema) gets :func:`fake_coordinator_reply`. The faulty modes
    derive from the neutral answer."""
    schema = ((request.get("response_format") or {}).get("json_schema") or {}).get("schema", {})
    props = schema.get("properties", {}) if isinstance(schema, dict) else {}
    if "verdicts" in props and mode == "valid":
        return fake_coordinator_reply(request)
    obj: dict[str, Any] = {"reasoning": "fake model: keep going"}
    if not props or "scenario_encoding" in props:
        obj["scenario_encoding"] = {"ego_trajectory": 0, "attention": [],
                                    "agent_trajectories": {}}
    obj["action_guidance"] = {"accel_interval": 3, "steer_interval": 2}
    if mode == "valid" and "yield at" in _command_line(request):
        # it reads the coordinator's command in its prompt: brake ([-4, -2] m/s^2)
        obj["reasoning"] = "fake model: the coordinator says yield"
        obj["action_guidance"]["accel_interval"] = 1
    obj["weight_adjustment"] = {k: "normal" for k in
                                ("tracking", "action", "smoothness", "safety")}
    if mode == "garbage":
        return "I think the car should probably slow down a little and then go."
    if mode == "fenced":
        return "```json\n" + json.dumps(obj) + "\n```"
    if mode == "two_objects":
        return json.dumps(obj) + "\n" + json.dumps(obj)
    if mode == "unknown_action":
        obj["action_guidance"]["accel_interval"] = 29  # outside the configured pool
        return json.dumps(obj)
    if mode == "ghost":
        obj.setdefault("scenario_encoding", {"ego_trajectory": 0, "attention": [],
                                             "agent_trajectories": {}})
        obj["scenario_encoding"]["attention"] = ["ghost_vehicle_42"]
        return json.dumps(obj)
    if mode == "nan":
        return json.dumps(obj).replace('"accel_interval": 3', '"accel_interval": NaN')
    if mode == "empty":
        return ""
    return json.dumps(obj)


def _command_line(request: dict[str, Any]) -> str:
    """The coordinator's command line of a planner prompt ('' = none)."""
    for m in request.get("messages", []):
        for line in str(m.get("content", "")).splitlines():
            if line.startswith("Coordinator's command"):
                return line
    return ""


def fake_coordinator_reply(request: dict[str, Any]) -> str:
    """A coordinator's answer (``lmpc_llm_planner.coordination.llm``) from its prompt: the
    car that cannot stop any more, else the one nearest its conflict's entry (ties: the
    first listed) proceeds, every other car yields. A fixed rule read off the prompt's
    lines, not the project's rule set (no memory of earlier rounds)."""
    import re

    user = next((m.get("content", "") for m in request.get("messages", [])
                 if m.get("role") == "user"), "")
    cars = []
    for line in str(user).splitlines():
        m = re.match(r"- (\S+): .*?(\d+) m to its entry.*can still stop before the hold "
                     r"point: (yes|no)", line)
        if m:
            cars.append((m.group(3) == "yes", int(m.group(2)), len(cars), m.group(1)))
    order = [c[3] for c in sorted(cars)]
    return json.dumps({"reasoning": "fake coordinator: committed or nearest first",
                       "verdicts": [{"ego_id": e, "command": "proceed" if k == 0 else "yield",
                                     "priority": k} for k, e in enumerate(order)]})


class FakeLlmServer:
    """OpenAI-compatible ``/v1/chat/completions`` on 127.0.0.1 that answers call *i* in
    ``script[i]`` mode (``valid`` after the script ends). Simulates a model: it never
    reads the prompt, only the response schema's shape.

    Modes: ``valid``; ``delay`` (a valid answer ``delay_s`` late); ``hang`` (no answer
    for ``hang_s``); ``garbage`` (prose); ``fenced``; ``two_objects``; ``unknown_action``
    (interval index outside the pool); ``ghost`` (attends an agent that is not there);
    ``nan``; ``empty``; ``crash`` (the connection is closed without a reply, and every
    later call too: a server that died after N calls)."""

    def __init__(self, script: list[str], *, delay_s: float = 2.0, hang_s: float = 30.0) -> None:
        import http.server
        import threading

        for mode in script:
            if mode not in FAKE_LLM_MODES:
                raise ValueError(f"unknown fake LLM mode {mode!r}")
        self.script = list(script)
        self.delay_s = delay_s
        self.hang_s = hang_s
        self.calls: list[str] = []
        self.prompts: list[str] = []
        """The user message of every call, in order."""
        self.dead = False
        self._lock = threading.Lock()
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args: object) -> None:
                pass

            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                length = int(self.headers.get("Content-Length", "0"))
                body = json.loads(self.rfile.read(length) or b"{}")
                with outer._lock:
                    i = len(outer.calls)
                    mode = outer.script[i] if i < len(outer.script) else "valid"
                    if outer.dead:
                        mode = "crash"
                    if mode == "crash":
                        outer.dead = True
                    outer.calls.append(mode)
                    outer.prompts.append(next(
                        (str(m.get("content", "")) for m in body.get("messages", [])
                         if m.get("role") == "user"), ""))
                if mode == "crash":
                    self.close_connection = True
                    return  # no status line: the client sees the connection drop
                if mode == "delay":
                    time.sleep(outer.delay_s)
                elif mode == "hang":
                    time.sleep(outer.hang_s)
                text = fake_llm_reply(mode, body)
                reply = json.dumps({
                    "id": f"fake-{i}", "object": "chat.completion", "model": "fake",
                    "choices": [{"index": 0, "finish_reason": "stop",
                                 "message": {"role": "assistant", "content": text}}],
                    "usage": {"prompt_tokens": 100, "completion_tokens": 50},
                }).encode()
                try:
                    self.send_response(200)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(reply)))
                    self.end_headers()
                    self.wfile.write(reply)
                except OSError:
                    pass  # the client gave up (deadline): a late reply nobody reads

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self._thread.start()

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()

    def __enter__(self) -> "FakeLlmServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_planner_config(path: Path, **overrides: Any) -> Path:
    """The packaged planner YAML with ``overrides`` (nested dicts merge) written to ``path``."""
    import yaml

    from lmpc_llm_planner import config as planner_config

    base = Path(planner_config.__file__).parent / "config" / "planner.yaml"
    data = yaml.safe_load(base.read_text())
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key].update(value)
        else:
            data[key] = value
    path.write_text(yaml.safe_dump(data))
    return path


def write_mpc_config(path: Path, **overrides: Any) -> Path:
    """The packaged MPC YAML with top-level ``overrides`` written to ``path``."""
    import yaml

    from lmpc_mpc import config as mpc_config

    base = Path(mpc_config.__file__).parent / "config" / "mpc.yaml"
    data = yaml.safe_load(base.read_text())
    data.update(overrides)
    path.write_text(yaml.safe_dump(data))
    return path


def read_until(proc: "subprocess.Popen[str]", prefix: str) -> list[str]:
    """The lines ``proc`` printed up to and including the first that starts with
    ``prefix`` (asserted: the process printed it before it ended)."""
    lines: list[str] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line)
        if line.startswith(prefix):
            break
    assert lines and lines[-1].startswith(prefix), "".join(lines)
    return lines


def interrupt_after(proc: "subprocess.Popen[str]", prefix: str,
                    check: "Callable[[], None] | None" = None) -> str:
    """Everything ``proc`` printed, stopped with SIGTERM once a line starts with ``prefix``
    (after ``check()``, an assertion on what is written so far); its group is killed if
    it still runs 60 s later or the check fails."""
    lines: list[str] = []
    rest = ""
    try:
        lines = read_until(proc, prefix)
        if check is not None:
            check()
        proc.send_signal(signal.SIGTERM)
        rest, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return "".join(lines) + rest
