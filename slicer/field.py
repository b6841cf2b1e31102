"""Field evaluation API: validates inputs, builds the segment table and the
support grid, and calls the compiled kernels."""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ._kernels.binning import bin_boxes
from ._kernels.points import field_at_points
from ._kernels.union import field_max_at_points
from .blend import check_blend
from .errors import SceneError

if TYPE_CHECKING:          # annotations only: the skeleton module imports this one
    from .skeleton import Skeleton


def segment_table(skel: Skeleton) -> np.ndarray:
    """Per-segment constants for the kernels, oriented so the radius grows.

    Parameters
    ----------
    skel : Skeleton

    Returns
    -------
    (m, 10) float64
        Columns ``ax ay az ux uy uz L tau0 delta tau1`` (see
        :mod:`slicer._kernels.field`), with ``a`` the thinner end.
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
    """
    a, b = skel.endpoints()
    ra = skel.sigma * skel.radii[:, 0:1]
    rb = skel.sigma * skel.radii[:, 1:2]
    lo = np.minimum(a - ra, b - rb)
    hi = np.maximum(a + ra, b + rb)
    # pad outward so a point on a box face is binned in every cell it may need
    pad = 1e-9 * (np.abs(lo) + np.abs(hi) + (hi - lo))
    return lo - pad, hi + pad


@dataclass(frozen=True)
class PointGrid:
    """Uniform 3-D grid listing, per cell, the segments whose support box overlaps it."""

    origin: np.ndarray   # (3,) float64
    cell: np.ndarray     # (3,) float64
    dims: np.ndarray     # (3,) int64
    offsets: np.ndarray  # (ncell+1,) int64
    ids: np.ndarray      # (nnz,) int64


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
    blo = lo.min(axis=0)
    bhi = hi.max(axis=0)
    ext = np.maximum(bhi - blo, 1e-300)
    diam = np.median((hi - lo).max(axis=1))
    cell = max(0.5 * diam, float(np.cbrt(np.prod(ext) / max_cells)))
    dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
    budget = max(32 * skel.n_segments, max_cells)
    while np.prod(dims) > max_cells or (np.prod(dims) > 1 and _binned_entries(lo, hi, ext, dims) > budget):
        cell *= 1.25
        dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
    cellv = ext / dims
    order = np.arange(skel.n_segments, dtype=np.int64)
    offsets, ids = bin_boxes(lo, hi, order, blo, cellv, dims)
    grid = PointGrid(blo, cellv, dims, offsets, ids)
    _GRID_CACHE[skel] = (table, grid)
    return table, grid


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
        (:mod:`slicer.blend`); the gradient is then that of the largest field.

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


__all__ = ["evaluate", "segment_table", "support_boxes", "point_grid", "PointGrid", "as_points"]
