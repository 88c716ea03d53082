# LanguageMPC on ROS 2 — set-up, demo, tests.
# `make demo` and `make test` create .venv (if missing) and install everything first.
PYTHON ?= python3.11
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.lmpc-installed
# DDS discovery stays on this machine unless the caller opened it up (README: multi-machine).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

LLAMA_CMAKE_ARGS ?= -DGGML_NATIVE=OFF -DGGML_AVX2=ON -DGGML_FMA=ON -DGGML_F16C=ON
PKGS := src/lmpc_msgs_py src/lmpc_mpc src/lmpc_bridge src/lmpc_llm_planner
SETUPS := pyproject.toml $(foreach p,$(PKGS),$(p)/setup.py)

.PHONY: install solvers demo test lint bench train clean

install: $(STAMP)

$(STAMP): $(SETUPS)
	@test -x $(PY) || { command -v $(PYTHON) >/dev/null && $(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV); }
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(foreach p,$(PKGS),-e $(p)) -e '.[test]'
	# The embedded LLM (llama.cpp, built from source once; pip caches the wheel). A native
	# build dies with "Illegal instruction" on some CPUs: build for a portable AVX2 target.
	# `server`: its OpenAI-compatible server (fastapi, uvicorn), for the openai backend's tests.
	CMAKE_ARGS="$(LLAMA_CMAKE_ARGS)" $(PY) -m pip install --quiet -e 'src/lmpc_llm_planner[local,server]'
	@touch $@

# The MPC's problems as generated C (lmpc_mpc.codegen: the same iterates, a faster solve),
# compiled once into the solver cache (~1 min); a no-op while the cache has them.
solvers: install
	$(PY) -m lmpc_mpc.codegen

demo: install solvers
	$(PY) scripts/run_graph.py --scenario usi --seed 0 --planner rules --clock sync

# The paper's Table I: 5 families x 25 seeds x every row, in-process, one worker per core.
# dqn / ppo / sac / adp: the committed policies/*.npz (numpy only; docs/RL.md).
bench: install solvers
	$(PY) scripts/benchmark.py --families si,usi,lane,rab,eoa --seeds 0-24 \
		--methods mpc,dqn,ppo,sac,adp,lmpc-rules --out runs/bench

# Re-train the committed learned planners, DQN, PPO and SAC for each family (docs/RL.md,
# "Measured"): needs the rl extra (pip install -e '.[rl]': skrl on CPU JAX). 25 000 steps and
# two envs a pair (the 2026-12-05 runs on the 2-core machine: 5-9 min a pair with the
# held-out check, 93 min for all 15; docs/RL.md has each pair's steps, wall time, provenance).
TRAIN_STEPS ?= 25000
TRAIN_ALGOS ?= dqn ppo sac
TRAIN_ENVS ?= 2
train:
	for a in $(TRAIN_ALGOS); do for f in si usi lane rab eoa; do \
		$(PY) scripts/train_rl.py --algo $$a --family $$f --steps $(TRAIN_STEPS) --seed 10000 \
			--envs $(TRAIN_ENVS) --eval-scenes 5 --install || exit 1; done; done

# mypy: the modules listed in pyproject.toml [tool.mypy] (issue 15's scope; it says why).
lint: install
	$(PY) -m flake8 src scripts test
	$(PY) -m mypy

# the tests without node processes on TEST_WORKERS pytest-xdist workers (the Ray ones on one
# of them: --dist loadgroup), then the graph tests (marker `graph`) one at a time, so no two
# graphs share the cores their timing depends on
TEST_WORKERS ?= 2
test: install solvers lint
	$(PY) -m pytest -m "not graph" -n $(TEST_WORKERS) --dist loadgroup
	$(PY) -m pytest -m graph

clean:
	rm -rf $(VENV) build *.egg-info src/*/*.egg-info runs
