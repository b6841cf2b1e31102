"""Independent, slow reference for the SIIS field of one tapered segment.

This module deliberately shares **no code** with :mod:`slicer` (it must not
import it).  It lives in :mod:`validation` so the stiff-case suite
(:mod:`validation.stiff`) and the tests (``tests/reference.py`` re-exports it)
use the same reference.  It evaluates the definition (docs/math.md §1.1)

    f(p) = ∫_S (1/τ(q)) k(‖p − q‖ / τ(q)) dq,    k(d) = N (1 − (d/σ)²)^(n/2)

by brute-force Gauss–Legendre quadrature in the *original* variable (arc length
along the segment, uniform parametrisation ``q(s) = a + s (b − a)``,
``dq = L ds``), in numpy extended precision (``np.longdouble``, 64-bit
mantissa on x86-64), vectorised over many configurations at once.

How each piece is made accurate to the 1e-13 level:

* **Support interval.**  ``h(s) = ‖p − q(s)‖ − σ τ(s)`` is convex in ``s`` (a
  norm of an affine map minus an affine map), so the support set
  ``{s ∈ [0, 1] : h(s) < 0}`` is one interval.  It is found without any
  algebra: golden-section search for the minimiser of ``h`` on [0, 1], then
  bisection for each end on each side.  The integrand vanishes to order
  ``n/2`` at a support root, so an error ε in a root changes ``f`` by O(ε^(n/2+1)).
* **Quadrature.**  On the clipped interval the integrand is analytic (it equals
  ``N P(t)^m / τ^(n+1)`` with ``P`` a polynomial); its only singularity is the
  pole at the cone apex τ = 0, outside the interval.  The interval is split
  geometrically so that τ varies by at most a factor ``ratio`` (default 1.2)
  on each piece, and each piece gets an ``npts``-point rule (default 24).  The
  apex is then ≥ ~11 half-widths away from each piece: the rule converges like
  22^(−2·npts), far below rounding.
* **Nodes and weights** of the Gauss–Legendre rule are refined by Newton's
  method in extended precision.

The gradient is computed in the same pass by differentiating under the
integral sign (the boundary terms vanish because the kernel is zero at a
support root and the clip at the segment ends does not depend on ``p``):

    ∇f(p) = ∫ (1/τ²) k′(d) (p − q)/‖p − q‖ dq = −(N n / σ²) ∫ (1 − d²/σ²)^(m−1) (p − q) / τ³ dq
"""
from __future__ import annotations

import math

import numpy as np

LD = np.longdouble

#: default kernel (docs/math.md §1.2): degree 6, support factor 2
DEGREE = 6
SIGMA = 2.0


def normalisation(degree: int = DEGREE, sigma: float = SIGMA) -> float:
    """N putting the iso-value 1 at distance τ of an infinite strut (docs/math.md §1.3),
    written with the Gamma function: B_m = √π Γ(m+1) / Γ(m+3/2)."""
    m = degree / 2
    b_m = math.sqrt(math.pi) * math.gamma(m + 1) / math.gamma(m + 1.5)
    return 1.0 / (sigma * b_m * (1.0 - 1.0 / sigma**2) ** ((degree + 1) / 2))


