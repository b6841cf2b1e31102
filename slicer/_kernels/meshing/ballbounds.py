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

* each segment's own frame (docs/math.md §11, "A frame for each segment"):
  untapered, ``(u, n_p, m_p)`` with the end terms (or, away from the ends, the
  whole line in closed form); tapered, ``(v, n′, m_p)`` about its apex, where
  the field's invariance under scaling leaves end terms and ``∇f`` in the
  first row; the second derivatives across the frame ``R`` (or ``R′``) and
  ``−b`` are summed per piece (:func:`_radial_frame`, :func:`_segment_sides`);
* the frames added up as quadratic forms, ``(√λ + √E)²`` per side (§11,
  "Frames added up"): struts meeting at an angle count the larger of their
  curvatures, not their sum.

Every bound is over the whole ball, in all three dimensions: nothing
assumes a plane. Sums are widened by the relative ``SLACK`` of
:mod:`slicer._kernels.contours.cellbounds` (no directed rounding in Numba).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.contours.cellbounds import (GOLDEN, SLACK, _curvature_sup, _end_slope_sums, _end_slopes, _ipow, _line_bounds,
                                                _radial_constants, _radial_range, _reach_interval, _second_sup,
                                                _slope_sup, kernel_curvature_max, piece_count)
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ
from slicer._kernels.rays.support import kprime_max

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
def _piece_terms(ln, dist, dmax, pmax, tmin, tmax, r, m, sigma, norm, k1, k2, radial):
    """One piece's terms ``(u, l, h1, bh, bl, a, ap, ru, rl, g)`` of :func:`_segment_ball` (see
    the module docstring); ``radial = (κ_lo, κ_hi, u*)`` of the segment's radial integrand
    (:func:`_radial_frame`; ``ru``, ``rl`` are meaningless when it has none); ``g`` bounds the
    piece's part of ``‖∇f‖``."""
    inv_s2 = 1.0 / (sigma * sigma)
    dlo = dist * (1.0 - SLACK) - r
    s_lo = max(dlo, 0.0) / tmax * (1.0 - SLACK)
    if s_lo >= sigma:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
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
    # the radial integrand, as for a disc (docs/math.md §10)
    kap_lo, kap_hi, ustar = radial
    least, top = _radial_range(u_lo, u_hi, s_hi >= sigma, kap_lo, kap_hi, ustar, m)
    # times 1/τ³, τ anywhere in [tmin, tmax]: the side that widens each bound
    it3x = 1.0 / (tmax * tmax * tmax)
    ru = ln * cn * top * (it3 if top >= 0.0 else it3x)
    rl = ln * cn * least * (it3x if least >= 0.0 else it3)
    g = ln * _slope_sup(s_lo, w1, 2 * m, sigma, cn, k1) / (tmin * tmin)
    return up, low, h, bh, bl, a, a * pe * pe, ru, rl, g


@unrefcounted_kernel
def _segment_ball(seg, i, c, nu, r, m, sigma, norm, ks, reach, radial):
    """Segment ``i``'s sums ``(U, L, H₁, Bh, Bl, A, A_P, Ru, Rl, G)`` over the ball of centre
    ``c`` and radius ``r`` (``A_P`` for the plane of unit normal ``ν``; ``[Rl, Ru]`` holds the
    second derivative across the frame of :func:`_radial_frame`, whose constants are
    ``radial``; ``G >= ‖∇f‖``), from its reach interval ``reach = (ta, tb)``; ``c = (x, y, z)``,
    ``nu`` the plane's unit normal, ``ks = (k1, k2)`` the kernel's largest slope and curvature."""
    cx, cy, cz = c
    nx, ny, nz = nu
    k1, k2 = ks
    ta, tb = reach
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
    su = sl = sh = sbh = sbl = sa = sap = sru = srl = sg = 0.0
    for j in range(k):
        t1 = ta + (j + 1) * step if j < k - 1 else tb
        d1, p1 = _axis_distances(wx, wy, wz, ux, uy, uz, nx, ny, nz, t1)
        tmin = tau0 + d * t0
        if not tmin > 0.0:
            return np.inf, 0.0, np.inf, np.inf, 0.0, np.inf, np.inf, np.inf, -np.inf, np.inf
        dist = d0 if wu <= t0 else (d1 if wu >= t1 else foot)
        tmax = tau0 + d * t1
        up, low, h, bh, bl, a, ap, ru, rl, g = _piece_terms(t1 - t0, dist, max(d0, d1), max(p0, p1),
                                                            min(tmin, tmax), max(tmin, tmax), r, m, sigma, norm,
                                                            k1, k2, radial)
        su += up
        sl += low
        sh += h
        sbh += bh
        sbl += bl
        sa += a
        sap += ap
        sru += ru
        srl += rl
        sg += g
        t0, d0, p0 = t1, d1, p1
    return su, sl, sh, sbh, sbl, sa, sap, sru, srl, sg


