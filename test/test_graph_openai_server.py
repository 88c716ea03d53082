"""The ``openai`` backend against a real OpenAI-compatible server (issue 22).

llama-cpp-python's own server (``python -m llama_cpp.server``, the ``server`` extra) serves
the SmolLM2-135M GGUF we ship on a free loopback port; the graph runs usi seed 0 with
``--planner openai`` on the sync clock and ``config/planner_server.yaml`` (deadline the CPU
model can meet, fixed 2.5 s simulated latency). The server refuses the OpenAI
``json_schema`` form with HTTP 500, so the backend has to negotiate down to the form it
takes (``{"type": "json_object", "schema": ...}``). Fake-server tests of the error paths
and the negotiation are in src/lmpc_llm_planner/test/test_planner_backend_openai.py.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Iterator

import pytest

from graphkit import graph_processes, run_graph

pytestmark = [pytest.mark.graph, pytest.mark.slow]

MODEL_ALIAS = "smollm2"
SERVER_START_S = 120.0
MIN_VALID_SHARE = 0.9


def free_port() -> int:
    """A loopback port nothing listens on now (bound, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def server_command(port: int) -> list[str]:
    """The command the README gives, on ``port``; skips the test without the extra."""
    pytest.importorskip("llama_cpp.server", reason="needs the server extra: "
                        "pip install -e 'src/lmpc_llm_planner[local,server]'")
    from lmpc_llm_planner.backends import BackendError
    from lmpc_llm_planner.backends.local import find_packaged_model

    try:
        model = find_packaged_model()
    except BackendError as exc:
        pytest.skip(str(exc))
    return [sys.executable, "-m", "llama_cpp.server", "--model", str(model),
            "--host", "127.0.0.1", "--port", str(port), "--n_threads", "1",
            # one thread for the prompt too (the server's default is every CPU)
            "--n_threads_batch", "1", "--n_ctx", "2048", "--model_alias", MODEL_ALIAS]


def stop_group(proc: subprocess.Popen[bytes]) -> None:
    """SIGINT, then SIGTERM, then SIGKILL to the server's process group."""
    for sig, wait_s in ((signal.SIGINT, 10.0), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            break
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            continue


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.fixture
def llama_server(tmp_path: Path) -> Iterator[str]:
    """Base URL of a llama-cpp-python server on a free port; stopped (group) afterwards."""
    port = free_port()
    log = (tmp_path / "server.log").open("wb")
    proc = subprocess.Popen(server_command(port), stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    base_url = f"http://127.0.0.1:{port}/v1"
    try:
        t_end = time.monotonic() + SERVER_START_S
        while True:
            if proc.poll() is not None:
                raise AssertionError(f"server exited ({proc.returncode}):\n"
                                     + (tmp_path / "server.log").read_text()[-3000:])
            try:
                with urllib.request.urlopen(base_url + "/models", timeout=2.0) as resp:
                    if resp.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > t_end:
                raise AssertionError(f"server not up within {SERVER_START_S:.0f} s")
            time.sleep(0.5)
        yield base_url
    finally:
        stop_group(proc)
        log.close()
        assert proc.poll() is not None and not group_alive(proc.pid), "server left running"


@pytest.mark.timeout(1500)
def test_usi_through_llama_cpp_server(tmp_path: Path, domain_id: int, llama_server: str,
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from lmpc_llm_planner.config import SERVER_CONFIG_PATH

    monkeypatch.setenv("LMPC_OPENAI_BASE_URL", llama_server)
    monkeypatch.setenv("LMPC_OPENAI_MODEL", MODEL_ALIAS)
    run = run_graph(tmp_path, domain_id, "--scenario", "usi", "--seed", "0",
                    "--planner", "openai", "--planner-config", str(SERVER_CONFIG_PATH),
                    "--clock", "sync", "--quiet", "--wall-timeout-s", "1200",
                    timeout_s=1300)
    s = run.summary
    assert run.crosstalk == [], "another graph shared this test's ROS domain"
    assert s["outcome"] == "reached", f"{s['outcome']}: {s['detail']}\n{run.output[-3000:]}"
    assert run.returncode == 0 and s["collisions"] == 0
    records = [json.loads(line) for line in
               (tmp_path / "run" / "decisions.jsonl").read_text().splitlines()]
    assert len(records) == s["decisions"] >= 5
    model = [r for r in records if r["source"] == f"llm:{MODEL_ALIAS}"]
    assert len(model) >= MIN_VALID_SHARE * len(records), [
        (r["source"], r["error_kind"]) for r in records]
    assert s["fallbacks"] == len(records) - len(model)
    # The answers are the model's (schema-valid: the planner validated every one), each
    # within the output budget, and they took real wall time (not a canned reply).
    for r in model:
        last = r["attempts"][-1]
        assert last["error_kind"] is None and last["tokens_out"] <= 384
        assert r["measured_latency_s"] > 0.2 and r["latency_s"] == pytest.approx(2.5)
    planner_log = (tmp_path / "run" / "planner.log").read_text(errors="replace")
    assert "valid answers with response form json_object_schema" in planner_log
    assert not graph_processes(domain_id)
