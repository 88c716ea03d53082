"""Real-time priority for the 10 Hz nodes (``lmpc_msgs_py.scheduling``), in a child
process so the test runner keeps its own scheduling."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from lmpc_msgs_py.scheduling import PRIORITY_ENV

_PROBE = ("import os; from lmpc_msgs_py.scheduling import apply_priority_from_env as a; "
          "r = a(); print(repr(r), os.sched_getscheduler(0) == os.SCHED_FIFO, "
          "os.sched_getparam(0).sched_priority)")


def _probe(value: str) -> tuple[str, str]:
    env = dict(os.environ, **{PRIORITY_ENV: value})
    proc = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip(), proc.stderr.strip()


@pytest.mark.parametrize("value", ["0", "100", "high"])
def test_a_bad_priority_is_named_and_ignored(value: str) -> None:
    out, err = _probe(value)
    assert out == "None False 0"
    assert f"{PRIORITY_ENV}={value!r} is not a priority 1-99" in err


def test_a_priority_is_applied_or_the_refusal_said() -> None:
    out, err = _probe("7")
    if out.startswith("None"):  # no CAP_SYS_NICE here: said once, normal scheduling
        assert out == "None False 0" and "SCHED_FIFO refused" in err
    else:
        assert out == "'SCHED_FIFO priority 7' True 7" and err == ""
