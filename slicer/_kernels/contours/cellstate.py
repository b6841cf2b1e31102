"""States of quadtree cells of a layer plane from their centre's Taylor data and
the disc bounds (:mod:`slicer.contours.cells`, docs/contours.md step 1).

One pass per batch of cells instead of a few dozen whole-array numpy steps:
the arithmetic is the same, operation by operation, so the states, curvature
and slope bounds are the same floats; what changes is that the plane threads
no longer hold the GIL for it.
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import inline_kernel, kernel
from slicer._kernels.contours.brackets import np_maximum, np_minimum

#: leaf states (:mod:`slicer.contours.cells`): proven outside, proven inside,
#: monotone in x and y, monotone in one of them with no cap deeper than the
#: tolerance, finest level, on a crest narrower than the finest leaves
OUT, IN, SIMPLE, ONEDIR, SMALL, THIN = 0, 1, 2, 3, 4, 5
#: half side of a square cell per unit of the radius of the disc around it
#: (1/sqrt(2), rounded up: a bound on the square may only grow)
HALF_SIDE = 0.7071067811865476 * (1.0 + 1e-15)


@inline_kernel
def grad_norm(gx, gy):
    """``‖(gx, gy)‖`` as ``sqrt(gx² + gy²)``, inline (``math.hypot`` is a call
    into libm, made for every cell): within two float64 spacings of the
    exact norm, far inside the 1e-9 relative slack every test adds; it
    overflows to inf only above 1e154 (no test passes then) and underflows
    to 0 only below 1e-154, far below the slack's absolute floor
    ``1e-9 (1 + |f|)``."""
    return math.sqrt(gx * gx + gy * gy)


@inline_kernel
def _judge_one(f, gx, gy, G, H, r, far, tol, slack):
    """State, curvature bound and the two slope bounds of one cell (see
    :func:`judge_cells`)."""
    gn = grad_norm(gx, gy)
    # over the square: |F - f| <= r G, and F - f lies within g.d +- H |d|^2 / 2,
    # at most h (|gx| + |gy|) + H r^2 / 2 (h the half side, |d| <= r)
    spread = np_minimum(r * G, HALF_SIDE * r * (abs(gx) + abs(gy)) + 0.5 * r * r * H)    # NaN compares false
    fs = slack * (1.0 + abs(f))
    gs = _slope_margin(gn, G, H, r, slack)
    state = -1
    if f + spread + fs < 1.0 or far:
        state = OUT
    if f - spread - fs > 1.0:
        state = IN
    mx = abs(gx) > gs
    my = abs(gy) > gs
    if state < 0 and mx and my:
        state = SIMPLE
    # monotone in one direction: along the other one, an edge of side
    # s = r sqrt(2) may hide a cap of depth <= H s^2 / (8 g_min)
    gmin = max(abs(gx), abs(gy)) - gs
    if state < 0 and (mx or my) and gmin > 0.0 and H * r * r / (4.0 * gmin) <= 0.5 * tol:
        state = ONEDIR
    glo = gn - gs
    kappa = H / glo if glo > 0.0 else math.inf
    sx = abs(gx) - gs
    sy = abs(gy) - gs
    sx = sx if math.isfinite(sx) and sx > 0.0 else 0.0
    sy = sy if math.isfinite(sy) and sy > 0.0 else 0.0
    return state, kappa, sx, sy


@inline_kernel
def _slope_margin(gn, G, H, r, slack):
    """``gs = slack (gn + G) + r H`` (NaN: inf): how far a partial derivative
    may move from its value at the centre over the disc, evaluation error included."""
    gs = slack * (gn + G) + r * H
    if gs != gs:
        gs = math.inf
    return gs


@inline_kernel
def monotone_axes(gx, gy, G, H, r, slack):
    """``(mx, my)``: whether ``∂F/∂x``, resp. ``∂F/∂y``, is proven nonzero over
    the disc (``|∂F/∂x(c)| > gs``, :func:`judge_cells`)."""
    gs = _slope_margin(grad_norm(gx, gy), G, H, r, slack)
    return abs(gx) > gs, abs(gy) > gs


@inline_kernel
def edge_clear(a, b, H, s, slack):
    """Whether ``F`` crosses 1 along an edge of length ``s`` (mm) exactly as the
    signs of its end values ``a``, ``b`` say: not at all when both are on one
    side, once when they differ (docs/math.md §10.2). ``H`` bounds ``|F''|``
    along the edge (the in-plane Hessian's norm over a disc holding it).

    ``φ(x) = F`` along the edge lies within ``H x (s − x)/2 <= H s²/8`` of the
    chord between its end values, so both ends at least that far below 1
    (above 1) leave no crossing; and ``φ'`` is within ``H s`` of the chord's
    slope ``(b − a)/s`` everywhere, so ``|b − a| > H s²`` makes φ strictly
    monotone: one crossing. Each end value carries its evaluation error
    ``slack (1 + |F|)``; the bump gets ``1e-12`` relative for its own rounding
    (NaN or infinite ``H``: not clear).
    """
    ea = slack * (1.0 + abs(a))
    eb = slack * (1.0 + abs(b))
    bump = 0.125 * H * s * s * (1.0 + 1e-12)
    if a < 1.0 and b < 1.0:
        return max(a + ea, b + eb) + bump < 1.0
    if a >= 1.0 and b >= 1.0:
        return min(a - ea, b - eb) - bump > 1.0
    return abs(b - a) - ea - eb > 8.0 * bump


@inline_kernel
def corners_clear(f00, f10, f11, f01, mx, my, H, s, slack):
    """Whether a cell with one partial derivative proven nonzero (``mx`` or
    ``my``, :func:`monotone_axes`) holds no cap its corners cannot see: the
    edges across the monotone direction are monotone already, and both edges
    along it are :func:`edge_clear` (corners ``f00, f10, f11, f01``
    counter-clockwise from ``(x0, y0)``, side ``s``)."""
    if my and edge_clear(f00, f10, H, s, slack) and edge_clear(f01, f11, H, s, slack):
        return True
    return mx and edge_clear(f00, f01, H, s, slack) and edge_clear(f10, f11, H, s, slack)


@kernel
def judge_cells(f, g, G, H, far, r, tol, slack):
    """States of cells from the field and in-plane gradient at their centres
    and bounds over their discs.

    With ``gn = ‖g‖``, ``spread = min(r G, h (|gx| + |gy|) + r² H / 2)``
    (``h = r/√2`` the half side of the square cell: over the square, F lies
    within ``g·d ± H |d|²/2`` of ``f``) and
    ``gs = slack (gn + G) + r H`` (NaN: inf; a NaN spread settles nothing), a cell is OUT where
    ``f + spread + slack (1 + |f|) < 1`` or ``far``, IN where
    ``f − spread − slack (1 + |f|) > 1``, else SIMPLE where both partials
    exceed ``gs`` in size, ONEDIR where one does and the cap an edge may hide,
    ``H r² / (4 (max |∂| − gs))``, is at most ``tol / 2``, else -1.

    Parameters
    ----------
    f : (c,) float64
        Field at the centres.
    g : (c, 2) float64, 1/mm
        In-plane gradient at the centres.
    G, H : (c,) float64, 1/mm and 1/mm²
        Bounds of the in-plane slope and Hessian norm over each disc.
    far : (c,) bool
        Cells the value bound already puts outside.
    r : (c,) float64, mm
        Disc radii.
    tol : float, mm
    slack : float
        Relative error budget of one field evaluation.

    Returns
    -------
    state : (c,) int8
    kappa : (c,) float64, 1/mm
        ``H / (gn − gs)`` where positive, else inf: a bound of the contour's
        curvature in the cell.
    slope : (c, 2) float64, 1/mm
        ``max(|∂F/∂x| − gs, 0)`` and the same in y (0 where not finite).
    """
    nc = f.shape[0]
    state = np.empty(nc, np.int8)
    kappa = np.empty(nc)
    slope = np.empty((nc, 2))
    for j in range(nc):
        st, kp, sx, sy = _judge_one(f[j], g[j, 0], g[j, 1], G[j], H[j], r[j], far[j], tol, slack)
        state[j] = st
        kappa[j] = kp
        slope[j, 0] = sx
        slope[j, 1] = sy
    return state, kappa, slope


@inline_kernel
def corner_candidate(f, gx, gy, G, H, r, s, slack):
    """Whether an unresolved cell of side ``s`` is worth the corner test
    (:func:`corners_clear`, four evaluations): one partial derivative proven
    nonzero, and the centre's linear model ``f + g·(p − c)`` at the corners
    passes the test (a forecast, not a proof: it only saves evaluations
    where the corners would most likely not clear the cell)."""
    mx, my = monotone_axes(gx, gy, G, H, r, slack)
    if not (mx or my):
        return False
    h = 0.5 * s
    return corners_clear(f - gx * h - gy * h, f + gx * h - gy * h, f + gx * h + gy * h, f - gx * h + gy * h,
                         mx, my, H, s, 0.0)


@kernel
def corner_candidates(f, g, G, H, r, s, slack):
    """:func:`corner_candidate` of cells with the centre's field ``f``,
    gradient ``g`` (c, 2) and bounds ``G``, ``H``; ``r`` the disc radius and
    ``s`` the side (mm): (c,) bool."""
    nc = G.shape[0]
    out = np.zeros(nc, np.bool_)
    for j in range(nc):
        out[j] = corner_candidate(f[j], g[j, 0], g[j, 1], G[j], H[j], r, s, slack)
    return out


@kernel
def clear_cells(corners, g, G, H, r, s, slack):
    """:func:`corners_clear` of cells of side ``s`` (mm) with the field at their
    corners, ``corners`` (4, c) counter-clockwise from the lower left, and their
    centre's gradient ``g`` (c, 2) and bounds ``G``, ``H``: (c,) bool."""
    nc = G.shape[0]
    out = np.zeros(nc, np.bool_)
    for j in range(nc):
        mx, my = monotone_axes(g[j, 0], g[j, 1], G[j], H[j], r, slack)
        out[j] = corners_clear(corners[0, j], corners[1, j], corners[2, j], corners[3, j], mx, my, H[j], s, slack)
    return out


@kernel
def settle_from_parent(f, g, G, H, r, cx, cy, parent, slack):
    """IN, OUT or -1 of child cells from their parent's Taylor data: over the
    child's square (half side ``h = r/√2``, ``r`` the radius of its disc,
    inside the parent's of radius ``2 r``), ``F`` lies within
    ``g·d ± H |d|²/2`` of the parent's ``f`` (``d`` from the parent's
    centre); the bound's largest and least values are at the child's
    corners. Up to ``slack (1 + |f| + 2 r (‖g‖ + G))``; an infinite or NaN
    ``H`` settles nothing.

    Parameters
    ----------
    f, g, G, H : (p,), (p, 2), (p,), (p,) float64
        The parents' field, in-plane gradient and disc bounds.
    r : float, mm
    cx, cy : (4 p,) float64, mm
        Child centres; child ``j``'s parent is ``j // 4``.
    parent : ((p,) float64, (p,) float64), mm
        Parent centres.
    slack : float

    Returns
    -------
    (4 p,) int8
    """
    px, py = parent
    nc = cx.shape[0]
    state = np.empty(nc, np.int8)
    for j in range(nc):
        k = j // 4
        state[j] = settle_one(f[k], g[k, 0], g[k, 1], G[k], H[k], r, cx[j] - px[k], cy[j] - py[k], slack)
    return state


@inline_kernel
def settle_one(f, gx, gy, G, H, r, dx, dy, slack):
    """IN, OUT or -1 of one child cell, offset ``(dx, dy)`` from its parent's
    centre, from the parent's Taylor data (:func:`settle_from_parent`): the
    parent's model ``f + g·d ± H |d|²/2`` (d from the parent's centre) is
    convex (concave) in d, so its largest (least) value over the child's
    square is at one of its four corners."""
    if not H < math.inf:        # inf or NaN: nothing settles, as before
        return -1
    gn = grad_norm(gx, gy)
    h = HALF_SIDE * r
    hi = -math.inf
    lo = math.inf
    for c in range(4):
        ex = dx + (h if c & 1 else -h)
        ey = dy + (h if c & 2 else -h)
        lin = gx * ex + gy * ey
        q = 0.5 * H * (ex * ex + ey * ey)
        hi = np_maximum(hi, lin + q)        # NaN stays NaN: a NaN gradient settles nothing
        lo = np_minimum(lo, lin - q)
    sl = slack * (1.0 + abs(f) + 2.0 * r * (gn + G))
    st = -1
    if f + hi + sl < 1.0:
        st = OUT
    if f + lo - sl > 1.0:
        st = IN
    return st


@kernel
def crest_candidates(state, f, g, G, H, r, thin, slack, bound_slack):
    """Unresolved cells (``state < 0``) that may hold a critical point of the
    field in the plane, ``‖g‖ <= r H (1 + bound_slack) + slack (‖g‖ + G)``, and
    where ``F`` is not proven above ``1 + H thin²/8``: its least value a step
    ``t = min(‖g‖/H, r)`` up the gradient, ``f + ‖g‖ t − H t²/2`` less the
    evaluation slack, is not above it (NaN counts as not proven).

    Parameters
    ----------
    state : (c,) int8
    f, g, G, H : (c,), (c, 2), (c,), (c,) float64
        Taylor data of the centres and disc bounds.
    r : float, mm
        Disc radius.
    thin : float, mm
        Widest section a crest cell may hold.
    slack, bound_slack : float
        Relative error budgets of a field evaluation and of the disc bounds.

    Returns
    -------
    (c,) bool
    """
    nc = f.shape[0]
    out = np.zeros(nc, np.bool_)
    for j in range(nc):
        if state[j] >= 0:
            continue
        out[j] = crest_candidate(f[j], g[j, 0], g[j, 1], G[j], H[j], r, thin, slack, bound_slack)
    return out


@inline_kernel
def crest_candidate(f, gx, gy, G, H, r, thin, slack, bound_slack):
    """Whether one unresolved cell is a crest candidate (:func:`crest_candidates`)."""
    gn = grad_norm(gx, gy)
    t = np_minimum(gn / H, r)
    low = f + gn * t - 0.5 * H * t * t - slack * (1.0 + abs(f) + r * (gn + G))
    return gn <= r * H * (1.0 + bound_slack) + slack * (gn + G) and not low > 1.0 + 0.125 * H * thin ** 2
