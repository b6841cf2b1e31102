"""Mapping a function over a stream on a few threads, results kept in order.

The one pipelined pool of the package: layer encoding
(:func:`formats.base.write_ordered`) and the contours of layer planes
(:func:`slicer.contours.iter_contours`) both compute items independently and
consume them strictly in order, so the output does not depend on the number
of threads.
"""
from __future__ import annotations

import collections
import queue
import threading
from concurrent.futures import Future
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

    An exception raised by ``fn`` is raised here, at its item. Closing the
    generator early (an error or a signal in the consumer) cancels the items
    not yet started and does not wait for the running ones: the workers are
    daemon threads, so a job interrupted in the middle of a long item exits
    at once (the item's result is dropped).

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
    tasks: queue.SimpleQueue = queue.SimpleQueue()
    threads = [threading.Thread(target=_work, args=(fn, tasks), name=f"{name}-{i}", daemon=True)
               for i in range(int(workers))]
    for t in threads:
        t.start()
    pending: collections.deque = collections.deque()
    finished = False
    try:
        for item in items:
            fut: Future = Future()
            tasks.put((item, fut))
            pending.append((item, fut))
            if len(pending) >= ahead * workers:
                item0, fut0 = pending.popleft()
                yield item0, fut0.result()
        while pending:
            item0, fut0 = pending.popleft()
            yield item0, fut0.result()
        finished = True
    finally:
        for _, fut in pending:
            fut.cancel()
        for _ in threads:
            tasks.put(None)
        if finished:
            for t in threads:
                t.join()


def _work(fn: Callable, tasks: queue.SimpleQueue) -> None:
    """A worker of :func:`map_in_order`: run ``fn`` on queued items until ``None``."""
    while True:
        job = tasks.get()
        if job is None:
            return
        item, fut = job
        if not fut.set_running_or_notify_cancel():
            continue
        try:
            fut.set_result(fn(item))
        except BaseException as exc:             # handed to the consumer, raised at its item
            fut.set_exception(exc)


__all__ = ["map_in_order"]
