"""The ``openai`` backend: any OpenAI-compatible chat-completions endpoint.

Works with OpenAI, vLLM, Ollama (``/v1``) and the llama.cpp server. It speaks plain
HTTP through the standard library (``http.client``), on purpose not through the
``openai`` package: a pinned client that breaks on upgrade is a known failure of
earlier LanguageMPC code, and the protocol used here is one POST.

- Deadline: the whole call (connect, send, every read) must finish within
  ``request.deadline_s`` of wall time (the planner's deadline, default 8 s); each
  socket operation gets the time that is left, so the client's own default (600 s in
  the ``openai`` package) never applies. Past the deadline -> ``error_kind="timeout"``.
- Structured output (``openai.response_format``, default ``auto``): the decision schema
  narrowed to the request (``constrain.narrow_schema``) goes to the server in the first
  form it accepts, tried in this order (``FORMS``): OpenAI ``json_schema`` (OpenAI, vLLM,
  llama.cpp's ``llama-server``); ``{"type": "json_object", "schema": ...}``
  (llama-cpp-python's server, grammar-constrained); Ollama's ``format``; vLLM's
  ``guided_json``; plain ``json_object``; none. A 4xx / 5xx whose body names the format
  (``FORMAT_REFUSAL``: llama-cpp-python answers ``json_schema`` with HTTP 500 "Input
  should be 'text' or 'json_object'") means "not supported": the same call steps down to
  the next form at once; any other error is a transport error. The first form that gives
  a valid answer is kept for the rest of the run and logged. An explicit setting is the
  only form used (no negotiation).
- Output budget: ``max_tokens`` is what the longest valid answer of the narrowed schema
  needs (``constrain.output_token_budget``; ``reasoning`` capped at
  ``max_reasoning_chars``), at most ``max_output_tokens``; the prompt shows that compact
  answer form (``constrain.compact_prompt``). A reply cut off at ``max_tokens``
  (``finish_reason: length``) is flagged ``truncated``: the planner's re-ask tells the
  model so.
- Tokens in / out from the reply's ``usage`` when present (else 0: the planner then
  uses its estimate).
- The API key: read once from the environment, sent only in the ``Authorization``
  header, never logged, never in an error message (server text is redacted), never in
  ``repr``. Over plain http it is sent only to a loopback host unless
  ``allow_plain_http_key`` is set.

Not supported: HTTP proxies (``HTTPS_PROXY``), streaming, tool calls.
"""
from __future__ import annotations

import http.client
import ipaddress
import json
import logging
import os
import re
import socket
import ssl
import threading
import time
import urllib.parse
from dataclasses import dataclass
from typing import Any, Callable, Literal, Mapping, Optional

from lmpc_llm_planner.backends.base import BackendError, BackendReply, DecisionRequest
from lmpc_llm_planner.backends.constrain import (
    SYSTEM_PROMPT,
    compact_prompt,
    narrow_schema,
    output_token_budget,
)
from lmpc_llm_planner.config import OpenAIConfig
from lmpc_llm_planner.validation import parse_decision

LOG = logging.getLogger(__name__)

ENV_BASE_URL = "LMPC_OPENAI_BASE_URL"
ENV_MODEL = "LMPC_OPENAI_MODEL"
ENV_KEY_FALLBACK = "OPENAI_API_KEY"
FORMS: tuple[str, ...] = ("json_schema", "json_object_schema", "ollama_format", "guided_json",
                          "json_object", "none")
"""Structured-output forms in the order ``auto`` tries them (strongest constraint first)."""
FORMAT_REFUSAL = re.compile(
    r"response_format|json_schema|json_object|guided_json|\bformat\b", re.IGNORECASE)
"""An error body naming one of these refuses the form, not the request: step down."""
OUTPUT_SLACK_TOKENS = 32
MAX_BODY_BYTES = 4_000_000
"""A reply body larger than this is refused (a decision is a few kB)."""
MAX_ERROR_EXCERPT = 300
SCHEMA_NAME = "lmpc_decision"
SOURCE_PATTERN = re.compile(r"[^\w.:/\-]")
KEY_CHARS = re.compile(r"^[\x21-\x7e]+$")
"""Printable ASCII without spaces: what an ``Authorization`` header can carry."""
KEY_REQUIRED_HOSTS = ("api.openai.com",)
"""Hosts that answer nothing without a key: fail at start-up, not on every call."""

ResponseFormat = Literal["json_schema", "json_object_schema", "ollama_format", "guided_json",
                         "json_object", "none"]


class _Deadline(Exception):
    """The call ran past the request's deadline."""


