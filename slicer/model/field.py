"""Field evaluation API: validates inputs, builds the segment table and the
support grid, and calls the compiled kernels."""
from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.field.points import field_at_points
from slicer._kernels.field.union import field_max_at_points
from slicer.model.blend import check_blend
from slicer.errors import SceneError

if TYPE_CHECKING:          # annotations only: the skeleton module imports this one
    from slicer.model.skeleton import Skeleton


def segment_table(skel: Skeleton) -> np.ndarray:
    """Per-segment constants for the kernels, oriented so the radius grows.

    Parameters
    ----------
    skel : Skeleton

    Returns
    -------
    (m, 10) float64
        Columns ``ax ay az ux uy uz L tau0 delta tau1`` (see
        :mod:`slicer._kernels.field.segment`), with ``a`` the thinner end.
    """
    a, b = skel.endpoints()
    r = skel.radii
    flip = r[:, 1] < r[:, 0]
    a2 = np.where(flip[:, None], b, a)
    b2 = np.where(flip[:, None], a, b)
    t0 = np.where(flip, r[:, 1], r[:, 0])
    t1 = np.where(flip, r[:, 0], r[:, 1])
    D = b2 - a2
    L = np.linalg.norm(D, axis=1)
    u = D / L[:, None]
    table = np.empty((skel.n_segments, 10))
    table[:, 0:3] = a2
    table[:, 3:6] = u
    table[:, 6] = L
    table[:, 7] = t0
    table[:, 8] = (t1 - t0) / L
    table[:, 9] = t1
    return table


