"""Steps of the bracketed root solver of contour crossings
(:mod:`slicer._kernels.contours.crossings`): the starting bracket, where to evaluate
next, and the bracket narrowed by the value found there.

The solver keeps, per segment ``a -> b`` (parameter ``t`` in [0, 1]), a
bracket ``[lo, hi]`` with ``F − 1`` of value ``glo >= 0`` at ``lo`` and
``ghi < 0`` at ``hi`` (Illinois-scaled), and, with a slope bound, the interval
``[clo, chi]`` that the values prove the root in. A segment's state travels
as one tuple of floats, ``state = (lo, hi, glo, ghi, side, width1, width2,
clo, chi, t)`` (``side``: the end moved last, +1 lo, −1 hi, 0 none; the
widths: the bracket's one and two steps ago; ``t``: the answer so far).
"""
from __future__ import annotations

import numpy as np

from slicer._jit import inline_kernel


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


@inline_kernel
def bracket_start(fa, fb, length, tol, reach_t, slack):
    """The starting state of a segment of ``length`` mm with the field ``fa``
    at its inside end and ``fb`` at its outside end.

    ``reach_t`` is ``1 / (slope × length)`` where a lower bound ``slope`` of
    ``|dF/dl|`` holds along the segment, else inf: a value ``F`` then proves
    the root within ``(|F − 1| + ε) reach_t`` of its point (ε = ``slack (1 +
    |F|)``, the evaluation's error budget).

    Returns
    -------
    state : tuple
        (module docstring); ``t`` is the answer when no step is needed: the
        end whose value is nearer 1 where ``F(a) >= 1 > F(b)`` fails, the
        inside end where ``F(a) = 1``, the middle of the proven interval, or
        the segment's middle.
    bracketed : bool
        ``F(a) >= 1 > F(b)``.
    open : bool
        Steps are needed: bracketed, longer than ``tol`` and not proven.
    """
    glo = fa - 1.0
    ghi = fb - 1.0
    bracketed = glo >= 0.0 and ghi < 0.0
    t = 0.0 if abs(glo) <= abs(ghi) else 1.0
    ea = (abs(glo) + slack * (1.0 + abs(fa))) * reach_t
    eb = (abs(ghi) + slack * (1.0 + abs(fb))) * reach_t
    chi = np_minimum(1.0, ea)
    clo = np_maximum(0.0, 1.0 - eb)
    proved = bracketed and (chi - clo) * length <= tol
    if bracketed:
        t = 0.0 if glo == 0.0 else 0.5
    if proved and length > tol and glo != 0.0:
        t = 0.5 * (clo + chi)
    state = (0.0, 1.0, glo, ghi, 0.0, 1.0, 1.0, clo, chi, t)
    return state, bracketed, bracketed and length > tol and not proved


@inline_kernel
def bracket_next(state, tol_t, it):
    """The next point of an open segment: the secant point of its bracket
    kept ``tol_t / 2`` inside it (``tol_t``: the tolerance as a fraction of
    the segment), or the middle when two steps failed to halve the bracket
    (iteration ``it > 2``, from 1) or the secant point is not strictly
    inside. Shifts the bracket widths of the last two steps.

    Returns
    -------
    tm : float
    state : tuple
    """
    lo, hi, glo, ghi, side, width1, width2, clo, chi, t = state
    w = hi - lo
    q = 0.5 * tol_t
    ts = lo + w * glo / (glo - ghi)            # glo >= 0 > ghi: a point of [lo, hi]
    # tol/2 inside the bracket: near the root, the next step then lands on
    # the other side and closes the bracket to about tol
    ts = np_minimum(np_maximum(ts, lo + q), hi - q)
    if (w > 0.5 * width2 and it > 2) or not ts > lo or not ts < hi:
        ts = 0.5 * (lo + hi)
    return ts, (lo, hi, glo, ghi, side, w, width1, clo, chi, t)


@inline_kernel
def bracket_narrow(state, m, f, reach_t, length, tol, slack):
    """The bracket narrowed with the value ``f`` at ``m`` (Illinois: the
    stale end's value is halved when the same end moves twice), and the
    interval the values prove the root in (``reach_t`` as for
    :func:`bracket_start`). A segment is finished when the value is exactly
    1 or the bracket is at most ``tol`` long (``t``: the secant point of the
    final bracket), or when the proven interval is (``t``: its middle).

    Returns
    -------
    state : tuple
    open : bool
    """
    lo, hi, glo, ghi, side, width1, width2, clo, chi, t = state
    g = f - 1.0
    up = g >= 0.0
    if up:
        if side == 1.0:
            ghi = 0.5 * ghi
        lo, glo, side = m, g, 1.0
    else:
        if side == -1.0:
            glo = 0.5 * glo
        hi, ghi, side = m, g, -1.0
    t = m
    e = (abs(g) + slack * (1.0 + abs(f))) * reach_t
    chi = np_minimum(chi, m + e if up else m)
    clo = np_maximum(clo, m if up else m - e)
    pr = (np_minimum(chi, hi) - np_maximum(clo, lo)) * length <= tol
    exact = g == 0.0
    done = exact or (hi - lo) * length <= tol
    if pr and not done:
        t = 0.5 * (np_minimum(chi, hi) + np_maximum(clo, lo))
    if done and not exact:
        # secant point of the final bracket (Illinois-scaled values keep their signs)
        ts = lo + (hi - lo) * glo / (glo - ghi)
        t = np_minimum(np_maximum(ts, lo), hi)
    return (lo, hi, glo, ghi, side, width1, width2, clo, chi, t), not (done or pr)
