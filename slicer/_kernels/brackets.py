"""Steps of the bracketed root solver of contour crossings
(:func:`slicer.contours.roots.solve_crossings`): where to evaluate next, and
the brackets narrowed by the values found there.

The solver keeps, per segment ``a -> b`` (parameter ``t`` in [0, 1]), a
bracket ``[lo, hi]`` with ``F − 1`` of value ``glo >= 0`` at ``lo`` and
``ghi < 0`` at ``hi`` (Illinois-scaled), and, with a slope bound, the interval
``[clo, chi]`` that the values prove the root in. The arrays travel as one
tuple, ``br = (lo, hi, glo, ghi, side, width1, width2, clo, chi, t)``, and only
the rows ``act`` (segments still open) are touched.
"""
from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel


@inline_kernel
def np_minimum(a, b):
    """``np.minimum`` of two floats: NaN if either is NaN."""
    if a != a or b != b:
        return np.nan
    return a if a <= b else b


@inline_kernel
def np_maximum(a, b):
    """``np.maximum`` of two floats: NaN if either is NaN."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@kernel
def bracket_points(act, br, tol_t, it, a, d):
    """The next point of each open segment: the secant point of its bracket
    kept ``tol_t / 2`` inside it, or the middle when two steps failed to halve
    the bracket (``it > 2``) or the secant point is not strictly inside.
    Shifts the bracket widths of the last two steps.

    Parameters
    ----------
    act : (k,) int64
        Open segments.
    br : tuple
        The solver's arrays (module docstring).
    tol_t : (n,) float64
        Tolerance as a fraction of each segment.
    it : int
        Iteration, from 1.
    a, d : (n, 3) float64, mm
        Segment starts and directions (``b − a``).

    Returns
    -------
    tm : (k,) float64
    points : (k, 3) float64, mm
    """
    lo, hi, glo, ghi, _, width1, width2, _, _, _ = br
    k = act.shape[0]
    tm = np.empty(k)
    pts = np.empty((k, 3))
    for j in range(k):
        i = act[j]
        l = lo[i]
        h = hi[i]
        gl = glo[i]
        w = h - l
        q = 0.5 * tol_t[i]
        ts = l + w * gl / (gl - ghi[i])           # gl >= 0 > gh: a point of [l, h]
        # tol/2 inside the bracket: near the root, the next step then lands on
        # the other side and closes the bracket to about tol
        ts = np_minimum(np_maximum(ts, l + q), h - q)
        if (w > 0.5 * width2[i] and it > 2) or not ts > l or not ts < h:
            ts = 0.5 * (l + h)
        width2[i] = width1[i]
        width1[i] = w
        tm[j] = ts
        for c in range(3):
            pts[j, c] = a[i, c] + ts * d[i, c]
    return tm, pts


@kernel
def bracket_update(act, tm, f, br, reach_t, length, tol, slack):
    """Narrow each open segment's bracket with the value ``f`` at ``tm``
    (Illinois: the stale end's value is halved when the same end moves
    twice), and with a slope bound (``reach_t`` finite: 1 / (slope × length))
    the interval the values prove the root in. A segment is finished when the
    value is exactly 1 or the bracket is at most ``tol`` long (``t``: the
    secant point of the final bracket), or when the proven interval is
    (``t``: its middle).

    Returns
    -------
    (k',) int64
        The segments still open.
    """
    lo, hi, glo, ghi, side, _, _, clo, chi, t = br
    k = act.shape[0]
    keep = np.empty(k, np.int64)
    nk = 0
    for j in range(k):
        i = act[j]
        m = tm[j]
        g = f[j] - 1.0
        up = g >= 0.0
        gl, gh = glo[i], ghi[i]
        if up:
            if side[i] == 1:
                gh = 0.5 * gh
            lo[i], glo[i], ghi[i], side[i] = m, g, gh, 1
        else:
            if side[i] == -1:
                gl = 0.5 * gl
            glo[i], hi[i], ghi[i], side[i] = gl, m, g, -1
        t[i] = m
        e = (abs(g) + slack * (1.0 + abs(f[j]))) * reach_t[i]
        chi[i] = np_minimum(chi[i], m + e if up else m)
        clo[i] = np_maximum(clo[i], m if up else m - e)
        lo2, hi2 = lo[i], hi[i]
        pr = (np_minimum(chi[i], hi2) - np_maximum(clo[i], lo2)) * length[i] <= tol
        exact = g == 0.0
        done = exact or (hi2 - lo2) * length[i] <= tol
        if pr and not done:
            t[i] = 0.5 * (np_minimum(chi[i], hi2) + np_maximum(clo[i], lo2))
        if done and not exact:
            # secant point of the final bracket (Illinois-scaled values keep their signs)
            ts = lo2 + (hi2 - lo2) * glo[i] / (glo[i] - ghi[i])
            t[i] = np_minimum(np_maximum(ts, lo2), hi2)
        if not (done or pr):
            keep[nk] = i
            nk += 1
    return keep[:nk].copy()