def support_boxes(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes of each segment's support (union of its end balls).

    The support of a segment is the round cone hull of the balls of radius
    ``sigma * tau`` at its ends (docs/math.md §3.2), so these boxes are tight.

    Returns
    -------
    lo, hi : (m, 3) float64, mm
        Read-only (cached per skeleton: each layer plane asks again).
    """
    hit = _BOX_CACHE.get(skel)
    if hit is not None:
        return hit
    a, b = skel.endpoints()
    ra = skel.sigma * skel.radii[:, 0:1]
    rb = skel.sigma * skel.radii[:, 1:2]
    lo = np.minimum(a - ra, b - rb)
    hi = np.maximum(a + ra, b + rb)
    # pad outward so a point on a box face is binned in every cell it may need
    pad = 1e-9 * (np.abs(lo) + np.abs(hi) + (hi - lo))
    lo, hi = lo - pad, hi + pad
    lo.setflags(write=False)
    hi.setflags(write=False)
    _BOX_CACHE[skel] = (lo, hi)
    return lo, hi


_BOX_CACHE: "weakref.WeakKeyDictionary[Skeleton, tuple[np.ndarray, np.ndarray]]" = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class PointGrid:
    """Uniform 3-D grid listing, per cell, the segments whose support box overlaps it."""

    origin: np.ndarray   # (3,) float64
    cell: np.ndarray     # (3,) float64
    dims: np.ndarray     # (3,) int64
    offsets: np.ndarray  # (ncell+1,) int64
    ids: np.ndarray      # (nnz,) int64


def _uniform_cells(lo: np.ndarray, hi: np.ndarray, fraction: float, max_cells: int, budget: int):
    """A uniform grid over boxes ``lo``..``hi`` ((n, d) each, d = 2 or 3): cells of
    ``fraction`` times the median box's largest side, coarsened by 1.25 until there
    are at most ``max_cells`` of them and the boxes' lists hold at most ``budget``
    entries. Returns its origin and cell size, (d,) float64, and its cells per axis,
    (d,) int64."""
    blo = lo.min(axis=0)
    ext = np.maximum(hi.max(axis=0) - blo, 1e-300)
    root = np.cbrt if lo.shape[1] == 3 else np.sqrt
    cell = max(fraction * float(np.median((hi - lo).max(axis=1))), float(root(np.prod(ext) / max_cells)))
    dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
    while np.prod(dims) > max_cells or (np.prod(dims) > 1 and _binned_entries(lo, hi, ext, dims) > budget):
        cell *= 1.25
        dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
    return blo, ext / dims, dims


_GRID_CACHE: "weakref.WeakKeyDictionary[Skeleton, tuple[np.ndarray, PointGrid]]" = weakref.WeakKeyDictionary()


def _binned_entries(lo: np.ndarray, hi: np.ndarray, ext: np.ndarray, dims: np.ndarray) -> int:
    """Upper bound of the cell-list entries of boxes ``lo``..``hi`` (each (n, 3)) on a
    grid of ``dims`` cells over ``ext``: each box covers at most ceil(size / cell) + 1
    cells per axis."""
    cell = ext / dims
    per_axis = np.minimum(np.ceil((hi - lo) / cell) + 1.0, dims)
    return int(np.prod(per_axis, axis=1).sum())


def point_grid(skel: Skeleton, max_cells: int = 2_000_000) -> tuple[np.ndarray, PointGrid]:
    """Segment table and support grid of a skeleton (cached per skeleton).

    Cells are half the median support diameter (a point then visits few
    segments whose support cannot reach it), coarsened until the grid has at
    most ``max_cells`` cells and its lists at most ``max(32 n, max_cells)``
    entries for ``n`` segments. The field does not depend on the grid: a
    point sums the segments of its cell in segment order, and a segment whose
    support misses the point adds exactly 0.
    """
    hit = _GRID_CACHE.get(skel)
    if hit is not None:
        return hit
    table = segment_table(skel)
    lo, hi = support_boxes(skel)
    blo, cellv, dims = _uniform_cells(lo, hi, 0.5, max_cells, max(32 * skel.n_segments, max_cells))
    order = np.arange(skel.n_segments, dtype=np.int64)
    offsets, ids = bin_boxes(lo, hi, order, blo, cellv, dims)
    grid = PointGrid(blo, cellv, dims, offsets, ids)
    _GRID_CACHE[skel] = (table, grid)
    return table, grid


#: plane grids kept per skeleton (the planes being contoured at once, with room)
PLANE_CACHE = 16
_PLANE_CACHE: "weakref.WeakKeyDictionary[Skeleton, dict[float, PointGrid]]" = weakref.WeakKeyDictionary()
_PLANE_LOCK = threading.Lock()


def plane_footprints(skel: Skeleton, z: float, reach: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes in the plane ``z`` holding each segment's support section.

    The support of a segment lies within ``sigma * max(tau0, tau1)`` = R of
    its axis, so its section by the plane lies within R of the part of the
    axis between the planes ``z - R`` and ``z + R``: the box of that part
    grown by R (and cut by the segment's support box). For a long slanted
    strut this is far smaller than its support box. With ``reach``, the boxes
    hold every point of the plane within ``reach`` of a support ball: those of
    the support grown by ``reach`` (R + reach in place of R).

    Parameters
    ----------
    skel : Skeleton
    z : float, mm
    reach : float, mm

    Returns
    -------
    ids : (q,) int64
        The segments whose support box meets the plane, ascending.
    lo, hi : (q, 2) float64, mm
        Their footprints' corners, padded outward for rounding.
    """
    slo, shi = support_boxes(skel)
    ids = np.flatnonzero((slo[:, 2] <= z) & (z <= shi[:, 2])).astype(np.int64)
    a, b = skel.endpoints()
    a, b = a[ids], b[ids]
    R = skel.sigma * skel.radii[ids].max(axis=1) * (1.0 + 1e-12) + reach
    dz = b[:, 2] - a[:, 2]
    flat = dz == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = np.where(flat, 0.0, (z - R - a[:, 2]) / np.where(flat, 1.0, dz))
        s2 = np.where(flat, 1.0, (z + R - a[:, 2]) / np.where(flat, 1.0, dz))
    lo_s = np.clip(np.minimum(s1, s2), 0.0, 1.0)
    hi_s = np.clip(np.maximum(s1, s2), 0.0, 1.0)
    pa = a[:, :2] + lo_s[:, None] * (b[:, :2] - a[:, :2])
    pb = a[:, :2] + hi_s[:, None] * (b[:, :2] - a[:, :2])
    lo = np.minimum(pa, pb) - R[:, None]
    hi = np.maximum(pa, pb) + R[:, None]
    pad = 1e-9 * (np.abs(lo) + np.abs(hi) + (hi - lo) + R[:, None])
    lo = np.maximum(lo - pad, slo[ids, :2] - reach)
    hi = np.minimum(hi + pad, shi[ids, :2] + reach)
    return ids, lo, hi


def plane_grid(skel: Skeleton, z: float, max_cells: int = 250_000) -> PointGrid:
    """Support grid of the layer plane ``z`` (cached for the last few planes
    of each skeleton): one layer of squares, each listing the segments whose
    support section (:func:`plane_footprints`) overlaps it, in segment order.

    Squares are an eighth of the median footprint side, coarsened until there are at
    most ``max_cells`` of them and their lists hold at most
    ``max(32 q, max_cells)`` entries for ``q`` segments. A point of the plane
    then visits few segments whose support cannot reach it, and its field is
    that of :func:`evaluate` to the bit: both sum the segments that reach it
    in segment order, and the others add exactly 0.
    """
    z = float(z)
    with _PLANE_LOCK:
        hit = _PLANE_CACHE.get(skel, {}).get(z)
    if hit is not None:
        return hit
    ids, lo, hi = plane_footprints(skel, z)
    if ids.size == 0:
        grid = PointGrid(np.array([0.0, 0.0, z - 1.0]), np.ones(3), np.ones(3, np.int64),
                         np.zeros(2, np.int64), ids)
    else:
        blo, cellv, dims = _uniform_cells(lo, hi, 0.125, max_cells, max(32 * ids.size, max_cells))
        blo3 = np.column_stack([lo, np.full(ids.size, z)])
        bhi3 = np.column_stack([hi, np.full(ids.size, z)])
        origin = np.array([blo[0], blo[1], z - 1.0])
        dims3 = np.array([dims[0], dims[1], 1], np.int64)
        offsets, local = bin_boxes(blo3, bhi3, np.arange(ids.size, dtype=np.int64), origin,
                                   np.array([cellv[0], cellv[1], 2.0]), dims3)
        grid = PointGrid(origin, np.array([cellv[0], cellv[1], 2.0]), dims3, offsets, ids[local])
    with _PLANE_LOCK:
        planes = _PLANE_CACHE.setdefault(skel, {})
        planes[z] = grid
        while len(planes) > PLANE_CACHE:
            del planes[next(iter(planes))]
    return grid


def evaluate_plane(skel: Skeleton, points: np.ndarray, gradient: bool = False):
    """:func:`evaluate` (blend ``sum``) of points that all lie in one plane
    ``z = points[0, 2]``, through that plane's support grid
    (:func:`plane_grid`): the same values to the bit, with fewer segments
    visited per point.

    Parameters
    ----------
    skel : Skeleton
    points : (k, 3) float64, mm
        Contiguous, with one z.
    gradient : bool

    Returns
    -------
    f : (k,) float64
    g : (k, 3) float64, 1/mm, or None
    """
    p = as_points(points)
    if p.shape[0] and not np.all(p[:, 2] == p[0, 2]):
        raise SceneError("evaluate_plane: the points do not share one z")
    return plane_field(skel, p, gradient)


def plane_field(skel: Skeleton, p: np.ndarray, gradient: bool = False):
    """:func:`evaluate_plane` of points the caller made: a C-contiguous
    (k, 3) float64 array of finite points with one z (not checked)."""
    if p.shape[0] == 0 or skel.n_segments == 0:
        return np.zeros(p.shape[0]), (np.zeros_like(p) if gradient else None)
    z = float(p[0, 2])
    table = point_grid(skel)[0]
    grid = plane_grid(skel, z)
    f, g = field_at_points(p, table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims,
                           skel.degree // 2, 1.0 / skel.sigma**2, skel.normalisation, bool(gradient))
    return f, (g if gradient else None)


def as_points(points, name: str = "points") -> np.ndarray:
    """Validate and coerce query points to a contiguous (k, 3) float64 array."""
    try:
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"'{name}' must be an array of numbers ({exc})") from None
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise SceneError(f"'{name}' must have shape (k, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        i = int(np.argwhere(~np.isfinite(p))[0][0])
        raise SceneError(f"{name}[{i}] is not finite: {p[i].tolist()}")
    return np.ascontiguousarray(p)


def evaluate(skel: Skeleton, points, gradient: bool = False, blend: str = "sum") -> tuple[np.ndarray, np.ndarray | None]:
    """Field (and gradient) of a skeleton at points.

    Only the segments whose support box covers a point's grid cell are
    evaluated; the result does not depend on the thread count.

    Parameters
    ----------
    skel : Skeleton
    points : (k, 3) float64, mm
    gradient : bool, default False
    blend : {"sum", "union"}
        ``sum``: the sum of the segments' fields (the paper's blending);
        ``union``: their maximum, each strut keeping its own surface
        (:mod:`slicer.model.blend`); the gradient is then that of the largest field.

    Returns
    -------
    f : (k,) float64
    g : (k, 3) float64, 1/mm, or None

    Examples
    --------
    >>> from slicer import Skeleton
    >>> s = Skeleton([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[0, 1], [0, 2]], [[1.0, 1.0], [1.0, 1.0]])
    >>> p = [[0.5, 0.5, 0.0]]
    >>> bool(evaluate(s, p)[0][0] > evaluate(s, p, blend="union")[0][0])
    True
    """
    union = check_blend(blend) == "union"
    p = as_points(points)
    if skel.n_segments == 0:
        return np.zeros(p.shape[0]), (np.zeros_like(p) if gradient else None)
    table, grid = point_grid(skel)
    kern = field_max_at_points if union else field_at_points
    f, g = kern(p, table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims,
                skel.degree // 2, 1.0 / skel.sigma**2, skel.normalisation, bool(gradient))
    return f, (g if gradient else None)


__all__ = ["evaluate", "evaluate_plane", "plane_field", "plane_grid", "plane_footprints", "segment_table", "support_boxes", "point_grid", "PointGrid", "as_points"]
