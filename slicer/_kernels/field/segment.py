"""Closed-form SIIS field of one tapered segment (docs/math.md §2).

Segment table layout (one row per segment, built by
:func:`slicer.model.field.segment_table`), oriented so the radius grows from ``a``:

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
allocated once per point batch / ray by the caller. Their first ``SERIES``
entries are :func:`segment_eval`'s; the rest hold the ``LANES`` segments that
:func:`segment_lanes` evaluates at one point at once (layout below).
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import inline_kernel, unrefcounted_kernel

# 1/k for k < 256: the moment series multiplies instead of dividing per term
_RECIP = np.array([0.0] + [1.0 / k for k in range(1, 256)])
# columns of the segment table
AX, AY, AZ, UX, UY, UZ, LEN, TAU0, DELTA, TAU1 = range(10)
NCOL = 10

#: entries of a scratch array used by the general series (:func:`_series`)
SERIES = 72
#: segments :func:`segment_lanes` evaluates at once (8 float64: one AVX-512 register)
LANES = 8
#: scratch offsets of the lanes: the segment table's NCOL columns (column c of
#: lane k at ``LANE_IN + c * LANES + k``), then f, gx, gy, gz and the "redo"
#: flag (``LANE_OUT + o * LANES + k``, o = 0..4), then each lane's caller tag
LANE_IN = SERIES
LANE_OUT = LANE_IN + NCOL * LANES
LANE_TAG = LANE_OUT + 5 * LANES
SCRATCH = LANE_TAG + LANES


@inline_kernel
def _axial_split(seg, i, px, py, pz):
    """p - a of segment ``i`` split along and across its unit axis u.

    Returns
    -------
    wu : float
        (p - a).u, the foot's arc length from a (mm; any sign, may exceed L).
    qx, qy, qz, perp2 : float
        The component of p - a perpendicular to the axis (mm), its square norm.
    """
    return _axial_parts(px - seg[i, AX], py - seg[i, AY], pz - seg[i, AZ], seg[i, UX], seg[i, UY], seg[i, UZ])


@inline_kernel
def _axial_parts(wx, wy, wz, ux, uy, uz):
    """:func:`_axial_split` of ``w = p - a`` on the unit axis ``u``."""
    wu = wx * ux + wy * uy + wz * uz
    qx = wx - wu * ux
    qy = wy - wu * uy
    qz = wz - wu * uz
    perp2 = qx * qx + qy * qy + qz * qz
    return wu, qx, qy, qz, perp2


@inline_kernel
def _local_origin(wu, L):
    """Local origin of the support polynomial for the foot at arc length ``wu``.

    Returns
    -------
    to : float
        The foot itself when it lies on the segment (0 < wu < L), else the
        end beyond which it lies (0 or L).
    e : float
        wu - to: 0 for a foot on the segment, the signed overshoot otherwise.
    """
    if wu <= 0.0:
        return 0.0, wu
    if wu >= L:
        return L, wu - L
    return wu, 0.0


@inline_kernel
def _clip_cone(c2, h, c0, disc, lo, hi):
    """Clip [lo, hi] to where P = c2 t'^2 + 2 h t' + c0 > 0 for c2 < 0 (the
    usual case: P > 0 between its roots), with the stable root pair ``q / c2``,
    ``c0 / q`` (docs/math.md §2.2). ``disc`` = h^2 - c2 c0.

    Returns
    -------
    lo, hi : float
        The clipped interval (0, -1 when empty).
    root_a, root_b : bool
        Whether lo (hi) is a root of P rather than the clip passed in.
    """
    if disc <= 0.0:
        return 0.0, -1.0, False, False
    sq = math.sqrt(disc)
    q = -(h + sq) if h >= 0.0 else -(h - sq)
    if q == 0.0:
        return 0.0, -1.0, False, False
    r1 = q / c2
    r2 = c0 / q
    rlo = min(r1, r2)
    rhi = max(r1, r2)
    root_a = False
    root_b = False
    if rlo > lo:
        lo = rlo
        root_a = True
    if rhi < hi:
        hi = rhi
        root_b = True
    return lo, hi, root_a, root_b


@inline_kernel
def _clip_nested(c2, h, c0, disc, lo, hi):
    """:func:`_clip_cone` for c2 > 0 (nested end balls): P > 0 outside its
    roots and only the thick branch is real, so only ``lo`` can move.

    Returns
    -------
    lo, hi : float
        The clipped interval (``hi`` unchanged).
    root_a, root_b : bool
        Whether lo is a root of P; root_b is always false.
    """
    if disc > 0.0:
        sq = math.sqrt(disc)
        q = -(h + sq) if h >= 0.0 else -(h - sq)
        rhi = max(q / c2, c0 / q)
        if rhi > lo:
            return rhi, hi, True, False
    return lo, hi, False, False


@inline_kernel
def _clip_linear(h, c0, lo, hi):
    """:func:`_clip_cone` for c2 = 0: P linear, 2 h t' + c0 > 0.

    Returns
    -------
    lo, hi : float
        The clipped interval (0, -1 when empty).
    root_a, root_b : bool
        Whether lo (hi) is the root of P rather than the clip passed in.
    """
    if h > 0.0:
        r = -c0 / (2.0 * h)
        if r > lo:
            return r, hi, True, False
    elif h < 0.0:
        r = -c0 / (2.0 * h)
        if r < hi:
            return lo, r, False, True
    elif c0 <= 0.0:
        return 0.0, -1.0, False, False
    return lo, hi, False, False


@inline_kernel
def _support_quadratic(tau0, d, to, e, wu, perp2, inv_s2):
    """The support polynomial's coefficients about the origin ``to``
    (:func:`_support_local`): ``tau_o`` (radius there), ``c2``, ``h = c1/2``,
    ``c0`` and the discriminant ``h^2 - c2 c0``, computed without cancellation."""
    tau_o = tau0 + d * to
    tfoot = tau0 + d * wu
    c2 = d * d - inv_s2
    h = tau_o * d + e * inv_s2                       # c1 / 2
    c0 = tau_o * tau_o - (perp2 + e * e) * inv_s2
    disc = (tfoot * tfoot + c2 * perp2) * inv_s2     # h^2 - c2 c0
    return tau_o, c2, h, c0, disc


@inline_kernel
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
    L = seg[i, LEN]
    d = seg[i, DELTA]
    tau0 = seg[i, TAU0]
    wu, qx, qy, qz, perp2 = _axial_split(seg, i, px, py, pz)
    to, e = _local_origin(wu, L)
    tau_o, c2, h, c0, disc = _support_quadratic(tau0, d, to, e, wu, perp2, inv_s2)
    lo = -to
    hi = L - to
    if c2 < 0.0:
        lo, hi, root_a, root_b = _clip_cone(c2, h, c0, disc, lo, hi)
    elif c2 > 0.0:
        lo, hi, root_a, root_b = _clip_nested(c2, h, c0, disc, lo, hi)
    else:
        lo, hi, root_a, root_b = _clip_linear(h, c0, lo, hi)
    return to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o


@unrefcounted_kernel
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


#: below this z the moment series is its first SHORT_TERMS terms, summed by Estrin's scheme
#: (written out in :func:`_series_sum` as seven pairs)
SHORT_Z = 0.0625
SHORT_TERMS = 14


@inline_kernel
def _short_sum(z, c):
    """``sum_{k<SHORT_TERMS} z^k / (c + k)`` by Estrin's scheme (:func:`_series_sum`)."""
    z2 = z * z
    z4 = z2 * z2
    z8 = z4 * z4
    a0 = _RECIP[c] + z * _RECIP[c + 1]
    a1 = _RECIP[c + 2] + z * _RECIP[c + 3]
    a2 = _RECIP[c + 4] + z * _RECIP[c + 5]
    a3 = _RECIP[c + 6] + z * _RECIP[c + 7]
    a4 = _RECIP[c + 8] + z * _RECIP[c + 9]
    a5 = _RECIP[c + 10] + z * _RECIP[c + 11]
    a6 = _RECIP[c + 12] + z * _RECIP[c + 13]
    return ((a0 + z2 * a1) + z4 * (a2 + z2 * a3)) + z8 * ((a4 + z2 * a5) + z4 * a6)


