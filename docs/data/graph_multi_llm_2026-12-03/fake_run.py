"""How the runs of runs.csv were made: start test/graphkit.py's FakeLlmServer (a SIMULATED
OpenAI-compatible model on loopback), point LMPC_OPENAI_BASE_URL at it and run
scripts/run_graph.py with the remaining arguments. ``--deaf`` first: the simulated planner
ignores the coordinator's command (always the neutral answer; run E1).

    python docs/data/graph_multi_llm_2026-12-03/fake_run.py [--deaf] --scenario narrow \
        --seed 101 --planner openai --coordination central --coordinator-backend openai
"""
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "test"))
import graphkit  # noqa: E402

argv = sys.argv[1:]
if argv[:1] == ["--deaf"]:
    argv = argv[1:]
    graphkit._command_line = lambda request: ""
with graphkit.FakeLlmServer([]) as server:
    env = dict(os.environ, LMPC_OPENAI_BASE_URL=server.base_url, LMPC_OPENAI_MODEL="fake")
    t0 = time.monotonic()
    rc = subprocess.call([sys.executable, str(REPO / "scripts" / "run_graph.py"), *argv], env=env)
    coordinator = sum("Cars in a shared conflict" in p for p in server.prompts)
    told = sum("Coordinator's command" in p for p in server.prompts)
    print(f"[fake_run] rc={rc} wall={time.monotonic() - t0:.1f}s calls={len(server.calls)} "
          f"coordinator_calls={coordinator} planner_prompts_with_command={told}")
sys.exit(rc)
