"""Chaining of oriented contour segments into closed rings."""
from __future__ import annotations

import numpy as np

from slicer._jit import inline_kernel, kernel
from slicer._kernels.raster.counting_sort import stable_order


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


@kernel
def _sorted_points(keys, passes):
    """Unique ``keys`` in ascending order and each key's rank among them."""
    order = stable_order(keys, passes)
    rank = np.empty(keys.shape[0], np.int64)
    uniq = np.empty(keys.shape[0], np.int64)
    nu = -1
    for j in range(keys.shape[0]):
        k = keys[order[j]]
        if nu < 0 or k != uniq[nu]:
            nu += 1
            uniq[nu] = k
        rank[order[j]] = nu
    return uniq[:nu + 1].copy(), rank


@kernel
def leaf_walks(X0, Y0, X1, Y1, passes):
    """Counter-clockwise walks over the boundaries of leaves (lattice squares
    ``[X0, X1] x [Y0, Y1]``), through every leaf corner lying on them
    (:func:`slicer.contours.cells._boundary_walks` documents the results).

    Each walk starts at its leaf's bottom-left corner: along the bottom (x
    rising), the right side (y rising), the top (x falling), the left side (y
    falling). The corners lying strictly inside a side are those between its
    two end corners in row order (sides along x) or column order (along y).
    ``passes``: radix digits of the largest key ``(max + 2)² `` (see
    :func:`slicer._kernels.raster.counting_sort.stable_order`).

    Returns
    -------
    px, py : (v,) int64
    leaf, point : (w,) int64
    """
    n = X0.shape[0]
    big = max(X0.max(), X1.max(), Y0.max(), Y1.max()) + 2
    keys = np.empty(4 * n, np.int64)
    for i in range(n):
        keys[i] = Y0[i] * big + X0[i]
        keys[n + i] = Y0[i] * big + X1[i]
        keys[2 * n + i] = Y1[i] * big + X1[i]
        keys[3 * n + i] = Y1[i] * big + X0[i]
    uniq, point_of = _sorted_points(keys, passes)
    nv = uniq.shape[0]
    py = uniq // big
    px = uniq - py * big
    cols = np.empty(nv, np.int64)
    for p in range(nv):
        cols[p] = px[p] * big + py[p]
    ocol = stable_order(cols, passes)
    col_rank = np.empty(nv, np.int64)
    for k in range(nv):
        col_rank[ocol[k]] = k
    total = 0
    for i in range(n):
        bl, br, tr, tl = point_of[i], point_of[n + i], point_of[2 * n + i], point_of[3 * n + i]
        total += 4 + (br - bl - 1) + (col_rank[tr] - col_rank[br] - 1) + (tr - tl - 1) + (col_rank[tl] - col_rank[bl] - 1)
    leaf = np.empty(total, np.int64)
    point = np.empty(total, np.int64)
    w = 0
    for i in range(n):
        bl, br, tr, tl = point_of[i], point_of[n + i], point_of[2 * n + i], point_of[3 * n + i]
        start = w
        point[w] = bl
        w += 1
        for k in range(bl + 1, br):
            point[w] = k
            w += 1
        point[w] = br
        w += 1
        for k in range(col_rank[br] + 1, col_rank[tr]):
            point[w] = ocol[k]
            w += 1
        point[w] = tr
        w += 1
        for k in range(tr - 1, tl, -1):
            point[w] = k
            w += 1
        point[w] = tl
        w += 1
        for k in range(col_rank[tl] - 1, col_rank[bl], -1):
            point[w] = ocol[k]
            w += 1
        leaf[start:w] = i
    return px, py, leaf, point


@inline_kernel
def _slot(x, y, mask):
    """Hash slot of the lattice point ``(x, y)`` in a table of ``mask + 1`` slots."""
    return ((x * 0x9E3779B1) ^ (y * 0x85EBCA77) ^ (x >> 7)) & mask


@kernel
def known_values(px, py, kx, ky, kf):
    """The field at the lattice points ``(px, py)`` ((v,) int64) where a
    point ``(kx, ky)`` ((k,) int64) holds it (``kf``; the first such entry),
    NaN elsewhere, (v,) float64: a hash table of the known points (open
    addressing, linear probing)."""
    k = kx.shape[0]
    size = 2
    while size < 2 * k:
        size *= 2
    mask = size - 1
    slots = np.full(size, -1, np.int64)
    for j in range(k):
        h = _slot(kx[j], ky[j], mask)
        while slots[h] >= 0 and not (kx[slots[h]] == kx[j] and ky[slots[h]] == ky[j]):
            h = (h + 1) & mask
        if slots[h] < 0:
            slots[h] = j
    out = np.full(px.shape[0], np.nan)
    for i in range(px.shape[0]):
        h = _slot(px[i], py[i], mask)
        while slots[h] >= 0:
            s = slots[h]
            if kx[s] == px[i] and ky[s] == py[i]:
                out[i] = kf[s]
                break
            h = (h + 1) & mask
    return out


@kernel
def next_in_group(group):
    """Index of the next element of the same (contiguous) group, cyclically."""
    n = group.shape[0]
    nxt = np.empty(n, np.int64)
    start = 0
    for j in range(n):
        if j + 1 == n or group[j + 1] != group[j]:
            nxt[j] = start
            start = j + 1
        else:
            nxt[j] = j + 1
    return nxt


@kernel
def pair_crossings(leaf, point, inside, npts, passes):
    """Sign changes along the leaves' walks, each exit from the inside paired
    with the next crossing of its leaf's walk
    (:func:`slicer.contours.cells._pair_crossings` documents the results).

    ``passes``: radix digits of the largest edge key ``npts²`` (see
    :func:`slicer._kernels.raster.counting_sort.stable_order`).

    Returns
    -------
    ukey, succ, exit_leaf : (e,) int64
    """
    nxt = next_in_group(leaf)
    nc = 0
    for j in range(leaf.shape[0]):
        if inside[point[j]] != inside[point[nxt[j]]]:
            nc += 1
    cross = np.empty(nc, np.int64)
    q = 0
    for j in range(leaf.shape[0]):
        if inside[point[j]] != inside[point[nxt[j]]]:
            cross[q] = j
            q += 1
    lf = leaf[cross]
    nxt_c = next_in_group(lf)
    keys = np.empty(nc, np.int64)
    for q in range(nc):
        a, b = point[cross[q]], point[nxt[cross[q]]]
        keys[q] = a * npts + b if inside[a] else b * npts + a     # inside point, outside point
    ukey, eid = _sorted_points(keys, passes)
    succ = np.full(ukey.shape[0], -1, np.int64)
    exit_leaf = np.full(ukey.shape[0], -1, np.int64)
    for q in range(nc):
        if inside[point[cross[q]]]:         # inside -> outside going counter-clockwise: an exit
            succ[eid[q]] = eid[nxt_c[q]]
            exit_leaf[eid[q]] = lf[q]
    return ukey, succ, exit_leaf