# --------------------------------------------------------------------------- Gauss–Legendre
_GL_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def gauss_legendre(npts: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights on [-1, 1] in extended precision (Newton-polished)."""
    hit = _GL_CACHE.get(npts)
    if hit is not None:
        return hit
    x0, _ = np.polynomial.legendre.leggauss(npts)
    x = x0.astype(LD)
    for _ in range(4):
        p0 = np.ones_like(x)
        p1 = x.copy()
        for k in range(2, npts + 1):
            p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
        dp = npts * (x * p1 - p0) / (x * x - 1)
        x = x - p1 / dp
    p0 = np.ones_like(x)
    p1 = x.copy()
    for k in range(2, npts + 1):
        p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
    dp = npts * (x * p1 - p0) / (x * x - 1)
    w = 2 / ((1 - x * x) * dp * dp)
    _GL_CACHE[npts] = (x, w)
    return x, w


# --------------------------------------------------------------------------- helpers
def _prep(a, b, tau_a, tau_b, p):
    """Broadcast the inputs to (k, 3) / (k,) extended-precision arrays, local to a."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    tau_a = np.asarray(tau_a, dtype=np.float64)
    tau_b = np.asarray(tau_b, dtype=np.float64)
    k = np.broadcast_shapes(a.shape[:-1], b.shape[:-1], p.shape[:-1], tau_a.shape, tau_b.shape)
    a = np.broadcast_to(a, k + (3,)).reshape(-1, 3).astype(LD)
    b = np.broadcast_to(b, k + (3,)).reshape(-1, 3).astype(LD)
    p = np.broadcast_to(p, k + (3,)).reshape(-1, 3).astype(LD)
    t0 = np.broadcast_to(tau_a, k).reshape(-1).astype(LD)
    t1 = np.broadcast_to(tau_b, k).reshape(-1).astype(LD)
    # the double inputs are exact; the difference of two doubles within a
    # factor 2 of each other is exact, so w and D carry no rounding in offset
    # scenes (otherwise one extended-precision rounding, 1e-19 relative)
    w = p - a
    D = b - a
    return k, w, D, t0, t1


def _margin(s, w, D, t0, t1, sigma):
    """h(s) = ‖p − q(s)‖ − σ τ(s), vectorised over rows (s has shape (k,))."""
    r = w - s[:, None] * D
    return np.sqrt(np.sum(r * r, axis=1)) - sigma * (t0 + s * (t1 - t0))


def _support(w, D, t0, t1, sigma, iters_golden=100, iters_bisect=80):
    """Clipped support interval [s0, s1] ⊂ [0, 1] (in the segment parameter).

    Returns s0, s1, nonempty, hmin.
    """
    k = w.shape[0]
    sig = LD(sigma)
    lo = np.zeros(k, dtype=LD)
    hi = np.ones(k, dtype=LD)
    g = (np.sqrt(LD(5)) - 1) / 2          # 0.618...
    for _ in range(iters_golden):
        # golden-section step on the convex h (both probes re-evaluated: simple, cheap)
        x1 = hi - g * (hi - lo)
        x2 = lo + g * (hi - lo)
        left = _margin(x1, w, D, t0, t1, sig) <= _margin(x2, w, D, t0, t1, sig)
        hi = np.where(left, x2, hi)          # minimiser in [lo, x2]
        lo = np.where(left, lo, x1)          # minimiser in [x1, hi]
    cand = np.stack([lo, hi, (lo + hi) / 2, np.zeros(k, LD), np.ones(k, LD)], axis=1)
    hv = np.stack([_margin(cand[:, j], w, D, t0, t1, sig) for j in range(cand.shape[1])], axis=1)
    j = np.argmin(hv, axis=1)
    smin = cand[np.arange(k), j]
    hmin = hv[np.arange(k), j]
    inside = hmin < 0
    # left end: h(0) < 0 → clip at 0, else bisect on [0, smin] (h(0) >= 0 > h(smin))
    h0 = _margin(np.zeros(k, LD), w, D, t0, t1, sig)
    h1 = _margin(np.ones(k, LD), w, D, t0, t1, sig)
    a_lo = np.zeros(k, LD)
    a_hi = smin.copy()
    b_lo = smin.copy()
    b_hi = np.ones(k, LD)
    for _ in range(iters_bisect):
        am = (a_lo + a_hi) / 2
        ha = _margin(am, w, D, t0, t1, sig)
        a_hi = np.where(ha < 0, am, a_hi)
        a_lo = np.where(ha < 0, a_lo, am)
        bm = (b_lo + b_hi) / 2
        hb = _margin(bm, w, D, t0, t1, sig)
        b_lo = np.where(hb < 0, bm, b_lo)
        b_hi = np.where(hb < 0, b_hi, bm)
    s0 = np.where(h0 < 0, LD(0), a_hi)
    s1 = np.where(h1 < 0, LD(1), b_lo)
    return s0, s1, inside & (s1 > s0), hmin


def support_interval(a, b, tau_a, tau_b, p, sigma: float = SIGMA):
    """Arc-length support interval [t0, t1] ⊂ [0, L] of p, measured from ``a``.

    Returns
    -------
    t0, t1 : float64 arrays (NaN where empty)
    """
    _, w, D, t0, t1 = _prep(a, b, tau_a, tau_b, p)
    s0, s1, ok, _ = _support(w, D, t0, t1, sigma)
    L = np.sqrt(np.sum(D * D, axis=1))
    ta = np.where(ok, s0 * L, np.nan).astype(np.float64)
    tb = np.where(ok, s1 * L, np.nan).astype(np.float64)
    return ta, tb


def homothetic_margin(a, b, tau_a, tau_b, p, sigma: float = SIGMA):
    """min_s (‖p − q(s)‖ − σ τ(s)) over the segment: < 0 inside the support."""
    _, w, D, t0, t1 = _prep(a, b, tau_a, tau_b, p)
    return _support(w, D, t0, t1, sigma, iters_bisect=0)[3].astype(np.float64)


# --------------------------------------------------------------------------- field
def segment_field(a, b, tau_a, tau_b, p, degree: int = DEGREE, sigma: float = SIGMA,
                  norm: float | None = None, gradient: bool = False,
                  npts: int = 24, ratio: float = 1.2, chunk: int = 4096):
    """Field (and gradient) of segments a→b with end radii tau_a, tau_b at points p.

    All array arguments broadcast against each other (``a, b, p`` have a
    trailing axis of 3).

    Returns
    -------
    f : float64 array of the broadcast shape
    g : float64 array (..., 3), only if ``gradient``
    """
    if norm is None:
        norm = normalisation(degree, sigma)
    shape, w, D, t0, t1 = _prep(a, b, tau_a, tau_b, p)
    k = w.shape[0]
    f = np.zeros(k, dtype=LD)
    g = np.zeros((k, 3), dtype=LD)
    for c0 in range(0, k, chunk):
        sl = slice(c0, min(k, c0 + chunk))
        fc, gc = _field_rows(w[sl], D[sl], t0[sl], t1[sl], degree, sigma, norm, gradient, npts, ratio)
        f[sl] = fc
        g[sl] = gc
    f = f.astype(np.float64).reshape(shape)
    if gradient:
        return f, g.astype(np.float64).reshape(shape + (3,))
    return f


def _field_rows(w, D, t0, t1, degree, sigma, norm, gradient, npts, ratio):
    k = w.shape[0]
    m = degree // 2
    sig2 = LD(sigma) ** 2
    nrm = LD(norm)
    s0, s1, ok, _ = _support(w, D, t0, t1, sigma)
    L = np.sqrt(np.sum(D * D, axis=1))
    f = np.zeros(k, dtype=LD)
    g = np.zeros((k, 3), dtype=LD)
    ta = t0 + s0 * (t1 - t0)
    tb = t0 + s1 * (t1 - t0)
    logr = np.zeros(k, dtype=LD)
    logr[ok] = np.log(tb[ok] / ta[ok])
    npiece = np.ones(k, dtype=np.int64)
    npiece[ok] = np.maximum(1, np.ceil(np.abs(logr[ok]) / math.log(ratio) - 1e-9)).astype(np.int64)
    xg, wg = gauss_legendre(npts)
    for K in np.unique(npiece[ok]):
        rows = np.nonzero(ok & (npiece == K))[0]
        lr = logr[rows][:, None]
        frac = np.arange(K + 1, dtype=LD)[None, :] / K
        tiny = np.abs(lr) < LD(1e-30)
        # geometric break points in τ: (s - s0)/(s1 - s0) = expm1(j/K log r)/expm1(log r)
        den = np.where(tiny, LD(1), np.expm1(lr))
        geo = np.where(tiny, frac, np.expm1(frac * lr) / den)
        geo[:, 0] = 0
        geo[:, -1] = 1
        sa = s0[rows][:, None]
        sb = s1[rows][:, None]
        br = sa + (sb - sa) * geo                           # (r, K+1)
        left = br[:, :-1, None]
        half = (br[:, 1:, None] - br[:, :-1, None]) / 2     # (r, K, 1)
        s = left + half * (1 + xg[None, None, :])           # (r, K, npts)
        wq = half * wg[None, None, :]
        tau = t0[rows][:, None, None] + s * (t1 - t0)[rows][:, None, None]
        rv = w[rows][:, None, None, :] - s[..., None] * D[rows][:, None, None, :]
        d2 = np.sum(rv * rv, axis=-1) / (tau * tau)
        x = np.maximum(1 - d2 / sig2, 0)
        Lr = L[rows][:, None, None]
        f[rows] = nrm * np.sum(wq * Lr * x**m / tau, axis=(1, 2))
        if gradient:
            xm1 = x ** (m - 1) if m > 1 else (x > 0).astype(LD)
            coef = wq * Lr * xm1 / tau**3
            g[rows] = -(nrm * degree / sig2) * np.sum(coef[..., None] * rv, axis=(1, 2))
    return f, g


def skeleton_field(nodes, segments, radii, points, degree: int = DEGREE, sigma: float = SIGMA,
                   gradient: bool = False):
    """Brute-force sum of :func:`segment_field` over all segments.

    The only pruning is a mathematically certain one, written independently
    of any grid: a segment contributes nothing at p when the distance from p
    to the segment exceeds σ·max(τa, τb) (every support ball lies within that
    distance of the segment).  The test is padded by a relative 1e-6.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    segments = np.asarray(segments)
    radii = np.asarray(radii, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a = nodes[segments[:, 0]]
    b = nodes[segments[:, 1]]
    D = b - a
    LL = np.sum(D * D, axis=1)
    reach = sigma * radii.max(axis=1)
    pi, si = [], []
    for c0 in range(0, points.shape[0], 256):
        p = points[c0:c0 + 256, None, :]
        s = np.clip(np.sum((p - a) * D, axis=2) / LL, 0.0, 1.0)
        dist = np.linalg.norm(p - (a + s[..., None] * D), axis=2)
        ii, jj = np.nonzero(dist <= reach * (1 + 1e-6) + 1e-12 * np.abs(p).max(axis=2))
        pi.append(ii + c0)
        si.append(jj)
    pi = np.concatenate(pi)
    si = np.concatenate(si)
    f = np.zeros(points.shape[0])
    g = np.zeros((points.shape[0], 3))
    if pi.size:
        out = segment_field(a[si], b[si], radii[si, 0], radii[si, 1], points[pi], degree, sigma,
                            gradient=gradient)
        if gradient:
            np.add.at(f, pi, out[0])
            np.add.at(g, pi, out[1])
        else:
            np.add.at(f, pi, out)
    return (f, g) if gradient else f


__all__ = ["normalisation", "gauss_legendre", "support_interval", "homothetic_margin",
           "segment_field", "skeleton_field", "DEGREE", "SIGMA"]
