"""Per-primitive bounds of the field's in-plane slope and curvature over a
disc of a layer plane (docs/math.md §10).

For a point ``p`` and one segment, ``f(p) = ∫ (1/τ) k(‖p − q‖/τ) dq`` over
the arc length ``t`` (docs/math.md §1.1). The integrand's gradient in ``p``
is ``k'(s) e / τ²`` (``e = (p − q)/‖p − q‖``, ``s = ‖p − q‖/τ``) and its
Hessian ``α e eᵀ − β I`` with ``α = (k'' − k'/s)/τ³ >= 0`` and
``β = −(k'/s)/τ³ >= 0``; both vanish unless ``‖p − q(t)‖ < στ(t)``. Over
every ``p`` of the disc of centre ``c`` and radius ``r`` the points of the
axis that can act satisfy ``‖c − q(t)‖ < στ(t) + r``: an interval
``[ta, tb]`` of arc length, the roots of a quadratic, clipped to ``[0, L]``.
That interval is cut into ``PIECES`` pieces, on each of which ``s``, ``τ``
and the in-plane part of ``e`` are bounded; summing over pieces and
segments gives ``G`` (in-plane slope), ``H`` (in-plane Hessian: the smaller
of the summed norms and ``max(b, tr M − b)``, ``M`` the integral of the
positive semi-definite part, ``b`` of the isotropic one) and ``U`` (value).
Where no support ball of the disc reaches an untapered segment's ends,
the segment's field over the disc is the whole line's, a function of the
distance to the axis in closed form: its extremes replace the pieces
(:func:`_line_bounds`, docs/math.md §10, "Away from the ends").
The roots are widened by a relative margin and the sums scaled by
``1 ± 1e-9`` (no directed rounding in Numba: a margin far above the
rounding error of the few operations involved).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ
from slicer._kernels.rays.support import kprime_max
from slicer.constants import BOUND_SLACK as SLACK

#: discs per task of :func:`disc_bounds_binned` (each task owns one work area)
CHUNK = 64



@unrefcounted_kernel
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


@unrefcounted_kernel
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


#: pieces of the reach interval bounded separately (tighter than one piece:
#: the kernel's slope and curvature fall off away from the foot of c), at most
PIECES = 32
#: fewest pieces of a reach interval (:func:`piece_count`)
MIN_PIECES = 4


@inline_kernel
def piece_count(ta, tb, r, pieces):
    """Pieces of the reach interval ``[ta, tb]`` for a disc of radius ``r``:
    about one per ``r`` of arc length, rounded up to a multiple of
    ``MIN_PIECES``, and at most ``pieces`` (``pieces`` itself when it is
    ``MIN_PIECES`` or fewer).

    A piece's bounds hold for every point of the disc, so its distances
    carry ``± r`` however short it is: pieces much shorter than ``r`` tighten
    little and cost as much (docs/math.md §10). Any count gives valid bounds;
    a multiple of ``MIN_PIECES`` refines the cheap bounds' pieces, so the full
    bounds stay at least as tight as the cheap ones.
    """
    if pieces <= MIN_PIECES or not tb - ta < pieces * r:
        return pieces
    return min(pieces, max(MIN_PIECES, MIN_PIECES * int(math.ceil((tb - ta) / (MIN_PIECES * r)))))


@inline_kernel
def _ipow(x, k):
    """``x**k`` for a small integer ``k >= 0`` by repeated products."""
    out = 1.0
    for _ in range(k):
        out *= x
    return out


@inline_kernel
def _slope_sup(s, w1, n, sigma, cn, k1):
    """``sup |k'(s')|`` over ``s' >= s`` (``s < sigma``; ``w1 = (1 − s²/σ²)^(n/2−1)``,
    ``cn = N n/σ²``): |k'| rises up to d* = sigma/sqrt(n-1), then falls."""
    if s * s * (n - 1.0) <= sigma * sigma:
        return k1
    return cn * s * w1


@inline_kernel
def _curvature_sup(u, w1, m, cn, k2):
    """``sup max(|k''(s')|, |k'(s')/s'|)`` over ``s' >= s`` (``u = s²/σ² < 1``,
    ``w1 = (1 − u)^(m−1)``, ``cn = N n/σ²``; see :func:`kernel_curvature_max`)."""
    if m < 2:
        return np.inf
    if m == 2:
        second = 2.0
    else:
        v = max(u, 1.0 / (m - 1.0))
        second = 2.0 * (m - 1.0) * v * _ipow(1.0 - v, m - 2)
    return min(k2, cn * max(w1, second))


