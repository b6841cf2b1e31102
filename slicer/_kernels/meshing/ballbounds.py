"""Bounds of the field, and of its Hessian's norm, over balls of space (docs/math.md §11).

For a ball ``B = {p : ‖p − c‖ <= r}`` and one segment, the axis points that
can act on a point of B are those with ``‖c − q(t)‖ < στ(t) + r``: the reach
interval of :func:`slicer._kernels.contours.cellbounds._reach_interval`, whose
derivation holds for a ball as for a disc. It is cut into pieces
(:func:`slicer._kernels.contours.cellbounds.piece_count`); on a piece ``[t0, t1]``
every p of B has ``s_lo <= ‖p − q(t)‖/τ(t) <= s_hi`` with
``s_lo = (dist(c, piece) − r)/τ(t1)`` and
``s_hi = (max(‖c − q(t0)‖, ‖c − q(t1)‖) + r)/τ(t0)`` (the radius grows
along the table's orientation), so, k falling with s,

* ``U = Σ len · k(s_lo)/τ(t0)``        >= sup_B F,
* ``L = Σ len · k(s_hi)/τ(t1)``        <= inf_B F (pieces beyond the reach add 0),
* ``H₁ = Σ len · sup_{s>=s_lo} max(|k''|, |k'/s|)/τ(t0)³``  >= sup_B ‖∇²F‖
  (:func:`slicer._kernels.contours.cellbounds._curvature_sup`);
* the split Hessian of docs/math.md §10 without the plane: the integrand's
  Hessian is ``α e eᵀ − β I`` with ``α, β >= 0``, so ``∇²F = M − b I`` with M
  positive semi-definite, and its eigenvalues lie in ``[−b, tr M − b]``:
  ``‖∇²F‖ <= max(Bh, A − Bl)`` with ``Bh``, ``Bl`` the bounds of b and ``A``
  that of ``tr M`` (``‖e‖ = 1``), summed as ``H₁``; ``H = min(H₁, max(Bh, A − Bl))``;
* restricted to a plane of unit normal ν (projection P), the second
  derivatives ``vᵀ∇²F v`` (v in the plane) lie in ``[−b, tr PMP − b]`` with
  ``tr PMP = ∫ α ‖Pe‖²``, and ``‖Pe‖ <= pe = (max ‖P(c − q)‖ + r)/(dist − r)``
  on a piece (``‖P(c − q(t))‖`` is convex in t: its largest value is at an
  end): ``H_P = min(H, max(Bh, A_P − Bl))`` with ``A_P`` summed with ``pe²``
  (docs/math.md §10 does the same for the layer plane).

Every bound is over the whole ball, in all three dimensions: nothing
assumes a plane. Sums are widened by the relative ``SLACK`` of
:mod:`slicer._kernels.contours.cellbounds` (no directed rounding in Numba).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.contours.cellbounds import SLACK, _curvature_sup, _ipow, _reach_interval, _second_sup, kernel_curvature_max, piece_count
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, TAU0, UX, UY, UZ

#: balls per task of :func:`ball_bounds` (each task owns one stamp array)
CHUNK = 64
#: most pieces a segment's reach interval is cut into
PIECES = 32


@inline_kernel
def _axis_distances(wx, wy, wz, ux, uy, uz, nx, ny, nz, t):
    """Distance from ``c`` (``w = c − a``) to the axis point at arc length ``t``, and
    the norm of its part in the plane of unit normal ``ν`` (the whole distance for ν = 0)."""
    x = wx - t * ux
    y = wy - t * uy
    z = wz - t * uz
    d2 = x * x + y * y + z * z
    a = x * nx + y * ny + z * nz
    return math.sqrt(d2), math.sqrt(max(d2 - a * a, 0.0))


@inline_kernel
def _piece_terms(ln, dist, dmax, pmax, tmin, tmax, r, m, sigma, norm, k2):
    """One piece's terms ``(u, l, h1, bh, bl, a, ap)`` of :func:`_segment_ball` (see the module docstring)."""
    inv_s2 = 1.0 / (sigma * sigma)
    dlo = dist * (1.0 - SLACK) - r
    s_lo = max(dlo, 0.0) / tmax * (1.0 - SLACK)
    if s_lo >= sigma:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    u_lo = s_lo * s_lo * inv_s2
    w = 1.0 - u_lo
    w1 = _ipow(w, m - 1)
    cn = norm * 2 * m * inv_s2
    it3 = 1.0 / (tmin * tmin * tmin)
    up = ln * norm * w1 * w / tmin
    h = ln * _curvature_sup(u_lo, w1, m, cn, k2) * it3
    s_hi = (dmax * (1.0 + SLACK) + r) / tmin * (1.0 + SLACK)
    u_hi = min(s_hi * s_hi * inv_s2, 1.0)
    low = ln * norm * _ipow(1.0 - u_hi, m) / tmax
    bh = ln * cn * w1 * it3
    bl = ln * cn * _ipow(1.0 - u_hi, m - 1) / (tmax * tmax * tmax)
    a = ln * cn * _second_sup(u_lo, u_hi, m) * it3
    pe = min(1.0, (pmax * (1.0 + SLACK) + r) / dlo) if dlo > 0.0 else 1.0
    return up, low, h, bh, bl, a, a * pe * pe


