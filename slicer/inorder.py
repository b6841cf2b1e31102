"""Mapping a function over a stream on a few threads, results kept in order.

The one pipelined pool of the package: layer encoding
(:func:`formats.base.write_ordered`) and the contours of layer planes
(:func:`slicer.contours.iter_contours`) both compute items independently and
consume them strictly in order, so the output does not depend on the number
of threads.
"""
from __future__ import annotations

import collections
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, Iterator, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def map_in_order(fn: Callable[[T], R], items: Iterable[T], workers: int, ahead: int = 2,
                 name: str = "inorder") -> Iterator[tuple[T, R]]:
    """Yield ``(item, fn(item))`` for each item, in the order of ``items``.

    With ``workers > 1``, ``fn`` runs on a pool of ``workers`` threads, at most
    ``ahead * workers`` items in flight while the caller consumes the
    results; ``fn`` must be thread-safe (it pays where it releases the GIL:
    compiled kernels, zlib, large numpy operations). With ``workers <= 1``
    everything runs in the calling thread. ``items`` is read in the calling
    thread only.

    An exception raised by ``fn`` is raised here, at its item; closing the
    generator early cancels the items not yet started and waits for the
    running ones.

    Parameters
    ----------
    fn : callable
    items : iterable
    workers : int
    ahead : int
        Items in flight per worker.
    name : str
        Prefix of the worker threads' names.

    Examples
    --------
    >>> [r for _, r in map_in_order(lambda x: x * x, range(6), workers=2)]
    [0, 1, 4, 9, 16, 25]
    """
    if workers <= 1:
        for item in items:
            yield item, fn(item)
        return
    pending: collections.deque = collections.deque()
    with ThreadPoolExecutor(max_workers=int(workers), thread_name_prefix=name) as pool:
        try:
            for item in items:
                pending.append((item, pool.submit(fn, item)))
                if len(pending) >= ahead * workers:
                    item0, fut = pending.popleft()
                    yield item0, fut.result()
            while pending:
                item0, fut = pending.popleft()
                yield item0, fut.result()
        finally:
            for _, fut in pending:
                fut.cancel()


__all__ = ["map_in_order"]
