"""The same model in-process (``local``) and through an OpenAI-compatible server
(``openai``), call by call on the same prompts (no ROS, no SUMO).

    python -m lmpc_llm_planner.backends.bench_server --base-url http://127.0.0.1:8080/v1 \\
        [--model smollm2] [--n 10]

Start the server as the README says (llama-cpp-python's, ``--n_threads 1 --n_threads_batch
1``: one thread, as ``local``; the SmolLM2 GGUF the ``local`` backend loads). Each
synthetic scene of ``bench_local`` is asked of both, the two calls back to back and
their order alternating, so both see the same machine load.
Settings: ``config/planner_local.yaml`` for ``local``, ``config/planner_server.yaml`` for
``openai`` (same reasoning cap and output limit). Prints one JSON line per call and a
summary per backend: latency median / p95, share valid on the first answer, tokens,
and how many answers were the same text in both.
"""
from __future__ import annotations

import argparse
import json
import statistics
from typing import Any, Sequence

from lmpc_mpc import synthetic as syn
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.backends.base import DecisionRequest
from lmpc_llm_planner.backends.bench_local import NORTH, percentile, scenes
from lmpc_llm_planner.backends.local import LocalBackend
from lmpc_llm_planner.backends.openai import OpenAIBackend
from lmpc_llm_planner.config import LOCAL_CONFIG_PATH, SERVER_CONFIG_PATH, load_planner_config
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision


def requests(n: int, deadline_s: float) -> list[DecisionRequest]:
    """The ``bench_local`` scenes as decision requests (the packaged planner settings)."""
    pcfg = load_planner_config().model_copy(update={"deadline_s": deadline_s})
    space = load_decision_space()
    out = []
    for sc in scenes(n):
        map_ = syn.four_way_junction(arm_m=100.0, ego_turn=sc["turn"])
        ego = syn.ego_state(x_m=1.6, y_m=sc["ego_y_m"], yaw_rad=NORTH, v_mps=sc["ego_v_mps"],
                            stamp_s=0.0, seq=0, lane_id="S_in_0")
        ego = ego.model_copy(update={"lane_pos_m": sc["ego_y_m"] + 100.0})
        agents = [syn.agent(a.pop("aid"), **a) for a in [dict(x) for x in sc["agents"]]]
        scene = build_scene(syn.observation(map_, ego, agents), lookahead_m=pcfg.lookahead_m,
                            max_agents=pcfg.max_agents_in_prompt)
        out.append(build_request(scene, config=pcfg, space=space,
                                 instruction=sc["instruction"]))
    return out


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    lat = [r["latency_s"] for r in rows]
    return {
        "n": len(rows),
        "latency_median_s": round(statistics.median(lat), 3),
        "latency_p95_s": round(percentile(lat, 0.95), 3),
        "valid_first_answer": sum(r["valid"] for r in rows) / len(rows),
        "tokens_in_median": statistics.median(r["tokens_in"] for r in rows),
        "tokens_out_median": statistics.median(r["tokens_out"] for r in rows),
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-url", required=True, help="the server, e.g. http://127.0.0.1:8080/v1")
    ap.add_argument("--model", default="smollm2", help="the server's model name (alias)")
    ap.add_argument("--n", type=int, default=10)
    args = ap.parse_args(argv)
    local_cfg = load_planner_config(LOCAL_CONFIG_PATH)
    server_cfg = load_planner_config(SERVER_CONFIG_PATH)
    local = LocalBackend.from_config(local_cfg.local)
    remote = OpenAIBackend(server_cfg.openai, base_url=args.base_url, model=args.model)
    rows: dict[str, list[dict[str, Any]]] = {"local": [], "openai": []}
    texts: dict[str, list[str]] = {"local": [], "openai": []}
    for i, req in enumerate(requests(args.n, max(local_cfg.deadline_s,
                                                 server_cfg.deadline_s))):
        order: list[tuple[str, Any]] = [("local", local), ("openai", remote)]
        for name, backend in order if i % 2 == 0 else order[::-1]:
            reply = backend.complete(req)
            parsed = parse_decision(reply.text or "", request=req) if reply.ok else None
            row = {"i": i, "backend": name, "latency_s": round(reply.latency_s, 3),
                   "tokens_in": reply.tokens_in, "tokens_out": reply.tokens_out,
                   "valid": bool(parsed and parsed.success),
                   "error": reply.error_kind or (parsed.error_kind if parsed else None)}
            rows[name].append(row)
            texts[name].append(reply.text or "")
            print(json.dumps(row), flush=True)
    same = sum(a == b for a, b in zip(texts["local"], texts["openai"]))
    out: dict[str, Any] = {name: summary(r) for name, r in rows.items()}
    out["same_text"] = f"{same}/{len(texts['local'])}"
    out["response_form"] = remote.confirmed_format
    print(json.dumps({"summary": out}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
