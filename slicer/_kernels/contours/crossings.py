"""Crossings of ``F = 1`` one point at a time: the bracketed root solve of a
segment, the first-order distance of a point to a layer's contour and its
projection onto it (:mod:`slicer.contours.roots` validates and documents
them; docs/contours.md).

The field travels as one tuple, ``fld = (seg, offsets, ids, origin, cell,
dims, m, inv_s2, norm)``: the segment table, a support grid (a plane's or
the skeleton's: the values are the same to the bit,
:func:`slicer.model.field.plane_grid`), half the kernel degree, ``1/σ²`` and the
normalisation. Each point is solved to the end before the next, with the
arithmetic of a batch solve operation by operation, so the answers and the
evaluation counts do not depend on how points are grouped.
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import inline_kernel, kernel
from slicer._kernels.contours.brackets import bracket_narrow, bracket_next, bracket_start, np_minimum
from slicer._kernels.field.segment import SCRATCH
from slicer._kernels.field.points import point_field

#: iterations of the bracketed solver before it gives up (bisection halves
#: the bracket at least every other step, so 200 is far beyond need)
MAX_ITER = 200


@inline_kernel
def field_of(fld, x, y, z, grad, scratch):
    """``(f, gx, gy, gz)`` at one point (gradient zeros unless ``grad``)."""
    seg, offsets, ids, origin, cell, dims, m, inv_s2, norm = fld
    return point_field(seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad, scratch, x, y, z)


@inline_kernel
def reach_of(slope, length):
    """``1 / (slope × length)`` for a slope bound ``slope > 0`` along a
    segment of positive ``length``, else inf (nothing proven)."""
    if slope > 0.0 and length > 0.0:
        return 1.0 / (slope * length)
    return np.inf


@inline_kernel
def seg_length(d):
    """Length of the vector ``d = (dx, dy, dz)``, mm."""
    return math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])


@kernel
def solve_one(fld, a, d, fab, slope, tol, slack, scratch):
    """The crossing on the segment from ``a`` to ``a + d`` (3-tuples, mm),
    with the field ``fab = (F(a), F(a + d))`` at its ends and a lower bound
    ``slope`` of ``|dF/dl|`` along it (0: none): the steps of
    :mod:`slicer._kernels.contours.brackets` until the segment is finished or
    ``MAX_ITER`` steps (then the bracket's middle).

    Returns
    -------
    t : float
        Position along the segment, in [0, 1].
    bracketed : bool
    evaluations : int
    """
    length = seg_length(d)
    tol_t = tol / length if length > 0.0 else 1.0
    reach_t = reach_of(slope, length)
    fa, fb = fab
    state, bracketed, open_ = bracket_start(fa, fb, length, tol, reach_t, slack)
    it = 0
    while open_ and it < MAX_ITER:
        it += 1
        tm, state = bracket_next(state, tol_t, it)
        f = field_of(fld, a[0] + tm * d[0], a[1] + tm * d[1], a[2] + tm * d[2], False, scratch)[0]
        state, open_ = bracket_narrow(state, tm, f, reach_t, length, tol, slack)
    lo, hi, _, _, _, _, _, _, _, t = state      # docs: slicer._kernels.contours.brackets
    if open_:   # pragma: no cover - the bisection safeguard makes this unreachable
        t = 0.5 * (lo + hi)
    return t, bracketed, it


@kernel
def solve_segments(fld, a, b, ends, slope, tol, slack):
    """:func:`solve_one` of each segment ``a[i] -> b[i]`` ((n, 3) float64, mm).

    ``ends = (fa, fb, known_a, known_b)``: the field at the ends, used where
    ``known_a`` (``known_b``), else evaluated here. ``slope`` (n,) float64:
    lower bounds of ``|dF/dl|`` (0: none).

    Returns
    -------
    t : (n,) float64
    bracketed : (n,) bool
    evaluations : int
    """
    fa, fb, known_a, known_b = ends
    n = a.shape[0]
    t = np.empty(n)
    ok = np.empty(n, np.bool_)
    scratch = np.empty(SCRATCH)
    ev = 0
    for i in range(n):
        va = fa[i] if known_a else field_of(fld, a[i, 0], a[i, 1], a[i, 2], False, scratch)[0]
        vb = fb[i] if known_b else field_of(fld, b[i, 0], b[i, 1], b[i, 2], False, scratch)[0]
        ev += (0 if known_a else 1) + (0 if known_b else 1)
        d = (b[i, 0] - a[i, 0], b[i, 1] - a[i, 1], b[i, 2] - a[i, 2])
        t[i], ok[i], e = solve_one(fld, (a[i, 0], a[i, 1], a[i, 2]), d, (va, vb), slope[i], tol, slack, scratch)
        ev += e
    return t, ok, ev


@inline_kernel
def distance_at(fld, x, y, z, scratch):
    """First-order in-plane distance ``|F − 1| / ‖∇_xy F‖`` of ``(x, y, z)``
    to the contour (inf where the in-plane gradient vanishes), with ``F``,
    ``∂F/∂x``, ``∂F/∂y`` and ``‖∇_xy F‖`` there.

    Returns
    -------
    dist, f, gx, gy, gn : float
    """
    f, gx, gy, _ = field_of(fld, x, y, z, True, scratch)
    gn = math.hypot(gx, gy)
    dist = abs(f - 1.0) / gn if gn > 0.0 else np.inf
    return dist, f, gx, gy, gn


@kernel
def distances(fld, xy, z):
    """:func:`distance_at` of each point of ``xy`` ((n, 2) float64, mm) in the plane ``z``.

    Returns
    -------
    dist, f : (n,) float64
    g : (n, 2) float64
    """
    n = xy.shape[0]
    dist = np.empty(n)
    f = np.empty(n)
    g = np.empty((n, 2))
    scratch = np.empty(SCRATCH)
    for i in range(n):
        dist[i], f[i], g[i, 0], g[i, 1], _ = distance_at(fld, xy[i, 0], xy[i, 1], z, scratch)
    return dist, f, g


@kernel
def _solve_on(fld, a, b, tol, slack, scratch):
    """:func:`solve_one` from ``a`` to ``b`` (3-tuples, mm), both ends
    evaluated: ``(x, y)`` of the answer, bracketed, evaluations."""
    fa = field_of(fld, a[0], a[1], a[2], False, scratch)[0]
    fb = field_of(fld, b[0], b[1], b[2], False, scratch)[0]
    d = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    t, ok, e = solve_one(fld, a, d, (fa, fb), 0.0, tol, slack, scratch)
    return a[0] + t * d[0], a[1] + t * d[1], ok, e + 2


@kernel
def project_one(fld, x, y, z, tol, reach, slack, scratch):
    """The point of the contour of the plane ``z`` on the in-plane gradient
    line through ``(x, y)`` (:func:`slicer.contours.roots.project_to_contour`):
    the Newton point bracketed ``tol / 2`` either side where that lies within
    the search segment, else (or where that fails) the whole segment
    ``(x, y) ± r n``, ``r = min(3 dist + tol, reach)``.

    Returns
    -------
    rx, ry : float
        ``(x, y)`` itself where no root was bracketed.
    ok : bool
    dist : float
        :func:`distance_at` of the point.
    evaluations : int
    """
    dist, f, gx, gy, gn = distance_at(fld, x, y, z, scratch)
    ev = 1
    usable = math.isfinite(dist)
    r = np_minimum(3.0 * dist + tol if usable else 0.0, reach)
    unit = gn if gn > 0.0 else 1.0
    nx = gx / unit                          # toward growing F: inward
    ny = gy / unit
    if not (usable and r > 0.0):
        return x, y, False, dist, ev
    if dist + 0.5 * tol <= r:
        c = (1.0 - f) / gn
        sx = x + c * nx
        sy = y + c * ny
        hx = 0.4999 * tol * nx              # a bracket just under tol: its midpoint, no iteration
        hy = 0.4999 * tol * ny
        rx, ry, ok, e = _solve_on(fld, (sx + hx, sy + hy, z), (sx - hx, sy - hy, z), tol, slack, scratch)
        ev += e
        if ok:
            return rx, ry, True, dist, ev
    rx, ry, ok, e = _solve_on(fld, (x + r * nx, y + r * ny, z), (x - r * nx, y - r * ny, z), tol, slack, scratch)
    ev += e
    if ok:
        return rx, ry, True, dist, ev
    return x, y, False, dist, ev


@kernel
def project_points(fld, xy, z, tol, reach, slack):
    """:func:`project_one` of each point of ``xy`` ((n, 2) float64, mm), with
    ``reach`` (n,) float64 (inf: no limit).

    Returns
    -------
    roots : (n, 2) float64
    ok : (n,) bool
    dist : (n,) float64
    evaluations : int
    """
    n = xy.shape[0]
    roots = np.empty((n, 2))
    ok = np.empty(n, np.bool_)
    dist = np.empty(n)
    scratch = np.empty(SCRATCH)
    ev = 0
    for i in range(n):
        roots[i, 0], roots[i, 1], ok[i], dist[i], e = project_one(fld, xy[i, 0], xy[i, 1], z, tol, reach[i], slack,
                                                                  scratch)
        ev += e
    return roots, ok, dist, ev