@inline_kernel
def _radial_frame(seg, i, cx, cy, cz, r, m, sigma):
    """``((κ_lo, κ_hi, u*, D), (n, ε_n), (m, ε_m))``: the constants of segment ``i``'s second
    derivative across its frame over the ball and the least distance ``D`` from the ball to
    its apex (inf for an untapered segment; 0 when the ball may hold the apex: no frame);
    then the frame's directions n (n_p or n′) and m_p at the ball's centre, each with a bound
    of how far it moves over the ball.

    Untapered: the frame is ``(u, n_p, m_p)`` and ``κ = 2(m − 1) ρ_p²/(στ)² − 1`` (docs/math.md
    §10, "Across the axis"). Tapered, with apex A (where τ = 0, on the axis line): the frame is
    ``(v, n′, m_p)`` with v the unit vector from A to p and n′ ⊥ v in the plane of u and p;
    along n′ the integrand of the second derivative is ``(1 − u)^(m−2) (κ + u)`` over
    ``N n/σ² / τ³`` with ``κ = 2(m − 1) sin²φ/(σδ)² − 1`` the same for every t, φ the angle
    between u and v, ``sin φ = ρ_p/‖p − A‖`` (docs/math.md §11).
    """
    wx = cx - seg[i, AX]
    wy = cy - seg[i, AY]
    wz = cz - seg[i, AZ]
    ux, uy, uz = seg[i, UX], seg[i, UY], seg[i, UZ]
    wu = wx * ux + wy * uy + wz * uz
    rho_c = math.sqrt(max(wx * wx + wy * wy + wz * wz - wu * wu, 0.0))
    tau0, d = seg[i, TAU0], seg[i, DELTA]
    # m_p = u × n_p at c, n_p the unit vector from the axis line to c; over the ball
    # ‖n_p(p) − n_p(c)‖ <= 2 r / ρ_c (and <= 2, unit vectors), as is m_p's change
    px = wx - wu * ux
    py = wy - wu * uy
    pz = wz - wu * uz
    inv = 1.0 / rho_c if rho_c > 0.0 else 0.0
    npx, npy, npz = px * inv, py * inv, pz * inv
    mx = uy * npz - uz * npy
    my = uz * npx - ux * npz
    mz = ux * npy - uy * npx
    spread = min(2.0, 2.0 * r / rho_c * (1.0 + 4.0 * SLACK)) if rho_c > 0.0 else 2.0
    if d == 0.0:
        kap_lo, kap_hi, ustar = _radial_constants(rho_c, rho_c * (1.0 + SLACK) + r, r, sigma * tau0, m)
        return (kap_lo, kap_hi, ustar, np.inf), (npx, npy, npz, spread), (mx, my, mz, spread)
    t_apex = -tau0 / d
    ax = wx - t_apex * ux
    ay = wy - t_apex * uy
    az = wz - t_apex * uz
    dc = math.sqrt(ax * ax + ay * ay + az * az)
    dlo = dc * (1.0 - SLACK) - r - SLACK * abs(t_apex)
    if not dlo > 0.0:
        return (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0), (0.0, 0.0, 0.0, 2.0)
    sin_lo = max(rho_c * (1.0 - SLACK) - r, 0.0) / (dc * (1.0 + SLACK) + r)
    sin_hi = min(1.0, (rho_c * (1.0 + SLACK) + r) / dlo)
    sd = sigma * abs(d)
    kap_lo = 2.0 * (m - 1.0) * (sin_lo / sd) ** 2 * (1.0 - 4.0 * SLACK) - 1.0
    kap_hi = 2.0 * (m - 1.0) * (sin_hi / sd) ** 2 * (1.0 + 4.0 * SLACK) - 1.0
    # n′ = m_p × v, v the unit vector from the apex: it moves by at most m_p's and v's changes
    vx, vy, vz = ax / dc, ay / dc, az / dc
    nx = my * vz - mz * vy
    ny = mz * vx - mx * vz
    nz = mx * vy - my * vx
    spread_n = min(2.0, spread + 2.0 * r / dlo * (1.0 + 4.0 * SLACK))
    return (kap_lo, kap_hi, (1.0 - (m - 2.0) * kap_hi) / (m - 1.0), dlo), (nx, ny, nz, spread_n), (mx, my, mz, spread)