@inline_kernel
def _series_sum(z, nmax):
    """``sum_{k>=0} z^k / (nmax + 1 + k)`` for 0 <= z < 1 (docs/math.md §2.4).

    For z <= SHORT_Z (every tapered strut of a typical lattice) the first
    SHORT_TERMS terms, evaluated by Estrin's scheme (pairs, then powers z^2,
    z^4, z^8: a dependency chain of four steps instead of fourteen); the
    terms left out add less than 1e-17 of the sum. Otherwise term by term
    until a term is below 1e-17 of the sum.
    """
    c = nmax + 1
    if z <= SHORT_Z:
        return _short_sum(z, c)
    s = 0.0
    zk = 1.0
    for k in range(200):
        term = zk * _RECIP[c + k]
        s += term
        if term < 1e-17 * s:
            break
        zk *= z
    return s


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
        w[J + nmax] = w[Yp + nmax + 1] * _series_sum(z, nmax)
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
assert S_YP + MAX_DEGREE + 3 <= SERIES, "segment_eval's scratch layout outgrows SERIES"
# the series terms _series_sum leaves out below SHORT_Z, relative to the sum, for every degree:
# (c / (c + SHORT_TERMS)) z^SHORT_TERMS / (1 - z), c = n + 1 <= MAX_DEGREE + 1
assert ((MAX_DEGREE + 1) / (MAX_DEGREE + 1 + SHORT_TERMS) * SHORT_Z ** SHORT_TERMS / (1.0 - SHORT_Z) < 1e-17), \
    "_series_sum's short form leaves out too much"


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


