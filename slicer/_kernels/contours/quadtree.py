"""The quadtree of one layer plane in one compiled call (:mod:`slicer.contours.cells`,
docs/contours.md step 1).

Level by level, every cell is settled from its parent's Taylor data, or
classified from its centre's field and gradient and the disc bounds
(:mod:`slicer._kernels.contours.cellbounds`), or proven free of hidden caps by the
field at its corners (one partial derivative nonzero, :func:`corner_test`),
or tried as a crest cell (:mod:`slicer._kernels.contours.ridgebounds`); cells left
unresolved are split. The
cells of a level are independent (``prange``); leaves, known centre values
and the next level are gathered serially, in cell order. The arithmetic is
that of the cell-state passes (:mod:`slicer._kernels.contours.cellstate`), operation
by operation, so the leaves do not depend on the thread count.

A plane travels as one pair, ``plane = (arrays, constants)``
(:func:`plane_data` documents it), borrowed once per kernel so that the
inlined per-cell steps count no references; a level's cells and their
parents' data travel as arrays indexed by cell.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.contours.brackets import np_maximum, np_minimum
from slicer._kernels.contours.cellbounds import SLACK, _disc, disc_work, kernel_curvature_max, square_of
from slicer._kernels.contours.cellstate import (IN, ONEDIR, OUT, SMALL, THIN, _judge_one, corner_candidate, corners_clear, crest_candidate,
                        monotone_axes, settle_one)
from slicer._kernels.field.segment import SCRATCH
from slicer._kernels.field.points import point_field
from slicer._kernels.rays.support import kprime_max
from slicer._kernels.contours.ridgebounds import FRAME_WORK, _frame_along, _nearest_axis

#: cells per task of a level's ``prange`` (each task owns one field scratch array)
CHUNK = 64

# A plane's constants (:func:`plane_data`) and the cell settings are plain tuples, read by unpacking them
# whole (a parfor body takes tuples of scalars, not named tuples):
#   constants = (x0, y0, side, nx, ny, rmax, z, n, sigma, norm, k1, k2, inv_s2): the root grid of the
#     plane's segment bins (x0, y0 mm, square side mm, nx by ny squares, discs up to radius rmax mm), the
#     plane's height z (mm), the kernel's degree n, support factor sigma and normalisation norm, its slope
#     and curvature bounds k1 and k2 (kprime_max, kernel_curvature_max) and inv_s2 = 1/sigma^2;
#   settings = (tol, thin, pieces, coarse, fslack, bslack): the contour tolerance and the thinnest feature
#     (mm), the disc bounds' pieces, and the relative slacks of the field and of the bounds.

# rows of a level's Taylor data, one column per cell: centre, field, gradient, the disc bounds G, H, U (the
# parents' data of the next level), then the field at the four corners (NaN where not evaluated)
T_CX, T_CY, T_F, T_GX, T_GY, T_G, T_H, T_U, T_CORNERS = range(9)
T_ROWS = T_CORNERS + 4


def plane_data(seg, bins, ids, pgrid, z, n, sigma, norm):
    """The pair ``(arrays, constants)`` a plane's quadtree kernels take (the
    kernels borrow the arrays once: no reference counting per call).

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table.
    bins : tuple
        ``(x0, y0, side, nx, ny, rmax, offsets, lists)``: the plane's segments
        binned on the root grid (:func:`slicer.contours.cells._bin_segments`).
    ids : (q,) int64
        All segments of the plane (for discs the bins do not hold).
    pgrid : tuple
        ``(offsets, ids, origin, cell, dims)`` of the plane's point grid
        (:func:`slicer.model.field.plane_grid`).
    z : float, mm
    n, sigma, norm : int, float, float
        Kernel degree, support factor and normalisation.
    """
    x0, y0, side, nx, ny, rmax, offsets, lists = bins
    po, pi, porig, pcell, pdims = pgrid
    n, sigma, norm = int(n), float(sigma), float(norm)
    arrays = (seg, np.ascontiguousarray(offsets, np.int64), np.ascontiguousarray(lists, np.int64),
              np.ascontiguousarray(ids, np.int64), po, pi, porig, pcell, pdims)
    consts = (float(x0), float(y0), float(side), int(nx), int(ny), float(rmax), float(z), n, sigma, norm,
              kprime_max(n, sigma, norm), kernel_curvature_max(n, sigma, norm), 1.0 / sigma**2)
    return arrays, consts


@inline_kernel
def cell_scratch(pieces, coarse):
    """Length of a cell's work array: the field's scratch
    (:data:`slicer._kernels.field.segment.SCRATCH`), then the disc bounds' work area
    for ``pieces`` or ``coarse`` pieces (:func:`slicer._kernels.contours.cellbounds.disc_work`)
    or the crest bounds' (:data:`slicer._kernels.contours.ridgebounds.FRAME_WORK`), the larger."""
    return SCRATCH + max(disc_work(max(pieces, coarse)), FRAME_WORK)