@inline_kernel
def _radial(u, kap, m):
    """``(1 − u)^(m−2) (κ + u)``: the radial second derivative's integrand of an
    untapered segment over ``N n/σ² / τ³`` (docs/math.md §10, "Across the axis"),
    ``κ = 2(m − 1) ρ²/(στ)² − 1``; in u it rises up to
    ``u* = (1 − (m − 2) κ)/(m − 1)`` and then falls."""
    return _ipow(1.0 - u, m - 2) * (kap + u)


@inline_kernel
def _radial_range(u_lo, u_hi, beyond, kap_lo, kap_hi, ustar, m):
    """``(least, top)`` of :func:`_radial` over ``u`` in ``[u_lo, u_hi]`` and ``κ`` in
    ``[κ_lo, κ_hi]``: the least at an end of the u range with κ_lo, the top at ``u*``
    (clamped) with κ_hi, or on the curve ``κ <= 2(m − 1) u − 1`` (ρ_p <= ‖p − q‖), which
    peaks at ``u = 3/(2m − 1)``, whichever is smaller; both take in 0 when the range goes
    ``beyond`` the support."""
    least = min(_radial(u_lo, kap_lo, m), _radial(u_hi, kap_lo, m))
    uc = min(max(3.0 / (2.0 * m - 1.0), u_lo), u_hi)
    top = min(_radial(min(max(ustar, u_lo), u_hi), kap_hi, m), _radial(uc, 2.0 * (m - 1.0) * uc - 1.0, m))
    if beyond:
        least = min(least, 0.0)
        top = max(top, 0.0)
    return least, top


@inline_kernel
def _second_sup(ulo, uhi, m):
    """``sup 2(m − 1) u (1 − u)^(m−2)`` over ``u`` in ``[ulo, uhi]`` (within [0, 1];
    it rises up to ``u = 1/(m − 1)`` and then falls; for m = 2 it is 2u)."""
    if m == 2:
        return 2.0 * uhi
    peak = 1.0 / (m - 1.0)
    u = peak if ulo <= peak <= uhi else (uhi if uhi < peak else ulo)
    return 2.0 * (m - 1.0) * u * _ipow(1.0 - u, m - 2)


#: rows of a disc's work area (:func:`_piece_bounds`), each ``pieces + 1`` long:
#: the pieces' ends (arc length, squared in-plane and full distance from the
#: centre, 1/radius), then per piece whether it acts and its eight terms
_T, _QI, _DI, _IT, _ON, _G, _H, _F, _BH, _BL, _A, _RU, _RL = range(13)
_ROWS = 13


@inline_kernel
def disc_work(pieces):
    """Length of the float64 work area :func:`_disc` needs for reach
    intervals cut into at most ``pieces`` pieces."""
    return _ROWS * (max(pieces, 1) + 1)


@inline_kernel
def _axis_frame(seg, i, cx, cy, cz):
    """``w = c − a`` of segment ``i``, its axis ``u``, ``w·u`` and the distance
    ``ρ_c`` of ``c`` from the axis line (every p of a disc of radius r around c
    is within ``ρ_c + r`` of it): ``(wx, wy, wz, ux, uy, uz, wu, rho_c)``."""
    wx = cx - seg[i, AX]
    wy = cy - seg[i, AY]
    wz = cz - seg[i, AZ]
    ux = seg[i, UX]
    uy = seg[i, UY]
    uz = seg[i, UZ]
    wu = wx * ux + wy * uy + wz * uz
    return wx, wy, wz, ux, uy, uz, wu, math.sqrt(max(wx * wx + wy * wy + wz * wz - wu * wu, 0.0))


