"""Root solving on segments of a layer plane: bracketed crossings of ``F = 1``,
first-order distances to the contour and projections onto it (docs/contours.md)."""
from __future__ import annotations

import numpy as np

from .._kernels.brackets import bracket_points, bracket_update
from .._kernels.launch import serial
from ..checks import positive_number
from ..errors import GridError
from ..field import evaluate, plane_field
from ..skeleton import Skeleton

#: iterations of the bracketed solver before it gives up (bisection halves
#: the bracket at least every other step, so 200 is far beyond need)
MAX_ITER = 200

#: relative error budget of one closed-form field evaluation (docs/math.md §2.6
#: and the stiff-case suite: ~1e-13)
FIELD_SLACK = 1e-9

#: batches smaller than this are evaluated on one thread: waking the pool
#: costs more than it saves, and on a loaded machine a parallel launch can
#: wait a whole scheduler time slice for its second thread
SERIAL_BATCH = 4096


def _field(skel: Skeleton, points: np.ndarray, gradient: bool = False):
    """:func:`slicer.field.evaluate`, serial for small batches (same values);
    points of one layer plane go through that plane's support grid
    (:func:`slicer.field.plane_field`, the same values)."""
    kern = evaluate
    if points.shape[0] and np.all(points[:, 2] == points[0, 2]):
        kern = plane_field
        points = np.ascontiguousarray(points, dtype=np.float64)
    if points.shape[0] >= SERIAL_BATCH:
        return kern(skel, points, gradient)
    with serial():
        return kern(skel, points, gradient)


def _check_tol(tol) -> float:
    return positive_number(tol, "contour tolerance", GridError)


