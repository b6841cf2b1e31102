"""Root solving on segments of a layer plane: bracketed crossings of ``F = 1``,
first-order distances to the contour and projections onto it (docs/contours.md)."""
from __future__ import annotations

import numpy as np

from slicer._kernels.contours.crossings import MAX_ITER, distances, project_points, solve_segments
from slicer._kernels.runtime.launch import serial
from slicer.arguments import positive_number
from slicer.errors import GridError
from slicer.model.field import PointGrid, evaluate, plane_field, plane_grid, point_grid
from slicer.model.skeleton import Skeleton
from slicer.constants import FIELD_SLACK


#: batches smaller than this are evaluated on one thread: waking the pool
#: costs more than it saves, and on a loaded machine a parallel launch can
#: wait a whole scheduler time slice for its second thread
SERIAL_BATCH = 4096


def _field(skel: Skeleton, points: np.ndarray, gradient: bool = False):
    """:func:`slicer.model.field.evaluate`, serial for small batches (same values);
    points of one layer plane go through that plane's support grid
    (:func:`slicer.model.field.plane_field`, the same values)."""
    kern = evaluate
    if points.shape[0] and np.all(points[:, 2] == points[0, 2]):
        kern = plane_field
        points = np.ascontiguousarray(points, dtype=np.float64)
    if points.shape[0] >= SERIAL_BATCH:
        return kern(skel, points, gradient)
    with serial():
        return kern(skel, points, gradient)


def field_tuple(skel: Skeleton, z: float | None = None) -> tuple:
    """The field as the compiled root solvers take it
    (:mod:`slicer._kernels.contours.crossings`): the segment table with the support
    grid of the plane ``z`` (None: of the whole skeleton; the values are the
    same to the bit), half the kernel degree, ``1/σ²`` and the normalisation."""
    if skel.n_segments == 0:      # no segment: F = 0 everywhere
        table, grid = np.zeros((0, 10)), PointGrid(np.zeros(3), np.ones(3), np.ones(3, np.int64),
                                                    np.zeros(2, np.int64), np.zeros(0, np.int64))
    else:
        table, grid = point_grid(skel)
        if z is not None:
            grid = plane_grid(skel, float(z))
    return (table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims, skel.degree // 2,
            1.0 / skel.sigma**2, float(skel.normalisation))


def _one_plane(a: np.ndarray, b: np.ndarray) -> float | None:
    """The z all the points of ``a`` and ``b`` share, else None."""
    if a.shape[0] == 0:
        return None
    z = a[0, 2]
    return float(z) if np.all(a[:, 2] == z) and np.all(b[:, 2] == z) else None


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
    evaluation at all where the values at the ends already prove it). The
    segments are solved one after another in compiled code
    (:func:`slicer._kernels.contours.crossings.solve_segments`).

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
    if n == 0:
        return a.copy(), np.zeros(0), np.zeros(0, bool), 0
    known = (fa is not None, fb is not None)
    fa = np.zeros(n) if fa is None else np.ascontiguousarray(fa, dtype=np.float64)
    fb = np.zeros(n) if fb is None else np.ascontiguousarray(fb, dtype=np.float64)
    slope = np.zeros(n) if slope is None else np.ascontiguousarray(slope, dtype=np.float64)
    t, bracketed, evals = solve_segments(field_tuple(skel, _one_plane(a, b)), a, b, (fa, fb, *known), slope,
                                         float(tol), FIELD_SLACK)
    return a + t[:, None] * (b - a), t, bracketed, int(evals)


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
    return distances(field_tuple(skel, z), np.ascontiguousarray(xy, dtype=np.float64), float(z))


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
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    n = xy.shape[0]
    reach = np.full(n, np.inf) if reach is None else np.ascontiguousarray(reach, dtype=np.float64)
    roots, ok, dist, evals = project_points(field_tuple(skel, z), xy, float(z), float(tol), reach, FIELD_SLACK)
    return roots, ok, dist, int(evals)


__all__ = ["solve_crossings", "plane_distance", "project_to_contour", "MAX_ITER", "SERIAL_BATCH"]