@unrefcounted_kernel
def _piece_bounds(seg, i, cx, cy, cz, r, ta, tb, n, sigma, norm, k1, k2, pieces, work):
    """Slope, curvature and value bounds of segment ``i`` over the disc, from the
    axis points ``t`` in ``[ta, tb]``, split into ``pieces`` pieces: on a piece,
    ``dist(c, piece) − r <= ‖p − q‖ <= max(‖c − q(t0)‖, ‖c − q(t1)‖) + r``,
    ``tau_min <= tau <= tau_max`` and the in-plane part of the unit vector
    ``e = (p − q)/‖p − q‖`` is at most ``pe = (max |P(c − q)| + r)/(dist − r)``.
    Pieces whose nearest point is beyond the support (``s_lo >= sigma``) add
    nothing. Neighbouring pieces share their end ``ta + j (tb − ta)/pieces``,
    its distances from ``c`` and its radius.

    Three passes over ``work`` (at least :func:`disc_work` ``(pieces)``
    float64): the ends, then every piece's terms (both without a dependence
    from one piece to the next, so the compiler runs them on vector lanes),
    then the sums in piece order, so the bounds are those of one loop over
    the pieces to the bit.

    Returns ``g`` (in-plane slope), ``h`` (the integrand's Hessian norm),
    ``f`` (value), the sums of the split Hessian (docs/math.md §10):
    ``bh``, ``bl`` (upper and lower bounds of the isotropic part
    ``b = ∫ β dt``) and ``a`` (upper bound of the trace of the in-plane part
    of ``∫ α e eᵀ dt``), then, for an untapered segment (meaningless for a
    tapered one), upper and lower bounds ``ru``, ``rl`` of its second
    derivative across the axis, ``R = ∫ (α (e·n_p)² − β) dt``, and the
    lower bounds ``zm``, ``zn`` of :func:`_cross_reach` (docs/math.md §10,
    "Across the axis")."""
    wx, wy, wz, ux, uy, uz, wu, rho_c = _axis_frame(seg, i, cx, cy, cz)
    rho = rho_c * (1.0 + SLACK) + r
    st = pieces + 1
    rows = (work[_T * st:(_T + 1) * st], work[_QI * st:(_QI + 1) * st], work[_DI * st:(_DI + 1) * st],
            work[_IT * st:(_IT + 1) * st])
    if not _piece_ends(rows, wx, wy, wz, ux, uy, uz, seg[i, TAU0], seg[i, DELTA], ta, tb, pieces):
        return np.inf, np.inf, np.inf, np.inf, 0.0, np.inf, np.inf, -np.inf, 0.0, 0.0
    terms = (work[_ON * st:(_ON + 1) * st], work[_G * st:(_G + 1) * st], work[_H * st:(_H + 1) * st],
             work[_F * st:(_F + 1) * st], work[_BH * st:(_BH + 1) * st], work[_BL * st:(_BL + 1) * st],
             work[_A * st:(_A + 1) * st], work[_RU * st:(_RU + 1) * st], work[_RL * st:(_RL + 1) * st])
    # the distance from c to the axis point nearest it (used by the piece holding it)
    dfoot = math.sqrt(_end_distances(wx, wy, wz, ux, uy, uz, wu)[1])
    geo = (wu, rho, dfoot, r) + _radial_constants(rho_c, rho, r, sigma * seg[i, TAU0], n // 2)
    if n == 6:      # the default kernel: the powers unroll, the piece loop runs on vector lanes
        _piece_terms(rows, terms, geo, pieces, 6, sigma, norm, k1, k2)
    else:
        _piece_terms(rows, terms, geo, pieces, n, sigma, norm, k1, k2)
    g, h, f, bh, bl, a, ru, rl = _piece_sums(terms, pieces, n // 2)
    zm, zn = _cross_reach(wx, wy, wz, ux, uy, uz, wu, rho_c, r)
    return g, h, f, bh, bl, a, ru, rl, zm, zn


@inline_kernel
def _radial_constants(rho_c, rho, r, S, m):
    """``(κ_lo, κ_hi, u*)`` of an untapered segment of support radius ``S = στ``
    (docs/math.md §10, "Across the axis"): ``κ = 2(m − 1) ρ_p²/S² − 1`` over the
    disc, ``ρ_p`` within ``[ρ_c − r, rho]`` (rho: the upper bound of ``ρ_c + r``),
    and ``u*`` where :func:`_radial` with ``κ_hi`` peaks. A zero radius has no
    bound (:func:`_piece_ends`): its constants are unused."""
    S2 = S * S
    S2 = S2 if S2 > 0.0 else 1.0
    rho_lo = max(rho_c * (1.0 - SLACK) - r, 0.0)
    kap_lo = 2.0 * (m - 1.0) * rho_lo * rho_lo / S2 * (1.0 - SLACK) - 1.0
    kap_hi = 2.0 * (m - 1.0) * rho * rho / S2 * (1.0 + SLACK) - 1.0
    ustar = (1.0 - (m - 2.0) * kap_hi) / (m - 1.0) if m >= 2 else 1.0     # m = 1: no second derivatives
    return kap_lo, kap_hi, ustar


@inline_kernel
def _cross_reach(wx, wy, wz, ux, uy, uz, wu, rho_c, r):
    """``(zm, zn)``: lower bounds over the disc of ``(m_p·ẑ)²`` and ``(n_p·ẑ)²``,
    with ``n_p`` the unit vector from the axis line to p (across the axis) and
    ``m_p = u × n_p`` (docs/math.md §10, "Across the axis"): ``m_p·ẑ = n_p·k``
    with ``k = ẑ × u``, ``n_p·k = (p − a)·k / ρ_p`` and ``|(p − c)·k| <= r |k|``;
    ``n_p·ẑ = (p − a)·ẑ′ / ρ_p`` with ``ẑ′ = ẑ − u_z u`` and
    ``|(p − c)·ẑ′| <= r |u_z| |k|``; ``ρ_p <= ρ_c + r``. 0 where nothing is proven."""
    kn = math.sqrt(ux * ux + uy * uy)
    big = (rho_c + r) * (1.0 + SLACK) + SLACK * (abs(wx) + abs(wy) + abs(wz))
    if not big > 0.0:
        return 0.0, 0.0
    # (c − a)·k with k = (−u_y, u_x, 0); (c − a)·ẑ′ = w_z − u_z (w·u)
    ck = abs(ux * wy - uy * wx) - SLACK * (abs(wx) + abs(wy)) - r * kn * (1.0 + SLACK)
    cz = abs(wz - uz * wu) - SLACK * (abs(wz) + abs(uz * wu)) - r * abs(uz) * kn * (1.0 + SLACK)
    lk = min(max(ck, 0.0) / big, 1.0)
    lz = min(max(cz, 0.0) / big, 1.0)
    return lk * lk, lz * lz


@inline_kernel
def _plane_eigen(R, b, zu, zn, zm):
    """Largest and least eigenvalues of ``diag(0, R, −b)`` (in the frame u, n_p,
    m_p) restricted to the plane whose unit normal has the squared components
    ``zu, zn, zm`` there: the roots of ``μ² − B μ + C``, ``B = R (zu + zm) −
    b (zu + zn)``, ``C = −zu R b`` (docs/math.md §10, "Across the axis")."""
    B = R * (zu + zm) - b * (zu + zn)
    q = math.sqrt(max(B * B + 4.0 * zu * R * b, 0.0))
    return 0.5 * (B + q), 0.5 * (B - q)


@inline_kernel
def _piece_ends(rows, wx, wy, wz, ux, uy, uz, tau0, d, ta, tb, pieces):
    """Fill ``rows = (t, q, D, 1/tau)`` at the ``pieces + 1`` ends of the
    pieces of ``[ta, tb]`` (``q``, ``D``: squared in-plane and full distance
    from ``c``, ``w = c − a``); False if a piece starts at a radius that is
    not positive (no bound)."""
    T, Qi, Di, IT = rows
    step = (tb - ta) / pieces
    for j in range(pieces + 1):
        t = ta + j * step if j < pieces else tb
        q, Q = _end_distances(wx, wy, wz, ux, uy, uz, t)
        T[j] = t
        Qi[j] = q
        Di[j] = math.sqrt(Q)
        IT[j] = 1.0 / (tau0 + d * t)
    for j in range(pieces):
        if not tau0 + d * T[j] > 0.0:
            return False
    return True


@inline_kernel
def _piece_terms(rows, terms, geo, pieces, n, sigma, norm, k1, k2):
    """Each piece's terms of :func:`_piece_bounds` into ``terms = (on, g, h,
    f, bh, bl, a, ru, rl)`` (``on``: 1 where the piece acts, else 0 and its
    terms unused), from its ends ``rows`` and ``geo = (wu, rho, dfoot, r,
    κ_lo, κ_hi, u*)``: the foot's arc length, the disc's reach from the axis
    line, the distance from ``c`` to the foot, the disc radius, and the
    constants of the radial terms (:func:`_radial_constants`)."""
    T, Qi, Di, IT = rows
    ON, TG, TH, TF, TBH, TBL, TA, TRU, TRL = terms
    wu, rho, dfoot, r, kap_lo, kap_hi, ustar = geo
    m = n // 2
    inv_s2 = 1.0 / (sigma * sigma)
    cn = norm * n * inv_s2
    for j in range(pieces):
        t0 = T[j]
        t1 = T[j + 1]
        D0 = Di[j]
        D1 = Di[j + 1]
        # distance to the piece: to the foot when it lies on the piece, else to the nearer end
        dist = D0 if wu <= t0 else (D1 if wu >= t1 else dfoot)
        dmax = max(D0, D1)
        qmax = max(Qi[j], Qi[j + 1])
        dlo = dist * (1.0 - SLACK) - r
        it = IT[j]
        ith = IT[j + 1]
        s_lo = max(dlo, 0.0) * ith * (1.0 - SLACK)
        ON[j] = 0.0 if s_lo >= sigma else 1.0
        pos = dlo > 0.0
        idl = 1.0 / dlo
        pe = min(1.0, (math.sqrt(qmax) * (1.0 + SLACK) + r) * idl) if pos else 1.0
        pp = min(1.0, rho * idl) if pos else 1.0
        s_hi = (dmax * (1.0 + SLACK) + r) * it * (1.0 + SLACK)
        ln = t1 - t0
        it3 = it * it * it
        # k falls with s: k(s') <= k(s_lo); powers of w = 1 - s_lo²/σ²
        u_lo = s_lo * s_lo * inv_s2
        w = 1.0 - u_lo
        w1 = _ipow(w, m - 1)
        TG[j] = ln * pe * _slope_sup(s_lo, w1, n, sigma, cn, k1) * it * it
        TH[j] = ln * _curvature_sup(u_lo, w1, m, cn, k2) * it3
        TF[j] = ln * norm * w1 * w * it
        if m >= 2:
            u_hi = min(s_hi * s_hi * inv_s2, 1.0)
            TBH[j] = ln * cn * w1 * it3
            TBL[j] = ln * cn * _ipow(1.0 - u_hi, m - 1) * (ith * ith * ith)
            sec = ln * cn * _second_sup(u_lo, u_hi, m) * it3
            TA[j] = sec * pe * pe
            # an untapered segment's radial integrand (τ fixed), from below (at an
            # end of [u_lo, u_hi]) and above (at u* clamped); ρ_p <= ‖p − q‖ puts
            # ρ_p²/(στ)² <= u, so κ <= 2(m − 1) u − 1 too, which peaks at 3/(2m − 1)
            least, top = _radial_range(u_lo, u_hi, s_hi >= sigma, kap_lo, kap_hi, ustar, m)
            TRU[j] = ln * cn * top * it3
            TRL[j] = ln * cn * least * it3


@inline_kernel
def _piece_sums(terms, pieces, m):
    """The sums of :func:`_piece_bounds` over the acting pieces, in piece order."""
    ON, TG, TH, TF, TBH, TBL, TA, TRU, TRL = terms
    g = h = f = bh = bl = a = ru = rl = 0.0
    for j in range(pieces):
        if ON[j] != 0.0:
            g += TG[j]
            h += TH[j]
            f += TF[j]
            if m >= 2:
                bh += TBH[j]
                bl += TBL[j]
                a += TA[j]
                ru += TRU[j]
                rl += TRL[j]
    if m < 2:
        bh = np.inf
    return g, h, f, bh, bl, a, ru, rl


@inline_kernel
def _end_distances(wx, wy, wz, ux, uy, uz, t):
    """Squared in-plane and full distances from ``c`` (``w = c − a``) to the axis point at ``t``."""
    x = wx - t * ux
    y = wy - t * uy
    z = wz - t * uz
    q = x * x + y * y
    return q, q + z * z


@unrefcounted_kernel
def _end_slopes(seg, i, cx, cy, cz, r, n, sigma, norm, k1):
    """Upper bound over the disc of ``|∇ψ(p − a)| + |∇ψ(p − b)|``, ψ the integrand
    at the segment's ends ``a`` and ``b`` (radii τ0 and τ1)."""
    return _end_slope_sums(seg, i, cx, cy, cz, r, n, sigma, norm, k1)[0]


@unrefcounted_kernel
def _end_slope_sums(seg, i, cx, cy, cz, r, n, sigma, norm, k1):
    """Upper bounds over the disc (or ball) of ``|k′(s_a)|/τ0² + |k′(s_b)|/τ1²`` (that is
    ``|∇ψ(p − a)| + |∇ψ(p − b)|``) and of ``|k′(s_a)|/τ0 + |k′(s_b)|/τ1``, s_a and s_b the
    scaled distances to the segment's ends."""
    L = seg[i, LEN]
    cn = norm * n / (sigma * sigma)
    out = 0.0
    once = 0.0
    for end in range(2):
        t = 0.0 if end == 0 else L
        tau = seg[i, TAU0] + seg[i, DELTA] * t
        ex = cx - seg[i, AX] - t * seg[i, UX]
        ey = cy - seg[i, AY] - t * seg[i, UY]
        ez = cz - seg[i, AZ] - t * seg[i, UZ]
        d = math.sqrt(ex * ex + ey * ey + ez * ez)
        s_lo = max(d * (1.0 - SLACK) - r, 0.0) / (tau * (1.0 + SLACK))
        if s_lo < sigma:
            w1 = _ipow(1.0 - s_lo * s_lo / (sigma * sigma), n // 2 - 1)
            k = _slope_sup(s_lo, w1, n, sigma, cn, k1)
            out += k / (tau * tau)
            once += k / tau
    return out, once


#: largest ``2 a b + a²`` over ``a² + b² = 1`` (the eigenvalue (1 + √5)/2 of [[1, 1], [1, 0]])
GOLDEN = 1.6180339887498950


@inline_kernel
def _disc_sums(seg, lst, a, b, cx, cy, z, r, n, sigma, norm, k1, k2, pieces, work):
    """The sums over the segments ``lst[a:b]`` behind :func:`_disc`: ``g``, ``h``
    (summed Hessian norms), ``u``, ``low`` and ``top`` (every in-plane second
    derivative of F over the disc lies in ``[−low, top]``, before slack) and
    ``mag`` (the size of the terms behind ``top``, for its rounding slack)."""
    g = 0.0
    h = 0.0
    u = 0.0
    low = 0.0
    top = 0.0
    mag = 0.0
    for q in range(a, b):
        i = lst[q]
        ta, tb = _reach_interval(seg, i, cx, cy, z, r, sigma)
        if not tb > ta:
            continue
        untapered = seg[i, DELTA] == 0.0
        # no support ball of the disc reaches an end (the interval was not clipped):
        # the field is the whole line's, with no end terms
        line = untapered and n >= 4 and ta > 0.0 and tb < seg[i, LEN]
        if line:
            gi, hi, ui, bhi, bli, rui, rli, zmi, zni = _line_bounds(seg, i, cx, cy, z, r, n // 2, sigma, norm)
            lo = max(bhi, -rli)
            up = max(rui, 0.0)
            mag += bhi + abs(rui) + abs(rli)
        else:
            k = piece_count(ta, tb, r, pieces)
            gi, hi, ui, bhi, bli, ai, rui, rli, zmi, zni = _piece_bounds(seg, i, cx, cy, z, r, ta, tb, n, sigma, norm,
                                                                          k1, k2, k, work)
            lo = bhi
            up = ai - bli
            mag += ai + bli
        # this segment's in-plane second derivatives lie in [-lo, up]
        g += gi
        h += hi
        u += ui
        if untapered:   # the axial derivatives are end terms
            w = 0.0 if line else _end_slopes(seg, i, cx, cy, z, r, n, sigma, norm, k1)
            lo, up, eps = _across_axis(seg[i, UZ], bhi, bli, rui, rli, zmi, zni, w, lo, up)
            mag += w + eps
        low += lo
        top += up
    return g, h, u, low, top, mag


@inline_kernel
def _line_phi(v, m):
    """``(1 − v)^(m − 3/2) (2 m v − 1)``: the line's second derivative across its
    axis over ``C = N σ B_m (2m + 1)/S²`` at ``v = ρ²/S²`` (``m >= 2``); it rises
    up to ``v = 3/(2m)`` and then falls to 0 at ``v = 1``."""
    a = max(1.0 - v, 0.0)
    return _ipow(a, m - 2) * math.sqrt(a) * (2.0 * m * v - 1.0)


@unrefcounted_kernel
def _line_bounds(seg, i, cx, cy, z, r, m, sigma, norm):
    """Bounds over the disc of an untapered segment (``m >= 2``) whose support
    balls, from every point of the disc, meet its axis line only within the
    segment: there the field is that of the whole line, ``f∞(ρ) = K A^(m + 1/2)``
    with ``K = N σ B_m``, ``A = 1 − ρ²/S²``, ``S = στ`` and ``ρ`` the distance
    to the axis (docs/math.md §10, "Away from the ends"), its Hessian exactly
    ``diag(0, R, −b)`` in the frame ``(u, n_p, m_p)`` with ``b = −f∞′/ρ =
    C A^(m − 1/2)`` and ``R = f∞″ = C A^(m − 3/2) (2 m v − 1)``, ``v = ρ²/S²``,
    ``C = K (2m + 1)/S²``. Over the disc ``ρ`` lies in ``[ρ_c − r, ρ_c + r]``.

    Returns ``g, h, u, bh, bl, ru, rl, zm, zn`` as :func:`_piece_bounds` does
    (no ``a``: R and b are bounded directly; ``h`` the larger of ``|R|`` and
    ``b``). The extremes over ``[ρ_c − r, ρ_c + r]``, rounded outwards, are
    at its ends or at the one turn of each function: they are the true ones."""
    wx, wy, wz, ux, uy, uz, wu, rho_c = _axis_frame(seg, i, cx, cy, z)
    S = sigma * seg[i, TAU0]
    S2 = S * S
    bm = 2.0
    for k in range(1, m + 1):
        bm *= 2.0 * k / (2.0 * k + 1.0)
    K = norm * sigma * bm
    C = K * (2.0 * m + 1.0) / S2
    rlo = max(rho_c * (1.0 - SLACK) - r, 0.0)
    rhi = (rho_c + r) * (1.0 + SLACK) + SLACK * (abs(wx) + abs(wy) + abs(wz))
    vlo = rlo * rlo / S2 * (1.0 - SLACK)
    vhi = min(rhi * rhi / S2 * (1.0 + SLACK), 1.0)
    alo = max(1.0 - vhi, 0.0)
    ahi = max(1.0 - vlo, 0.0)
    up = 1.0 + 8.0 * SLACK
    dn = 1.0 - 8.0 * SLACK
    # value and b fall as ρ grows
    u = K * _ipow(ahi, m) * math.sqrt(ahi) * up
    bh = C * _ipow(ahi, m - 1) * math.sqrt(ahi) * up
    bl = C * _ipow(alo, m - 1) * math.sqrt(alo) * dn
    # R: its only turn in [0, 1] is a maximum, at v = 3/(2m)
    pa = _line_phi(vlo, m)
    pb = _line_phi(vhi, m)
    vs = 3.0 / (2.0 * m)
    top = _line_phi(vs, m) if vlo <= vs <= vhi else max(pa, pb)
    least = min(pa, pb)
    ru = C * top * (up if top > 0.0 else dn)
    rl = C * least * (dn if least > 0.0 else up)
    zm, zn = _cross_reach(wx, wy, wz, ux, uy, uz, wu, rho_c, r)
    # |f∞′| = 2 K (m + 1/2) ρ A^(m − 1/2) / S²: ρ A^(m − 1/2) rises up to ρ² = S²/(2m), then falls;
    # the in-plane part of n_p is at most sqrt(1 − zn)
    rs = S / math.sqrt(2.0 * m)
    rg = rs if rlo <= rs <= rhi else (rhi if rhi < rs else rlo)
    ag = max(1.0 - rg * rg / S2, 0.0)
    g = C * rg * _ipow(ag, m - 1) * math.sqrt(ag) * math.sqrt(max(1.0 - zn, 0.0)) * up * up
    h = max(bh, abs(ru), abs(rl))
    return g, h, u, bh, bl, ru, rl, zm, zn


@inline_kernel
def _across_axis(uz, bh, bl, ru, rl, zm, zn, w, lo, up):
    """``(lo, up, eps)`` of an untapered segment sharpened across its axis
    (docs/math.md §10, "Across the axis"): in the frame ``(u, n_p, m_p)`` its
    Hessian is ``diag(0, R, −b)`` plus end terms of norm at most
    ``GOLDEN w`` along the plane, ``R`` in ``[rl, ru]``, ``b`` in ``[bl, bh]``,
    and the plane's unit normal has the squared components ``u_z²``,
    ``(n_p·ẑ)² >= zn`` and ``(m_p·ẑ)² >= zm``; the largest eigenvalue of the
    restriction to the plane falls as ``(n_p·ẑ)²`` grows and the least one
    too (when ``R >= 0``), so both are bounded at the extreme normals
    (:func:`_plane_eigen`). ``eps``: the rounding slack added to both sides."""
    eps = 4.0 * SLACK * (bh + abs(ru) + abs(rl))
    uz2 = uz * uz
    rest = max(1.0 - uz2, 0.0)            # (n_p·ẑ)² + (m_p·ẑ)²
    zn = min(zn, rest)
    zm = min(zm, rest)
    high, _ = _plane_eigen(max(ru + eps, 0.0), bl, uz2, zn, rest - zn)
    up = min(up, high + GOLDEN * w + eps)
    if rl - eps >= 0.0:
        _, least = _plane_eigen(rl - eps, bh, uz2, rest - zm, zm)
        lo = min(lo, -least + GOLDEN * w + eps)
    else:                                  # R may be negative: -b (v·m_p)² + min(R, 0) (v·n_p)²
        neg = min(eps - rl, bh)
        lo = min(lo, neg + (bh - neg) * (1.0 - zm) + GOLDEN * w + eps)
    return lo, up, eps


@inline_kernel
def _split_sides(low, top, mag):
    """The split Hessian's sides with their slack: every in-plane second
    derivative over the disc lies in ``[−lo, hi]`` (:func:`_disc_sums`)."""
    return low * (1.0 + SLACK), (top + 4.0 * SLACK * mag) * (1.0 + SLACK)


@unrefcounted_kernel
def _disc(seg, lst, a, b, cx, cy, z, r, n, sigma, norm, k1, k2, pieces, work):
    """:func:`disc_bounds` of one disc from the segments ``lst[a:b]`` (in that
    order; those whose support cannot reach the disc add nothing), with the
    work area ``work`` (at least :func:`disc_work` ``(pieces)`` float64).

    Returns
    -------
    G, H, U : float
    """
    g, h, u, low, top, mag = _disc_sums(seg, lst, a, b, cx, cy, z, r, n, sigma, norm, k1, k2, pieces, work)
    lo, hi = _split_sides(low, top, mag)
    split = max(lo, hi)
    return g * (1.0 + SLACK), min(h * (1.0 + SLACK), split), u * (1.0 + SLACK)


@kernel
def curvature_range(seg, ids, cx, cy, z, r, n, sigma, norm, pieces=PIECES):
    """Bounds ``(lo, hi)``, (c,) float64 each, 1/mm², such that every in-plane
    second derivative ``vᵀ ∇²F v`` (v a unit vector of the plane) over each
    disc lies in ``[−lo, hi]``: the two sides of the split Hessian that
    :func:`disc_bounds` takes the larger of (arguments as there)."""
    k1 = kprime_max(n, sigma, norm)
    k2 = kernel_curvature_max(n, sigma, norm)
    work = np.empty(disc_work(pieces))
    lo = np.empty(cx.shape[0])
    hi = np.empty(cx.shape[0])
    for j in range(cx.shape[0]):
        _, _, _, low, top, mag = _disc_sums(seg, ids, 0, ids.shape[0], cx[j], cy[j], z, r[j], n, sigma, norm, k1, k2,
                                            pieces, work)
        lo[j], hi[j] = _split_sides(low, top, mag)
    return lo, hi


def disc_bounds(seg, ids, cx, cy, z, r, n, sigma, norm, pieces=PIECES):
    """In-plane slope and curvature bounds of the field over discs of the plane ``z``.

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table (:mod:`slicer._kernels.field.segment`).
    ids : (q,) int64
        Segments to consider (those whose support meets the plane).
    cx, cy, r : (c,) float64, mm
        Disc centres and radii.
    z : float, mm
    n, sigma, norm : int, float, float
        Kernel degree, support factor and normalisation.
    pieces : int
        Pieces each segment's reach interval is cut into: fewer give looser
        bounds sooner (cut into a multiple of them, the bounds can only
        tighten, up to rounding: every piece's bound holds over its parts).

    Returns
    -------
    G : (c,) float64, 1/mm
        Upper bound of the in-plane gradient's norm ``‖∇_xy F‖`` over each
        disc (0: no support reaches it).
    H : (c,) float64, 1/mm²
        Upper bound of the norm of the in-plane Hessian ``∇²_xy F`` (the
        2 x 2 block of the second derivatives in x and y) over each disc
        (inf: none).
    U : (c,) float64
        Upper bound of ``F`` over each disc (the integrand ``k(s)/tau`` is at
        most ``k(s_lo)/tau_min`` on each piece).
    """
    return disc_bounds_binned(seg, single_bin(ids), cx, cy, z, r, n, sigma, norm, pieces)


def single_bin(ids):
    """The binned kernels' lists with one square holding every segment ``ids``:
    ``(offsets, lists, x0, y0, side, nx, ny)``."""
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    return np.array([0, ids.size], dtype=np.int64), ids, 0.0, 0.0, np.inf, 1, 1


@inline_kernel
def square_of(x, y, x0, y0, side, nx, ny):
    """Index ``iy * nx + ix`` of the square of side ``side`` from ``(x0, y0)``
    holding the point ``(x, y)``, clamped to the ``nx x ny`` grid."""
    ix = min(max(int(math.floor((x - x0) / side)), 0), nx - 1)
    iy = min(max(int(math.floor((y - y0) / side)), 0), ny - 1)
    return iy * nx + ix


@parallel_kernel
def disc_bounds_binned(seg, squares, cx, cy, z, r, n, sigma, norm, pieces=PIECES):
    """:func:`disc_bounds` with the plane's segments binned on a grid of
    squares, ``squares = (offsets, bins, x0, y0, side, nx, ny)``: ``nx x ny``
    squares of side ``side`` from ``(x0, y0)``. Each disc looks only at the
    list of the square holding its centre, ``bins[offsets[c] : offsets[c + 1]]``
    (``c = iy * nx + ix``, segment order kept), which must hold every segment
    whose support can reach a disc centred in the square (its footprint in
    the plane grown by the largest radius); every centre must lie in the
    grid. The bounds are those of :func:`disc_bounds` over all the plane's
    segments, to the bit.
    """
    offsets, bins, x0, y0, side, nx, ny = squares
    k1 = kprime_max(n, sigma, norm)
    k2 = kernel_curvature_max(n, sigma, norm)
    seg = borrow(seg)        # slicer._kernels.runtime.borrow: arguments outlive the call
    bins = borrow(bins)
    nc = cx.shape[0]
    G = np.zeros(nc)
    H = np.zeros(nc)
    U = np.zeros(nc)
    nw = disc_work(pieces)
    for ch in prange((nc + CHUNK - 1) // CHUNK):
        own = np.empty(nw)
        work = borrow(own)
        for j in range(ch * CHUNK, min(nc, (ch + 1) * CHUNK)):
            c = square_of(cx[j], cy[j], x0, y0, side, nx, ny)
            G[j], H[j], U[j] = _disc(seg, bins, offsets[c], offsets[c + 1], cx[j], cy[j], z, r[j], n, sigma, norm,
                                     k1, k2, pieces, work)
        keep_alive((own,))
    return G, H, U