def solve_crossings(skel: Skeleton, a: np.ndarray, b: np.ndarray, tol: float,
                    fa: np.ndarray | None = None, fb: np.ndarray | None = None,
                    slope: np.ndarray | None = None):
    """Points where ``F = 1`` on segments ``a -> b``, to ``tol`` mm.

    Each segment must bracket the surface: ``F(a) >= 1 > F(b)``. The bracket
    ``[lo, hi]`` is narrowed by Illinois (modified regula falsi) steps, kept
    ``tol/2`` inside the bracket, with a bisection step whenever two steps
    fail to halve it, until it is at most ``tol`` long; the answer is the
    secant point of the final bracket, so it is within ``tol`` of a root.
    Where ``slope`` proves ``|dF/dl| >= slope`` all along a segment (l its
    arc length, mm), a value ``F(t)`` also proves the root (then unique)
    within ``(|F(t) − 1| + ε)/slope`` of ``t`` on the side its sign gives
    (ε: the evaluation's error budget, ``FIELD_SLACK (1 + |F|)``); once the
    intersection of these intervals with the bracket is at most ``tol``
    long, its midpoint is the answer, within ``tol/2`` of the root (no
    evaluation at all where the values at the ends already prove it). Every
    iteration evaluates the field at all unfinished segments in one
    compiled batch.

    Parameters
    ----------
    skel : Skeleton
    a, b : (n, 3) float64, mm
        Inside and outside ends.
    tol : float, mm
    fa, fb : (n,) float64, optional
        Field at ``a`` and ``b`` if already known.
    slope : (n,) float64, optional, 1/mm
        Lower bound of ``|dF/dl|`` along each segment (0 or absent: none).

    Returns
    -------
    points : (n, 3) float64, mm
    t : (n,) float64
        Position along each segment, in [0, 1].
    bracketed : (n,) bool
        False where ``F(a) >= 1 > F(b)`` does not hold; such a segment gets
        the end whose field is closer to 1.
    evaluations : int
        Field evaluations spent.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    n = a.shape[0]
    evals = 0
    if fa is None:
        fa = _field(skel, a)[0]
        evals += n
    if fb is None:
        fb = _field(skel, b)[0]
        evals += n
    d = b - a
    length = np.sqrt((d * d).sum(axis=1))
    glo = fa - 1.0
    ghi = fb - 1.0
    bracketed = (glo >= 0.0) & (ghi < 0.0)
    lo = np.zeros(n)
    hi = np.ones(n)
    t = np.where(np.abs(glo) <= np.abs(ghi), 0.0, 1.0)
    side = np.zeros(n, np.int8)          # last end moved: +1 lo, -1 hi
    with np.errstate(divide="ignore"):
        tol_t = np.where(length > 0, tol / length, 1.0)
    width1 = hi - lo                      # bracket width one and two steps ago
    width2 = hi - lo
    # interval proved by the slope bound, in t; (clo, chi) = (0, 1) without one
    clo = np.zeros(n)
    chi = np.ones(n)
    if slope is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            reach_t = np.where((slope > 0) & (length > 0), 1.0 / (slope * length), np.inf)
        ea = (np.abs(glo) + FIELD_SLACK * (1.0 + np.abs(fa))) * reach_t
        eb = (np.abs(ghi) + FIELD_SLACK * (1.0 + np.abs(fb))) * reach_t
        chi = np.minimum(chi, ea)
        clo = np.maximum(clo, 1.0 - eb)
    proved = bracketed & ((chi - clo) * length <= tol)
    act = np.flatnonzero(bracketed & (length > tol) & ~proved)
    t[bracketed] = np.where(glo[bracketed] == 0.0, 0.0, 0.5)
    pf = np.flatnonzero(proved & (length > tol) & (glo != 0.0))
    t[pf] = 0.5 * (clo[pf] + chi[pf])
    if slope is None:
        reach_t = np.full(n, np.inf)        # proves nothing: (clo, chi) stay (0, 1)
    br = (lo, hi, glo, ghi, side, width1, width2, clo, chi, t)
    it = 0
    while act.size and it < MAX_ITER:
        it += 1
        tm, pts = bracket_points(act, br, tol_t, it, a, d)
        f = _field(skel, pts)[0]
        evals += act.size
        act = bracket_update(act, tm, f, br, reach_t, length, float(tol), FIELD_SLACK)
    if act.size:   # pragma: no cover - the bisection safeguard makes this unreachable
        t[act] = 0.5 * (lo[act] + hi[act])
    return a + t[:, None] * d, t, bracketed, evals



def plane_distance(skel: Skeleton, xy: np.ndarray, z: float):
    """First-order distance of points to the contour of layer ``z``, in its plane.

    Parameters
    ----------
    skel : Skeleton
    xy : (n, 2) float64, mm
    z : float, mm

    Returns
    -------
    dist : (n,) float64, mm
        ``|F - 1| / |grad_xy F|`` (inf where the in-plane gradient vanishes).
    f : (n,) float64
    gxy : (n, 2) float64, 1/mm
    """
    p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
    f, g = _field(skel, p, gradient=True)
    gxy = g[:, :2]
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
    return dist, f, gxy


def project_to_contour(skel: Skeleton, xy: np.ndarray, z: float, tol: float, reach=None):
    """Points of the contour of layer ``z`` on the in-plane gradient line through each point.

    The root of ``F = 1`` is bracketed on the segment ``xy +- r n`` (``n`` the
    unit in-plane gradient, ``r`` three first-order distances plus ``tol``, or
    ``reach``) and solved to ``tol``. ``|xy - root|`` is then an upper bound (to
    ``tol``) of the in-plane distance of ``xy`` to the contour.

    The Newton point ``xy + (1 − F) n / |∇F|`` is tried first: where the
    segment of length ``tol`` centred on it, on that line and within ``r`` of
    ``xy``, brackets the root (two evaluations), its midpoint is within
    ``tol / 2`` of the root; only the others are solved on the whole segment.

    Parameters
    ----------
    skel : Skeleton
    xy : (n, 2) float64, mm
    z : float, mm
    tol : float, mm
    reach : (n,) float64, optional, mm
        Upper limit of the half-length of each search segment.

    Returns
    -------
    roots : (n, 2) float64, mm
        ``xy`` itself where no root was bracketed.
    ok : (n,) bool
    first_order : (n,) float64, mm
        :func:`plane_distance` of the points.
    evaluations : int
    """
    n = xy.shape[0]
    dist, f, gxy = plane_distance(skel, xy, z)
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    usable = np.isfinite(dist)
    r = np.where(usable, 3.0 * np.where(usable, dist, 0.0) + tol, 0.0)
    if reach is not None:
        r = np.minimum(r, reach)
    nrm = gxy / np.where(gn > 0, gn, 1.0)[:, None]          # toward growing F: inward
    zz = np.full(n, float(z))
    A = np.column_stack([xy + r[:, None] * nrm, zz])
    B = np.column_stack([xy - r[:, None] * nrm, zz])
    roots = xy.copy()
    ok = np.zeros(n, bool)
    evals = n
    idx = np.flatnonzero(usable & (r > 0))
    # the Newton point, bracketed tol/2 either side (within the search segment)
    near = idx[dist[idx] + 0.5 * tol <= r[idx]]
    if near.size:
        step = ((1.0 - f[near]) / gn[near])[:, None] * nrm[near]
        half = 0.4999 * tol * nrm[near]          # a bracket just under tol: its midpoint, no iteration
        pts, _, br, ne = solve_crossings(skel, np.column_stack([xy[near] + step + half, zz[near]]),
                                         np.column_stack([xy[near] + step - half, zz[near]]), tol)
        evals += ne
        roots[near[br]] = pts[br, :2]
        ok[near[br]] = True
        idx = np.setdiff1d(idx, near[br], assume_unique=True)
    if idx.size:
        pts, _, br, ne = solve_crossings(skel, A[idx], B[idx], tol)
        evals += ne
        roots[idx[br]] = pts[br, :2]
        ok[idx[br]] = True
    return roots, ok, dist, evals


__all__ = ["solve_crossings", "plane_distance", "project_to_contour", "MAX_ITER", "SERIAL_BATCH"]
