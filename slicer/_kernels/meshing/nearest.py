"""Bounds of the distance from each triangle of one mesh to another mesh (docs/mesh.md).

For a triangle ``T`` and a triangle ``S``, ``p ↦ d(p, S)`` is convex (the
distance to a convex set), so over ``T`` it is largest at a corner:
``sup_{p∈T} d(p, S) = max_v d(v, S)``. Hence, for a mesh ``M``,
``sup_{p∈T} d(p, M) <= min_S max_v d(v, S)``. Where no single ``S`` gives a
bound below the target (``T`` straddles an edge of ``M``), ``T`` is cut into
four at its edges' midpoints and each quarter is bounded alone, up to
``DEPTH`` times; the quarters cover ``T`` up to the rounding of the
midpoints, which ``SLACK`` covers.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel

#: most halvings of a triangle's edges
DEPTH = 6
#: triangles per task (each task owns one stamp array)
CHUNK = 256
#: relative widening of a computed distance (rounding of the corner and distance arithmetic)
SLACK = 1e-9
#: absolute widening, mm: the quarters' midpoints are rounded, so they cover a triangle up to
#: gaps of a few units in the last place of its coordinates (1e-14 mm at 100 mm)
GAP = 1e-9
#: a triangle whose corners' angle at ``a`` has a squared sine below this is treated as its edges
FLAT = 1e-24


@inline_kernel
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@unrefcounted_kernel
def point_triangle_sq(p, a, b, c):
    """Squared distance from point ``p`` to the triangle ``a b c`` (each a 3-tuple, mm):
    the closest point by the Voronoi region of ``p`` (a corner, an edge or the face); an
    edge's distance is that to the segment, so two equal corners need no division by zero."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    if not _dot(nx, ny, nz, nx, ny, nz) > FLAT * _dot(abx, aby, abz, abx, aby, abz) * _dot(acx, acy, acz, acx, acy, acz):
        # a degenerate triangle (corners equal or in line): its three edges hold it
        return min(_edge_sq(p, a, b), _edge_sq(p, b, c), _edge_sq(p, c, a))
    apx, apy, apz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = _dot(abx, aby, abz, apx, apy, apz)
    d2 = _dot(acx, acy, acz, apx, apy, apz)
    if d1 <= 0.0 and d2 <= 0.0:
        return _dot(apx, apy, apz, apx, apy, apz)
    bpx, bpy, bpz = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = _dot(abx, aby, abz, bpx, bpy, bpz)
    d4 = _dot(acx, acy, acz, bpx, bpy, bpz)
    if d3 >= 0.0 and d4 <= d3:
        return _dot(bpx, bpy, bpz, bpx, bpy, bpz)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _edge_sq(p, a, b)
    cpx, cpy, cpz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = _dot(abx, aby, abz, cpx, cpy, cpz)
    d6 = _dot(acx, acy, acz, cpx, cpy, cpz)
    if d6 >= 0.0 and d5 <= d6:
        return _dot(cpx, cpy, cpz, cpx, cpy, cpz)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _edge_sq(p, a, c)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return _edge_sq(p, b, c)
    den = va + vb + vc
    if not den > 0.0:       # a degenerate triangle: its three edges hold it
        return min(_edge_sq(p, a, b), _edge_sq(p, b, c), _edge_sq(p, c, a))
    v = vb / den
    w = vc / den
    return _sq_to(p, a[0] + v * abx + w * acx, a[1] + v * aby + w * acy, a[2] + v * abz + w * acz)


@inline_kernel
def _sq_to(p, x, y, z):
    dx, dy, dz = p[0] - x, p[1] - y, p[2] - z
    return dx * dx + dy * dy + dz * dz


