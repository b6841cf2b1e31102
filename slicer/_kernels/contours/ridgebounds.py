"""Signed second-derivative bounds of the field over a disc of a layer plane, in
a frame along and across a strut (docs/math.md §10.1).

Where a layer plane touches the top (or bottom) of a strut lying in it, the
field has a ridge in the plane: strictly concave across the strut, nearly
constant along it, its crest within rounding of 1. The norm bounds of
:mod:`slicer._kernels.contours.cellbounds` settle no cell there. In the frame of the
strut nearest the disc's centre -- ``u`` its in-plane direction, ``v`` the
in-plane normal -- this module bounds, over the disc, ``F_vv`` from above
(negative on a crest), ``F_uu`` from above and ``|F_uv|``: the integrand's
Hessian is ``α e eᵀ − β I`` (``α, β >= 0``), so ``wᵀ(α e eᵀ − β I)w' =
α (e·w)(e·w') − β w·w'`` with ``|e·w|`` bounded on each piece of the axis
like the in-plane part of ``e`` in :func:`slicer._kernels.contours.cellbounds._piece_bounds`;
for an untapered segment the derivatives along its own axis are end terms
(``∂f/∂a = ψ(p − a0) − ψ(p − a1)``), zero away from its ends.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.contours.cellbounds import (CHUNK, PIECES, SLACK, _end_distances, _end_slopes, _ipow, _reach_interval, _second_sup,
                         single_bin, square_of)
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ
from slicer._kernels.rays.support import kprime_max


@unrefcounted_kernel
def _nearest_axis(seg, lst, a, b, cx, cy, cz, r, sigma):
    """In-plane unit direction ``(ux, uy)`` of the segment of ``lst[a:b]`` whose axis
    is nearest ``c`` relative to its radius there, among those whose support can
    reach the disc; ``(1, 0)`` when none reaches or its axis is nearly vertical."""
    best = np.inf
    ux = 1.0
    uy = 0.0
    for q in range(a, b):
        i = lst[q]
        ta, tb = _reach_interval(seg, i, cx, cy, cz, r, sigma)
        if not tb > ta:
            continue
        wx = cx - seg[i, AX]
        wy = cy - seg[i, AY]
        wz = cz - seg[i, AZ]
        t = min(max(wx * seg[i, UX] + wy * seg[i, UY] + wz * seg[i, UZ], 0.0), seg[i, LEN])
        d2 = _end_distances(wx, wy, wz, seg[i, UX], seg[i, UY], seg[i, UZ], t)[1]
        tau = seg[i, TAU0] + seg[i, DELTA] * t
        if tau > 0.0 and d2 < best * tau * tau:
            best = d2 / (tau * tau)
            axy = math.hypot(seg[i, UX], seg[i, UY])
            if axy > 1e-3:
                ux = seg[i, UX] / axy
                uy = seg[i, UY] / axy
            else:
                ux = 1.0
                uy = 0.0
    return ux, uy


@inline_kernel
def _across(cw, aw, nw, t0, t1, r, dlo):
    """Upper bound of ``|e·w|`` over the disc and a piece ``[t0, t1]`` of an axis
    ``q(t) = a0 + t a``, for a direction ``w`` with ``cw = (c − a0)·w``, ``aw = a·w``
    and ``nw = ‖w‖``: ``|(p − q)·w| <= max(|cw − t0 aw|, |cw − t1 aw|) + r nw``
    (linear in t; ``p − c`` in the plane, at most r long) over ``‖p − q‖ >= dlo``,
    and ``|e·w| <= nw`` (``e`` a unit vector)."""
    top = max(abs(cw - t0 * aw), abs(cw - t1 * aw)) * (1.0 + SLACK) + r * nw
    if dlo > 0.0:
        return min(nw, top / dlo)
    return nw


@inline_kernel
def _piece_weights(wx, wy, wz, ax, ay, az, tau_lo, tau_hi, t0, t1, r, sigma, m, cn):
    """Over the disc and the axis piece ``[t0, t1]`` (radii ``tau_lo <= tau_hi``):
    ``dlo`` (least ``‖p − q‖``), ``sec`` (upper bound of ``∫ α dt``), ``bl`` and
    ``bh`` (bounds of ``∫ β dt``); ``sec < 0`` when no point of the piece reaches
    (the others are then 0). Every term is computed and the far case selected,
    without a branch: the piece loop runs on vector lanes."""
    tc = min(max(wx * ax + wy * ay + wz * az, t0), t1)
    dist = math.sqrt(_end_distances(wx, wy, wz, ax, ay, az, tc)[1])
    dmax = math.sqrt(max(_end_distances(wx, wy, wz, ax, ay, az, t0)[1],
                         _end_distances(wx, wy, wz, ax, ay, az, t1)[1]))
    dlo = dist * (1.0 - SLACK) - r
    ith = 1.0 / tau_hi
    s_lo = max(dlo, 0.0) * ith * (1.0 - SLACK)
    far = s_lo >= sigma
    it = 1.0 / tau_lo
    s_hi = (dmax * (1.0 + SLACK) + r) * it * (1.0 + SLACK)
    inv_s2 = 1.0 / (sigma * sigma)      # loop-invariant where this is inlined
    u_lo = s_lo * s_lo * inv_s2
    u_hi = min(s_hi * s_hi * inv_s2, 1.0)
    ln = (t1 - t0) * cn
    it3 = it * it * it
    sec = ln * _second_sup(u_lo, u_hi, m) * it3
    bl = ln * _ipow(1.0 - u_hi, m - 1) * (ith * ith * ith)
    bh = ln * _ipow(1.0 - u_lo, m - 1) * it3
    return dlo, -1.0 if far else sec, 0.0 if far else bl, 0.0 if far else bh


#: rows of :func:`_segment_frame`'s work area, each ``PIECES`` long: each
#: piece's ``sec``, ``bl``, ``bh`` (:func:`_piece_weights`) and its ``|e·w|``
#: bounds along u and v, general and across the axis
_SEC, _BL, _BH, _PU, _PV, _TU, _TV = range(7)
#: float64 entries of :func:`_segment_frame`'s work area
FRAME_WORK = 7 * PIECES


@unrefcounted_kernel
def _segment_frame(seg, i, cx, cy, cz, r, ta, tb, ux, uy, n, sigma, norm, k1, work):
    """Bounds over the disc of segment ``i``'s ``f_vv`` and ``f_uu`` (above) and
    ``|f_uv|``, from the axis points in ``[ta, tb]`` cut into ``PIECES`` pieces
    (:func:`_piece_weights`; ``e·w`` by :func:`_across`), and a magnitude of the
    terms summed (for the rounding slack); ``u = (ux, uy, 0)``, ``v = (−uy, ux, 0)``.

    General form: ``f_ww <= Σ sec pe_w² − Bl``, ``|f_uv| <= Σ sec pe_u pe_v``.
    Untapered, with ``w = w_a a + w'`` (``a`` the axis, ``w' ⟂ a``) and ``W`` the
    end terms' slope bound: ``f_ww <= Σ sec pe_w'² − Bl ‖w'‖² + |w_a| (|w_a| +
    2‖w'‖) W`` and ``|f_uv| <= Σ sec pe_u' pe_v' + |u'·v'| Bh + (|u_a| + |v_a| ‖u'‖) W``.
    The smaller form is taken.

    Each piece's weights go to ``work`` (:data:`FRAME_WORK` float64) in a
    loop without a dependence from one piece to the next (vector lanes),
    then the sums run in piece order: the bounds of one loop, to the bit."""
    wx, wy, wz = cx - seg[i, AX], cy - seg[i, AY], cz - seg[i, AZ]
    ax, ay, az = seg[i, UX], seg[i, UY], seg[i, UZ]
    d = seg[i, DELTA]
    tau0 = seg[i, TAU0]
    vx, vy = -uy, ux
    ua, va = ux * ax + uy * ay, vx * ax + vy * ay          # along the axis
    upx, upy, upz = ux - ua * ax, uy - ua * ay, -ua * az   # across it
    vpx, vpy, vpz = vx - va * ax, vy - va * ay, -va * az
    nu = math.sqrt(upx * upx + upy * upy + upz * upz)
    nv = math.sqrt(vpx * vpx + vpy * vpy + vpz * vpz)
    cu, cv = wx * ux + wy * uy, wx * vx + wy * vy           # (c − a0)·w
    cup, cvp = wx * upx + wy * upy + wz * upz, wx * vpx + wy * vpy + wz * vpz
    step = (tb - ta) / PIECES
    for j in range(PIECES):
        if not tau0 + d * (ta + j * step) > 0.0:
            return np.inf, np.inf, np.inf, np.inf
    rows = (work[_SEC * PIECES:(_SEC + 1) * PIECES], work[_BL * PIECES:(_BL + 1) * PIECES],
            work[_BH * PIECES:(_BH + 1) * PIECES], work[_PU * PIECES:(_PU + 1) * PIECES],
            work[_PV * PIECES:(_PV + 1) * PIECES], work[_TU * PIECES:(_TU + 1) * PIECES],
            work[_TV * PIECES:(_TV + 1) * PIECES])
    geo = (wx, wy, wz, ax, ay, az, tau0, d, ta, tb, step, r)
    dirs = (cu, ua, cv, va, cup, nu, cvp, nv)
    if n == 6:      # the default kernel: the powers unroll, the piece loop runs on vector lanes
        _frame_weights(rows, geo, dirs, 6, sigma, norm)
    else:
        _frame_weights(rows, geo, dirs, n, sigma, norm)
    SEC, BL, BH, PU, PV, TU, TV = rows
    guu = gvv = guv = tuu = tvv = tuv = bl = bh = 0.0
    for j in range(PIECES):
        sec = SEC[j]
        if sec < 0.0:
            continue
        bl += BL[j]
        bh += BH[j]
        pu = PU[j]
        pv = PV[j]
        guu += sec * pu * pu
        gvv += sec * pv * pv
        guv += sec * pu * pv
        if d == 0.0:        # the untapered form's sums (a tapered segment has none)
            pu = TU[j]
            pv = TV[j]
            tuu += sec * pu * pu
            tvv += sec * pv * pv
            tuv += sec * pu * pv
    fuu, fvv, fuv = guu - bl, gvv - bl, guv
    mag = guu + gvv + guv + bh
    if d == 0.0:
        W = _end_slopes(seg, i, cx, cy, cz, r, n, sigma, norm, k1)
        ua, va = abs(ua), abs(va)
        fuu = min(fuu, tuu - bl * nu * nu + ua * (ua + 2.0 * nu) * W)
        fvv = min(fvv, tvv - bl * nv * nv + va * (va + 2.0 * nv) * W)
        fuv = min(fuv, tuv + abs(upx * vpx + upy * vpy + upz * vpz) * bh + (ua + va * nu) * W)
        mag += tuu + tvv + tuv + 3.0 * W
    return fvv, fuu, fuv, mag


@inline_kernel
def _frame_weights(rows, geo, dirs, n, sigma, norm):
    """Each piece's :func:`_piece_weights` and :func:`_across` bounds into
    ``rows`` (:func:`_segment_frame`), from ``geo = (wx, wy, wz, ax, ay, az,
    tau0, d, ta, tb, step, r)`` and ``dirs = (cu, ua, cv, va, cup, nu, cvp,
    nv)``."""
    SEC, BL, BH, PU, PV, TU, TV = rows
    wx, wy, wz, ax, ay, az, tau0, d, ta, tb, step, r = geo
    cu, ua, cv, va, cup, nu, cvp, nv = dirs
    m = n // 2
    cn = norm * n / (sigma * sigma)
    for j in range(PIECES):
        t0 = ta + j * step
        t1 = tb if j == PIECES - 1 else ta + (j + 1) * step
        dlo, sec, blj, bhj = _piece_weights(wx, wy, wz, ax, ay, az, tau0 + d * t0, tau0 + d * t1, t0, t1, r,
                                            sigma, m, cn)
        SEC[j] = sec
        BL[j] = blj
        BH[j] = bhj
        PU[j] = _across(cu, ua, 1.0, t0, t1, r, dlo)
        PV[j] = _across(cv, va, 1.0, t0, t1, r, dlo)
        TU[j] = _across(cup, 0.0, nu, t0, t1, r, dlo)
        TV[j] = _across(cvp, 0.0, nv, t0, t1, r, dlo)


@unrefcounted_kernel
def _frame_disc(seg, lst, a, b, cx, cy, z, r, n, sigma, norm, k1, work):
    """:func:`ridge_bounds` of one disc from the segments ``lst[a:b]`` (``work``:
    :data:`FRAME_WORK` float64, :func:`_segment_frame`'s).

    Returns
    -------
    ux, uy, FVV, FUU, FUV : float
    """
    ux, uy = _nearest_axis(seg, lst, a, b, cx, cy, z, r, sigma)
    vv, uu, uv = _frame_along(seg, lst, a, b, cx, cy, z, r, ux, uy, n, sigma, norm, k1, work)
    return ux, uy, vv, uu, uv


@unrefcounted_kernel
def _frame_along(seg, lst, a, b, cx, cy, z, r, ux, uy, n, sigma, norm, k1, work):
    """The bounds of :func:`_frame_disc` in the frame of the in-plane unit
    direction ``u = (ux, uy)`` (:func:`_nearest_axis`'s, for those).

    Returns
    -------
    FVV, FUU, FUV : float
    """
    if n < 4:       # n = 2: the gradient jumps at the support's edge, no second-derivative bound
        return np.inf, np.inf, np.inf
    vv = uu = uv = mag = 0.0
    for q in range(a, b):
        i = lst[q]
        ta, tb = _reach_interval(seg, i, cx, cy, z, r, sigma)
        if not tb > ta:
            continue
        fvv, fuu, fuv, mg = _segment_frame(seg, i, cx, cy, z, r, ta, tb, ux, uy, n, sigma, norm, k1, work)
        vv += fvv
        uu += fuu
        uv += fuv
        mag += mg
    pad = 4.0 * SLACK * mag
    return vv + pad, uu + pad, (uv + pad) * (1.0 + SLACK)


def ridge_bounds(seg, ids, cx, cy, z, r, n, sigma, norm):
    """Frame and signed second-derivative bounds of the field over discs of the plane ``z``.

    Parameters are those of :func:`slicer._kernels.contours.cellbounds.disc_bounds`
    (the segment table, the plane's segments ``ids``, the disc centres and
    radii ``cx, cy, r`` in mm, ``z`` and the kernel's ``n, sigma, norm``).

    Returns
    -------
    ux, uy : (c,) float64
        In-plane unit direction ``u`` of the axis nearest each centre
        (relative to its radius); ``v = (−uy, ux)``.
    FVV, FUU : (c,) float64, 1/mm²
        Upper bounds of ``∂²F/∂v²`` and ``∂²F/∂u²`` over each disc (negative:
        ``F`` is strictly concave along that direction there; inf: none, as
        for the degree 2, whose gradient jumps at the support's edge).
    FUV : (c,) float64, 1/mm²
        Upper bound of ``|∂²F/∂u∂v|`` over each disc.
    """
    return ridge_bounds_binned(seg, single_bin(ids), cx, cy, z, r, n, sigma, norm)


@parallel_kernel
def ridge_bounds_binned(seg, squares, cx, cy, z, r, n, sigma, norm):
    """:func:`ridge_bounds` with the plane's segments binned as for
    :func:`slicer._kernels.contours.cellbounds.disc_bounds_binned` (the same squares serve both)."""
    offsets, bins, x0, y0, side, nx, ny = squares
    k1 = kprime_max(n, sigma, norm)
    seg = borrow(seg)        # slicer._kernels.runtime.borrow: arguments outlive the call
    bins = borrow(bins)
    nc = cx.shape[0]
    UXo = np.zeros(nc)
    UYo = np.zeros(nc)
    VV = np.zeros(nc)
    UU = np.zeros(nc)
    UV = np.zeros(nc)
    for ch in prange((nc + CHUNK - 1) // CHUNK):
        own = np.empty(FRAME_WORK)
        work = borrow(own)
        for j in range(ch * CHUNK, min(nc, (ch + 1) * CHUNK)):
            c = square_of(cx[j], cy[j], x0, y0, side, nx, ny)
            UXo[j], UYo[j], VV[j], UU[j], UV[j] = _frame_disc(seg, bins, offsets[c], offsets[c + 1], cx[j], cy[j],
                                                              z, r[j], n, sigma, norm, k1, work)
        keep_alive((own,))
    return UXo, UYo, VV, UU, UV
