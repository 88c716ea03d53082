"""The method registry (``scripts/methods.py``) and ``benchmark.py --list-methods``."""
from __future__ import annotations

import subprocess
import sys

import pytest
from graphkit import REPO

from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_scripts import methods


def test_list_methods_prints_every_registered_method_on_one_line() -> None:
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "benchmark.py"),
                          "--list-methods"], capture_output=True, text=True, check=True).stdout
    names = [line.split()[0] for line in out.splitlines()]
    assert names == list(methods.METHODS)
    assert {"mpc", "lmpc-rules", "lmpc-local", "lmpc-openai", "lmpc-replay"} <= set(names)
    assert all(len(line.split(maxsplit=1)) == 2 for line in out.splitlines())


def test_the_registry_names_an_unknown_method_and_a_replay_without_its_log() -> None:
    with pytest.raises(KeyError, match="unknown method 'lmpc-nope'"):
        methods.build(SceneSpec("lmpc-nope", "usi", 0))
    with pytest.raises(ValueError, match="--replay-from"):
        methods.build(SceneSpec("lmpc-replay", "usi", 0))


def test_a_factory_named_module_function_is_imported_when_the_method_runs() -> None:
    entry = methods.Method("x", "a method by name", "lmpc_scripts.methods:build_mpc")
    wiring = entry.build(SceneSpec("x", "usi", 0))
    assert wiring.planner is None and hasattr(wiring.controller, "compute")
    assert set(wiring.finish(None)) == {"route_overrides", "stale_steps", "stale_agent_steps"}