@unrefcounted_kernel
def _edge_sq(p, a, b):
    """Squared distance from ``p`` to the segment ``a b``."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ll = _dot(abx, aby, abz, abx, aby, abz)
    s = 0.0
    if ll > 0.0:
        s = min(max(_dot(abx, aby, abz, p[0] - a[0], p[1] - a[1], p[2] - a[2]) / ll, 0.0), 1.0)
    return _sq_to(p, a[0] + s * abx, a[1] + s * aby, a[2] + s * abz)


@inline_kernel
def _corner(v, f, t, k):
    i = f[t, k]
    return (v[i, 0], v[i, 1], v[i, 2])


@inline_kernel
def _cell(x, o, c, n):
    return min(max(int(math.floor((x - o) / c)), 0), n - 1)


@unrefcounted_kernel
def _piece_bound(p0, p1, p2, v1, f1, grid, reach, stamp, tag):
    """``min_S max_v d(v, S)`` over the triangles ``S`` of the second mesh listed in the
    grid cells the piece's box touches (inf when there are none), and a lower bound of
    the largest distance from a corner to the second mesh.

    Every triangle within ``reach`` of a corner is listed, so a corner's smallest
    distance over the listed ones is its distance to the mesh when at most ``reach``,
    and the mesh is at least ``reach`` away from it otherwise."""
    offsets, ids, origin, cell, dims = grid
    lo = (min(p0[0], p1[0], p2[0]), min(p0[1], p1[1], p2[1]), min(p0[2], p1[2], p2[2]))
    hi = (max(p0[0], p1[0], p2[0]), max(p0[1], p1[1], p2[1]), max(p0[2], p1[2], p2[2]))
    best = np.inf
    r2 = reach * reach
    n0 = n1 = n2 = r2
    for iz in range(_cell(lo[2], origin[2], cell[2], dims[2]), _cell(hi[2], origin[2], cell[2], dims[2]) + 1):
        for iy in range(_cell(lo[1], origin[1], cell[1], dims[1]), _cell(hi[1], origin[1], cell[1], dims[1]) + 1):
            for ix in range(_cell(lo[0], origin[0], cell[0], dims[0]),
                            _cell(hi[0], origin[0], cell[0], dims[0]) + 1):
                q = (iz * dims[1] + iy) * dims[0] + ix
                for e in range(offsets[q], offsets[q + 1]):
                    s = ids[e]
                    if stamp[s] == tag:
                        continue
                    stamp[s] = tag
                    a, b, c = _corner(v1, f1, s, 0), _corner(v1, f1, s, 1), _corner(v1, f1, s, 2)
                    d0 = point_triangle_sq(p0, a, b, c)
                    d1 = point_triangle_sq(p1, a, b, c)
                    d2 = point_triangle_sq(p2, a, b, c)
                    n0 = min(n0, d0)
                    n1 = min(n1, d1)
                    n2 = min(n2, d2)
                    best = min(best, max(d0, d1, d2))
    return math.sqrt(best), math.sqrt(max(n0, n1, n2))


@inline_kernel
def _mid(a, b):
    return (0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2]))


@unrefcounted_kernel
def _triangle_bound(p0, p1, p2, v1, f1, grid, target, reach, stamp, tag, stack):
    """The bound of one triangle: its own, or the largest of its quarters' (recursively,
    while above ``target`` and a corner's own distance does not already exceed it, at
    most ``DEPTH`` deep); ``stack`` holds pieces (9 coordinates and a depth per row);
    ``tag`` is advanced per piece and returned."""
    out = 0.0
    stack[0, 0], stack[0, 1], stack[0, 2] = p0
    stack[0, 3], stack[0, 4], stack[0, 5] = p1
    stack[0, 6], stack[0, 7], stack[0, 8] = p2
    stack[0, 9] = 0.0
    sp = 1
    while sp > 0:
        sp -= 1
        a = (stack[sp, 0], stack[sp, 1], stack[sp, 2])
        b = (stack[sp, 3], stack[sp, 4], stack[sp, 5])
        c = (stack[sp, 6], stack[sp, 7], stack[sp, 8])
        depth = stack[sp, 9]
        tag += 1
        d, corner = _piece_bound(a, b, c, v1, f1, grid, reach, stamp, tag)
        if d <= target or depth >= DEPTH or corner > target:
            out = max(out, d)
            continue
        ab, bc, ca = _mid(a, b), _mid(b, c), _mid(c, a)
        for q in range(4):
            if q == 0:
                x, y, z = a, ab, ca
            elif q == 1:
                x, y, z = ab, b, bc
            elif q == 2:
                x, y, z = ca, bc, c
            else:
                x, y, z = ab, bc, ca
            stack[sp, 0], stack[sp, 1], stack[sp, 2] = x
            stack[sp, 3], stack[sp, 4], stack[sp, 5] = y
            stack[sp, 6], stack[sp, 7], stack[sp, 8] = z
            stack[sp, 9] = depth + 1.0
            sp += 1
    return out, tag


@parallel_kernel
def distance_bounds(v0, f0, v1, f1, offsets, ids, origin, cell, dims, target, reach):
    """For each triangle of the first mesh, a bound of the largest distance from its
    points to the second mesh.

    Parameters
    ----------
    v0 : (n0, 3) float64, mm
    f0 : (t0, 3) int64
        The first mesh.
    v1 : (n1, 3) float64, mm
    f1 : (t1, 3) int64
        The second mesh.
    offsets, ids, origin, cell, dims
        The second mesh's triangles binned by their boxes widened by the search
        reach (:func:`slicer._kernels.field.binning.bin_boxes`): a triangle of
        the second mesh closer than the reach to a piece is in a cell the
        piece's box touches.
    target : float, mm
        Pieces are split while their bound is above it (and no corner of theirs is
        farther than it from the second mesh: splitting could not bring them below).
    reach : float, mm
        The widening of the binned boxes.

    Returns
    -------
    (t0,) float64, mm
        ``sup_{p∈T} d(p, M1)`` is at most this, for each triangle T of the first
        mesh (inf: no triangle of the second mesh within the reach).
    """
    t0 = f0.shape[0]
    out = np.empty(t0)
    grid = (offsets, ids, origin, cell, dims)
    for ch in prange((t0 + CHUNK - 1) // CHUNK):
        stamp = np.full(f1.shape[0], -1, np.int64)
        stack = np.empty((3 * DEPTH + 2, 10))
        tag = np.int64(0)
        for t in range(ch * CHUNK, min(t0, (ch + 1) * CHUNK)):
            d, tag = _triangle_bound(_corner(v0, f0, t, 0), _corner(v0, f0, t, 1), _corner(v0, f0, t, 2), v1, f1,
                                     grid, target, reach, stamp, tag, stack)
            out[t] = d * (1.0 + SLACK) + GAP
    return out