@unrefcounted_kernel
def _segment_ball(seg, i, cx, cy, cz, nx, ny, nz, r, m, sigma, norm, k2):
    """Segment ``i``'s sums ``(U, L, H₁, Bh, Bl, A, A_P)`` over the ball of centre ``c`` and
    radius ``r`` (``A_P`` for the plane of unit normal ``ν``)."""
    ta, tb = _reach_interval(seg, i, cx, cy, cz, r, sigma)
    if not tb > ta:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    k = piece_count(ta, tb, r, PIECES)
    wx = cx - seg[i, AX]
    wy = cy - seg[i, AY]
    wz = cz - seg[i, AZ]
    ux, uy, uz = seg[i, UX], seg[i, UY], seg[i, UZ]
    wu = wx * ux + wy * uy + wz * uz
    foot = _axis_distances(wx, wy, wz, ux, uy, uz, nx, ny, nz, wu)[0]
    tau0, d = seg[i, TAU0], seg[i, DELTA]
    step = (tb - ta) / k
    t0 = ta
    d0, p0 = _axis_distances(wx, wy, wz, ux, uy, uz, nx, ny, nz, t0)
    su = sl = sh = sbh = sbl = sa = sap = 0.0
    for j in range(k):
        t1 = ta + (j + 1) * step if j < k - 1 else tb
        d1, p1 = _axis_distances(wx, wy, wz, ux, uy, uz, nx, ny, nz, t1)
        tmin = tau0 + d * t0
        if not tmin > 0.0:
            return np.inf, 0.0, np.inf, np.inf, 0.0, np.inf, np.inf
        dist = d0 if wu <= t0 else (d1 if wu >= t1 else foot)
        up, low, h, bh, bl, a, ap = _piece_terms(t1 - t0, dist, max(d0, d1), max(p0, p1), tmin, tau0 + d * t1, r,
                                                 m, sigma, norm, k2)
        su += up
        sl += low
        sh += h
        sbh += bh
        sbl += bl
        sa += a
        sap += ap
        t0, d0, p0 = t1, d1, p1
    return su, sl, sh, sbh, sbl, sa, sap


@inline_kernel
def _cell_range(x, r, o, c, n):
    """Grid cells ``[lo, hi]`` along one axis that the interval ``x ± r`` touches."""
    lo = min(max(int(math.floor((x - r - o) / c)), 0), n - 1)
    hi = min(max(int(math.floor((x + r - o) / c)), 0), n - 1)
    return lo, hi


