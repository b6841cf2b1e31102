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

from .._jit import inline_kernel, kernel
from .brackets import np_minimum

#: leaf states (:mod:`slicer.contours.cells`): proven outside, proven inside,
#: monotone in x and y, monotone in one of them with no cap deeper than the
#: tolerance, finest level, on a crest narrower than the finest leaves
OUT, IN, SIMPLE, ONEDIR, SMALL, THIN = 0, 1, 2, 3, 4, 5


@inline_kernel
def _judge_one(f, gx, gy, G, H, r, far, tol, slack):
    """State, curvature bound and the two slope bounds of one cell (see
    :func:`judge_cells`)."""
    gn = math.hypot(gx, gy)
    spread = r * np_minimum(G, gn + 0.5 * r * H)      # NaN compares false, as inf would
    fs = slack * (1.0 + abs(f))
    gs = slack * (gn + G) + r * H
    if gs != gs:
        gs = math.inf
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


@kernel
def judge_cells(f, g, G, H, far, r, tol, slack):
    """States of cells from the field and in-plane gradient at their centres
    and bounds over their discs.

    With ``gn = ‖g‖``, ``spread = r min(G, gn + r H / 2)`` and
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


@kernel
def settle_from_parent(f, g, G, H, r, cx, cy, parent, slack):
    """IN, OUT or -1 of child cells from their parent's Taylor data: over the
    child's disc (radius ``r``, inside the parent's of radius ``2 r``), ``F``
    lies within ``r ‖g‖ + 2 H r²`` of the parent's linear model at the child's
    centre, up to ``slack (1 + |f| + 2 r (‖g‖ + G))``.

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
    centre, from the parent's Taylor data (:func:`settle_from_parent`)."""
    gn = math.hypot(gx, gy)
    lin = f + gx * dx + gy * dy
    spread = r * gn + 2.0 * H * r * r
    sl = slack * (1.0 + abs(f) + 2.0 * r * (gn + G))
    st = -1
    if lin + spread + sl < 1.0:
        st = OUT
    if lin - spread - sl > 1.0:
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
    gn = math.hypot(gx, gy)
    t = np_minimum(gn / H, r)
    low = f + gn * t - 0.5 * H * t * t - slack * (1.0 + abs(f) + r * (gn + G))
    return gn <= r * H * (1.0 + bound_slack) + slack * (gn + G) and not low > 1.0 + 0.125 * H * thin ** 2
