"""Measure the ``local`` backend on varied hand-made junction scenes (no ROS, no SUMO).

    python -m lmpc_llm_planner.backends.bench_local [--n 10] [--threads 1]

Per prompt: latency, tokens in / out (and the SmolLM2 token count of the full,
uncompacted prompt), whether the first answer passed validation (``parse_decision``)
and, if not, why, and whether it agrees with the ``rules`` backend (ego trajectory,
accel interval) as a crude quality proxy. Prints one JSON line per prompt and a summary
(median / p95 latency, share valid on the first answer, agreement, and whether the
first prompt asked again gives the identical text). The scenes are synthetic
(``lmpc_mpc.synthetic.four_way_junction``): ego approaching a junction turning left,
right or straight, with 0-4 other vehicles at varied places and speeds.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from typing import Any, Sequence

from lmpc_mpc import synthetic as syn
from lmpc_msgs_py.vocabulary import load_decision_space

from lmpc_llm_planner.backends.local import LocalBackend
from lmpc_llm_planner.backends.rules import RulesBackend
from lmpc_llm_planner.config import LocalConfig, load_planner_config
from lmpc_llm_planner.planner import build_request
from lmpc_llm_planner.scene import build_scene
from lmpc_llm_planner.validation import parse_decision

SOUTH, NORTH = -math.pi / 2.0, math.pi / 2.0


def scenes(n: int) -> list[dict[str, Any]]:
    """``n`` varied scene descriptions (deterministic)."""
    turns = ("l", "s", "r")
    out = []
    for i in range(n):
        agents = []
        for j in range(i % 5):
            if j % 2 == 0:  # oncoming, southbound
                agents.append(dict(aid=f"car{j}", x_m=-1.6, y_m=15.0 + 12.0 * j + 3.0 * i,
                                   yaw_rad=SOUTH, v_mps=6.0 + j + 0.5 * i, lane_id="N_in_0"))
            else:  # leader ahead, northbound
                agents.append(dict(aid=f"veh_{j}", x_m=1.6, y_m=-30.0 + 5.0 * j + i,
                                   yaw_rad=NORTH, v_mps=3.0 + 0.3 * i, lane_id="S_in_0"))
        out.append(dict(turn=turns[i % 3], ego_y_m=-45.0 + 3.0 * i, ego_v_mps=4.0 + 0.7 * i,
                        agents=agents, instruction="drive carefully" if i % 4 == 3 else None))
    return out


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))
    return ordered[k]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    pcfg = load_planner_config()
    space = load_decision_space()
    t_load = time.perf_counter()
    backend = LocalBackend.from_config(LocalConfig(n_threads=args.threads))
    print(json.dumps({"model": str(backend.model_path),
                      "load_s": round(time.perf_counter() - t_load, 3)}))
    rows = []
    rules = RulesBackend()
    first_req = None
    first_text = None
    for i, sc in enumerate(scenes(args.n)):
        map_ = syn.four_way_junction(arm_m=100.0, ego_turn=sc["turn"])
        ego = syn.ego_state(x_m=1.6, y_m=sc["ego_y_m"], yaw_rad=NORTH, v_mps=sc["ego_v_mps"],
                            stamp_s=0.0, seq=0, lane_id="S_in_0")
        ego = ego.model_copy(update={"lane_pos_m": sc["ego_y_m"] + 100.0})
        agents = [syn.agent(a.pop("aid"), **a) for a in [dict(x) for x in sc["agents"]]]
        obs = syn.observation(map_, ego, agents)
        scene = build_scene(obs, lookahead_m=pcfg.lookahead_m,
                            max_agents=pcfg.max_agents_in_prompt)
        req = build_request(scene, config=pcfg.model_copy(update={"deadline_s": 120.0}),
                            space=space, instruction=sc["instruction"])
        reply = backend.complete(req)
        if first_req is None:
            first_req, first_text = req, reply.text
        parsed = parse_decision(reply.text or "", request=req) if reply.ok else None
        ref = json.loads(rules.complete(req).text or "{}")
        ans = parsed.wire if parsed and parsed.success else None
        agree = ans is not None and (
            ans.scenario_encoding.ego_trajectory == ref["scenario_encoding"]["ego_trajectory"]
            and ans.action_guidance.accel_interval == ref["action_guidance"]["accel_interval"])
        full_tokens = len(backend.tokenize(backend.chat_prompt(req).text))
        row = {
            "i": i, "turn": sc["turn"], "agents": len(agents),
            "latency_s": round(reply.latency_s, 3), "tokens_in": reply.tokens_in,
            "tokens_out": reply.tokens_out, "prompt_chars": len(req.prompt),
            "estimate": req.tokens_estimate, "tokens_full_prompt": full_tokens,
            "agrees_with_rules": agree,
            "valid": bool(parsed and parsed.success),
            "error": reply.error_kind or (parsed.error_kind if parsed else None),
            "text": (reply.text or "")[:400],
        }
        rows.append(row)
        print(json.dumps(row))
    lat = [r["latency_s"] for r in rows]
    summary = {
        "n": len(rows), "threads": args.threads,
        "latency_median_s": round(statistics.median(lat), 3),
        "latency_p95_s": round(percentile(lat, 0.95), 3),
        "valid_first_answer": sum(r["valid"] for r in rows) / len(rows),
        "tokens_in_median": statistics.median(r["tokens_in"] for r in rows),
        "tokens_out_median": statistics.median(r["tokens_out"] for r in rows),
        "tokens_full_prompt_median": statistics.median(r["tokens_full_prompt"] for r in rows),
        "chars_per_token_full_prompt": round(sum(r["prompt_chars"] for r in rows)
                                             / max(1, sum(r["tokens_full_prompt"] for r in rows)),
                                             2),
        "agrees_with_rules": sum(r["agrees_with_rules"] for r in rows) / len(rows),
    }
    if first_req is not None:
        summary["repeat_identical"] = backend.complete(first_req).text == first_text
    print(json.dumps({"summary": summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