@inline_kernel
def _bin_of(plane, cx, cy, r):
    """``(list, a, b)``: the segments that can reach the disc, ``list[a:b]``."""
    _, offsets, lists, ids, _, _, _, _, _ = plane[0]
    x0, y0, side, nx, ny, rmax, _, _, _, _, _, _, _ = plane[1]
    if cx >= x0 and cx < x0 + nx * side and cy >= y0 and cy < y0 + ny * side and r <= rmax:
        c = square_of(cx, cy, x0, y0, side, nx, ny)
        return lists, offsets[c], offsets[c + 1]
    return ids, 0, ids.shape[0]


@inline_kernel
def disc_at(plane, cx, cy, r, pieces, scratch):
    """``G, H, U`` of one disc (:func:`slicer._kernels.contours.cellbounds.disc_bounds`);
    ``scratch`` (:func:`cell_scratch`) lends its disc work area."""
    lst, a, b = _bin_of(plane, cx, cy, r)
    _, _, _, _, _, _, z, n, sigma, norm, k1, k2, _ = plane[1]
    seg, _, _, _, _, _, _, _, _ = plane[0]
    return _disc(seg, lst, a, b, cx, cy, z, r, n, sigma, norm, k1, k2, pieces, scratch[SCRATCH:])


@inline_kernel
def axis_at(plane, cx, cy, r):
    """``ux, uy``: the frame of one disc's crest bounds, the in-plane direction
    of the axis nearest its centre (:func:`slicer._kernels.contours.ridgebounds._nearest_axis`)."""
    lst, a, b = _bin_of(plane, cx, cy, r)
    seg, _, _, _, _, _, _, _, _ = plane[0]
    _, _, _, _, _, _, z, _, sigma, _, _, _, _ = plane[1]
    return _nearest_axis(seg, lst, a, b, cx, cy, z, r, sigma)


@inline_kernel
def frame_at(plane, cx, cy, r, ux, uy, scratch):
    """``FVV, FUU, FUV`` of one disc in the frame ``u = (ux, uy)`` (:func:`axis_at`;
    :func:`slicer._kernels.contours.ridgebounds.ridge_bounds`); ``scratch``
    (:func:`cell_scratch`) lends its disc work area."""
    lst, a, b = _bin_of(plane, cx, cy, r)
    _, _, _, _, _, _, z, n, sigma, norm, k1, _, _ = plane[1]
    seg, _, _, _, _, _, _, _, _ = plane[0]
    return _frame_along(seg, lst, a, b, cx, cy, z, r, ux, uy, n, sigma, norm, k1, scratch[SCRATCH:])