@inline_kernel
def _powers_m3(Y):
    """Y^1 .. Y^7 for :func:`_series_m3`, multiplied up as :func:`_series`
    fills its table (``1.0 * Y`` included).

    Returns
    -------
    tuple of 7 floats
    """
    y1 = 1.0 * Y
    y2 = y1 * Y
    y3 = y2 * Y
    y4 = y3 * Y
    y5 = y4 * Y
    y6 = y5 * Y
    y7 = y6 * Y
    return y1, y2, y3, y4, y5, y6, y7


@inline_kernel
def _cube_m3(r0, r1, r2):
    """Coefficients of R^2 and R^3, R(y) = r0 + r1 y + r2 y^2, accumulated in
    the order of :func:`_poly_mul_quad` (from R = 1 * R, zeros included).

    Returns
    -------
    a : tuple of 5 floats
        [R^2]_0 .. [R^2]_4 (the gradient's R^(m-1)).
    b : tuple of 7 floats
        [R^3]_0 .. [R^3]_6.
    """
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
    return (a0, a1, a2, a3, a4), (b0, b1, b2, b3, b4, b5, b6)


@inline_kernel
def _moments_m3_series(d, z, nmax, y):
    """:func:`_moments`' series branch for nmax = 6: J_6 from the series in
    z = d Y, then the damping downward recurrence to J_0.

    ``y`` holds Y^1 .. Y^7 (:func:`_powers_m3`). Returns J_0 .. J_6 (tuple of 7).
    """
    return _downward_m3(d, y[6] * _series_sum(z, nmax), y)


@inline_kernel
def _downward_m3(d, j6, y):
    """J_5 .. J_0 from J_6 by the damping downward recurrence
    ``J_(j-1) = d J_j + Y^j / j`` (``y`` holds Y^1 .. Y^7). Returns J_0 .. J_6."""
    j5 = d * j6 + y[5] * _RECIP[6]
    j4 = d * j5 + y[4] * _RECIP[5]
    j3 = d * j4 + y[3] * _RECIP[4]
    j2 = d * j3 + y[2] * _RECIP[3]
    j1 = d * j2 + y[1] * _RECIP[2]
    j0 = d * j1 + y[0] * _RECIP[1]
    return j0, j1, j2, j3, j4, j5, j6


@inline_kernel
def _exact_m3(y):
    """J_0 .. J_6 for d = 0: ``Y^(j+1) / (j + 1)`` (``y`` holds Y^1 .. Y^7)."""
    return (y[0] * _RECIP[1], y[1] * _RECIP[2], y[2] * _RECIP[3], y[3] * _RECIP[4],
            y[4] * _RECIP[5], y[5] * _RECIP[6], y[6] * _RECIP[7])