@unrefcounted_kernel
def _segment_sides(seg, i, cx, cy, cz, r, m, sigma, norm, k1, ta, tb, sums, frame_d):
    """``(lo, up, mag)``: every second derivative ``vᵀ∇²f v`` (unit v, any direction) of
    segment ``i`` over the ball lies in ``[−lo, up]``, before slack; ``mag`` sizes the
    terms behind ``up`` (for its rounding slack). ``sums = (Bh, Bl, A, Ru, Rl, G)`` of
    :func:`_segment_ball`; ``frame_d``: ``D`` of :func:`_radial_frame`.

    In general ``[−Bh, A − Bl]`` (the split Hessian). In the frame of :func:`_radial_frame`
    the Hessian is ``diag(·, R, −b)`` whose first row is a vector ``w``, so every second
    derivative lies in ``[min(R, 0) − b, max(R, 0)]`` widened by ``GOLDEN ‖w‖``
    (docs/math.md §10, "Along the axis"; §11). Untapered, w is made of end terms; where no
    support ball of the ball reaches the ends, R and b are those of the whole line, in
    closed form, and w = 0 (§10, "Away from the ends"). Tapered, the field is invariant
    under scaling about the apex, so ``(p − A)·∇f = E = (k(s_a) − k(s_b))/δ`` and
    ``w = ∇²f v = (∇E − ∇f)/‖p − A‖``.

    Also returns the frame's parts ``(framed, R⁺, R⁻, b, GOLDEN w)`` (upper bounds) for
    :func:`_ball`, which adds the frames of all segments as quadratic forms.
    """
    bh, bl, a, ru, rl, g = sums
    lo = bh
    up = a - bl
    mag = a + bl
    if m < 2 or not frame_d > 0.0:
        return lo, up, mag, (False, 0.0, 0.0, 0.0, 0.0)
    if seg[i, DELTA] == 0.0:
        if ta > 0.0 and tb < seg[i, LEN]:
            _, _, _, bh, bl, ru, rl, _, _ = _line_bounds(seg, i, cx, cy, cz, r, m, sigma, norm)
            w = 0.0
        else:
            w = _end_slopes(seg, i, cx, cy, cz, r, 2 * m, sigma, norm, k1)
    else:
        w = (_end_slope_sums(seg, i, cx, cy, cz, r, 2 * m, sigma, norm, k1)[1] / abs(seg[i, DELTA]) + g) \
            / frame_d * (1.0 + 4.0 * SLACK)
    eps = 4.0 * SLACK * (bh + abs(ru) + abs(rl))
    rp = max(ru + eps, 0.0)
    rn = max(eps - rl, 0.0)
    lo = min(lo, max(bh, rn) + GOLDEN * w + eps)
    up = min(up, rp + GOLDEN * w + eps)
    # the frame's parts: vᵀ∇²f v <= R⁺ (v·n)² + GOLDEN w, >= −(b (v·m)² + R⁻ (v·n)²) − GOLDEN w
    return lo, up, mag + bh + abs(ru) + abs(rl) + w + eps, (True, rp, rn, bh + eps, GOLDEN * w + eps)


@inline_kernel
def _sym3_top(a, b, c, d, e, f):
    """An upper bound of the largest eigenvalue of the positive semi-definite matrix
    ``[[a, d, e], [d, b, f], [e, f, c]]``: the closed form (trigonometric, for a symmetric
    3 x 3) plus a margin for its rounding, and at most the trace."""
    q = (a + b + c) / 3.0
    p1 = d * d + e * e + f * f
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1
    trace = max(a + b + c, 0.0)
    if not p2 > 0.0:
        return min(trace, q * (1.0 + 1e-12) + 1e-300) if q > 0.0 else 0.0
    p = math.sqrt(p2 / 6.0)
    ba, bb, bc = (a - q) / p, (b - q) / p, (c - q) / p
    bd, be, bf = d / p, e / p, f / p
    det = ba * (bb * bc - bf * bf) - bd * (bd * bc - bf * be) + be * (bd * bf - bb * be)
    rr = min(max(0.5 * det, -1.0), 1.0)
    top = q + 2.0 * p * math.cos(math.acos(rr) / 3.0)
    return min(trace * (1.0 + 1e-12), top + 1e-7 * (abs(q) + p))


@inline_kernel
def _with_spread(lam, spread):
    """``(√λ + √E)²``: the least over t > 0 of ``(1 + t) λ + (1 + 1/t) E``."""
    return (math.sqrt(max(lam, 0.0)) + math.sqrt(max(spread, 0.0))) ** 2


@inline_kernel
def _cell_range(x, r, o, c, n):
    """Grid cells ``[lo, hi]`` along one axis that the interval ``x ± r`` touches."""
    lo = min(max(int(math.floor((x - r - o) / c)), 0), n - 1)
    hi = min(max(int(math.floor((x + r - o) / c)), 0), n - 1)
    return lo, hi