@inline_kernel
def convex_across(plane, cx, cy, r, ux, uy, gx0, gy0, G, fslack, scratch):
    """Whether ``F_vv > 0`` somewhere in the disc (``v = (−uy, ux)``), proven
    by the gradient at one or two points: ``(∇F(c + h v) − ∇F(c))·v`` is the
    integral of ``F_vv`` along the segment from ``c`` to ``c + h v`` (h signed,
    ``|h| < r``), so a positive value puts a positive ``F_vv`` in the disc, and
    no upper bound of ``F_vv`` over it can be negative: the crest test would fail
    (docs/math.md §10.1). The side away from the crest (where ``F`` falls along
    v) is tried first. ``gx0, gy0``: the gradient at ``c``; a difference counts
    only beyond the two gradients' error budget ``fslack (‖∇F‖ + ‖∇F(c)‖ + 2 G)``
    (``G`` bounds the in-plane slope over the disc).

    Returns
    -------
    convex : bool
    evaluations : int
    """
    vx, vy = -uy, ux
    gv0 = gx0 * vx + gy0 * vy
    g0 = math.hypot(gx0, gy0)
    h = -0.999 * r if gv0 >= 0.0 else 0.999 * r
    for k in range(2):
        _, gx, gy = field_at(plane, cx + h * vx, cy + h * vy, scratch)
        rise = (gx * vx + gy * vy - gv0) * (1.0 if h > 0.0 else -1.0)
        if rise > fslack * (math.hypot(gx, gy) + g0 + 2.0 * G):
            return True, k + 1
        h = -h
    return False, 2


