"""Keeping the 10 Hz loop on time on a busy machine: real-time priority for a node, and the
executor that spins it (:func:`executor_from_env`).

``run_graph.py --rt-priority N`` starts the bridge and the MPC with ``LMPC_RT_PRIORITY=N``
and the planner (not the embedded LLM's) with N-1, so the MPC preempts its decision steps;
:func:`apply_priority_from_env` (called by ``run_node`` before ``rclpy.init``, so every
DDS thread the node starts inherits it) switches the process to ``SCHED_FIFO`` at
priority N. A FIFO thread runs as soon as it is ready and keeps the core until it waits
again; the nodes wait on DDS between steps, so they take a core only for the ~5-10 ms of
a step and a benchmark worker next to them gets the rest. Needs ``CAP_SYS_NICE`` (root,
or an ``rtprio`` limit in /etc/security/limits.conf): without it the node says so once
and runs at normal priority. Measured effect: docs/RESULTS.md, "Where the time goes".

``run_graph.py --cpu-dma-latency US`` holds a Linux PM QoS request (:class:`CpuLatencyHold`)
for the run: no core goes into an idle state it needs longer than ``US`` microseconds to
leave (0: the cores only poll while idle). Between the steps of a realtime run (~93 ms of
100 ms idle) the cores otherwise sleep deeply and every stage of the next step runs slower.
The standard real-time Linux setting (cyclictest holds the same request); it costs power,
not time.
"""
from __future__ import annotations

import os
import struct
import sys
from typing import Optional

PRIORITY_ENV = "LMPC_RT_PRIORITY"
EXECUTOR_ENV = "LMPC_EXECUTOR"
EXECUTORS = ("events", "single")
"""How ``run_node`` spins a node (``$LMPC_EXECUTOR``; ``run_graph.py --executor``):
``events``, ``rclpy.experimental.EventsExecutor`` (the default since 2026-12-06: a step of
the sync graph ~0.6 ms shorter, the whole graph test suite passes under it;
docs/RESULTS.md, "The EventsExecutor"); ``single``, rclpy's single-threaded executor
(``rclpy.spin``), the default before. Not the multi-threaded executor: it is slow in these
wheels (README)."""
DEFAULT_EXECUTOR = "events"


def executor_from_env() -> str:
    """The executor ``$LMPC_EXECUTOR`` names (unset or empty: ``DEFAULT_EXECUTOR``);
    ValueError naming the value and the choices for anything else."""
    name = os.environ.get(EXECUTOR_ENV, "").strip() or DEFAULT_EXECUTOR
    if name not in EXECUTORS:
        raise ValueError(f"{EXECUTOR_ENV}={name!r} is not an executor: use one of "
                         f"{', '.join(EXECUTORS)}")
    return name


def apply_priority_from_env() -> Optional[str]:
    """Apply ``$LMPC_RT_PRIORITY`` (1-99) to this process; what was done, or None."""
    value = os.environ.get(PRIORITY_ENV, "")
    if not value:
        return None
    try:
        priority = int(value)
        if not 1 <= priority <= 99:
            raise ValueError
    except ValueError:
        print(f"{PRIORITY_ENV}={value!r} is not a priority 1-99: normal scheduling",
              file=sys.stderr, flush=True)
        return None
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as exc:
        print(f"{PRIORITY_ENV}={priority}: SCHED_FIFO refused ({exc}; needs CAP_SYS_NICE or "
              "an rtprio limit): normal scheduling", file=sys.stderr, flush=True)
        return None
    return f"SCHED_FIFO priority {priority}"


def node_priorities(priority: int, planner: str) -> dict[str, int]:
    """Node -> real-time priority under ``run_graph.py --rt-priority N`` (none for 0): N for
    the bridge and the MPC; N - 1 for the planner (the bridge waits for its status every
    step, so it must not fall behind a benchmark worker, but its decision steps take up
    to ~20 ms on a city map and must not hold a core the MPC needs: the MPC preempts
    it); none for the embedded LLM's planner (``planner`` "local"), which would keep its
    core busy for seconds at real-time priority."""
    if not priority:
        return {}
    out = {"bridge": priority, "mpc": priority}
    if planner != "local" and priority > 1:
        out.update(planner=priority - 1, mock_llm=priority - 1)
    return out


CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"


class CpuLatencyHold:
    """The PM QoS request "wake-up latency at most ``max_us``" held while this is open
    (the kernel drops it when the file is closed, also when the process dies); ``state``
    says what was done or why not. Needs write access to the device (root); without it,
    or without the device, nothing is held and ``state`` names the reason."""

    def __init__(self, max_us: Optional[int], device: str = CPU_LATENCY_DEVICE) -> None:
        self._fd: Optional[int] = None
        self.state: Optional[str] = None
        if max_us is None:
            return
        if max_us < 0:
            raise ValueError(f"a wake-up latency must be >= 0 us, not {max_us}")
        try:
            fd = os.open(device, os.O_WRONLY)
        except OSError as exc:
            self.state = f"not held: cannot open {device} ({exc.strerror})"
            return
        try:
            os.write(fd, struct.pack("i", max_us))
        except OSError as exc:
            os.close(fd)
            self.state = f"not held: {device} refused {max_us} ({exc.strerror})"
            return
        self._fd = fd
        self.state = f"held: wake-up latency <= {max_us} us ({device})"

    @property
    def held(self) -> bool:
        return self._fd is not None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
