"""Chaining of oriented contour segments into closed rings."""
from __future__ import annotations

import numpy as np

from .._jit import kernel


@kernel
def chain_rings(nxt):
    """Split a successor map into its cycles.

    Every vertex has exactly one outgoing segment ``v -> nxt[v]`` and one
    incoming segment, so the map is a permutation whose cycles are the rings.
    Each ring starts at its smallest vertex index and rings come in the order
    of those indices, so the output does not depend on any thread count.

    Parameters
    ----------
    nxt : (n,) int64
        Successor of each vertex. A value outside ``[0, n)`` or a vertex
        reached twice is a broken map.

    Returns
    -------
    order : (n,) int64
        Vertex indices, ring after ring.
    starts : (r + 1,) int64
        Ring ``q`` is ``order[starts[q]:starts[q + 1]]``.
    status : int
        0 on success, 1 if ``nxt`` is not a permutation (then the outputs
        hold the rings chained before the fault).
    """
    n = nxt.shape[0]
    seen = np.zeros(n, np.bool_)
    order = np.empty(n, np.int64)
    starts = np.empty(n + 1, np.int64)
    nr = 0
    pos = 0
    status = 0
    for v0 in range(n):
        if seen[v0]:
            continue
        starts[nr] = pos
        nr += 1
        v = v0
        while True:
            if v < 0 or v >= n or seen[v]:
                status = 1
                break
            seen[v] = True
            order[pos] = v
            pos += 1
            v = nxt[v]
            if v == v0:
                break
        if status != 0:
            break
    starts[nr] = pos
    return order[:pos], starts[:nr + 1], status


@kernel
def ring_areas(xy, starts):
    """Shoelace area of each ring, summed in vertex order: ring ``q`` is
    ``xy[starts[q]:starts[q + 1]]``, (n, 2) float64, mm; returns (r,) float64,
    mm² (positive: counter-clockwise)."""
    nr = starts.shape[0] - 1
    out = np.empty(nr)
    for q in range(nr):
        a = starts[q]
        b = starts[q + 1]
        s1 = 0.0
        s2 = 0.0
        for i in range(a, b):
            j = i + 1 if i + 1 < b else a
            s1 += xy[i, 0] * xy[j, 1]
            s2 += xy[j, 0] * xy[i, 1]
        out[q] = 0.5 * (s1 - s2)
    return out