@unrefcounted_kernel
def _ball(seg, grid, c, nu, r, m, sigma, norm, k2, stamp, tag):
    """``(U, L, H, H_P)`` of one ball of centre ``c = (x, y, z)``, with ``nu`` the
    plane's unit normal, summed over the segments listed in the support grid's
    cells the ball's box touches, each once (``stamp[i] == tag`` once seen), in
    the order the cells list them."""
    offsets, ids, origin, cell, dims = grid
    cx, cy, cz = c
    nx, ny, nz = nu
    x0, x1 = _cell_range(cx, r, origin[0], cell[0], dims[0])
    y0, y1 = _cell_range(cy, r, origin[1], cell[1], dims[1])
    z0, z1 = _cell_range(cz, r, origin[2], cell[2], dims[2])
    su = sl = sh = sbh = sbl = sa = sap = 0.0
    for iz in range(z0, z1 + 1):
        for iy in range(y0, y1 + 1):
            for ix in range(x0, x1 + 1):
                q = (iz * dims[1] + iy) * dims[0] + ix
                for e in range(offsets[q], offsets[q + 1]):
                    i = ids[e]
                    if stamp[i] == tag:
                        continue
                    stamp[i] = tag
                    up, low, h, bh, bl, a, ap = _segment_ball(seg, i, cx, cy, cz, nx, ny, nz, r, m, sigma, norm, k2)
                    su += up
                    sl += low
                    sh += h
                    sbh += bh
                    sbl += bl
                    sa += a
                    sap += ap
    full = min(sh, max(sbh, sa - sbl * (1.0 - SLACK))) * (1.0 + SLACK)
    plane = min(full, max(sbh, sap - sbl * (1.0 - SLACK)) * (1.0 + SLACK))
    return su * (1.0 + SLACK), sl * (1.0 - SLACK), full, plane


@parallel_kernel
def ball_bounds(seg, offsets, ids, origin, cell, dims, centres, radii, normals, n, sigma, norm):
    """Upper and lower bounds of F, and upper bounds of ‖∇²F‖ and of its
    restriction to a plane, over balls.

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table (:mod:`slicer._kernels.field.segment`).
    offsets, ids, origin, cell, dims
        The support grid of :func:`slicer.model.field.point_grid` (every segment
        whose support box meets a grid cell is listed in it; the grid must
        cover every support).
    centres : (k, 3) float64, mm
    radii : (k,) float64, mm
    normals : (k, 3) float64
        Unit normal of each ball's plane (zeros: the whole space).
    n, sigma, norm : int, float, float
        Kernel degree (>= 4), support factor and normalisation.

    Returns
    -------
    U, L : (k,) float64
        ``L <= F(p) <= U`` for every p of each ball.
    H : (k,) float64, 1/mm²
        ``‖∇²F(p)‖ <= H`` (spectral norm) for every p of each ball.
    HP : (k,) float64, 1/mm²
        ``|vᵀ∇²F(p) v| <= HP`` for every p of each ball and unit v orthogonal
        to its normal.
    """
    k = centres.shape[0]
    U = np.zeros(k)
    L = np.zeros(k)
    H = np.zeros(k)
    HP = np.zeros(k)
    m = n // 2
    k2 = kernel_curvature_max(n, sigma, norm)
    grid = (offsets, ids, origin, cell, dims)
    for ch in prange((k + CHUNK - 1) // CHUNK):
        stamp = np.full(seg.shape[0], -1, np.int64)
        for j in range(ch * CHUNK, min(k, (ch + 1) * CHUNK)):
            c = (centres[j, 0], centres[j, 1], centres[j, 2])
            nu = (normals[j, 0], normals[j, 1], normals[j, 2])
            U[j], L[j], H[j], HP[j] = _ball(seg, grid, c, nu, radii[j], m, sigma, norm, k2, stamp, j)
    return U, L, H, HP