@inline_kernel
def _moments_m3(Y, d, l, nmax, y):
    """:func:`_moments` for nmax = 6 on scalars: J_j = int_0^Y y^j / (1 - d y) dy,
    j = 0..6 (docs/math.md §2.4), with the same branches and operations.

    ``y`` holds Y^1 .. Y^7 (:func:`_powers_m3`); ``nmax`` (= 6) is passed, not
    folded, so that ``z ** nmax`` is the same power routine as the general path's.

    Returns
    -------
    tuple of 7 floats
        J_0 .. J_6.
    """
    z = d * Y
    if d == 0.0:
        return _exact_m3(y)
    if z <= 0.5 or z ** nmax <= 0.015625:
        return _moments_m3_series(d, z, nmax, y)
    j0 = math.log1p(d * l) / d
    j1 = (j0 - y[0] / 1) / d
    j2 = (j1 - y[1] / 2) / d
    j3 = (j2 - y[2] / 3) / d
    j4 = (j3 - y[3] / 4) / d
    j5 = (j4 - y[4] / 5) / d
    j6 = (j5 - y[5] / 6) / d
    return j0, j1, j2, j3, j4, j5, j6


@inline_kernel
def _grad_sums_m3(a, y, d):
    """:func:`_series`' gradient sums for m = 3, term by term in its order.

    ``a`` holds the coefficients of R^2 (:func:`_cube_m3`), ``y`` Y^1 .. Y^7.

    Returns
    -------
    h0, h1 : float
        ``sum_j [R^2]_j (Y^(j+1)/(j+1) - d Y^(j+2)/(j+2))`` and
        ``sum_j [R^2]_j Y^(j+2)/(j+2)``.
    """
    h0 = 0.0
    h1 = 0.0
    t1 = y[0] / 1
    t2 = y[1] / 2
    h0 += a[0] * (t1 - d * t2)
    h1 += a[0] * t2
    t1 = y[1] / 2
    t2 = y[2] / 3
    h0 += a[1] * (t1 - d * t2)
    h1 += a[1] * t2
    t1 = y[2] / 3
    t2 = y[3] / 4
    h0 += a[2] * (t1 - d * t2)
    h1 += a[2] * t2
    t1 = y[3] / 4
    t2 = y[4] / 5
    h0 += a[3] * (t1 - d * t2)
    h1 += a[3] * t2
    t1 = y[4] / 5
    t2 = y[5] / 6
    h0 += a[4] * (t1 - d * t2)
    h1 += a[4] * t2
    return h0, h1


@inline_kernel
def _dot_m3(b, J):
    """``sum_j [R^3]_j J_j``, j = 0..6, in order from 0.0 (as :func:`_series`)."""
    f = 0.0 + b[0] * J[0]
    f += b[1] * J[1]
    f += b[2] * J[2]
    f += b[3] * J[3]
    f += b[4] * J[4]
    f += b[5] * J[5]
    f += b[6] * J[6]
    return f


@inline_kernel
def _series_m3(Y, d, l, r0, r1, r2, m, grad):
    """:func:`_series` for the default kernel n = 6 (m = 3): the same
    operations in the same order on scalars (bit-identical results), without
    the work array and the per-degree loops. ``m`` (= 3) is passed, not
    folded, so that ``z ** nmax`` is the same power routine as the general path's.

    Returns
    -------
    f, h0, h1 : float
        As :func:`_series`.
    """
    y = _powers_m3(Y)
    a, b = _cube_m3(r0, r1, r2)
    f = _dot_m3(b, _moments_m3(Y, d, l, 2 * m, y))
    if not grad:
        return f, 0.0, 0.0
    h0, h1 = _grad_sums_m3(a, y, d)
    return f, h0, h1


@inline_kernel
def _from_entry(qx, qy, qz, perp2, ux, uy, uz, wu, taua, d, inv_s2):
    """``w = p - q(ta) = perp + wu u`` (``wu = e - lo``) from the local frame,
    and the coefficients of ``R`` in t about the support's entry: ``p0``,
    ``p1``, ``p2`` (docs/math.md §2.4). Returns ``wx, wy, wz, p0, p1, p2``."""
    wx = qx + wu * ux
    wy = qy + wu * uy
    wz = qz + wu * uz
    ww = perp2 + wu * wu
    p0 = 1.0 - ww * inv_s2 / (taua * taua)
    p1 = 2.0 * (d + wu * inv_s2 / taua)
    p2 = d * d - inv_s2
    return wx, wy, wz, p0, p1, p2


