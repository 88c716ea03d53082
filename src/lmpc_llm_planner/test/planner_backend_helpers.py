"""Helpers of the backend tests: a fake OpenAI-compatible chat server on 127.0.0.1 and
request builders. Not a test module (no ``test_`` prefix)."""
from __future__ import annotations

import json
import socket
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable, Optional

from lmpc_mpc.config import MpcConfig

from lmpc_llm_planner.backends.base import DecisionRequest
from lmpc_llm_planner.config import PlannerConfig
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene

SECRET = "sk-test-SECRET-0123456789abcdef"


def make_request(obs, *, config: PlannerConfig, mpc_config: MpcConfig, **kw) -> DecisionRequest:
    scene = build_scene(obs, lookahead_m=config.lookahead_m,
                        max_agents=config.max_agents_in_prompt)
    return build_request(scene, config=config, mpc_config=mpc_config, **kw)


def completion(content: Optional[str], *, usage: Optional[dict] = None) -> dict[str, Any]:
    """A chat-completions reply body carrying ``content``."""
    body: dict[str, Any] = {
        "id": "chatcmpl-1", "object": "chat.completion", "model": "test-model",
        "choices": [{"index": 0, "finish_reason": "stop",
                     "message": {"role": "assistant", "content": content}}],
    }
    if usage is not None:
        body["usage"] = usage
    return body


@dataclass
class Answer:
    """What the fake server does with one request."""

    status: int = 200
    body: bytes = b""
    delay_s: float = 0.0


Action = Callable[[dict[str, Any]], Answer]
"""Request JSON -> the answer (lets a test answer by the request's content)."""


def ok(content: str, **kw) -> Action:
    return lambda req: Answer(200, json.dumps(completion(content, **kw)).encode())


@dataclass
class Seen:
    path: str
    headers: dict[str, str]
    json: dict[str, Any]


@dataclass
class FakeChatServer:
    """A chat-completions server in a thread; answers with the queued actions in order
    (then with ``default``)."""

    actions: list[Action] = field(default_factory=list)
    default: Optional[Action] = None
    seen: list[Seen] = field(default_factory=list)

    def __post_init__(self) -> None:
        fake = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                n = int(self.headers.get("Content-Length") or 0)
                raw = self.rfile.read(n)
                try:
                    req = json.loads(raw)
                except ValueError:
                    req = {}
                fake.seen.append(Seen(self.path, dict(self.headers.items()), req))
                action = fake.actions.pop(0) if fake.actions else fake.default
                answer = action(req) if action else Answer(500, b"no action queued")
                if answer.delay_s:
                    time.sleep(answer.delay_s)
                try:
                    self.send_response(answer.status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(answer.body)))
                    self.end_headers()
                    self.wfile.write(answer.body)
                except OSError:
                    pass  # the client gave up (deadline): nothing to answer

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.server.block_on_close = False  # a handler still sleeping must not block close
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/v1"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def refused_port() -> int:
    """A port on 127.0.0.1 that nothing listens on (bound, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