@dataclass(frozen=True)
class Endpoint:
    """Where requests go (no secret in here: safe to log)."""

    scheme: str
    host: str
    port: int
    path: str
    """Path of ``.../chat/completions``."""

    @property
    def url(self) -> str:
        return f"{self.scheme}://{self.host}:{self.port}{self.path}"

    @property
    def loopback(self) -> bool:
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False


def parse_endpoint(base_url: str) -> Endpoint:
    """``base_url`` (e.g. ``http://127.0.0.1:8000/v1``) -> the chat-completions endpoint.

    Raises :class:`BackendError` for a URL that is not http(s) with a host.
    """
    parts = urllib.parse.urlsplit(base_url.strip())
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise BackendError(
            f"openai backend: base URL {base_url!r} must be http(s)://host[:port]/path "
            f"(set openai.base_url or {ENV_BASE_URL})"
        )
    if parts.username or parts.password:
        raise BackendError(
            "openai backend: the base URL must not carry credentials; put the key in "
            f"the environment ({ENV_KEY_FALLBACK} or openai.api_key_env)"
        )
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        raise BackendError(f"openai backend: base URL {base_url!r} has a bad port") from None
    path = parts.path.rstrip("/")
    if not path.endswith("/chat/completions"):
        path += "/chat/completions"
    return Endpoint(scheme=parts.scheme, host=parts.hostname, port=port, path=path)


def source_name(model: str) -> str:
    """Decision source ``llm:<model>`` (characters the message schema refuses -> ``-``)."""
    return "llm:" + SOURCE_PATTERN.sub("-", model)[:96]


def format_fields(
    fmt: ResponseFormat, schema: Mapping[str, Any], *, strict: bool
) -> dict[str, Any]:
    """The request fields that ask for structured output in form ``fmt`` (none for none)."""
    if fmt == "json_schema":
        return {"response_format": {
            "type": "json_schema",
            "json_schema": {"name": SCHEMA_NAME, "schema": dict(schema), "strict": strict},
        }}
    if fmt == "json_object_schema":
        return {"response_format": {"type": "json_object", "schema": dict(schema)}}
    if fmt == "ollama_format":
        return {"format": dict(schema)}
    if fmt == "guided_json":
        return {"guided_json": dict(schema)}
    if fmt == "json_object":
        return {"response_format": {"type": "json_object"}}
    return {}


def refuses_format(status: int, body: bytes) -> bool:
    """Whether an HTTP error answer says the structured-output form is not supported."""
    return status >= 400 and bool(FORMAT_REFUSAL.search(body[:MAX_ERROR_EXCERPT * 10]
                                                        .decode("utf-8", "replace")))