@unrefcounted_kernel
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
        Also compute the gradient. Callers pass a run-time bool
        (``bool(True)``, not ``True``): a literal is a type of its own to
        Numba and would compile this function once more (docs/development.md).
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
    wx, wy, wz, p0, p1, p2 = _from_entry(qx, qy, qz, perp2, ux, uy, uz, e - lo, taua, d, inv_s2)
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


# ---------------------------------------------------------------- lanes
# segment_eval for n = 6 on LANES segments at one point: the same operations
# in the same order, with selects where segment_eval branches, so that LLVM
# evaluates the lanes side by side in vector registers (no fastmath: every
# operation is the IEEE one segment_eval does, so every lane's result is its
# result, to the bit). Lanes segment_eval would send down a rarer branch
# (nested end balls, c2 >= 0; a moment series longer than the short form) are
# flagged for the caller to redo with segment_eval.

@inline_kernel
def lane_load(scratch, k, seg, i):
    """Put row ``i`` of the segment table in lane ``k`` of ``scratch``."""
    for c in range(NCOL):
        scratch[LANE_IN + c * LANES + k] = seg[i, c]


@inline_kernel
def lane_copy(scratch, k, j):
    """Copy lane ``k``'s segment to lane ``j``."""
    for c in range(NCOL):
        scratch[LANE_IN + c * LANES + j] = scratch[LANE_IN + c * LANES + k]


@inline_kernel
def lane_result(scratch, k):
    """``(f, gx, gy, gz, redo)`` of lane ``k`` after :func:`segment_lanes`;
    ``redo``: evaluate this segment with :func:`segment_eval` instead."""
    return (scratch[LANE_OUT + k], scratch[LANE_OUT + LANES + k], scratch[LANE_OUT + 2 * LANES + k],
            scratch[LANE_OUT + 3 * LANES + k], scratch[LANE_OUT + 4 * LANES + k] != 0.0)


@inline_kernel
def _lane_support(wx, wy, wz, ux, uy, uz, L, tau0, d, inv_s2):
    """:func:`_support_local` with ``_clip_cone`` (c2 < 0), branch-free.

    Returns ``to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o, empty``.
    """
    wu, qx, qy, qz, perp2 = _axial_parts(wx, wy, wz, ux, uy, uz)
    below = wu <= 0.0
    beyond = wu >= L
    to = 0.0 if below else (L if beyond else wu)
    e = wu if below else (wu - L if beyond else 0.0)
    tau_o, c2, h, c0, disc = _support_quadratic(tau0, d, to, e, wu, perp2, inv_s2)
    lo = -to
    hi = L - to
    sq = math.sqrt(disc if disc > 0.0 else 1.0)
    q = -(h + sq) if h >= 0.0 else -(h - sq)
    qq = q if q != 0.0 else 1.0
    r1 = qq / c2
    r2 = c0 / qq
    rlo = min(r1, r2)
    rhi = max(r1, r2)
    root_a = rlo > lo
    lo = rlo if root_a else lo
    root_b = rhi < hi
    hi = rhi if root_b else hi
    empty = disc <= 0.0 or q == 0.0 or not hi > lo
    return to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o, empty


@inline_kernel
def _lane_moments(Y, d):
    """:func:`_moments_m3`'s d = 0 and short-series branches, as a select:
    Y^1 .. Y^7 and J_0 .. J_6 (two tuples of 7)."""
    y = _powers_m3(Y)
    J = _downward_m3(d, y[6] * _short_sum(d * Y, 7), y)
    if d == 0.0:
        J = _exact_m3(y)
    return y, J


