"""Closed-form SIIS field of one tapered segment (docs/math.md §2).

Segment table layout (one row per segment, built by
:func:`slicer.field.segment_table`), oriented so the radius grows from ``a``:

====  ===========================================
col   meaning
====  ===========================================
0-2   a, the thinner end (mm)
3-5   u, unit axis from a to b
6     L, length (mm)
7     tau0, radius at a (mm)
8     delta = (tau1 - tau0) / L >= 0
9     tau1, radius at b (mm)
====  ===========================================

``scratch`` arguments are float64 work arrays of at least ``SCRATCH`` entries,
allocated once per point batch / ray by the caller.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel

SCRATCH = 72
# 1/k for k < 256: the moment series multiplies instead of dividing per term
_RECIP = np.array([0.0] + [1.0 / k for k in range(1, 256)])
# columns of the segment table
AX, AY, AZ, UX, UY, UZ, LEN, TAU0, DELTA, TAU1 = range(10)
NCOL = 10


@kernel
def _support_local(seg, i, px, py, pz, inv_s2):
    """Support interval of segment ``i`` at p, in arc lengths measured from a
    local origin ``to``: the foot of p on the axis, clamped to [0, L]
    (docs/math.md §2.2).

    With ``t' = t - to`` and ``e = (p - a).u - to`` the support polynomial is
    ``P = c2 t'^2 + 2 (tau_o delta + e / sigma^2) t' + tau_o^2 - (perp^2 + e^2) / sigma^2``.
    When the foot lies on the segment, e = 0 and the coefficients and roots
    are of the size of the radius: the interval has full relative accuracy
    however far along a long strut p lies (arc lengths from ``a`` carry
    rounding errors ~ eps (p - a).u, i.e. ~ eps L / tau relative to the
    radius). When the foot lies beyond an end, the origin is that end, where
    the support is. The discriminant ``(tau_foot^2 + c2 perp^2) / sigma^2``,
    the same in every frame, has no cancellation.

    Returns
    -------
    to : float
        The origin: 0, L or the foot's arc length.
    e : float
        (p - a).u - to (0 when the foot is the origin).
    lo, hi : float
        The clipped interval in t' (``lo = -to`` is the clip at t = 0,
        ``hi = L - to`` the clip at t = L); ``hi <= lo`` means empty.
    root_a, root_b : bool
        Whether lo (hi) is a root of P rather than a clip.
    qx, qy, qz, perp2 : float
        The component of p - a perpendicular to the axis, its square norm.
    tau_o : float
        Radius at the origin.
    """
    wx = px - seg[i, AX]
    wy = py - seg[i, AY]
    wz = pz - seg[i, AZ]
    ux = seg[i, UX]
    uy = seg[i, UY]
    uz = seg[i, UZ]
    L = seg[i, LEN]
    d = seg[i, DELTA]
    tau0 = seg[i, TAU0]
    wu = wx * ux + wy * uy + wz * uz
    qx = wx - wu * ux
    qy = wy - wu * uy
    qz = wz - wu * uz
    perp2 = qx * qx + qy * qy + qz * qz
    if wu <= 0.0:
        to = 0.0
        e = wu
    elif wu >= L:
        to = L
        e = wu - L
    else:
        to = wu
        e = 0.0
    tau_o = tau0 + d * to
    tfoot = tau0 + d * wu
    c2 = d * d - inv_s2
    h = tau_o * d + e * inv_s2                       # c1 / 2
    c0 = tau_o * tau_o - (perp2 + e * e) * inv_s2
    disc = (tfoot * tfoot + c2 * perp2) * inv_s2     # h^2 - c2 c0
    lo = -to
    hi = L - to
    root_a = False
    root_b = False
    if c2 < 0.0:
        if disc <= 0.0:
            return to, e, 0.0, -1.0, False, False, qx, qy, qz, perp2, tau_o
        sq = math.sqrt(disc)
        q = -(h + sq) if h >= 0.0 else -(h - sq)
        if q == 0.0:
            return to, e, 0.0, -1.0, False, False, qx, qy, qz, perp2, tau_o
        r1 = q / c2
        r2 = c0 / q
        rlo = min(r1, r2)
        rhi = max(r1, r2)
        if rlo > lo:
            lo = rlo
            root_a = True
        if rhi < hi:
            hi = rhi
            root_b = True
    elif c2 > 0.0:
        # nested end balls: P > 0 outside its roots; only the thick branch is real
        if disc > 0.0:
            sq = math.sqrt(disc)
            q = -(h + sq) if h >= 0.0 else -(h - sq)
            rhi = max(q / c2, c0 / q)
            if rhi > lo:
                lo = rhi
                root_a = True
    else:
        # P linear: 2 h t' + c0 > 0
        if h > 0.0:
            r = -c0 / (2.0 * h)
            if r > lo:
                lo = r
                root_a = True
        elif h < 0.0:
            r = -c0 / (2.0 * h)
            if r < hi:
                hi = r
                root_b = True
        elif c0 <= 0.0:
            return to, e, 0.0, -1.0, False, False, qx, qy, qz, perp2, tau_o
    return to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o


@kernel
def support_interval(seg, i, px, py, pz, inv_s2):
    """Arc-length interval [ta, tb] of segment ``i`` whose support ball holds p.

    Solves ``P(t) = tau(t)^2 - |p - q(t)|^2 / sigma^2 > 0`` (docs/math.md §2.2);
    see :func:`_support_local`, which this shifts back to arc lengths from a.

    Returns
    -------
    ta, tb : float
        Clipped to [0, L] (exactly 0 and L at the clips); ``tb <= ta`` means
        empty.
    root_a, root_b : bool
        Whether ta (tb) is a root of P rather than a clip at 0 (L).
    """
    to, _, lo, hi, root_a, root_b, _, _, _, _, _ = _support_local(seg, i, px, py, pz, inv_s2)
    if not hi > lo:
        return 0.0, -1.0, False, False
    ta = to + lo if root_a else 0.0
    tb = to + hi if root_b else seg[i, LEN]
    return ta, tb, root_a, root_b


@inline_kernel
def _poly_mul_quad(w, src, n_src, r0, r1, r2, dst):
    """w[dst : dst + n_src + 2] = w[src : src + n_src] * (r0 + r1 y + r2 y^2).

    Offsets into one work array rather than array views: a view costs an
    atomic reference-count increment and decrement per call.
    """
    for j in range(n_src + 2):
        w[dst + j] = 0.0
    for j in range(n_src):
        c = w[src + j]
        w[dst + j] += c * r0
        w[dst + j + 1] += c * r1
        w[dst + j + 2] += c * r2


@inline_kernel
def _moments(Y, d, l, nmax, w, J, Yp):
    """w[J + j] = int_0^Y y^j / (1 - d y) dy for j = 0..nmax (docs/math.md §2.4).

    ``w[Yp + j]`` must hold ``Y^j`` for j = 0..nmax+1 (``J``, ``Yp``: offsets
    into the work array ``w``).
    """
    z = d * Y
    if d == 0.0:
        for j in range(nmax + 1):
            w[J + j] = w[Yp + j + 1] * _RECIP[j + 1]
    elif z <= 0.5 or z ** nmax <= 0.015625:
        # series for J[nmax], then the damping downward recurrence.  The
        # upward recurrence amplifies errors by up to z^-nmax, so it is only
        # used once that is below 64 (z > 0.5 for n = 6; z > 0.77 for n = 16,
        # where the series still converges in < 160 terms).
        s = 0.0
        zk = 1.0
        for k in range(200):
            term = zk * _RECIP[nmax + k + 1]
            s += term
            if term < 1e-17 * s:
                break
            zk *= z
        w[J + nmax] = w[Yp + nmax + 1] * s
        for j in range(nmax, 0, -1):
            w[J + j - 1] = d * w[J + j] + w[Yp + j] * _RECIP[j]
    else:
        w[J + 0] = math.log1p(d * l) / d
        for j in range(1, nmax + 1):
            w[J + j] = (w[J + j - 1] - w[Yp + j] / j) / d


# scratch layout of the general series (offsets into one work array, not views):
# R^(m-1), R^m, the moments J and the powers Y^j, each MAX_COEF long
MAX_DEGREE = 16                       # largest kernel degree n the layout holds
MAX_COEF = MAX_DEGREE + 1             # coefficients of R^m, m = n / 2
S_PA, S_PB, S_J, S_YP = 0, MAX_COEF, 2 * MAX_COEF, 3 * MAX_COEF
assert S_YP + MAX_DEGREE + 3 <= SCRATCH, "segment_eval's scratch layout outgrows SCRATCH"


@inline_kernel
def _series(Y, d, l, r0, r1, r2, m, grad, scratch):
    """Any degree n = 2m <= MAX_DEGREE: ``sum_j [R^m]_j J_j`` and, with
    ``grad``, the two sums ``h0``, ``h1`` of R^(m-1) the gradient needs
    (docs/math.md §2.4); R(y) = r0 + r1 y + r2 y^2.

    Returns
    -------
    f, h0, h1 : float
        The un-normalised field and gradient sums (h0 = h1 = 0 without ``grad``).
    """
    nmax = 2 * m
    pa = S_PA
    pb = S_PB
    J = S_J
    Yp = S_YP
    scratch[Yp + 0] = 1.0
    for j in range(1, nmax + 3):
        scratch[Yp + j] = scratch[Yp + j - 1] * Y
    scratch[pa + 0] = 1.0
    deg = 0
    for _ in range(m - 1):
        _poly_mul_quad(scratch, pa, deg + 1, r0, r1, r2, pb)
        deg += 2
        for j in range(deg + 1):
            scratch[pa + j] = scratch[pb + j]
    # pa = R^(m-1) (degree 2m-2), pb = R^m (degree 2m)
    _poly_mul_quad(scratch, pa, deg + 1, r0, r1, r2, pb)
    _moments(Y, d, l, nmax, scratch, J, Yp)
    f = 0.0
    for j in range(nmax + 1):
        f += scratch[pb + j] * scratch[J + j]
    if not grad:
        return f, 0.0, 0.0
    h0 = 0.0
    h1 = 0.0
    for j in range(nmax - 1):
        c = scratch[pa + j]
        t1 = scratch[Yp + j + 1] / (j + 1)
        t2 = scratch[Yp + j + 2] / (j + 2)
        h0 += c * (t1 - d * t2)
        h1 += c * t2
    return f, h0, h1


@kernel
def _series_m3(Y, d, l, r0, r1, r2, m, grad):
    """:func:`_series` for the default kernel n = 6 (m = 3): the same
    operations in the same order on scalars (bit-identical results), without
    the work array and the per-degree loops. ``m`` (= 3) is passed, not
    folded, so that ``z ** nmax`` is the same power routine as the general path's.
    """
    nmax = 2 * m
    y1 = 1.0 * Y
    y2 = y1 * Y
    y3 = y2 * Y
    y4 = y3 * Y
    y5 = y4 * Y
    y6 = y5 * Y
    y7 = y6 * Y
    y8 = y7 * Y
    # R = 1 * (r0 + r1 y + r2 y^2), then R^2 and R^3, accumulated as _poly_mul_quad does
    c0 = 0.0 + 1.0 * r0
    c1 = 0.0 + 1.0 * r1
    c2 = 0.0 + 1.0 * r2
    a0 = 0.0 + c0 * r0
    a1 = (0.0 + c0 * r1) + c1 * r0
    a2 = ((0.0 + c0 * r2) + c1 * r1) + c2 * r0
    a3 = (0.0 + c1 * r2) + c2 * r1
    a4 = 0.0 + c2 * r2
    b0 = 0.0 + a0 * r0
    b1 = (0.0 + a0 * r1) + a1 * r0
    b2 = ((0.0 + a0 * r2) + a1 * r1) + a2 * r0
    b3 = ((0.0 + a1 * r2) + a2 * r1) + a3 * r0
    b4 = ((0.0 + a2 * r2) + a3 * r1) + a4 * r0
    b5 = (0.0 + a3 * r2) + a4 * r1
    b6 = 0.0 + a4 * r2
    # moments J_j = int_0^Y y^j / (1 - d y) dy, j = 0..6 (see _moments)
    z = d * Y
    if d == 0.0:
        j0 = y1 * _RECIP[1]
        j1 = y2 * _RECIP[2]
        j2 = y3 * _RECIP[3]
        j3 = y4 * _RECIP[4]
        j4 = y5 * _RECIP[5]
        j5 = y6 * _RECIP[6]
        j6 = y7 * _RECIP[7]
    elif z <= 0.5 or z ** nmax <= 0.015625:
        sm = 0.0
        zk = 1.0
        for k in range(200):
            term = zk * _RECIP[nmax + k + 1]
            sm += term
            if term < 1e-17 * sm:
                break
            zk *= z
        j6 = y7 * sm
        j5 = d * j6 + y6 * _RECIP[6]
        j4 = d * j5 + y5 * _RECIP[5]
        j3 = d * j4 + y4 * _RECIP[4]
        j2 = d * j3 + y3 * _RECIP[3]
        j1 = d * j2 + y2 * _RECIP[2]
        j0 = d * j1 + y1 * _RECIP[1]
    else:
        j0 = math.log1p(d * l) / d
        j1 = (j0 - y1 / 1) / d
        j2 = (j1 - y2 / 2) / d
        j3 = (j2 - y3 / 3) / d
        j4 = (j3 - y4 / 4) / d
        j5 = (j4 - y5 / 5) / d
        j6 = (j5 - y6 / 6) / d
    f = 0.0 + b0 * j0
    f += b1 * j1
    f += b2 * j2
    f += b3 * j3
    f += b4 * j4
    f += b5 * j5
    f += b6 * j6
    if not grad:
        return f, 0.0, 0.0
    h0 = 0.0
    h1 = 0.0
    t1 = y1 / 1
    t2 = y2 / 2
    h0 += a0 * (t1 - d * t2)
    h1 += a0 * t2
    t1 = y2 / 2
    t2 = y3 / 3
    h0 += a1 * (t1 - d * t2)
    h1 += a1 * t2
    t1 = y3 / 3
    t2 = y4 / 4
    h0 += a2 * (t1 - d * t2)
    h1 += a2 * t2
    t1 = y4 / 4
    t2 = y5 / 5
    h0 += a3 * (t1 - d * t2)
    h1 += a3 * t2
    t1 = y5 / 5
    t2 = y6 / 6
    h0 += a4 * (t1 - d * t2)
    h1 += a4 * t2
    return f, h0, h1



@kernel
def segment_eval(seg, i, px, py, pz, m, inv_s2, norm, grad, scratch):
    """Field of segment ``i`` at p, and its gradient if ``grad``.

    Möbius-variable closed form (docs/math.md §2.4): exact for every taper,
    including constant radius, and integrated only over the clipped support.

    Parameters
    ----------
    seg : (n, 10) float64
        Segment table (module docstring).
    i : int
        Row.
    px, py, pz : float
        Point (mm).
    m : int
        Half the kernel degree.
    inv_s2 : float
        1 / sigma^2.
    norm : float
        Kernel normalisation N.
    grad : bool
        Also compute the gradient.
    scratch : (>= SCRATCH,) float64
        Work array.

    Returns
    -------
    f, gx, gy, gz : float
        Field and gradient (gradient zero when ``grad`` is false).
    """
    to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o = _support_local(seg, i, px, py, pz, inv_s2)
    if not hi > lo:
        return 0.0, 0.0, 0.0, 0.0
    ux = seg[i, UX]
    uy = seg[i, UY]
    uz = seg[i, UZ]
    d = seg[i, DELTA]
    # w = p - q(ta) = perp + (e - lo) u, from the local frame: its component
    # along u is a difference of small numbers, not of two arc lengths from a
    taua = tau_o + d * lo if root_a else seg[i, TAU0]
    wu = e - lo
    wx = qx + wu * ux
    wy = qy + wu * uy
    wz = qz + wu * uz
    ww = perp2 + wu * wu
    p0 = 1.0 - ww * inv_s2 / (taua * taua)
    p1 = 2.0 * (d + wu * inv_s2 / taua)
    p2 = d * d - inv_s2
    # support length: local where both ends are roots, exactly L where both are
    # clips, else from the exact clip offset (-to or L - to: 0 or L when the
    # origin is an end; L - foot is exact near the far end by Sterbenz)
    if root_a and root_b:
        span = hi - lo
    elif root_a:
        span = (seg[i, LEN] - to) - lo
    elif root_b:
        span = hi + to
    else:
        span = seg[i, LEN]
    l = span / taua
    Y = l / (1.0 + d * l)
    if root_a:
        p0 = 0.0          # R(0) = 0 exactly at a support root
    r0 = p0
    r1 = p1 - 2.0 * d * p0
    r2 = p2 - d * p1 + d * d * p0
    if root_b:
        r1 = -(r0 / Y + r2 * Y)   # R(Y) = 0 exactly at a support root
    if m == 3:
        f, h0, h1 = _series_m3(Y, d, l, r0, r1, r2, m, grad)
    else:
        f, h0, h1 = _series(Y, d, l, r0, r1, r2, m, grad, scratch)
    f *= norm
    if not grad:
        return f, 0.0, 0.0, 0.0
    s = -2.0 * m * norm * inv_s2 / (taua * taua)
    gx = s * (wx * h0 - taua * ux * h1)
    gy = s * (wy * h0 - taua * uy * h1)
    gz = s * (wz * h0 - taua * uz * h1)
    return f, gx, gy, gz
