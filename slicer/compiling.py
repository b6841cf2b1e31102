"""Compiling on first use: whether a kernel is compiled for this machine yet, and saying so while it is.

Numba compiles a kernel the first time it is called and keeps the machine code in its cache
(:mod:`slicer._jit`); a fresh install, container or cluster machine pays that once per kernel group.
:func:`compiling` wraps the first launch of a job's kernels: when one of them is neither compiled in this
process nor in the cache, it logs one line on the ``skelslice.compile`` logger before compiling
(``compiling the tracer for this machine (first run only, about 60 s)``) and one after. The library only
logs (and never prints); the command line shows the lines on stderr, with the seconds ticking on a
terminal, and nothing with ``-q``.
"""
from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from typing import Iterable, Iterator

from slicer._jit import CACHE

#: about how long a feature's kernels take to compile in a fresh cache, s, on the 2-core development machine
#: (``python benchmarks/cold_start.py``; docs/benchmarks.md, "Cold start")
ABOUT = {"tracer": 65.0, "contours": 58.0, "renderer": 45.0}

#: the logger of the first-run messages
LOG = logging.getLogger("skelslice.compile")
#: ``record.skelslice_compile`` of the two messages
START, END = "start", "end"

_announcing = threading.local()


def is_compiled(dispatcher) -> bool:
    """Whether a Numba dispatcher has machine code at hand: compiled or loaded in this process, or an
    index of compiled versions in its cache folder (any signature)."""
    if dispatcher.overloads:
        return True
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    return cache_file is not None and os.path.exists(cache_file._index_path)


@contextlib.contextmanager
def compiling(what: str, dispatchers: Iterable, seconds: float) -> Iterator[bool]:
    """Announce the compilation of ``what`` around the block, if one of ``dispatchers`` needs it.

    Parameters
    ----------
    what : str
        What is compiled, for people: ``"the tracer and the layer writer"``.
    dispatchers : iterable of Numba dispatchers
        The entry kernels the block calls.
    seconds : float
        About how long compiling them takes on a 2-core machine (:data:`ABOUT`).

    Yields
    ------
    bool
        Whether the compilation was announced. Nested blocks announce nothing (the outer one spoke).
    """
    if getattr(_announcing, "on", False) or all(is_compiled(d) for d in dispatchers):
        yield False
        return
    _announcing.on = True
    when = "first run only" if CACHE else "every run: the compiled cache is off"
    LOG.info("compiling %s for this machine (%s, about %d s)", what, when, round(seconds),
             extra={"skelslice_compile": START})
    t0 = time.perf_counter()
    try:
        yield True
    finally:
        _announcing.on = False
        LOG.info("compiled %s in %.0f s", what, time.perf_counter() - t0, extra={"skelslice_compile": END})


__all__ = ["ABOUT", "LOG", "START", "END", "is_compiled", "compiling"]