@inline_kernel
def _lane(scratch, k, px, py, pz, inv_s2, norm):
    """Lane ``k`` of :func:`segment_lanes`."""
    ux = scratch[LANE_IN + UX * LANES + k]
    uy = scratch[LANE_IN + UY * LANES + k]
    uz = scratch[LANE_IN + UZ * LANES + k]
    L = scratch[LANE_IN + LEN * LANES + k]
    tau0 = scratch[LANE_IN + TAU0 * LANES + k]
    d = scratch[LANE_IN + DELTA * LANES + k]
    to, e, lo, hi, root_a, root_b, qx, qy, qz, perp2, tau_o, empty = _lane_support(
        px - scratch[LANE_IN + AX * LANES + k], py - scratch[LANE_IN + AY * LANES + k],
        pz - scratch[LANE_IN + AZ * LANES + k], ux, uy, uz, L, tau0, d, inv_s2)
    # from here on, segment_eval's operations (see there)
    taua = tau_o + d * lo if root_a else tau0
    wx, wy, wz, p0, p1, p2 = _from_entry(qx, qy, qz, perp2, ux, uy, uz, e - lo, taua, d, inv_s2)
    if root_a:
        span = hi - lo if root_b else (L - to) - lo
    else:
        span = hi + to if root_b else L
    l = span / taua
    Y = l / (1.0 + d * l)
    p0 = 0.0 if root_a else p0
    r0 = p0
    r1 = p1 - 2.0 * d * p0
    r2 = p2 - d * p1 + d * d * p0
    Yd = Y if Y != 0.0 else 1.0
    r1 = -(r0 / Yd + r2 * Y) if root_b else r1
    a, b = _cube_m3(r0, r1, r2)
    y, J = _lane_moments(Y, d)
    f = _dot_m3(b, J)
    h0, h1 = _grad_sums_m3(a, y, d)
    f *= norm
    s = -2.0 * 3 * norm * inv_s2 / (taua * taua)
    gx = s * (wx * h0 - taua * ux * h1)
    gy = s * (wy * h0 - taua * uy * h1)
    gz = s * (wz * h0 - taua * uz * h1)
    # c2 >= 0: the lane's support clip is not segment_eval's (whose may be non-empty)
    redo = (not d * d - inv_s2 < 0.0) or (not empty and d * Y > SHORT_Z and d != 0.0)
    scratch[LANE_OUT + k] = 0.0 if empty else f
    scratch[LANE_OUT + LANES + k] = 0.0 if empty else gx
    scratch[LANE_OUT + 2 * LANES + k] = 0.0 if empty else gy
    scratch[LANE_OUT + 3 * LANES + k] = 0.0 if empty else gz
    scratch[LANE_OUT + 4 * LANES + k] = 1.0 if redo else 0.0


@unrefcounted_kernel
def segment_lanes(scratch, px, py, pz, inv_s2, norm):
    """:func:`segment_eval` (n = 6, with the gradient) of the segments loaded
    in lanes 0 .. LANES - 1 of ``scratch`` (:func:`lane_load`) at the point p
    (mm), side by side; read each with :func:`lane_result`. A lane flagged
    ``redo`` holds no value: its segment takes a branch the lanes do not
    (c2 >= 0, or ``d Y > SHORT_Z``). Every lane is computed, so unused ones
    must hold a valid row (a copy)."""
    for k in range(LANES):
        _lane(scratch, k, px, py, pz, inv_s2, norm)


#: lanes of :func:`segment_half_lanes`
HALF_LANES = LANES // 2


@unrefcounted_kernel
def segment_half_lanes(scratch, px, py, pz, inv_s2, norm):
    """:func:`segment_lanes` over lanes 0 .. HALF_LANES - 1 only."""
    for k in range(HALF_LANES):
        _lane(scratch, k, px, py, pz, inv_s2, norm)


@inline_kernel
def segment_first_lanes(scratch, k, px, py, pz, inv_s2, norm):
    """:func:`segment_lanes` of the first ``k`` loaded lanes (2 .. LANES):
    ``HALF_LANES`` or fewer in half the lanes, the unused lanes of the width
    evaluated repeating the first."""
    width = HALF_LANES if k <= HALF_LANES else LANES
    for j in range(k, width):
        lane_copy(scratch, 0, j)
    if width == HALF_LANES:
        segment_half_lanes(scratch, px, py, pz, inv_s2, norm)
    else:
        segment_lanes(scratch, px, py, pz, inv_s2, norm)
