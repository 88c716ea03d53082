"""Where the calls of a run execute: the local process pool (the default) or Ray tasks.

An executor runs ``fn(*args)`` for each of ``calls`` and yields ``(index, result)`` as the
calls finish, in any order; a call whose worker failed (a process that died, a Ray task
that could not run) yields the exception object as its result. ``fn`` must be a
module-level function (it is sent to the workers by name). ``abort()`` abandons the
calls still running (their workers are killed); ``close()`` releases the workers. Used as
a context manager: ``with make_executor("ray", 2) as ex: for i, r in ex.results(...)``.

Each worker process runs one call at a time and is reused across calls, so a process
keeps what it prepared once (libsumo allows one simulation per process; the compiled MPC
solver): a pool worker or a Ray worker process (tasks of ``num_cpus=1``).

``ray``: ``ray.init`` connects to ``RAY_ADDRESS`` when the environment sets it (a cluster
of ``ray start --head`` / ``ray start --address=...``; README, "Running on a Ray
cluster"); otherwise it starts a private local Ray of ``workers`` CPUs without dashboard,
which ``close()`` stops. A cluster it connected to is only disconnected from, never shut
down. Ray is an optional dependency (the ``ray`` extra): only this executor imports it.
"""
from __future__ import annotations

import os
import socket
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from typing import Any, Callable, Iterator, Optional, Sequence

from lmpc_msgs_py.cli import int_arg

EXECUTORS = ("pool", "ray")
"""The executors ``make_executor`` knows; ``pool`` is the default everywhere."""

RAY_OBJECT_STORE_BYTES = 100 * 1024 * 1024
"""The object store of a local Ray (its default takes 30 % of the RAM): calls return rows."""

WORKER_ENV = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID")
"""Variables a Ray worker gets from the driver's environment (runtime env); DDS discovery
stays on the worker's machine unless the caller opened it up."""


class ExecutorError(RuntimeError):
    """The executor cannot start (e.g. Ray not installed, or no cluster at RAY_ADDRESS)."""


class PoolExecutor:
    """Local worker processes (``concurrent.futures.ProcessPoolExecutor``)."""

    name = "pool"

    def __init__(self, workers: int) -> None:
        self.workers = max(1, workers)
        self._pool: Optional[ProcessPoolExecutor] = None
        self._aborted = False

    def __enter__(self) -> "PoolExecutor":
        self._pool = ProcessPoolExecutor(max_workers=self.workers)
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def results(self, fn: Callable[..., Any], calls: Sequence[tuple[Any, ...]]
                ) -> Iterator[tuple[int, Any]]:
        assert self._pool is not None, "use the executor as a context manager"
        futures: dict[Future[Any], int] = {
            self._pool.submit(fn, *args): i for i, args in enumerate(calls)}
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. a worker process that died
                result = exc
            yield futures[fut], result

    def abort(self) -> None:
        self._aborted = True
        # the executor has no public way to stop a running call, and a worker may be
        # minutes into an LLM episode
        for proc in list((getattr(self._pool, "_processes", None) or {}).values()):
            proc.kill()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=not self._aborted, cancel_futures=True)
            self._pool = None


class RayExecutor:
    """Ray tasks (one CPU each) on a local Ray or the cluster at ``RAY_ADDRESS``."""

    name = "ray"

    def __init__(self, workers: int, *, log_to_driver: bool = True) -> None:
        self.workers = max(1, workers)
        self.log_to_driver = log_to_driver
        self.address: Optional[str] = os.environ.get("RAY_ADDRESS") or None
        self._ray: Any = None
        self._pending: list[Any] = []

    def __enter__(self) -> "RayExecutor":
        try:
            import ray
        except ImportError as exc:
            raise ExecutorError(
                "--executor ray needs Ray: pip install -e '.[ray]' (or pip install ray)"
            ) from exc
        env = {k: os.environ[k] for k in WORKER_ENV if k in os.environ}
        env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        kwargs: dict[str, Any] = dict(
            include_dashboard=False, log_to_driver=self.log_to_driver,
            runtime_env={"env_vars": env}, configure_logging=True, logging_level="warning")
        if self.address is None:
            # "local": a private Ray for this run, even if another one runs on this machine
            kwargs.update(address="local", num_cpus=self.workers, num_gpus=0,
                          object_store_memory=RAY_OBJECT_STORE_BYTES)
        else:
            _check_reachable(self.address)
            kwargs.update(address=self.address)
        try:
            ray.init(**kwargs)
        except Exception as exc:  # noqa: BLE001 - ConnectionError and Ray's own
            hint = ("" if self.address is None or os.environ.get("RAY_AUTH_MODE") else
                    " (a cluster with token authentication: set RAY_AUTH_MODE=token)")
            raise ExecutorError(f"ray.init({self.address or 'local'}): "
                                f"{type(exc).__name__}: {exc}{hint}") from exc
        self._ray = ray
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def results(self, fn: Callable[..., Any], calls: Sequence[tuple[Any, ...]]
                ) -> Iterator[tuple[int, Any]]:
        ray = self._ray
        assert ray is not None, "use the executor as a context manager"
        # max_retries=0: a scene whose worker died is an error row, as in the pool
        task = ray.remote(num_cpus=1, max_retries=0)(fn)
        index = {}
        for i, args in enumerate(calls):
            index[task.remote(*args)] = i
        self._pending = list(index)
        while self._pending:
            # a short timeout: Ctrl-C and SIGTERM reach the driver between waits
            done, self._pending = ray.wait(self._pending, num_returns=1, timeout=0.5)
            for ref in done:
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - WorkerCrashedError, RayTaskError
                    result = exc
                yield index[ref], result

    def abort(self) -> None:
        for ref in self._pending:
            try:
                self._ray.cancel(ref, force=True)  # kills the worker running it
            except Exception:  # noqa: BLE001 - already finished or gone
                pass
        self._pending = []

    def close(self) -> None:
        if self._ray is not None:
            # a local Ray stops with its driver; a cluster is only disconnected from
            self._ray.shutdown()
            self._ray = None


def _check_reachable(address: str) -> None:
    """A ``host:port`` address nobody listens at is named at once (``ray.init`` retries
    it for minutes); other forms (``auto``, ``ray://...``) are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or "/" in address or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as exc:
        raise ExecutorError(f"no Ray cluster at RAY_ADDRESS={address} ({exc}); start one "
                            "with `ray start --head` or unset RAY_ADDRESS for a local Ray"
                            ) from exc


Executor = PoolExecutor | RayExecutor


workers_arg = int_arg(1)
"""``--workers`` of the benchmark and regret scripts (0 or a negative count was taken as 1
without a word)."""


def make_executor(name: str, workers: int) -> Executor:
    """The executor called ``name`` (one of ``EXECUTORS``) with ``workers`` processes (a
    local Ray: its CPUs; a cluster: its own CPUs decide)."""
    if name == "pool":
        return PoolExecutor(workers)
    if name == "ray":
        return RayExecutor(workers)
    raise ValueError(f"unknown executor {name!r}; choose from {', '.join(EXECUTORS)}")
