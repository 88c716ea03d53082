"""The ``openai`` backend against a fake chat-completions server on 127.0.0.1 (an
``http.server`` thread on a random free port), alone and through ``PlannerCore``."""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import socket
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable, Optional

import pytest
from lmpc_mpc import synthetic as syn
from lmpc_msgs_py.vocabulary import DecisionSpace

from lmpc_llm_planner.backends import BackendError, make_backend
from lmpc_llm_planner.backends.base import DecisionRequest
from lmpc_llm_planner.backends.constrain import compact_prompt
from lmpc_llm_planner.backends.openai import OpenAIBackend, parse_endpoint, source_name
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import OpenAIConfig, PlannerConfig
from lmpc_llm_planner.planner import PlannerCore, build_request
from lmpc_llm_planner.scene import build_scene

SECRET = "sk-test-SECRET-0123456789abcdef"


def make_request(obs, *, config: PlannerConfig, space: DecisionSpace, **kw) -> DecisionRequest:
    scene = build_scene(obs, lookahead_m=config.lookahead_m,
                        max_agents=config.max_agents_in_prompt)
    return build_request(scene, config=config, space=space, **kw)


def completion(content: Optional[str], *, usage: Optional[dict] = None,
               finish_reason: str = "stop") -> dict[str, Any]:
    """A chat-completions reply body carrying ``content``."""
    body: dict[str, Any] = {
        "id": "chatcmpl-1", "object": "chat.completion", "model": "test-model",
        "choices": [{"index": 0, "finish_reason": finish_reason,
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
        self.thread = threading.Thread(
            target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
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


@pytest.fixture
def server():
    srv = FakeChatServer()
    yield srv
    srv.close()


@pytest.fixture
def request_(left_turn_map, obs_factory, planner_config, mpc_config):
    agents = [syn.agent("car1", x_m=-1.6, y_m=30.0, yaw_rad=-math.pi / 2, v_mps=10.0,
                        lane_id="N_in_0")]
    return make_request(obs_factory(left_turn_map, agents=agents), config=planner_config,
                        space=mpc_config)


def rf_schema(body: dict[str, Any]) -> dict[str, Any]:
    return body["response_format"]["json_schema"]["schema"]


def backend_for(server: FakeChatServer, **cfg) -> OpenAIBackend:
    return OpenAIBackend(OpenAIConfig(model="test-model", **cfg), api_key=SECRET,
                         base_url=server.base_url)


def test_valid_answer_with_usage_and_structured_output(server, request_):
    valid = RulesBackend().complete(request_).text
    server.actions.append(ok(valid, usage={"prompt_tokens": 1234, "completion_tokens": 56}))
    backend = backend_for(server)
    reply = backend.complete(request_)
    assert reply.ok and reply.text == valid
    assert (reply.tokens_in, reply.tokens_out) == (1234, 56)
    assert backend.name == "llm:test-model"
    seen = server.seen[0]
    assert seen.path == "/v1/chat/completions"
    assert seen.headers["Authorization"] == f"Bearer {SECRET}"
    body = seen.json
    assert body["model"] == "test-model" and body["temperature"] == 0.0
    assert [m["role"] for m in body["messages"]] == ["system", "user"]
    assert "JSON" in body["messages"][0]["content"]
    assert body["messages"][1]["content"] == compact_prompt(request_, rf_schema(body))
    rf = body["response_format"]
    assert rf["type"] == "json_schema"
    enc = rf["json_schema"]["schema"]["$defs"]["ScenarioEncoding"]["properties"]
    assert enc["attention"]["items"]["enum"] == ["car1"]  # narrowed to the offered ids


def test_no_usage_reports_zero_tokens(server, request_):
    server.actions.append(ok('{"reasoning": "x"}'))
    reply = backend_for(server).complete(request_)
    assert reply.ok and (reply.tokens_in, reply.tokens_out) == (0, 0)


def test_slow_reply_past_deadline_is_a_timeout(server, request_):
    server.actions.append(lambda req: Answer(200, json.dumps(completion("{}")).encode(),
                                             delay_s=1.0))
    req = dataclasses.replace(request_, deadline_s=0.3)
    t0 = time.perf_counter()
    reply = backend_for(server).complete(req)
    took = time.perf_counter() - t0
    assert reply.error_kind == "timeout" and reply.text is None
    assert 0.25 <= took < 0.8  # the deadline, not the server, decides
    assert "0.3 s deadline" in reply.error


def test_garbage_body_is_a_transport_error(server, request_):
    server.actions.append(lambda req: Answer(200, b"<html>502 upstream oops</html>"))
    reply = backend_for(server).complete(request_)
    assert reply.error_kind == "transport" and "not a chat completion" in reply.error


def test_null_content_is_a_transport_error(server, request_):
    server.actions.append(lambda req: Answer(200, json.dumps(completion(None)).encode()))
    reply = backend_for(server).complete(request_)
    assert reply.error_kind == "transport" and "no text" in reply.error


def test_http_500_is_a_transport_error_and_echoed_key_is_redacted(server, request_):
    # A server that echoes the request headers in its error body.
    echo = f"boom; Authorization: Bearer {SECRET}".encode()
    server.actions.append(lambda req: Answer(500, echo))
    reply = backend_for(server).complete(request_)
    assert reply.error_kind == "transport" and "HTTP 500" in reply.error
    assert SECRET not in reply.error and "[redacted]" in reply.error


LLAMA_CPP_REFUSAL = (b'{"error": {"message": "[{\'type\': \'literal_error\', \'loc\': '
                     b'(\'body\', \'response_format\', \'type\'), \'msg\': \"Input should be '
                     b'\'text\' or \'json_object\'\"}]"}}')
"""What llama-cpp-python's server answers (HTTP 500) to a json_schema response_format."""


def form_of(body: dict[str, Any]) -> str:
    """The structured-output form a request used (the names of openai.FORMS)."""
    rf = body.get("response_format") or {}
    if rf.get("type") == "json_schema":
        return "json_schema"
    if rf.get("type") == "json_object":
        return "json_object_schema" if "schema" in rf else "json_object"
    if "format" in body:
        return "ollama_format"
    if "guided_json" in body:
        return "guided_json"
    return "none"


def llama_cpp_like(valid: str) -> Action:
    """Refuses json_schema as llama-cpp-python's server does; answers anything else."""
    def act(req: dict[str, Any]) -> Answer:
        if form_of(req) == "json_schema":
            return Answer(500, LLAMA_CPP_REFUSAL)
        return Answer(200, json.dumps(completion(valid)).encode())
    return act


def test_500_naming_the_format_steps_down_and_remembers(server, request_, caplog):
    valid = RulesBackend().complete(request_).text
    server.default = llama_cpp_like(valid)
    backend = backend_for(server)
    assert backend.response_format == "json_schema"  # auto starts with the strongest form
    with caplog.at_level(logging.DEBUG):
        first = backend.complete(request_)
        second = backend.complete(request_)
    assert first.ok and second.ok and first.text == valid
    assert [form_of(s.json) for s in server.seen] == [
        "json_schema", "json_object_schema", "json_object_schema"]  # remembered
    rf = server.seen[1].json["response_format"]
    enc = rf["schema"]["$defs"]["ScenarioEncoding"]["properties"]
    assert enc["attention"]["items"]["enum"] == ["car1"]  # the narrowed schema rides along
    assert backend.response_format == backend.confirmed_format == "json_object_schema"
    assert "trying response form json_object_schema" in caplog.text
    assert "valid answers with response form json_object_schema" in caplog.text
    assert SECRET not in caplog.text


@pytest.mark.parametrize("accepted", ["ollama_format", "guided_json", "json_object", "none"])
def test_negotiation_walks_the_forms_in_order(server, request_, accepted):
    valid = RulesBackend().complete(request_).text
    order = ["json_schema", "json_object_schema", "ollama_format", "guided_json",
             "json_object", "none"]

    def picky(req):
        if form_of(req) != accepted:  # each refusal names its own field
            return Answer(400, json.dumps({"error": f"unsupported field {form_of(req)}; "
                                                    "check response_format"}).encode())
        return Answer(200, json.dumps(completion(valid)).encode())

    server.default = picky
    backend = backend_for(server)
    assert backend.complete(request_).ok
    tried = [form_of(s.json) for s in server.seen]
    assert tried == order[:order.index(accepted) + 1]
    if accepted in ("ollama_format", "guided_json"):
        field_name = "format" if accepted == "ollama_format" else "guided_json"
        assert "ScenarioEncoding" in json.dumps(server.seen[-1].json[field_name])
        assert "response_format" not in server.seen[-1].json
    assert backend.confirmed_format == accepted


def test_a_form_is_kept_only_after_a_valid_answer(server, request_, caplog):
    valid = RulesBackend().complete(request_).text
    server.actions += [ok("I would turn left."), ok(valid)]
    backend = backend_for(server)
    with caplog.at_level(logging.DEBUG):
        assert backend.complete(request_).ok  # prose: a 200, but not a valid answer
        assert backend.confirmed_format is None and "valid answers" not in caplog.text
        assert backend.complete(request_).ok
    assert backend.confirmed_format == "json_schema"
    assert caplog.text.count("valid answers with response form") == 1


def test_explicit_setting_wins(server, request_):
    valid = RulesBackend().complete(request_).text
    server.default = llama_cpp_like(valid)
    backend = backend_for(server, response_format="json_schema")
    reply = backend.complete(request_)
    assert reply.error_kind == "transport" and "HTTP 500" in reply.error
    assert "try auto" in reply.error
    assert [form_of(s.json) for s in server.seen] == ["json_schema"]  # no step-down
    server.seen.clear()
    backend = backend_for(server, response_format="json_object")
    assert backend.complete(request_).ok
    assert [form_of(s.json) for s in server.seen] == ["json_object"]  # not the schema form


def test_error_not_naming_the_format_does_not_step_down(server, request_):
    server.default = lambda req: Answer(400, b'{"error": "context length exceeded"}')
    backend = backend_for(server)
    reply = backend.complete(request_)
    assert reply.error_kind == "transport" and "HTTP 400" in reply.error
    assert len(server.seen) == 1  # the request is at fault, not the form
    assert backend.response_format == "json_schema" and backend.confirmed_format is None


def test_every_form_refused_is_a_transport_error(server, request_):
    server.default = lambda req: Answer(422, b'{"detail": "bad response_format"}')
    backend = backend_for(server)
    reply = backend.complete(request_)
    assert reply.error_kind == "transport" and "HTTP 422" in reply.error
    assert len(server.seen) == 6 and "json_schema: HTTP 422" in reply.error
    assert backend.response_format == "json_schema"  # nothing worked: nothing remembered


def test_max_tokens_sized_from_the_schema(server, request_):
    server.default = ok('{"reasoning": "x"}')
    backend_for(server).complete(request_)
    short = server.seen[-1].json
    backend_for(server, max_reasoning_chars=2000, max_output_tokens=None).complete(request_)
    long = server.seen[-1].json
    # 1,400 more reasoning characters at 2.5 characters a token
    assert long["max_tokens"] - short["max_tokens"] == pytest.approx(1400 * 1.1 / 2.5, abs=2)
    assert 100 < short["max_tokens"] <= OpenAIConfig().max_output_tokens
    backend_for(server, max_output_tokens=64).complete(request_)
    assert server.seen[-1].json["max_tokens"] == 64  # the configured cap still holds
    # the prompt shows the compact form: offered choices and the reasoning cap
    user = short["messages"][1]["content"]
    assert "at most 600 characters" in user and '"car1"' in user


def test_connection_refused_is_a_transport_error(request_):
    backend = OpenAIBackend(OpenAIConfig(), api_key=SECRET,
                            base_url=f"http://127.0.0.1:{refused_port()}/v1")
    t0 = time.perf_counter()
    reply = backend.complete(request_)
    assert reply.error_kind == "transport" and "ConnectionRefusedError" in reply.error
    assert time.perf_counter() - t0 < 2.0
    assert SECRET not in reply.error and SECRET not in repr(backend)


def test_environment_overrides_and_key_choice(server, request_):
    cfg = OpenAIConfig(base_url="https://example.invalid/v1", model="file-model")
    env = {"LMPC_OPENAI_BASE_URL": server.base_url, "LMPC_OPENAI_MODEL": "env/model:7b",
           "OPENAI_API_KEY": "second-choice", "LMPC_OPENAI_API_KEY": SECRET}
    backend = OpenAIBackend.from_env(cfg, env)
    assert backend.name == "llm:env/model:7b" and backend.endpoint.port > 0
    server.actions.append(ok("{}"))
    backend.complete(request_)
    assert server.seen[-1].headers["Authorization"] == f"Bearer {SECRET}"
    assert server.seen[-1].json["model"] == "env/model:7b"
    del env["LMPC_OPENAI_API_KEY"]
    server.actions.append(ok("{}"))
    OpenAIBackend.from_env(cfg, env).complete(request_)
    assert server.seen[-1].headers["Authorization"] == "Bearer second-choice"
    server.actions.append(ok("{}"))
    OpenAIBackend.from_env(cfg, {"LMPC_OPENAI_BASE_URL": server.base_url}).complete(request_)
    assert "Authorization" not in server.seen[-1].headers  # no key: none sent


def test_key_never_sent_in_clear_to_a_remote_host():
    with pytest.raises(BackendError) as exc:
        OpenAIBackend(OpenAIConfig(), api_key=SECRET, base_url="http://10.1.2.3:8000/v1")
    assert "clear text" in str(exc.value) and SECRET not in str(exc.value)
    # Without a key (a LAN vLLM) or with the explicit opt-in it is allowed.
    OpenAIBackend(OpenAIConfig(), api_key=None, base_url="http://10.1.2.3:8000/v1")
    OpenAIBackend(OpenAIConfig(allow_plain_http_key=True), api_key=SECRET,
                  base_url="http://10.1.2.3:8000/v1")


def test_openai_without_key_fails_at_start():
    with pytest.raises(BackendError, match="LMPC_OPENAI_API_KEY"):
        OpenAIBackend.from_env(OpenAIConfig(), {})
    bad = "sk-\u2019quoted key"
    with pytest.raises(BackendError, match="characters a header cannot carry") as exc:
        OpenAIBackend.from_env(OpenAIConfig(), {"OPENAI_API_KEY": bad})
    assert "quoted" not in str(exc.value)


def test_endpoint_and_source_parsing():
    assert parse_endpoint("http://localhost:11434/v1/").path == "/v1/chat/completions"
    assert parse_endpoint("https://api.openai.com/v1").port == 443
    assert parse_endpoint("http://h:1/v1/chat/completions").path == "/v1/chat/completions"
    for bad in ("ftp://x/v1", "localhost:8000", "http://user:pw@host/v1"):
        with pytest.raises(BackendError):
            parse_endpoint(bad)
    assert source_name("Qwen/Qwen2.5 7B@q4") == "llm:Qwen/Qwen2.5-7B-q4"


def test_make_backend_openai(planner_config):
    cfg = PlannerConfig.model_validate({**planner_config.model_dump(), "backend": "openai"})
    backend = make_backend(cfg, environ={"LMPC_OPENAI_MODEL": "m1", "OPENAI_API_KEY": "k"})
    assert isinstance(backend, OpenAIBackend) and backend.name == "llm:m1"


# -- through the planner -------------------------------------------------------------------
def core_for(server, planner_config, mpc_config, log_path):
    cfg = PlannerConfig.model_validate({**planner_config.model_dump(), "backend": "openai"})
    backend = make_backend(cfg, environ={"LMPC_OPENAI_BASE_URL": server.base_url,
                                         "LMPC_OPENAI_MODEL": "test-model",
                                         "LMPC_OPENAI_API_KEY": SECRET})
    return PlannerCore(cfg, backend, mpc_config, log_path=log_path)


def test_planner_prose_then_valid_on_re_ask(server, request_, left_turn_map, obs_factory,
                                            planner_config, mpc_config, tmp_path, caplog):
    valid = RulesBackend().complete(request_).text
    server.actions += [ok("Sure! Here is my decision: turn left."), ok(valid)]
    log = tmp_path / "decisions.jsonl"
    core = core_for(server, planner_config, mpc_config, log)
    with caplog.at_level(logging.DEBUG):
        d = core.on_observation(request_.scene.obs)
    assert d.source == "llm:test-model" and d.mode == "normal"
    assert d.attention and d.attention[0] == "car1"
    assert len(server.seen) == 2
    re_ask = server.seen[1].json["messages"][1]["content"]
    assert "refused: prose" in re_ask  # the re-ask carries the validation error
    assert core.counters.errors["prose"] == 1 and core.counters.fallbacks == 0
    text = log.read_text()
    assert SECRET not in text and SECRET not in caplog.text


def test_planner_truncated_answer_is_re_asked_with_the_cut(server, request_, planner_config,
                                                           mpc_config, tmp_path):
    valid = RulesBackend().complete(request_).text
    cut = valid[:len(valid) // 2]
    server.actions += [ok(cut, finish_reason="length",
                          usage={"prompt_tokens": 900, "completion_tokens": 321}), ok(valid)]
    core = core_for(server, planner_config, mpc_config, tmp_path / "decisions.jsonl")
    d = core.on_observation(request_.scene.obs)
    assert d.source == "llm:test-model" and len(server.seen) == 2
    re_ask = server.seen[1].json["messages"][1]["content"]
    assert "cut off at the output limit (321 tokens)" in re_ask and "invalid_json" in re_ask
    assert core.counters.errors["invalid_json"] == 1 and core.counters.fallbacks == 0
    server.actions.append(ok(valid))
    reply = backend_for(server).complete(request_)  # a complete answer is not flagged
    assert reply.ok and not reply.truncated


def test_planner_garbage_twice_falls_back(server, request_, planner_config, mpc_config,
                                          tmp_path):
    server.actions += [ok("```json\n{}\n```"), lambda req: Answer(200, b"not json at all")]
    log = tmp_path / "decisions.jsonl"
    core = core_for(server, planner_config, mpc_config, log)
    d = core.on_observation(request_.scene.obs)
    assert d.source == "fallback" and len(server.seen) == 2
    assert core.counters.errors["fenced"] == 1 and core.counters.errors["transport"] == 1
    rec = json.loads(log.read_text().splitlines()[-1])
    assert rec["error_kind"] == "transport" and SECRET not in log.read_text()


def stage_answers(route_id: int) -> Action:
    """Answers each chained stage by the stage its prompt asks for."""
    by_stage = {
        "scenario_encoding": {"scenario_encoding": {
            "ego_trajectory": route_id, "attention": ["car1"],
            "agent_trajectories": {"car1": 0}}},
        "action_guidance": {"action_guidance": {"accel_interval": 1, "steer_interval": 2}},
        "weight_adjustment": {"weight_adjustment": {
            "tracking": "low", "action": "high", "smoothness": "normal", "safety": "high"}},
    }

    def act(req: dict[str, Any]) -> Answer:
        prompt = req["messages"][-1]["content"]
        stage = next(s for s in by_stage if f"only the stage '{s}'" in prompt)
        body = {"reasoning": f"stage {stage}", **by_stage[stage]}
        return Answer(200, json.dumps(completion(json.dumps(body))).encode())
    return act


@pytest.mark.parametrize("mode", ["normal", "emergency"])
def test_planner_chained_stages_over_http(server, request_, planner_config, mpc_config,
                                          tmp_path, mode, left_turn_map, obs_factory):
    server.default = stage_answers(request_.scene.route_candidate_id)
    cfg = PlannerConfig.model_validate({**planner_config.model_dump(), "backend": "openai",
                                        "stages": "chained"})
    backend = make_backend(cfg, environ={"LMPC_OPENAI_BASE_URL": server.base_url,
                                         "LMPC_OPENAI_MODEL": "test-model"})
    core = PlannerCore(cfg, backend, mpc_config, log_path=tmp_path / "decisions.jsonl")
    agents = list(request_.scene.obs.agents.agents)
    if mode == "emergency":  # a wrong-way car 20 m ahead in the ego's lane: TTC ~1.1 s
        agents.append(syn.agent("wrongway", x_m=1.6, y_m=-20.0, yaw_rad=-math.pi / 2,
                                v_mps=10.0, lane_id="S_in_0"))
    d = core.on_observation(obs_factory(left_turn_map, agents=agents))
    stages = ["action_guidance", "weight_adjustment"]
    if mode == "normal":
        stages.insert(0, "scenario_encoding")
    assert len(server.seen) == len(stages)  # one HTTP call per stage, no re-asks
    for seen, stage in zip(server.seen, stages):
        schema = seen.json["response_format"]["json_schema"]["schema"]
        assert list(schema["properties"]) == ["reasoning", stage]
    # each later prompt carries the earlier stages' answers
    last_prompt = server.seen[-1].json["messages"][-1]["content"]
    assert '"action_guidance":{"accel_interval":1,"steer_interval":2}' in last_prompt
    assert d.source == "llm:test-model" and d.mode == mode
    assert d.accel_interval == 1 and d.weights.action == "high"
    assert "car1" in d.attention and core.counters.fallbacks == 0