@unrefcounted_kernel
def _ball(seg, grid, c, nu, r, m, sigma, norm, k1, k2, stamp, tag):
    """``(U, L, H, H_P)`` of one ball of centre ``c = (x, y, z)``, with ``nu`` the
    plane's unit normal, summed over the segments listed in the support grid's
    cells the ball's box touches, each once (``stamp[i] == tag`` once seen), in
    the order the cells list them."""
    offsets, ids, origin, cell, dims = grid
    cx, cy, cz = c
    x0, x1 = _cell_range(cx, r, origin[0], cell[0], dims[0])
    y0, y1 = _cell_range(cy, r, origin[1], cell[1], dims[1])
    z0, z1 = _cell_range(cz, r, origin[2], cell[2], dims[2])
    su = sl = sh = sbh = sbl = sa = sap = low = top = mag = 0.0
    # the frames' quadratic forms: upper side Σ R⁺ n nᵀ, lower side Σ (b m mᵀ + R⁻ n nᵀ),
    # their spreads Σ c ε², the end terms, and the segments without a frame (scalars)
    ua = ub = uc = ud = ue = uf = 0.0
    la = lb = lc = ld = le = lf = 0.0
    e_up = e_lo = ends = free_lo = free_up = 0.0
    for iz in range(z0, z1 + 1):
        for iy in range(y0, y1 + 1):
            for ix in range(x0, x1 + 1):
                q = (iz * dims[1] + iy) * dims[0] + ix
                for e in range(offsets[q], offsets[q + 1]):
                    i = ids[e]
                    if stamp[i] == tag:
                        continue
                    stamp[i] = tag
                    ta, tb = _reach_interval(seg, i, cx, cy, cz, r, sigma)
                    if not tb > ta:
                        continue
                    (kap_lo, kap_hi, ustar, frame_d), fn, fm = _radial_frame(seg, i, cx, cy, cz, r, m, sigma)
                    up, lw, h, bh, bl, a, ap, ru, rl, g = _segment_ball(seg, i, c, nu, r, m, sigma, norm, (k1, k2),
                                                                        (ta, tb), (kap_lo, kap_hi, ustar))
                    su += up
                    sl += lw
                    sh += h
                    sbh += bh
                    sbl += bl
                    sa += a
                    sap += ap
                    lo_i, up_i, mag_i, parts = _segment_sides(seg, i, cx, cy, cz, r, m, sigma, norm, k1, ta, tb,
                                                              (bh, bl, a, ru, rl, g), frame_d)
                    low += lo_i
                    top += up_i
                    mag += mag_i
                    framed, rp, rn, bb, wg = parts
                    if framed:
                        n0, n1, n2, en = fn
                        m0, m1, m2, em = fm
                        ua += rp * n0 * n0
                        ub += rp * n1 * n1
                        uc += rp * n2 * n2
                        ud += rp * n0 * n1
                        ue += rp * n0 * n2
                        uf += rp * n1 * n2
                        la += bb * m0 * m0 + rn * n0 * n0
                        lb += bb * m1 * m1 + rn * n1 * n1
                        lc += bb * m2 * m2 + rn * n2 * n2
                        ld += bb * m0 * m1 + rn * n0 * n1
                        le += bb * m0 * m2 + rn * n0 * n2
                        lf += bb * m1 * m2 + rn * n1 * n2
                        e_up += rp * en * en
                        e_lo += bb * em * em + rn * en * en
                        ends += wg
                    else:
                        free_lo += lo_i
                        free_up += up_i
    split = max(low, top + 4.0 * SLACK * mag)
    # Σ c (v·x(p))² <= (1 + t) vᵀ(Σ c x_c x_cᵀ) v + (1 + 1/t) Σ c ε² for every t > 0, at best
    # (√λ + √E)² with λ the form's largest eigenvalue (docs/math.md §11, "Frames added up")
    up2 = _with_spread(_sym3_top(ua, ub, uc, ud, ue, uf), e_up) + ends + free_up
    lo2 = _with_spread(_sym3_top(la, lb, lc, ld, le, lf), e_lo) + ends + free_lo
    forms = max(lo2, up2) * (1.0 + 16.0 * SLACK) + 4.0 * SLACK * mag
    full = min(sh, max(sbh, sa - sbl * (1.0 - SLACK)), split, forms) * (1.0 + SLACK)
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
    k1 = kprime_max(n, sigma, norm)
    k2 = kernel_curvature_max(n, sigma, norm)
    grid = (offsets, ids, origin, cell, dims)
    for ch in prange((k + CHUNK - 1) // CHUNK):
        stamp = np.full(seg.shape[0], -1, np.int64)
        for j in range(ch * CHUNK, min(k, (ch + 1) * CHUNK)):
            c = (centres[j, 0], centres[j, 1], centres[j, 2])
            nu = (normals[j, 0], normals[j, 1], normals[j, 2])
            U[j], L[j], H[j], HP[j] = _ball(seg, grid, c, nu, radii[j], m, sigma, norm, k1, k2, stamp, j)
    return U, L, H, HP
