"""Ray versus one segment's support: entry/exit, the pre-segmentation cut and
the data of the per-primitive directional Lipschitz bound (docs/math.md §3, §4.2).

The ray is ``r(t) = o + t d`` with ``|d| = 1``. All quantities are computed
from components perpendicular to ``d`` taken explicitly, so an axis-aligned
ray (slicing: ``d = e_z``) has no cancellation at all.
"""
from __future__ import annotations

import math

from slicer._jit import inline_kernel, unrefcounted_kernel
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ

# layout of the per-hit record written by ray_support into a row of ``hrec``
H_TIN, H_TOUT, H_TSTAR, H_LIP, H_S0, H_S1, H_TP0, H_TP1, H_FMAX, H_REACH = range(10)
NHIT = 10


@unrefcounted_kernel
def kprime_abs(x, n, sigma, norm):
    """|k'(x)| of the kernel k(x) = N (1 - x^2/sigma^2)^(n/2)."""
    if x >= sigma:
        return 0.0
    a = 1.0 - x * x / (sigma * sigma)
    return norm * n * x / (sigma * sigma) * a ** (n // 2 - 1)


@unrefcounted_kernel
def kprime_max(n, sigma, norm):
    """max |k'| = (n/sqrt(n-1)) (1 - 1/(n-1))^(n/2-1) N/sigma (EG22, docs/math.md §1.3)."""
    if n == 2:
        return 2.0 * norm / sigma
    return n / math.sqrt(n - 1.0) * (1.0 - 1.0 / (n - 1.0)) ** (n // 2 - 1) * norm / sigma


@unrefcounted_kernel
def _quad_neg_interval(A, B, C):
    """Sub-interval of [0, 1] where A s^2 + 2 B s + C < 0, assuming the
    valid branch is the one on the growing-radius side when A < 0.

    Returns (s0, s1); empty when s1 <= s0.
    """
    disc = B * B - A * C
    if A > 0.0:
        if disc <= 0.0:
            return 0.0, -1.0
        sq = math.sqrt(disc)
        q = -(B + sq) if B >= 0.0 else -(B - sq)
        if q == 0.0:
            return 0.0, -1.0
        r1 = q / A
        r2 = C / q
        return max(0.0, min(r1, r2)), min(1.0, max(r1, r2))
    if A < 0.0:
        if disc <= 0.0:
            return 0.0, 1.0
        sq = math.sqrt(disc)
        q = -(B + sq) if B >= 0.0 else -(B - sq)
        if q == 0.0:
            return 0.0, 1.0
        rhi = max(q / A, C / q)
        return max(0.0, rhi), 1.0
    if B > 0.0:
        return 0.0, min(1.0, -C / (2.0 * B))
    if B < 0.0:
        return max(0.0, -C / (2.0 * B)), 1.0
    if C < 0.0:
        return 0.0, 1.0
    return 0.0, -1.0


@inline_kernel
def _ray_frame(seg, i, ox, oy, oz, dx, dy, dz):
    """Segment ``i`` seen from the ray ``o + t d``: projections on d and the
    dot products of the parts perpendicular to d (docs/math.md §3.1).

    With w = a - o and D = b - a = L u, the parts perpendicular to d are taken
    explicitly (exact for axis-aligned rays), so that the squared distance of
    q(s) = a + s D to the ray line is ``Ap s^2 + 2 Bp s + Cp``.

    Returns
    -------
    wd, Dd : float
        w.d and D.d (mm): the projection of q(s) on the ray is ``wd + s Dd``.
    Ap, Bp, Cp : float
        |D_perp|^2, w_perp.D_perp, |w_perp|^2 (mm^2).
    """
    L = seg[i, LEN]
    Dx = L * seg[i, UX]
    Dy = L * seg[i, UY]
    Dz = L * seg[i, UZ]
    wx = seg[i, AX] - ox
    wy = seg[i, AY] - oy
    wz = seg[i, AZ] - oz
    wd = wx * dx + wy * dy + wz * dz
    Dd = Dx * dx + Dy * dy + Dz * dz
    # perpendicular parts (exact for axis-aligned rays)
    wpx = wx - wd * dx
    wpy = wy - wd * dy
    wpz = wz - wd * dz
    Dpx = Dx - Dd * dx
    Dpy = Dy - Dd * dy
    Dpz = Dz - Dd * dz
    Ap = Dpx * Dpx + Dpy * Dpy + Dpz * Dpz
    Bp = wpx * Dpx + wpy * Dpy + wpz * Dpz
    Cp = wpx * wpx + wpy * wpy + wpz * wpz
    return wd, Dd, Ap, Bp, Cp


@inline_kernel
def _stationary_point(k, A, B, C, Dd, E):
    """Root ``k`` (0 or 1) of A E s^2 + 2 B E s + (B^2 + Dd^2 C) = 0: the
    stationary points of the entry/exit t_c(s) -/+ sqrt(-Q(s)) (docs/math.md §3.2).

    Returns
    -------
    ok : bool
        Whether that root is a candidate (false: no such root).
    s : float
        The root (skeleton parameter).
    """
    a2 = A * E
    b2 = B * E
    c2 = B * B + Dd * Dd * C
    if a2 == 0.0:
        if k == 1 or b2 == 0.0:
            return False, 0.0
        return True, -c2 / (2.0 * b2)
    disc = b2 * b2 - a2 * c2
    if disc < 0.0:
        # a double root pushed negative by rounding (e.g. a strut
        # perpendicular to the ray): the vertex is the extremum.
        # Any s in [s0, s1] is a real point of the support, so an
        # extra candidate can never make the interval unsound.
        if k == 1:
            return False, 0.0
        disc = 0.0
    # stable roots q / a2 and c2 / q: with A ~ 0 (the ray along a
    # generator of the support cone) the textbook (-b2 + sq) / a2
    # cancels to 0 and the real stationary point was lost
    sq = math.sqrt(disc)
    qq = -(b2 + sq) if b2 >= 0.0 else -(b2 - sq)
    if qq == 0.0:
        if k == 1:
            return False, 0.0
        return True, 0.0
    return True, (qq / a2 if k == 0 else c2 / qq)


@inline_kernel
def _widen(A, B, C, wd, Dd, s, t_in, t_out):
    """[t_in, t_out] widened to the chord of the ray through the support ball
    of q(s): t_c(s) -/+ sqrt(-Q(s)), Q(s) = A s^2 + 2 B s + C clamped to <= 0.

    Returns
    -------
    t_in, t_out : float
    """
    q = -((A * s + 2.0 * B) * s + C)
    if q < 0.0:
        q = 0.0
    r = math.sqrt(q)
    tc = wd + s * Dd
    if tc - r < t_in:
        t_in = tc - r
    if tc + r > t_out:
        t_out = tc + r
    return t_in, t_out


@inline_kernel
def _entry_exit(A, B, C, wd, Dd, s0, s1):
    """Entry and exit of the ray through the support: the extremes of
    t_c(s) -/+ sqrt(-Q(s)) over [s0, s1] (docs/math.md §3.2), unpadded.

    Returns
    -------
    hit : bool
        False when the support (a ball at the thick end) misses the ray.
    t_in, t_out : float
    """
    E = A + Dd * Dd
    if E <= 0.0:
        # nested end balls: the support is the ball at the thick end (s = 1)
        q = -(A + 2.0 * B + C)
        if q <= 0.0:
            return False, math.inf, -math.inf
        r = math.sqrt(q)
        return True, wd + Dd - r, wd + Dd + r
    t_in = math.inf
    t_out = -math.inf
    # candidates: the ends s0, s1 of S, then the stationary points inside it
    t_in, t_out = _widen(A, B, C, wd, Dd, s0, t_in, t_out)
    t_in, t_out = _widen(A, B, C, wd, Dd, s1, t_in, t_out)
    for k in range(2):
        ok, s = _stationary_point(k, A, B, C, Dd, E)
        if ok and s > s0 and s < s1:
            t_in, t_out = _widen(A, B, C, wd, Dd, s, t_in, t_out)
    return True, t_in, t_out


@inline_kernel
def _cut(Ap, Bp, Cp, tau0, dtau):
    """Pre-segmentation cut: the skeleton parameter of least homothetic
    distance |q(s) - line|^2 / tau(s)^2 over s in [0, 1] (docs/math.md §3.3).

    Returns
    -------
    best_s : float
        Its argmin s (0, 1 or the interior stationary point).
    best_r : float
        The least squared homothetic distance (dimensionless).
    """
    best_s = 0.0
    best_r = Cp / (tau0 * tau0)
    t1 = tau0 + dtau
    r1 = (Ap + 2.0 * Bp + Cp) / (t1 * t1)
    if r1 < best_r:
        best_s = 1.0
        best_r = r1
    den = Ap * tau0 - Bp * dtau
    if den != 0.0:
        ss = (dtau * Cp - Bp * tau0) / den
        if ss > 0.0 and ss < 1.0:
            ts = tau0 + ss * dtau
            rs = ((Ap * ss + 2.0 * Bp) * ss + Cp) / (ts * ts)
            if rs < best_r:
                best_s = ss
                best_r = rs
    return best_s, best_r


@inline_kernel
def _lipschitz_factor(xmin, n, sigma, norm, kmax, L, tmin):
    """Per-primitive Lipschitz factor K' L / tau(s0)^2 (docs/math.md §4.1, §4.2).

    K' bounds |k'(x)| for x >= ``xmin``: ``kmax`` up to the inflection point
    sigma / sqrt(n - 1), |k'(xmin)| beyond; ``tmin`` = tau(s0) (mm).
    """
    if xmin <= sigma / math.sqrt(n - 1.0):
        kp = kmax
    else:
        kp = kprime_abs(xmin, n, sigma, norm)
    return kp * L / (tmin * tmin)


@inline_kernel
def _field_bound(xmin, n, sigma, norm, L, s0, s1, tmin):
    """Upper bound of the field anywhere on the ray (docs/math.md §3.3): every
    skeleton point q(s), s in [s0, s1], is at homothetic distance >= ``xmin``,
    so f <= k(xmin) * int ds L / tau(s) <= k(xmin) L (s1 - s0) / tau(s0)
    (``tmin`` = tau(s0)), padded by 1e-12 relative.
    """
    if xmin >= sigma:
        return 0.0
    kx = norm * (1.0 - xmin * xmin / (sigma * sigma)) ** (n // 2)
    return kx * L * (s1 - s0) / tmin * (1.0 + 1e-12)


@unrefcounted_kernel
def ray_support(seg, i, ox, oy, oz, dx, dy, dz, n, sigma, norm, kmax, hrec, row):
    """Intersect ray ``o + t d`` with the support of segment ``i``.

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table (:mod:`slicer._kernels.field.segment`).
    i : int
    ox, oy, oz, dx, dy, dz : float
        Ray origin (mm) and unit direction.
    n : int
        Kernel degree; ``sigma``, ``norm``: support factor and normalisation.
    kmax : float
        max |k'| (:func:`kprime_max`).
    hrec : (nh, NHIT) float64
        Hit records; row ``row`` is filled on a hit: t_in, t_out (padded outward), t* (cut), Lipschitz
        factor C (so that |f'| <= C * max(|D+|, |D-|) on a piece), skeleton
        range s0, s1, the projection t_proj(s) = tp0 + s tp1, fmax, an
        upper bound of the field anywhere on the ray, and the reach
        sigma * tau(s1): no q(s) with |t_proj(s) - t| >= reach is in the
        support of r(t).

    Returns
    -------
    bool
        Whether the ray meets the (open) support.
    """
    L = seg[i, LEN]
    tau0 = seg[i, TAU0]
    dtau = seg[i, DELTA] * L
    wd, Dd, Ap, Bp, Cp = _ray_frame(seg, i, ox, oy, oz, dx, dy, dz)
    # skeleton range S = [s0, s1] whose support ball meets the line: Q(s) < 0
    s2 = sigma * sigma
    A = Ap - s2 * dtau * dtau
    B = Bp - s2 * tau0 * dtau
    C = Cp - s2 * tau0 * tau0
    s0, s1 = _quad_neg_interval(A, B, C)
    if not s1 > s0:
        return False
    hit, t_in, t_out = _entry_exit(A, B, C, wd, Dd, s0, s1)
    if not hit:
        return False
    # padded outward, far above the rounding (docs/math.md §3.2)
    pad = 1e-9 * (abs(t_in) + abs(t_out) + L + sigma * (tau0 + dtau))
    hrec[row, H_TIN] = t_in - pad
    hrec[row, H_TOUT] = t_out + pad
    # pre-segmentation cut t* and the least homothetic distance x_min (§3.3)
    best_s, best_r = _cut(Ap, Bp, Cp, tau0, dtau)
    hrec[row, H_TSTAR] = wd + best_s * Dd
    xmin = math.sqrt(max(best_r, 0.0))
    tmin = tau0 + s0 * dtau
    hrec[row, H_LIP] = _lipschitz_factor(xmin, n, sigma, norm, kmax, L, tmin)
    hrec[row, H_FMAX] = _field_bound(xmin, n, sigma, norm, L, s0, s1, tmin)
    hrec[row, H_S0] = s0
    hrec[row, H_S1] = s1
    hrec[row, H_TP0] = wd
    hrec[row, H_TP1] = Dd
    # tau grows with s (table orientation), so tau(s1) is the largest radius on S;
    # padded far beyond the rounding of the t_proj(s) = t solves in lipschitz()
    hrec[row, H_REACH] = sigma * (tau0 + s1 * dtau) * (1.0 + 1e-9) + 1e-9 * (abs(wd) + abs(Dd))
    return True


@unrefcounted_kernel
def lipschitz(hrec, r, ta, tb):
    """Bound on |f'(t)| for t in [ta, tb] from a hit record (docs/math.md §4.2).

    D+ (D-) is the part of the skeleton range that lies ahead of (behind) some
    point of the piece. Only skeleton points whose support reaches the piece
    count: q(s) acts on r(t) only if |t_proj(s) - t| < sigma tau(s) <= reach,
    so D+ is also cut at t_proj < tb + reach and D- at t_proj > ta - reach.
    Without that cut a ray running along a long strut's axis would charge the
    whole strut to every piece (bound ~ L instead of ~ sigma tau).

    Parameters
    ----------
    hrec : (nh, NHIT) float64
        Hit records; row ``r`` was filled by :func:`ray_support` (a row
        index rather than a row view: a view costs atomic reference counting
        in this hot path).
    ta, tb : float
        Piece of the ray.
    """
    s0 = hrec[r, H_S0]
    s1 = hrec[r, H_S1]
    tp0 = hrec[r, H_TP0]
    tp1 = hrec[r, H_TP1]
    R = hrec[r, H_REACH]
    # |D+| = |{s in S : ta < tp(s) < tb + R}|, |D-| = |{s in S : ta - R < tp(s) < tb}|
    if tp1 != 0.0:
        # skeleton parameters s whose projection tp0 + s tp1 is ta, tb, ta - R, tb + R
        sa = (ta - tp0) / tp1
        sb = (tb - tp0) / tp1
        sa_r = (ta - R - tp0) / tp1
        sb_r = (tb + R - tp0) / tp1
        if tp1 > 0.0:
            dp = min(s1, sb_r) - max(s0, sa)
            dm = min(s1, sb) - max(s0, sa_r)
        else:
            dp = min(s1, sa) - max(s0, sb_r)
            dm = min(s1, sa_r) - max(s0, sb)
    else:
        dp = (s1 - s0) if (tp0 > ta and tp0 < tb + R) else 0.0
        dm = (s1 - s0) if (tp0 < tb and tp0 > ta - R) else 0.0
    w = max(dp, dm)
    if w < 0.0:
        w = 0.0
    if w > s1 - s0:
        w = s1 - s0
    return hrec[r, H_LIP] * w
