"""Per-primitive bounds of the field's slope and curvature over a disc of a
layer plane (docs/math.md §10).

For a point ``p`` and one segment, ``f(p) = ∫ (1/τ) k(‖p − q‖/τ) dq`` over
the arc length ``t`` (docs/math.md §1.1). The integrand's gradient in ``p``
has norm ``|k'(s)| / τ²`` and its Hessian norm at most
``max(|k''(s)|, |k'(s)/s|) / τ³`` (``s = ‖p − q‖/τ``), and both vanish
unless ``‖p − q(t)‖ < στ(t)``. Over every ``p`` of the disc of centre ``c``
and radius ``r`` the points of the axis that can act satisfy
``‖c − q(t)‖ < στ(t) + r``: an interval ``[ta, tb]`` of arc length, the
roots of a quadratic, clipped to ``[0, L]``. Hence, for all p in the disc,

    ‖∇f(p)‖  <= K1 ∫_ta^tb dt/τ²  = K1 (tb − ta) / (τa τb)
    ‖∇²f(p)‖ <= K2 ∫_ta^tb dt/τ³  = K2 (tb − ta)(τa + τb) / (2 τa² τb²)

with ``K1 = max|k'|`` and ``K2 = max(max|k''|, max|k'(s)/s|)``. The roots
are widened by a relative margin and the sums scaled up by ``1 + 1e-9``
(no directed rounding in Numba: a margin far above the rounding error of
the few operations involved).
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .field import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ

#: relative slack on every computed bound (rounding of a few dozen operations is ~1e-15)
SLACK = 1e-9


@kernel
def _reach_interval(seg, i, cx, cy, cz, r, sigma):
    """Arc-length interval of segment ``i`` whose support balls, grown by ``r``,
    hold ``c``: ``‖c − q(t)‖ < στ(t) + r``, clipped to [0, L] (empty: tb <= ta)."""
    wx = cx - seg[i, AX]
    wy = cy - seg[i, AY]
    wz = cz - seg[i, AZ]
    L = seg[i, LEN]
    wu = wx * seg[i, UX] + wy * seg[i, UY] + wz * seg[i, UZ]
    ww = wx * wx + wy * wy + wz * wz
    R0 = sigma * seg[i, TAU0] + r
    Rd = sigma * seg[i, DELTA]
    A = 1.0 - Rd * Rd
    B = wu + R0 * Rd
    C = ww - R0 * R0
    if A <= SLACK:                  # support cone steeper than 45 degrees: take all of it
        return 0.0, L
    disc = B * B - A * C
    scale = B * B + abs(A * C)
    if disc < -SLACK * scale:
        return 0.0, -1.0
    sq = math.sqrt(max(disc, 0.0) + SLACK * scale)
    m = SLACK * (L + math.sqrt(ww) + R0)
    ta = (B - sq) / A - m
    tb = (B + sq) / A + m
    return max(ta, 0.0), min(tb, L)


@kernel
def kernel_curvature_max(n, sigma, norm):
    """``max(max|k''|, max|k'(s)/s|)`` of ``k(s) = N (1 − s²/σ²)^(n/2)`` (docs/math.md §10).

    ``k'(s)/s = −N n/σ² (1 − u)^(m−1)`` (``u = s²/σ²``) is at most ``N n/σ²``;
    ``k'' = −N n/σ² [(1 − u)^(m−1) − 2(m − 1) u (1 − u)^(m−2)]``, a difference
    of two non-negative terms, the first at most 1, the second at most
    ``2 (1 − 1/(m − 1))^(m−2)`` (its maximum, at ``u = 1/(m − 1)``). For
    ``n = 2`` the gradient jumps at the support's edge: no bound (inf).
    """
    m = n // 2
    if m < 2:
        return np.inf
    second = 2.0 * (1.0 - 1.0 / (m - 1.0)) ** (m - 2) if m > 2 else 2.0
    return norm * n / (sigma * sigma) * max(1.0, second)


@kernel
def disc_bounds(seg, ids, cx, cy, z, r, sigma, k1, k2):
    """Slope and curvature bounds of the field over discs of the plane ``z``.

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table (:mod:`slicer._kernels.field`).
    ids : (q,) int64
        Segments to consider (those whose support meets the plane).
    cx, cy, r : (c,) float64, mm
        Disc centres and radii.
    z : float, mm
    sigma : float
    k1, k2 : float
        ``max|k'|`` (:func:`slicer._kernels.raysupport.kprime_max`) and
        :func:`kernel_curvature_max`.

    Returns
    -------
    G : (c,) float64, 1/mm
        Upper bound of ``‖∇F‖`` over each disc.
    H : (c,) float64, 1/mm²
        Upper bound of the Hessian's norm over each disc (inf: none).
    """
    nc = cx.shape[0]
    G = np.zeros(nc)
    H = np.zeros(nc)
    for j in range(nc):
        g = 0.0
        h = 0.0
        for q in range(ids.shape[0]):
            i = ids[q]
            ta, tb = _reach_interval(seg, i, cx[j], cy[j], z, r[j], sigma)
            if not tb > ta:
                continue
            tau_a = seg[i, TAU0] + seg[i, DELTA] * ta
            tau_b = seg[i, TAU0] + seg[i, DELTA] * tb
            if not tau_a > 0.0:
                g = np.inf
                h = np.inf
                break
            g += (tb - ta) / (tau_a * tau_b)
            h += (tb - ta) * (tau_a + tau_b) / (2.0 * tau_a * tau_a * tau_b * tau_b)
        G[j] = g * k1 * (1.0 + SLACK)
        H[j] = h * k2 * (1.0 + SLACK)
    return G, H
