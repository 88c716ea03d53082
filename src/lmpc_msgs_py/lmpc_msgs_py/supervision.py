"""A node process never outlives the launcher that started it (STYLE.md 14).

``scripts/run_graph.py`` starts each node with ``LMPC_SUPERVISOR_PID=<its pid>`` in the
environment. :func:`follow_supervisor`, called first thing in the node process, then

1. asks Linux to send this process ``SIGTERM`` when its parent dies
   (``prctl(PR_SET_PDEATHSIG)``, through ctypes; no-op elsewhere);
2. re-checks ``getppid()`` against the expected pid: a supervisor that died between our
   ``fork`` and the ``prctl`` call would otherwise never signal us (the race the man page
   warns about), so the process stops at once;
3. starts a daemon thread that polls ``getppid()`` every 0.25 s (the fallback where
   ``prctl`` is missing, and a second line of defence): when the parent changes it sends
   ``SIGTERM`` to this process, and ``SIGKILL`` if it is still alive 2 s later (a
   process whose main thread is stuck in native code never runs its signal handler).

``SIGTERM`` ends a node as Ctrl-C does (rclpy's handler shuts the context down,
``run_node`` tears the node down). Without the variable (a node started by hand,
``ros2 run``, ``ros2 launch``) nothing changes: the process follows nobody.

Caveat: ``PR_SET_PDEATHSIG`` fires when the parent *thread* that forked us ends, not
only the parent process; a supervisor must start its nodes from a thread that lives as
long as it does (run_graph starts them from its main thread).
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from typing import Optional

SUPERVISOR_ENV = "LMPC_SUPERVISOR_PID"
"""Environment variable naming the pid of the supervisor a node must not outlive."""
PARENT_POLL_S = 0.25
"""Period of the parent-pid watch (the fallback to PR_SET_PDEATHSIG)."""
KILL_AFTER_S = 2.0
"""After SIGTERM for a dead supervisor, SIGKILL if the process is still alive this long."""
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def set_parent_death_signal(sig: int = signal.SIGTERM) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)``; False where it is not available (not Linux)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def supervisor_pid(environ: Optional[dict[str, str]] = None) -> Optional[int]:
    """The pid in ``LMPC_SUPERVISOR_PID`` (None when unset); ValueError naming a bad value."""
    text = (os.environ if environ is None else environ).get(SUPERVISOR_ENV, "").strip()
    if not text:
        return None
    try:
        pid = int(text)
    except ValueError:
        raise ValueError(f"{SUPERVISOR_ENV}={text!r} is not a process id") from None
    if pid <= 1:
        raise ValueError(f"{SUPERVISOR_ENV}={pid}: not a supervisor's process id")
    return pid


def _watch_parent(expected: int, poll_s: float, kill_after_s: float) -> None:
    while os.getppid() == expected:
        time.sleep(poll_s)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(kill_after_s)
    os.kill(os.getpid(), signal.SIGKILL)  # the SIGTERM did not end us


def follow_supervisor(*, poll_s: float = PARENT_POLL_S,
                      kill_after_s: float = KILL_AFTER_S) -> Optional[int]:
    """Make this process end when its supervisor (``LMPC_SUPERVISOR_PID``) dies.

    Returns the supervisor's pid, or None when the variable is unset (then it does
    nothing). Call it before anything slow (ROS init, scene build, solver compile).
    """
    expected = supervisor_pid()
    if expected is None:
        return None
    set_parent_death_signal(signal.SIGTERM)
    if os.getppid() != expected:
        # the supervisor is already gone (died before the prctl took effect)
        print(f"supervisor {expected} is gone: exiting", file=sys.stderr, flush=True)
        os._exit(143)
    threading.Thread(target=_watch_parent, args=(expected, poll_s, kill_after_s),
                     name="lmpc-supervisor-watch", daemon=True).start()
    return expected