class OpenAIBackend:
    """Chat-completions client; see the module docstring. Thread-safe."""

    def __init__(
        self,
        config: OpenAIConfig,
        *,
        api_key: Optional[str] = None,
        base_url: Optional[str] = None,
        model: Optional[str] = None,
    ) -> None:
        self.config = config
        self.model = model or config.model
        self.endpoint = parse_endpoint(base_url or config.base_url)
        self.name = source_name(self.model)
        self._api_key = (api_key or "").strip() or None
        if self._api_key and not KEY_CHARS.match(self._api_key):
            # Checked here so a bad key never reaches http.client (whose error would
            # quote part of the header); the message does not quote it either.
            raise BackendError(
                "openai backend: the API key holds characters a header cannot carry "
                "(non-ASCII or whitespace); check the key variable's value"
            )
        if self._api_key and self.endpoint.scheme == "http" and not self.endpoint.loopback \
                and not config.allow_plain_http_key:
            raise BackendError(
                f"openai backend: refusing to send the API key in clear text to "
                f"{self.endpoint.host}; use https, or set openai.allow_plain_http_key"
            )
        if not self._api_key and self.endpoint.host in KEY_REQUIRED_HOSTS:
            raise BackendError(
                f"openai backend: {self.endpoint.host} needs an API key; set "
                f"{config.api_key_env} (or {ENV_KEY_FALLBACK}) in the environment"
            )
        self._negotiate = config.response_format == "auto"
        self._format: ResponseFormat = (
            "json_schema" if config.response_format == "auto" else config.response_format)
        self._confirmed: Optional[ResponseFormat] = None
        self._lock = threading.Lock()
        self._ssl = ssl.create_default_context() if self.endpoint.scheme == "https" else None

    @classmethod
    def from_env(
        cls, config: OpenAIConfig, environ: Optional[Mapping[str, str]] = None
    ) -> "OpenAIBackend":
        """Build from ``config`` with the environment's overrides and key."""
        env = os.environ if environ is None else environ
        key = env.get(config.api_key_env) or env.get(ENV_KEY_FALLBACK) or None
        return cls(
            config, api_key=key, base_url=env.get(ENV_BASE_URL) or None,
            model=env.get(ENV_MODEL) or None,
        )

    def __repr__(self) -> str:  # the key stays out of any printed form
        key = "set" if self._api_key else "none"
        return f"OpenAIBackend(url={self.endpoint.url!r}, model={self.model!r}, key={key})"

    @property
    def response_format(self) -> ResponseFormat:
        """The structured-output form requests use now (after any step-down)."""
        return self._format

    @property
    def confirmed_format(self) -> Optional[ResponseFormat]:
        """The form that gave the first valid answer (None before one did)."""
        return self._confirmed

    # -- Backend ---------------------------------------------------------------------------
    def complete(self, request: DecisionRequest) -> BackendReply:
        """One chat completion under ``request.deadline_s``; never raises."""
        schema = (
            narrow_schema(request, max_reasoning_chars=self.config.max_reasoning_chars)
            if self.config.narrow_schema else dict(request.json_schema)
        )
        # The compact answer form (offered choices, the reasoning cap) also guides a model
        # the server does not constrain (plain json_object / none).
        user = compact_prompt(request, schema) if self.config.spell_out_choices \
            else request.prompt
        return self.complete_json(
            SYSTEM_PROMPT, user, schema, deadline_s=request.deadline_s,
            valid=lambda text: parse_decision(text, request=request).error_kind is None)

    def complete_json(self, system: str, user: str, schema: Mapping[str, Any], *,
                      deadline_s: float,
                      valid: Optional[Callable[[str], bool]] = None) -> BackendReply:
        """One chat completion of ``system`` + ``user`` whose answer must match ``schema``
        (in the negotiated structured-output form), under ``deadline_s``; never raises.
        ``valid(text)``: whether an answer is valid, so its form can be kept for the run
        (other callers than the planner, e.g. the coordinator, use this too)."""
        t0 = time.perf_counter()
        t_end = t0 + deadline_s
        with self._lock:
            fmt = self._format
        formats = FORMS[FORMS.index(fmt):] if self._negotiate else (fmt,)
        refusals: list[str] = []
        try:
            for fmt in formats:
                status, body = self._post(self._payload(system, user, fmt, schema), t_end)
                if status != 200 and fmt != formats[-1] and refuses_format(status, body):
                    refusals.append(f"{fmt}: HTTP {status} {self._excerpt(body)}")
                    continue
                if status != 200:
                    hint = "" if self._negotiate or not refuses_format(status, body) else (
                        f" (openai.response_format {fmt} refused: try auto)")
                    return self._fail(t0, "transport", "; ".join(
                        refusals + [f"HTTP {status} from {self.endpoint.url}: "
                                    f"{self._excerpt(body)}{hint}"]))
                if refusals:
                    self._step_down(fmt, refusals)
                reply = self._reply(body, t0)
                if reply.ok and valid is not None and valid(reply.text or ""):
                    self._confirm(fmt)
                return reply
        except _Deadline:
            return self._fail(t0, "timeout", f"no complete reply from {self.endpoint.url} "
                                             f"within the {deadline_s:.1f} s deadline")
        except socket.timeout:
            return self._fail(t0, "timeout", f"no complete reply from {self.endpoint.url} "
                                             f"within the {deadline_s:.1f} s deadline")
        except (OSError, http.client.HTTPException) as exc:
            return self._fail(t0, "transport",
                              f"{type(exc).__name__} talking to {self.endpoint.url}: "
                              f"{self._redact(str(exc))}")
        return self._fail(t0, "transport", "no response format left to try")  # unreachable

    def max_tokens(self, schema: Mapping[str, Any]) -> int:
        """``max_tokens`` of a request with ``schema``: the longest valid answer's need,
        at most ``max_output_tokens``."""
        need = output_token_budget(schema, chars_per_token=self.config.output_chars_per_token,
                                   slack_tokens=OUTPUT_SLACK_TOKENS)
        cap = self.config.max_output_tokens
        return need if cap is None else min(need, cap)

    # -- internals -------------------------------------------------------------------------
    def _payload(self, system: str, user: str, fmt: ResponseFormat,
                 schema: Mapping[str, Any]) -> dict[str, Any]:
        payload: dict[str, Any] = {
            "model": self.model,
            "messages": [
                {"role": "system", "content": system},
                {"role": "user", "content": user},
            ],
            "temperature": self.config.temperature,
            "max_tokens": self.max_tokens(schema),
            "stream": False,
        }
        if self.config.seed is not None:
            payload["seed"] = self.config.seed
        payload.update(format_fields(fmt, schema, strict=self.config.json_schema_strict))
        return payload

    def _post(self, payload: Mapping[str, Any], t_end: float) -> tuple[int, bytes]:
        """POST ``payload``; (status, body). Raises _Deadline / OSError / HTTPException."""
        data = json.dumps(payload, separators=(",", ":")).encode("utf-8")
        headers = {
            "Content-Type": "application/json",
            "Accept": "application/json",
            "User-Agent": "lmpc-llm-planner",
        }
        if self._api_key:
            headers["Authorization"] = f"Bearer {self._api_key}"
        ep = self.endpoint
        conn: http.client.HTTPConnection
        if self._ssl is not None:
            conn = http.client.HTTPSConnection(
                ep.host, ep.port, timeout=_left(t_end), context=self._ssl)
        else:
            conn = http.client.HTTPConnection(ep.host, ep.port, timeout=_left(t_end))
        try:
            conn.connect()
            sock = conn.sock
            conn.request("POST", ep.path, body=data, headers=headers)
            sock.settimeout(_left(t_end))
            resp = conn.getresponse()
            chunks: list[bytes] = []
            size = 0
            while True:
                # Every read gets only the time that is left: a server that trickles
                # bytes cannot stretch the call past the deadline.
                sock.settimeout(_left(t_end))
                chunk = resp.read1(65536)
                if not chunk:
                    break
                size += len(chunk)
                if size > MAX_BODY_BYTES:
                    raise http.client.HTTPException(
                        f"reply body larger than {MAX_BODY_BYTES} bytes")
                chunks.append(chunk)
            return resp.status, b"".join(chunks)
        finally:
            conn.close()

    def _reply(self, body: bytes, t0: float) -> BackendReply:
        """The text of a 200 reply, or a transport error for a body that is not one."""
        try:
            obj = json.loads(body.decode("utf-8"))
            choice = obj["choices"][0]
            message = choice["message"]
            text = message.get("content")
        except (UnicodeDecodeError, ValueError, KeyError, IndexError, TypeError,
                AttributeError):
            return self._fail(t0, "transport", "the server's reply is not a chat completion "
                                               f"(body starts {self._excerpt(body)})")
        if not isinstance(text, str):
            refusal = message.get("refusal") if isinstance(message, dict) else None
            return self._fail(t0, "transport", "the reply carries no text"
                              + (f" (refusal: {self._redact(str(refusal))[:200]})"
                                 if refusal else ""))
        usage = obj.get("usage") if isinstance(obj, dict) else None
        return BackendReply(
            text=text,
            latency_s=time.perf_counter() - t0,
            tokens_in=_count(usage, "prompt_tokens"),
            tokens_out=_count(usage, "completion_tokens"),
            truncated=choice.get("finish_reason") == "length" if isinstance(choice, dict)
            else False,
        )

    def _step_down(self, fmt: ResponseFormat, refusals: list[str]) -> None:
        with self._lock:
            if FORMS.index(fmt) <= FORMS.index(self._format):
                return  # another thread already stepped this far
            self._format = fmt
        LOG.warning("openai backend: %s refused (%s); trying response form %s from now on",
                    self.endpoint.url, "; ".join(refusals), fmt)

    def _confirm(self, fmt: ResponseFormat) -> None:
        """Keep ``fmt`` for the run once it gave a valid answer (and say so, once); an
        invalid answer is the model's fault or the form's: not proof that the form works."""
        if self._confirmed is not None:
            return
        with self._lock:
            if self._confirmed is not None:
                return
            self._confirmed = fmt
            self._format = fmt
        # A warning so it shows: the nodes set up no Python logging, and Python's
        # last-resort handler prints warnings and above only.
        LOG.warning("openai backend: %s gives valid answers with response form %s; using it "
                    "for the rest of the run", self.endpoint.url, fmt)

    def _fail(self, t0: float, kind: Literal["timeout", "transport"], msg: str) -> BackendReply:
        return BackendReply(text=None, latency_s=time.perf_counter() - t0, error_kind=kind,
                            error=self._redact(msg))

    def _redact(self, text: str) -> str:
        """``text`` without the key (a server may echo headers in its error body)."""
        if self._api_key:
            text = text.replace(self._api_key, "[redacted]")
        return text

    def _excerpt(self, body: bytes) -> str:
        # Redact the whole body before cutting it, so no piece of the key survives.
        text = " ".join(self._redact(body.decode("utf-8", "replace")).split())
        return repr(text[:MAX_ERROR_EXCERPT])


def _left(t_end: float) -> float:
    """Seconds left before ``t_end``; raises _Deadline when none are."""
    left = t_end - time.perf_counter()
    if left <= 0.0:
        raise _Deadline()
    return left


def _count(usage: Any, key: str) -> int:
    if isinstance(usage, dict):
        value = usage.get(key)
        if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            return value
    return 0
