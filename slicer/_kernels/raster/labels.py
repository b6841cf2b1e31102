"""Connected components of raster layers, and their links between layers.

The printability check streams layers bottom to top and needs, per layer,
a label image of its regions (solid regions, 8-connected; empty regions,
4-connected, so that empty voxels join 6-connected in 3-D), and which
regions of two consecutive layers share a pixel. Components are found on
the layer's row runs with a union-find, as in :mod:`islands`.
"""
from __future__ import annotations

import numpy as np

from slicer._jit import kernel


@kernel
def _root(parent, x):
    """Root of ``x`` in the union-find forest, halving the path on the way."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@kernel
def _join(parent, a, b):
    """Merge the trees of ``a`` and ``b``; the smaller root index wins."""
    ra = _root(parent, a)
    rb = _root(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@kernel
def _count_runs(mask):
    """Number of runs of non-zero pixels over all rows of ``mask``."""
    h, w = mask.shape
    n = 0
    for r in range(h):
        inside = False
        for c in range(w):
            v = mask[r, c] != 0
            if v and not inside:
                n += 1
            inside = v
    return n


@kernel
def _find_runs(mask, start, stop, first):
    """Fill ``start``/``stop`` (column range of each run) and ``first`` (index
    of each row's first run; ``first[h]`` = number of runs)."""
    h, w = mask.shape
    k = 0
    for r in range(h):
        first[r] = k
        c = 0
        while c < w:
            if mask[r, c] != 0:
                c0 = c
                while c < w and mask[r, c] != 0:
                    c += 1
                start[k] = c0
                stop[k] = c
                k += 1
            else:
                c += 1
    first[h] = k


@kernel
def _join_rows(start, stop, first, h, ext, parent):
    """Join the runs of adjacent rows that share an edge (``ext = 0``) or also
    a corner (``ext = 1``)."""
    for r in range(1, h):
        i = first[r - 1]
        i_end = first[r]
        for b in range(first[r], first[r + 1]):
            while i < i_end and stop[i] + ext <= start[b]:   # run i ends before run b's reach
                i += 1
            j = i
            while j < i_end and start[j] < stop[b] + ext:
                _join(parent, j, b)
                j += 1


@kernel
def joined_runs(mask, eight):
    """The row runs of a layer's non-zero pixels, joined into connected regions.

    Parameters
    ----------
    mask : (h, w) uint8
    eight : bool
        8-connectivity (runs touching at a corner join); else 4-connectivity.

    Returns
    -------
    start, stop : (n,) int64
        Column range ``[start, stop)`` of each run, row after row.
    first : (h + 1,) int64
        Index of each row's first run; ``first[h] = n``.
    parent : (n,) int64
        Union-find forest of the runs; a region's root is its lowest run index (:func:`_root`).
    """
    h = mask.shape[0]
    n = _count_runs(mask)
    start = np.empty(n, np.int64)
    stop = np.empty(n, np.int64)
    first = np.empty(h + 1, np.int64)
    _find_runs(mask, start, stop, first)
    parent = np.empty(n, np.int64)
    for i in range(n):
        parent[i] = i
    _join_rows(start, stop, first, h, 1 if eight else 0, parent)
    return start, stop, first, parent


@kernel
def label_layer(mask, eight, labels):
    """Label the connected regions of a layer's non-zero pixels.

    Parameters
    ----------
    mask : (h, w) uint8
        Non-zero pixels belong to a region.
    eight : bool
        8-connectivity (pixels touching at a corner join); else 4-connectivity.
    labels : (h, w) int32
        Output: the region of each pixel, ``-1`` where ``mask`` is zero.
        Regions are numbered 0, 1, ... in the row-major order of their first
        pixel.

    Returns
    -------
    int
        Number of regions.
    """
    h, w = mask.shape
    start, stop, first, parent = joined_runs(mask, eight)
    n = start.shape[0]
    region = np.full(n, -1, np.int64)
    m = 0
    for i in range(n):                  # roots are the lowest run index of their tree
        ri = _root(parent, i)
        if region[ri] < 0:
            region[ri] = m
            m += 1
        region[i] = region[ri]
    for r in range(h):
        for c in range(w):
            labels[r, c] = -1
        for q in range(first[r], first[r + 1]):
            for c in range(start[q], stop[q]):
                labels[r, c] = region[q]
    return m


@kernel
def link_layers(below, above, m, n):
    """Join the regions of two consecutive layers that share a pixel.

    Parameters
    ----------
    below, above : (h, w) int32
        Label images (``-1``: no region) with ``m`` and ``n`` regions.
    m, n : int

    Returns
    -------
    (m + n,) int64
        The group of each region: nodes ``0 .. m-1`` are the regions of
        ``below``, ``m .. m+n-1`` those of ``above``; each node holds the
        lowest node index of its group.
    """
    h, w = below.shape
    parent = np.empty(m + n, np.int64)
    for i in range(m + n):
        parent[i] = i
    for r in range(h):
        for c in range(w):
            a = below[r, c]
            b = above[r, c]
            if a >= 0 and b >= 0:
                _join(parent, a, m + b)
    for i in range(m + n):
        parent[i] = _root(parent, i)
    return parent


@kernel
def region_stats(labels, n):
    """Pixel count, coordinate sums and bounding box of each region.

    Parameters
    ----------
    labels : (h, w) int32
        Label image (``-1``: no region) with ``n`` regions.
    n : int

    Returns
    -------
    (n, 7) int64
        Per region: pixels, sum of columns, sum of rows, first column, first
        row, last column, last row.
    """
    h, w = labels.shape
    out = np.zeros((n, 7), np.int64)
    for q in range(n):
        out[q, 3] = w
        out[q, 4] = h
        out[q, 5] = -1
        out[q, 6] = -1
    for r in range(h):
        for c in range(w):
            q = labels[r, c]
            if q < 0:
                continue
            out[q, 0] += 1
            out[q, 1] += c
            out[q, 2] += r
            if c < out[q, 3]:
                out[q, 3] = c
            if r < out[q, 4]:
                out[q, 4] = r
            if c > out[q, 5]:
                out[q, 5] = c
            if r > out[q, 6]:
                out[q, 6] = r
    return out


@kernel
def held_regions(labels, n, below):
    """Which regions have a pixel that is non-zero in ``below`` ((h, w) bool):
    (n,) bool."""
    h, w = labels.shape
    out = np.zeros(n, np.bool_)
    for r in range(h):
        for c in range(w):
            q = labels[r, c]
            if q >= 0 and below[r, c]:
                out[q] = True
    return out
