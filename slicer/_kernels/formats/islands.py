"""Islands of a raster layer: 8-connected components of its non-zero pixels.

Printer formats store per-layer statistics (NanoDLP ``info.json``: island
count, largest and smallest island area). Components are found on the
layer's row runs with a union-find: two runs in adjacent rows belong to the
same island when they overlap or touch diagonally (8-connectivity, as
OpenCV's ``findContours`` counts outer contours, which UVtools uses).
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
def island_sizes(img):
    """Pixel counts of the 8-connected islands of the non-zero pixels.

    Parameters
    ----------
    img : (h, w) uint8

    Returns
    -------
    sizes : (n,) int64
        Pixels of each island, islands in the row-major order of their first
        pixel (n = 0 for an empty image).
    """
    h, w = img.shape
    n = 0                                            # pass 1: count the runs
    for r in range(h):
        inside = False
        for c in range(w):
            v = img[r, c] != 0
            if v and not inside:
                n += 1
            inside = v
    start = np.empty(n, np.int64)                    # pass 2: runs [start, stop), row by row
    stop = np.empty(n, np.int64)
    first = np.empty(h + 1, np.int64)
    k = 0
    for r in range(h):
        first[r] = k
        c = 0
        while c < w:
            if img[r, c] != 0:
                c0 = c
                while c < w and img[r, c] != 0:
                    c += 1
                start[k] = c0
                stop[k] = c
                k += 1
            else:
                c += 1
    first[h] = k
    parent = np.empty(n, np.int64)
    for i in range(n):
        parent[i] = i
    for r in range(1, h):                            # join runs of adjacent rows that touch
        i = first[r - 1]
        i_end = first[r]
        for b in range(first[r], first[r + 1]):
            while i < i_end and stop[i] < start[b]:  # ends left of b's diagonal neighbour
                i += 1
            j = i
            while j < i_end and start[j] <= stop[b]:
                ra = _root(parent, j)
                rb = _root(parent, b)
                if ra < rb:
                    parent[rb] = ra
                elif rb < ra:
                    parent[ra] = rb
                j += 1
    size = np.zeros(n, np.int64)
    m = 0
    for i in range(n):
        ri = _root(parent, i)
        if ri == i:
            m += 1
        size[ri] += stop[i] - start[i]
    out = np.empty(m, np.int64)
    m = 0
    for i in range(n):
        if parent[i] == i:
            out[m] = size[i]
            m += 1
    return out
