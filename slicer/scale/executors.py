"""Where tile tasks run: one path for serial, threads, processes and Dask.

Every backend is a :class:`concurrent.futures.Executor` (style.md B.3): the
serial one runs each task at ``submit`` in the calling thread (Numba threads
inside the kernel, today's path), ``threads`` and ``processes`` are the
standard library pools, and ``dask`` is ``distributed.Client.get_executor()``,
on a local cluster by default or on the scheduler at ``--scheduler ADDRESS``.
Results are always consumed in submission order (:func:`map_ordered`), so
the output never depends on which task finishes first.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

from slicer._kernels.runtime.launch import limit_pool
from slicer.errors import OptionError, require

#: executor names accepted by :func:`open_executor` (and ``--executor``)
EXECUTORS = ("serial", "threads", "processes", "dask")
#: how long to wait for a Dask scheduler given by address
CONNECT_TIMEOUT = "20s"


class SerialExecutor(cf.Executor):
    """Runs each task immediately, in the calling thread, at ``submit``.

    Exceptions are stored in the future (as the pools do) and re-raised by
    ``result()``; ``KeyboardInterrupt`` propagates at once.
    """

    def submit(self, fn, /, *args, **kwargs):
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - delivered through the future
            fut.set_exception(exc)
        return fut


@dataclass(frozen=True)
class ExecutorInfo:
    """What an opened executor is.

    Attributes
    ----------
    kind : str
        One of :data:`EXECUTORS`.
    workers : int
        Tasks that can run at once.
    task_threads : int or None
        Numba threads each task should use: ``None`` (all cores) for the
        serial executor, 1 for pools, whose parallelism is the workers.
    address : str or None
        Dask scheduler address.
    """

    kind: str
    workers: int
    task_threads: int | None
    address: str | None = None

    def describe(self) -> str:
        if self.kind == "serial":
            return "serial (in process, Numba threads inside each tile)"
        where = f" at {self.address}" if self.address else ""
        return f"{self.kind}: {self.workers} worker{'s' if self.workers != 1 else ''}{where}, 1 thread per task"


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def executor_info(kind: str = "serial", workers: int | None = None,
                  scheduler: str | None = None) -> ExecutorInfo:
    """What :func:`open_executor` would open, without opening it (for plans
    and dry runs; a remote Dask cluster counts ``workers`` or 1)."""
    _check(kind, workers, scheduler)
    if kind == "serial":
        return ExecutorInfo("serial", 1, None)
    n = int(workers) if workers else (1 if scheduler else _default_workers())
    return ExecutorInfo(kind, n, 1, scheduler)


def _check(kind, workers, scheduler) -> None:
    if kind not in EXECUTORS:
        raise OptionError(f"unknown executor {kind!r}; choose one of {', '.join(EXECUTORS)}")
    if workers is not None and int(workers) < 1:
        raise OptionError(f"workers must be >= 1, got {workers}")
    if scheduler and kind != "dask":
        raise OptionError(f"--scheduler needs --executor dask (got --executor {kind})")


def _limit_threads() -> None:
    """Worker initialiser: keep each pool worker to one Numba thread
    (:func:`slicer._kernels.runtime.launch.limit_pool`)."""
    limit_pool(int(os.environ.get("NUMBA_NUM_THREADS", "1")))


@contextlib.contextmanager
def open_executor(kind: str = "serial", workers: int | None = None,
                  scheduler: str | None = None) -> Iterator[tuple[cf.Executor, ExecutorInfo]]:
    """Open an executor; it is shut down (and a local Dask cluster closed) on exit.

    Parameters
    ----------
    kind : {"serial", "threads", "processes", "dask"}
    workers : int, optional
        Pool size (default: the cores available; for Dask with
        ``scheduler``, the cluster's current worker count).
    scheduler : str, optional
        Dask only: address of a running scheduler, e.g.
        ``tcp://10.0.0.5:8786``. Default: start a local cluster.

    Yields
    ------
    (concurrent.futures.Executor, ExecutorInfo)

    Raises
    ------
    OptionError
        Unknown kind, ``workers < 1``, ``scheduler`` without Dask, Dask not
        installed, or a scheduler that cannot be reached.
    """
    _check(kind, workers, scheduler)
    if kind == "serial":
        ex = SerialExecutor()
        with ex:
            yield ex, ExecutorInfo("serial", 1, None)
        return
    n = int(workers) if workers else _default_workers()
    if kind == "threads":
        with cf.ThreadPoolExecutor(max_workers=n, thread_name_prefix="skelslice") as ex:
            yield ex, ExecutorInfo("threads", n, 1)
        return
    if kind == "processes":
        # spawn, not fork: OpenMP/TBB thread pools are not fork safe
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_limit_threads) as ex:
            yield ex, ExecutorInfo("processes", n, 1)
        return
    yield from _open_dask(workers, scheduler)


def _open_dask(workers, scheduler):
    distributed = require("distributed", "dist", "--executor dask")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster
    with contextlib.ExitStack() as stack:
        if scheduler:
            try:
                client = stack.enter_context(Client(scheduler, timeout=CONNECT_TIMEOUT))
            except (OSError, TimeoutError) as exc:
                raise OptionError(f"--scheduler: cannot reach the Dask scheduler at {scheduler}: {exc}") from None
            n = int(workers) if workers else max(1, sum(
                w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
            address = scheduler
        else:
            n = int(workers) if workers else _default_workers()
            cluster = stack.enter_context(LocalCluster(n_workers=n, threads_per_worker=1,
                                                       dashboard_address=None, processes=True))
            client = stack.enter_context(Client(cluster))
            address = cluster.scheduler_address
        yield client.get_executor(), ExecutorInfo("dask", n, 1, address)


def map_ordered(executor: cf.Executor, fn: Callable, argsets: Iterable[tuple],
                window: int) -> Iterator:
    """``fn(*args)`` for each ``args``, yielded in input order (``None`` for
    ``args`` that are None: nothing to run).

    At most ``window`` tasks are pending at once, so the results waiting to
    be consumed (and their memory) stay bounded. Pending tasks are cancelled
    if the consumer stops early or fails.
    """
    window = max(1, int(window))
    pending: deque = deque()
    try:
        for args in argsets:
            if args is None:
                fut: cf.Future = cf.Future()
                fut.set_result(None)
                pending.append(fut)
            else:
                pending.append(executor.submit(fn, *args))
            if len(pending) >= window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for fut in pending:
            fut.cancel()


__all__ = ["EXECUTORS", "ExecutorInfo", "executor_info", "SerialExecutor", "open_executor", "map_ordered"]
