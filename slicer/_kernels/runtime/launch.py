"""Launching compiled kernels: the one place that sets Numba's thread count.

Numba keeps the number of threads a parallel kernel may use per calling
thread (a thread-local mask over the pool), so a scope set here affects only
the Python thread that opened it: two tiles launched from two threads of the
``threads`` executor each keep their own count. Library code never calls
``numba.set_num_threads`` anywhere else (a test walks the sources).
"""
from __future__ import annotations

import contextlib
import os
from typing import Callable

import numba
import numpy as np

from slicer.errors import OptionError


def cores() -> int:
    """Threads in Numba's pool (``NUMBA_NUM_THREADS``, default: the cores)."""
    return int(numba.config.NUMBA_NUM_THREADS)


def limit_pool(n: int) -> None:
    """Make ``n`` the size of this process's Numba thread pool, before the pool starts.

    For a fresh worker process (a pool initialiser). The limit goes into
    Numba's configuration at once, not only into ``NUMBA_NUM_THREADS``:
    Numba reads the environment again whenever it compiles, and a worker
    whose kernels come from the cache starts its pool without compiling, so
    a later compile would find another count and refuse to go on ("Cannot
    set NUMBA_NUM_THREADS ... once the threads have been launched").
    """
    os.environ["NUMBA_NUM_THREADS"] = str(int(n))
    numba.config.reload_config()


@contextlib.contextmanager
def numba_threads(n: int | None):
    """Run the block with at most ``n`` Numba threads (``None``: leave the count).

    Parameters
    ----------
    n : int or None
        Threads for parallel kernels launched from this Python thread;
        clipped to :func:`cores`.

    Yields
    ------
    int
        The thread count in force inside the block.
    """
    if n is None:
        yield numba.get_num_threads()
        return
    n = int(n)
    if n < 1:
        raise OptionError(f"threads must be >= 1, got {n}")
    old = numba.get_num_threads()
    numba.set_num_threads(min(n, cores()))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(old)


@contextlib.contextmanager
def one_item_per_thread():
    """Dynamic schedules of the block's parallel kernels hand out one item
    (one bucket) at a time: buckets differ widely in cost, so chunks of
    several would leave threads idle at the end of a launch."""
    with numba.parallel_chunksize(1):
        yield


def launch_until_fits(launch: Callable[[np.ndarray, int], np.ndarray], items: np.ndarray, what: str,
                      grow: int = 4, tries: int = 16) -> None:
    """Launch a kernel on ``items`` and relaunch those whose output buffers filled up.

    The one retry loop of the tracer and the renderer: a kernel writes a
    variable amount per item (runs, roots) into buffers sized up front, and
    flags the items that did not fit; those are launched again with ``grow``
    times the room, at most ``tries`` times in all.

    Parameters
    ----------
    launch : callable
        ``launch(pending, scale)`` runs the kernel on ``pending`` (a subset
        of ``items``, in order) with buffers ``scale`` times their first
        size (1, grow, grow**2, ...), keeps the results of the items that
        fit, and returns a boolean array, True for each item to run again.
        It may raise when more room cannot help.
    items : (m,) int64
    what : str
        Names the kernel in the internal error raised when ``tries`` runs
        out.
    """
    pending, scale = items, 1
    for _ in range(tries):
        if not len(pending):
            return
        full = np.asarray(launch(pending, scale), dtype=bool)
        pending, scale = pending[full], scale * grow
    if len(pending):
        raise RuntimeError(f"internal error: the {what}'s buffers kept overflowing")  # pragma: no cover


def serial():
    """A scope of one Numba thread (small batches: waking the pool costs more than it saves)."""
    return numba_threads(1)


__all__ = ["cores", "numba_threads", "one_item_per_thread", "launch_until_fits", "serial"]
