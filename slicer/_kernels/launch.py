"""Launching compiled kernels: the one place that sets Numba's thread count.

Numba keeps the number of threads a parallel kernel may use per calling
thread (a thread-local mask over the pool), so a scope set here affects only
the Python thread that opened it: two tiles launched from two threads of the
``threads`` executor each keep their own count. Library code never calls
``numba.set_num_threads`` anywhere else (a test walks the sources).
"""
from __future__ import annotations

import contextlib

import numba

from ..errors import OptionError


def cores() -> int:
    """Threads in Numba's pool (``NUMBA_NUM_THREADS``, default: the cores)."""
    return int(numba.config.NUMBA_NUM_THREADS)


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


def serial():
    """A scope of one Numba thread (small batches: waking the pool costs more than it saves)."""
    return numba_threads(1)


__all__ = ["cores", "numba_threads", "one_item_per_thread", "serial"]