@inline_kernel
def field_at(plane, x, y, scratch):
    """Field and in-plane gradient ``(f, gx, gy)`` at ``(x, y, z)``."""
    seg, _, _, _, po, pi, porig, pcell, pdims = plane[0]
    _, _, _, _, _, _, z, n, _, norm, _, _, inv_s2 = plane[1]
    f, gx, gy, _ = point_field(seg, po, pi, porig, pcell, pdims, n // 2, inv_s2, norm, True, scratch, x, y, z)
    return f, gx, gy


@inline_kernel
def value_at(plane, x, y, scratch):
    """Field at ``(x, y, z)`` (no gradient)."""
    seg, _, _, _, po, pi, porig, pcell, pdims = plane[0]
    _, _, _, _, _, _, z, n, _, norm, _, _, inv_s2 = plane[1]
    return point_field(seg, po, pi, porig, pcell, pdims, n // 2, inv_s2, norm, False, scratch, x, y, z)[0]


@inline_kernel
def judge_at(f, gx, gy, G, H, U, r, tol, fslack):
    """State, curvature and slope bounds of one cell from the disc bounds
    ``G, H, U`` (:func:`slicer._kernels.contours.cellstate.judge_cells`) and the
    centre's field and gradient ``f, gx, gy`` (0 where ``U`` already puts the
    disc outside: not evaluated).

    Returns
    -------
    state, kappa, sx, sy
    """
    return _judge_one(f, gx, gy, G, H, r, U * (1.0 + fslack) < 1.0, tol, fslack)


@inline_kernel
def _crest_bound(f, gx, gy, G, ux, uy, r, fixed, uv, curv, fslack):
    """The bound ``M`` of F over a crest cell's disc from the point with field
    ``f`` and gradient ``(gx, gy)`` (:meth:`slicer.contours.cells._Bounds.ridge`)."""
    gn = math.hypot(gx, gy)
    eg = fslack * (gn + G)
    gu = abs(gx * ux + gy * uy) + eg
    gv = abs(gy * ux - gx * uy) + eg
    q = gv + r * uv
    return f + fslack * (1.0 + abs(f)) + r * gu + fixed + q * q / (2.0 * curv)


@unrefcounted_kernel
def ridge_at(plane, cx, cy, r, f0, gx0, gy0, G, thin2, fslack, scratch):
    """OUT, THIN or -1 of one crest cell (docs/math.md §10.1): the bound ``M``
    from the centre and two steps towards the crest along v (Newton, then
    secant), the least kept; -1 with no bound computed where
    :func:`convex_across` proves that none can be negative.

    Returns
    -------
    state, evaluations
    """
    _, _, _, _, _, _, _, n, _, _, _, _, _ = plane[1]
    if n < 4:     # degree 2: no second-derivative bound (ridge_bounds), no crest cell
        return -1, 0
    ux, uy = axis_at(plane, cx, cy, r)
    convex, ev = convex_across(plane, cx, cy, r, ux, uy, gx0, gy0, G, fslack, scratch)
    if convex:
        return -1, ev
    vv, uu, uv = frame_at(plane, cx, cy, r, ux, uy, scratch)
    if not -vv > 0.0:
        return -1, ev
    curv = -vv
    fixed = 0.5 * np_maximum(uu, 0.0) * r * r
    best = _crest_bound(f0, gx0, gy0, G, ux, uy, r, fixed, uv, curv, fslack)
    gv0 = gy0 * ux - gx0 * uy
    lim = 0.999 * r
    t1 = np_minimum(np_maximum(gv0 / curv, -lim), lim)
    f1, gx1, gy1 = field_at(plane, cx - t1 * uy, cy + t1 * ux, scratch)
    gv1 = gy1 * ux - gx1 * uy
    best = np_minimum(best, _crest_bound(f1, gx1, gy1, G, ux, uy, r, fixed, uv, curv, fslack))
    k = (gv0 - gv1) / t1
    if not (math.isfinite(k) and k > 0.0):
        k = curv
    t2 = np_minimum(np_maximum(t1 + gv1 / k, -lim), lim)
    f2, gx2, gy2 = field_at(plane, cx - t2 * uy, cy + t2 * ux, scratch)
    best = np_minimum(best, _crest_bound(f2, gx2, gy2, G, ux, uy, r, fixed, uv, curv, fslack))
    if best < 1.0:
        return OUT, ev + 2
    if 8.0 * (best - 1.0) <= curv * thin2:
        return THIN, ev + 2
    return -1, ev + 2


#: how a cell gets its disc bounds (:func:`classify_at`): an arbitrary disc
#: (cheap bounds, then full ones where those leave it neither IN nor OUT), a
#: small cell (its parent's bounds), a larger cell (its parent's, then its own
#: where those leave it unresolved), a root cell of the quadtree (the cheap
#: bounds only: its children get their own where the cheap ones leave them
#: unresolved)
ROOT, INHERIT, OWN, CHEAP = 0, 1, 2, 3


@inline_kernel
def classify_at(plane, cx, cy, r, kind, G, H, U, tol, pieces, coarse, fslack, scratch):
    """State and Taylor data of one cell (:meth:`slicer.contours.cells._Bounds.classify`).

    ``kind`` is ROOT, INHERIT, OWN or CHEAP; ``G, H, U`` are the parent's
    bounds (unused for ROOT and CHEAP).

    Returns
    -------
    state, kappa, sx, sy, f, gx, gy, G, H, U, evaluations
    """
    if kind == ROOT or kind == CHEAP:
        G, H, U = disc_at(plane, cx, cy, r, coarse, scratch)
    # the centre's field, unless U already puts the disc outside; the full
    # bounds below reuse it (one call site: one compiled copy of the evaluation)
    f = gx = gy = 0.0
    ev = 0
    if not U * (1.0 + fslack) < 1.0:
        f, gx, gy = field_at(plane, cx, cy, scratch)
        ev = 1
    st, kp, sx, sy = judge_at(f, gx, gy, G, H, U, r, tol, fslack)
    again = (st != IN and st != OUT) if kind == ROOT else (kind == OWN and st < 0)
    if again:
        G, H, U = disc_at(plane, cx, cy, r, pieces, scratch)
        st, kp, sx, sy = judge_at(f, gx, gy, G, H, U, r, tol, fslack)
    return st, kp, sx, sy, f, gx, gy, G, H, U, ev


@inline_kernel
def _cell(plane, cx, cy, rr, box, k, kind, parents, crests, settings, scratch):
    """One cell of :func:`quadtree_level` (parent ``k``; no parents: a root
    cell; ``box = (xa, ya, xb, yb, s)`` its corners and side): settled from the parent's
    Taylor data (inlined: most cells end here), or :func:`_classified`.

    Returns
    -------
    state, kappa, sx, sy, f, gx, gy, G, H, U, evaluations, corners
        (NaN f and corners, zero bounds and no evaluation when settled by the parent.)
    """
    pcx, pcy, pf, pgx, pgy, pG, pH, pU = parents
    if pcx.shape[0] == 0:
        # int(): a constant argument is a type of its own to Numba (one more compiled copy)
        return _classified(plane, cx, cy, rr, box, int(CHEAP), 0.0, 0.0, 0.0, crests, settings, scratch)
    _, _, _, _, fslack, _ = settings
    st = settle_one(pf[k], pgx[k], pgy[k], pG[k], pH[k], rr, cx - pcx[k], cy - pcy[k], fslack)
    if st >= 0:
        return st, np.inf, 0.0, 0.0, np.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 0, (np.nan, np.nan, np.nan, np.nan)
    return _classified(plane, cx, cy, rr, box, kind, pG[k], pH[k], pU[k], crests, settings, scratch)


@unrefcounted_kernel
def _classified(plane, cx, cy, rr, box, kind, G, H, U, crests, settings, scratch):
    """A cell its parent did not settle: classified (:func:`classify_at`,
    ``G, H, U`` the parent's bounds); if left unresolved with one partial
    derivative proven nonzero, its corners may prove it cap-free
    (:func:`corner_test`, tried where the centre's linear model forecasts
    it, :func:`slicer._kernels.contours.cellstate.corner_candidate`); otherwise, where ``crests`` and it may hold a
    critical point, it is tried as a crest cell (:func:`ridge_at`). A call,
    not inlined: it is long, and each cell that gets here costs far more
    than the call (the plane's arrays are borrowed: no reference counting).

    Returns
    -------
    state, kappa, sx, sy, f, gx, gy, G, H, U, evaluations, corners
        ``corners``: the field at the cell's corners counter-clockwise from
        ``(xa, ya)`` where the corner test ran, else NaN.
    """
    tol, thin, pieces, coarse, fslack, bslack = settings
    st, kp, ax, ay, f, gx, gy, G, H, U, ev = classify_at(plane, cx, cy, rr, kind, G, H, U, tol, pieces, coarse,
                                                           fslack, scratch)
    corners = (np.nan, np.nan, np.nan, np.nan)
    side = box[4]
    if st < 0 and corner_candidate(f, gx, gy, G, H, rr, side, fslack):
        st, corners = corner_test(plane, box, gx, gy, G, H, rr, fslack, scratch)
        ev += 4
    if crests and st < 0 and crest_candidate(f, gx, gy, G, H, rr, thin, fslack, bslack):
        st, e2 = ridge_at(plane, cx, cy, rr, f, gx, gy, G, thin ** 2, fslack, scratch)
        ev += e2
    return st, kp, ax, ay, f, gx, gy, G, H, U, ev, corners


@inline_kernel
def corner_test(plane, box, gx, gy, G, H, rr, fslack, scratch):
    """ONEDIR or -1 of a cell with one partial derivative proven nonzero
    (centre gradient ``gx, gy``, bounds ``G, H``, disc radius ``rr``), from
    the field at its corners (:func:`slicer._kernels.contours.cellstate.corners_clear`,
    docs/math.md §10.2), and those four values.

    Returns
    -------
    state, (f00, f10, f11, f01)
    """
    xa, ya, xb, yb, s = box
    mx, my = monotone_axes(gx, gy, G, H, rr, fslack)
    f00 = f10 = f11 = f01 = 0.0
    for c in range(4):      # one call site: one compiled copy of the evaluation
        v = value_at(plane, xb if c == 1 or c == 2 else xa, yb if c >= 2 else ya, scratch)
        if c == 0:
            f00 = v
        elif c == 1:
            f10 = v
        elif c == 2:
            f11 = v
        else:
            f01 = v
    st = ONEDIR if corners_clear(f00, f10, f11, f01, mx, my, H, s, fslack) else -1
    return st, (f00, f10, f11, f01)


@kernel
def _level_cells(plane, level, parents, settings, out, j0, j1):
    """Cells ``j0:j1`` of :func:`quadtree_level` into ``out = (state, kappa,
    sx, sy, taylor, evaluations)``, ``level = (ix, iy, x0, y0, s, rr, kind,
    crests)``, with one work array (:func:`cell_scratch`)."""
    _, _, pieces, coarse, _, _ = settings
    _cells_into(plane, level, parents, settings, out, j0, j1, np.empty(cell_scratch(pieces, coarse)))


@unrefcounted_kernel
def _cells_into(plane, level, parents, settings, out, j0, j1, scratch):
    """The loop of :func:`_level_cells` (no reference counting: the per-cell
    steps unpack the plane's arrays at every cell)."""
    ix, iy, x0, y0, s, rr, kind, crests = level
    state, kappa, sx, sy, tay, evals = out
    for j in range(j0, j1):
        cx = x0 + (ix[j] + 0.5) * s
        cy = y0 + (iy[j] + 0.5) * s
        # the corners as the leaf walks place them: x0 + (lattice index) h, h = s / unit (exact)
        box = (x0 + ix[j] * s, y0 + iy[j] * s, x0 + (ix[j] + 1) * s, y0 + (iy[j] + 1) * s, s)
        st, kp, ax, ay, f, gx, gy, G, H, U, ev, cv = _cell(plane, cx, cy, rr, box, j // 4, kind, parents, crests,
                                                           settings, scratch)
        state[j], kappa[j], sx[j], sy[j], evals[j] = st, kp, ax, ay, ev
        tay[T_CX, j], tay[T_CY, j], tay[T_F, j], tay[T_GX, j] = cx, cy, f, gx
        tay[T_GY, j], tay[T_G, j], tay[T_H, j], tay[T_U, j] = gy, G, H, U
        tay[T_CORNERS, j], tay[T_CORNERS + 1, j], tay[T_CORNERS + 2, j], tay[T_CORNERS + 3, j] = cv


@parallel_kernel
def quadtree_level(plane, ix, iy, x0, y0, s, rr, kind, parents, crests, settings):
    """States and Taylor data of the cells ``(ix, iy)`` of one level (side
    ``s``, disc radius ``rr``): settled from the parents' data when there are
    parents (child ``j``'s parent is ``j // 4``), else classified, then tried
    as crest cells where ``crests``.

    Parameters
    ----------
    parents : tuple of (p,) float64
        ``(cx, cy, f, gx, gy, G, H, U)`` of the parents (empty: root cells).
    settings : tuple
        ``(tol, thin, pieces, coarse, fslack, bslack)``: the tolerance and
        the widest section of a crest cell (mm), pieces per segment of the
        full and the cheap disc bounds, the relative error budgets of a field
        evaluation and of the disc bounds.

    Returns
    -------
    state : (c,) int8
    kappa, sx, sy : (c,) float64
    taylor : (12, c) float64
        ``cx, cy, f, gx, gy, G, H, U`` of each cell (NaN f where settled by
        the parent), then the field at its corners where the corner test
        ran (:func:`corner_test`), else NaN.
    evaluations : int
    """
    nc = ix.shape[0]
    state, kappa, sx, sy = np.empty(nc, np.int8), np.empty(nc), np.empty(nc), np.empty(nc)
    tay, evals = np.empty((T_ROWS, nc)), np.zeros(nc, np.int64)
    # a parfor cannot take a tuple of arrays: the tuples are rebuilt in each task
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = plane[0]
    consts = plane[1]
    p0, p1, p2, p3, p4, p5, p6, p7 = parents
    for ch in prange((nc + CHUNK - 1) // CHUNK):
        # one call per task: the parfor's body stays small (fast to compile)
        _level_cells(((a0, a1, a2, a3, a4, a5, a6, a7, a8), consts), (ix, iy, x0, y0, s, rr, kind, crests),
                     (p0, p1, p2, p3, p4, p5, p6, p7), settings, (state, kappa, sx, sy, tay, evals),
                     ch * CHUNK, min(nc, (ch + 1) * CHUNK))
    return state, kappa, sx, sy, tay, evals.sum()


@kernel
def _grow(a, need):
    """``a`` or a copy at least ``need`` long, with ``a``'s elements first."""
    if a.shape[0] >= need:
        return a
    out = np.empty(max(need, 2 * a.shape[0]), a.dtype)
    out[:a.shape[0]] = a
    return out


@kernel
def _gather(ix, iy, lev, levels, level, leaves, nl, known, nk):
    """Append the leaves of one level (cells with a state; at the finest
    level the unresolved ones become SMALL) to ``leaves``, the centre values
    of its split cells and then the corner values of its cells that had the
    corner test to ``known``, and make the next level: four children per
    split cell, in order, with their parent's Taylor data.

    Parameters
    ----------
    ix, iy : (c,) int64
        The level's cells.
    level : tuple
        ``(state, kappa, sx, sy, taylor)`` of :func:`quadtree_level`.
    leaves : tuple
        ``(X0, Y0, size, state, kappa, sx, sy)``, ``nl`` of them filled.
    known : tuple
        ``(kx, ky, kf)``, ``nk`` of them filled.

    Returns
    -------
    ix, iy, parents, leaves, nl, known, nk
    """
    state, kappa, sx, sy, tay = level
    nc = ix.shape[0]
    unit = 1 << (levels - lev)
    nsplit = 0
    ncorner = 0
    for j in range(nc):
        if state[j] < 0 and lev == levels:
            state[j] = SMALL
        if state[j] < 0:
            nsplit += 1
        if tay[T_CORNERS, j] == tay[T_CORNERS, j]:
            ncorner += 1
    LX, LY, LS, LST, LK, LSX, LSY = leaves
    LX, LY, LS, LST = _grow(LX, nl + nc), _grow(LY, nl + nc), _grow(LS, nl + nc), _grow(LST, nl + nc)
    LK, LSX, LSY = _grow(LK, nl + nc), _grow(LSX, nl + nc), _grow(LSY, nl + nc)
    KX, KY, KF = known
    need = nk + nsplit + 4 * ncorner
    KX, KY, KF = _grow(KX, need), _grow(KY, need), _grow(KF, need)
    nix = np.empty(4 * nsplit, np.int64)
    niy = np.empty(4 * nsplit, np.int64)
    par = np.empty((T_CORNERS, nsplit))
    q = 0
    for j in range(nc):
        if state[j] >= 0:
            LX[nl], LY[nl], LS[nl], LST[nl] = ix[j] * unit, iy[j] * unit, unit, state[j]
            LK[nl], LSX[nl], LSY[nl] = kappa[j], sx[j], sy[j]
            nl += 1
            continue
        if unit >= 2:
            KX[nk], KY[nk], KF[nk] = ix[j] * unit + unit // 2, iy[j] * unit + unit // 2, tay[T_F, j]
            nk += 1
        par[:, q] = tay[:T_CORNERS, j]
        for c in range(4):
            nix[4 * q + c] = 2 * ix[j] + (c & 1)
            niy[4 * q + c] = 2 * iy[j] + (c >> 1)
        q += 1
    for j in range(nc):
        if tay[T_CORNERS, j] == tay[T_CORNERS, j]:
            for c in range(4):          # counter-clockwise from (ix, iy), as corner_test evaluated them
                KX[nk] = (ix[j] + (1 if c == 1 or c == 2 else 0)) * unit
                KY[nk] = (iy[j] + (c >> 1)) * unit
                KF[nk] = tay[T_CORNERS + c, j]
                nk += 1
    parents = (par[T_CX], par[T_CY], par[T_F], par[T_GX], par[T_GY], par[T_G], par[T_H], par[T_U])
    return nix, niy, parents, (LX, LY, LS, LST, LK, LSX, LSY), nl, (KX, KY, KF), nk


@kernel
def quadtree(plane, root, levels, inherit_side, settings):
    """Leaves of the quadtree over the root cells, ``root = (x0, y0, s0, nx, ny)``
    (:func:`slicer.contours.cells._quadtree` documents the results): level by
    level, :func:`quadtree_level` then :func:`_gather`.

    Returns
    -------
    X0, Y0, size : (l,) int64
    state : (l,) int8
    kappa : (l,) float64
    slope : (l, 2) float64
    cells, evaluations : int
    kx, ky : (k,) int64
    kf : (k,) float64
    """
    x0, y0, s0, nx, ny = root
    ix = np.arange(nx * ny) % nx
    iy = np.arange(nx * ny) // nx
    e = np.zeros(0)
    parents = (e, e, e, e, e, e, e, e)
    z = np.zeros(0, np.int64)
    leaves = (z, z, z, np.zeros(0, np.int8), e, e, e)
    known = (z, z, e)
    nl = nk = cells = evaluations = 0
    for lev in range(levels + 1):
        if ix.shape[0] == 0:
            break
        s = s0 / 2.0 ** lev
        rr = 0.5 * math.sqrt(2.0) * s * (1.0 + SLACK)
        kind = INHERIT if s <= inherit_side else OWN
        state, kappa, sx, sy, tay, ev = quadtree_level(plane, ix, iy, x0, y0, s, rr, kind, parents, lev < levels,
                                                       settings)
        cells += ix.shape[0]
        evaluations += ev
        # int(): while typing the loop, the counters' first type is the constant 0
        ix, iy, parents, leaves, nl, known, nk = _gather(ix, iy, lev, levels, (state, kappa, sx, sy, tay), leaves,
                                                         int(nl), known, int(nk))
    LX, LY, LS, LST, LK, LSX, LSY = leaves
    slope = np.empty((nl, 2))
    slope[:, 0] = LSX[:nl]
    slope[:, 1] = LSY[:nl]
    KX, KY, KF = known
    return (LX[:nl].copy(), LY[:nl].copy(), LS[:nl].copy(), LST[:nl].copy(), LK[:nl].copy(), slope, cells,
            evaluations, KX[:nk].copy(), KY[:nk].copy(), KF[:nk].copy())


@parallel_kernel
def classify_cells(plane, cx, cy, r, settings):
    """:func:`classify_at` of root-kind cells (cheap bounds first, then full
    ones): the quadtree's classification of arbitrary square cells, given by
    their centre and the radius ``r`` of the disc around them (IN and OUT
    hold over the square of half side ``r/√2``; the bounds, SIMPLE and
    ONEDIR over the disc).

    Parameters
    ----------
    cx, cy, r : (c,) float64, mm
    settings : tuple
        As for :func:`quadtree_level`.

    Returns
    -------
    state : (c,) int8
    kappa, sx, sy, f, gx, gy, G, H, U : (c,) float64
    evaluations : int
    """
    tol, thin, pieces, coarse, fslack, bslack = settings
    nc = cx.shape[0]
    state = np.empty(nc, np.int8)
    out = np.empty((9, nc))
    evals = np.zeros(nc, np.int64)
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = borrow(plane[0])
    consts = plane[1]
    nw = cell_scratch(pieces, coarse)
    for ch in prange((nc + CHUNK - 1) // CHUNK):
        own = np.empty(nw)
        scratch = borrow(own)
        plane = ((a0, a1, a2, a3, a4, a5, a6, a7, a8), consts)
        for j in range(ch * CHUNK, min(nc, (ch + 1) * CHUNK)):
            st, kp, sx, sy, f, gx, gy, G, H, U, ev = classify_at(plane, cx[j], cy[j], r[j], ROOT, 0.0, 0.0, 0.0, tol,
                                                                 pieces, coarse, fslack, scratch)
            state[j] = st
            out[0, j], out[1, j], out[2, j], out[3, j], out[4, j] = kp, sx, sy, f, gx
            out[5, j], out[6, j], out[7, j], out[8, j] = gy, G, H, U
            evals[j] = ev
        keep_alive((own,))
    return state, out, evals.sum()


@parallel_kernel
def ridge_cells(plane, cx, cy, r, f, g, G, thin, fslack):
    """:func:`ridge_at` of discs with the Taylor data ``f``, ``g`` (c, 2) and ``G``
    of their centres: OUT, THIN or -1 each, (c,) int8, and the evaluations."""
    nc = cx.shape[0]
    state = np.empty(nc, np.int8)
    evals = np.zeros(nc, np.int64)
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = borrow(plane[0])
    consts = plane[1]
    nw = cell_scratch(0, 0)
    for ch in prange((nc + CHUNK - 1) // CHUNK):
        own = np.empty(nw)
        scratch = borrow(own)
        plane = ((a0, a1, a2, a3, a4, a5, a6, a7, a8), consts)
        for j in range(ch * CHUNK, min(nc, (ch + 1) * CHUNK)):
            state[j], evals[j] = ridge_at(plane, cx[j], cy[j], r[j], f[j], g[j, 0], g[j, 1], G[j], thin ** 2, fslack,
                                          scratch)
        keep_alive((own,))
    return state, evals.sum()
