"""Stable orders of integer keys in linear time (layer, pixel and run orders).

:func:`stable_argsort` is ``np.argsort(keys, kind="stable")`` and
:func:`lexsort2` is ``np.lexsort((minor, major))`` -- the same permutations,
bit for bit -- computed by radix counting passes
(:mod:`slicer._kernels.raster.counting_sort`) when the keys are non-negative integers of at
most 48 bits: tens of millions of runs are ordered in a fraction of a second
instead of several seconds.
"""
from __future__ import annotations

import numpy as np

from slicer._kernels.raster.counting_sort import DIGIT_BITS, rect_parts_order, run_events_by_layer, stable_order

#: keys wider than this many radix digits fall back to NumPy's merge sort
MAX_PASSES = 3


def stable_argsort(keys: np.ndarray) -> np.ndarray:
    """The stable ascending order of integer ``keys``.

    Parameters
    ----------
    keys : (n,) integer array

    Returns
    -------
    (n,) int64
        Equal to ``np.argsort(keys, kind="stable")``.

    Raises
    ------
    TypeError
        ``keys`` is not a one-dimensional integer array.

    Examples
    --------
    >>> stable_argsort(np.array([3, 1, 3, 0, 1]))
    array([3, 1, 4, 0, 2])
    """
    keys = np.asarray(keys)
    if keys.ndim != 1 or keys.dtype.kind not in "iu":
        raise TypeError(f"stable_argsort needs a 1-D integer array, got {keys.dtype} with shape {keys.shape}")
    if keys.size < 2:
        return np.arange(keys.size, dtype=np.int64)
    lo, hi = int(keys.min()), int(keys.max())
    passes = max(1, -(-hi.bit_length() // DIGIT_BITS))
    if lo < 0 or passes > MAX_PASSES:
        return np.argsort(keys, kind="stable").astype(np.int64, copy=False)
    return stable_order(np.ascontiguousarray(keys, dtype=np.int64), passes)


def lexsort2(minor: np.ndarray, major: np.ndarray) -> np.ndarray:
    """The order by ``major``, then ``minor``, ties in input order.

    Parameters
    ----------
    minor, major : (n,) integer arrays

    Returns
    -------
    (n,) int64
        Equal to ``np.lexsort((minor, major))``.

    Examples
    --------
    >>> lexsort2(np.array([5, 2, 7, 1]), np.array([1, 0, 1, 0]))
    array([3, 1, 0, 2])
    """
    first = stable_argsort(minor)
    return first[stable_argsort(np.asarray(major)[first])]


def layer_events(pix: np.ndarray, k0: np.ndarray, k1: np.ndarray, layers: int, value: int = 255):
    """The set and clear events of inside runs, grouped by layer.

    Parameters
    ----------
    pix, k0, k1 : (r,) int64
        Runs ``[k0, k1)`` of layer indices of pixel ``pix`` (``0 <= k0 < k1 <= layers``).
    layers : int
    value : int
        The grey a run sets (0..255).

    Returns
    -------
    starts : (layers + 1,) int64
        The events of layer k are ``[starts[k], starts[k + 1])``.
    ev_pix : (2 r,) int64
    ev_val : (2 r,) uint8
        Within a layer the sets (``value``), then the clears (0), each in run
        order: the events ``concatenate([k0, k1])`` in stable layer order.

    Raises
    ------
    ValueError
        A run outside ``[0, layers]`` or empty (the kernel would write out of bounds).
    """
    k0 = np.ascontiguousarray(k0, dtype=np.int64)
    k1 = np.ascontiguousarray(k1, dtype=np.int64)
    if k0.size and (k0.min() < 0 or k1.max() > layers or np.any(k1 <= k0)):
        bad = int(np.flatnonzero((k0 < 0) | (k1 > layers) | (k1 <= k0))[0])
        raise ValueError(f"run {bad} covers layers [{k0[bad]}, {k1[bad]}), not a non-empty range of [0, {layers})")
    return run_events_by_layer(np.ascontiguousarray(pix, dtype=np.int64), k0, k1, int(layers), np.uint8(value))


def rect_parts(parts, width: int, minor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Plate pixels of items held by non-overlapping rectangles, and their stable order.

    Parameters
    ----------
    parts : list of (i0, j0, tw, th, local)
        A rectangle of ``th`` rows and ``tw`` columns whose corner is plate
        column ``i0``, row ``j0``, and the local indices ``jl * tw + il`` of
        its items (a 1-D integer array). Parts in any order; items of all
        parts are numbered in the order of ``parts``.
    width : int
        Plate width, px.
    minor : (n,) integer array, optional
        A secondary key: the order is then by pixel, then ``minor``.

    Returns
    -------
    pix : (n,) int64
        Each item's plate pixel ``(j0 + jl) * width + i0 + il``.
    order : (n,) int64
        Equal to ``np.argsort(pix, kind="stable")`` (with ``minor``:
        ``np.lexsort((minor, pix))``). When every part's indices are sorted
        (the tracer's tiles and buckets), one pass over the plate's rows
        gives it (:func:`slicer._kernels.raster.counting_sort.rect_parts_order`); otherwise
        a radix sort.
    """
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    visit = np.array(sorted(range(len(parts)), key=lambda p: (parts[p][0], parts[p][1])), np.int64)
    starts = np.concatenate([[0], np.cumsum([len(pt[4]) for pt in parts])]).astype(np.int64)
    local = np.concatenate([np.asarray(pt[4]) for pt in parts]).astype(np.int64, copy=False)
    keyed = np.zeros(0, np.int64) if minor is None else np.ascontiguousarray(minor, dtype=np.int64)
    i0, j0, tw, th = (np.array([pt[k] for pt in parts], np.int64) for k in range(4))
    ok, order, pix = rect_parts_order(local, starts, i0, j0, tw, th, visit, int(width), keyed)
    if not ok:
        for (a0, b0, w, _, loc), a, b in zip(parts, starts[:-1], starts[1:]):
            jl, il = np.divmod(np.asarray(loc, np.int64), w)
            pix[a:b] = (b0 + jl) * width + a0 + il
        return pix, (stable_argsort(pix) if minor is None else lexsort2(minor, pix))
    return pix, order


__all__ = ["stable_argsort", "lexsort2", "layer_events", "rect_parts"]
