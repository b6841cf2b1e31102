"""Per-bucket primitive lists along the print direction (EG22 §4, docs/math.md §3.4).

The image is cut into square buckets of B x B pixel columns. Each bucket
lists the segments whose support footprint touches it, sorted by where their
support starts along z, so a ray walks upward adding and dropping primitives
and empty space costs nothing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer._kernels.field.binning import bin_boxes
from slicer.model.field import segment_table, support_boxes
from slicer.tracer.grid import SliceGrid
from slicer.model.skeleton import Skeleton

#: default bucket edge of the slicer, pixels (every API default and the CLI's ``--bucket``)
DEFAULT_BUCKET = 32


@dataclass(frozen=True)
class Buckets:
    """CSR bucket lists.

    Attributes
    ----------
    size : int
        Bucket edge B in pixels.
    nbx, nby : int
        Buckets along x (columns) and y (rows).
    offsets : (nbx*nby + 1,) int64
    ids : (nnz,) int64
        Segment ids of bucket ``b = by*nbx + bx`` are ``ids[offsets[b]:offsets[b+1]]``,
        sorted by support zmin.
    table : (m, 10) float64
        Segment table for the kernels.
    boxes : (m, 6) float64, mm
        Support box of each segment, ``xlo ylo zlo xhi yhi zhi``.
    """

    size: int
    nbx: int
    nby: int
    offsets: np.ndarray
    ids: np.ndarray
    table: np.ndarray
    boxes: np.ndarray

    def nonempty(self) -> np.ndarray:
        """(k,) int64: flat indices of buckets with at least one segment."""
        return np.nonzero(np.diff(self.offsets) > 0)[0].astype(np.int64)

    def longest(self) -> int:
        return int(np.diff(self.offsets).max()) if self.offsets.shape[0] > 1 else 0


def build_buckets(skel: Skeleton, grid: SliceGrid, size: int = DEFAULT_BUCKET) -> Buckets:
    """Bin the segments' support footprints into B x B pixel buckets.

    Parameters
    ----------
    skel : Skeleton
    grid : SliceGrid
    size : int
        Bucket edge B in pixels; ``0`` means one bucket for the whole image
        (a single global list, as in Liu et al. 2021).
    """
    W, H = grid.width, grid.height
    B = int(size) if size and size > 0 else max(W, H)
    nbx = -(-W // B)
    nby = -(-H // B)
    table = segment_table(skel)
    lo, hi = support_boxes(skel)
    px, py = grid.pixel_size
    # work in (x, -y) so bucket rows grow with image rows
    blo = np.stack([lo[:, 0], -hi[:, 1], np.zeros(len(lo))], axis=1)
    bhi = np.stack([hi[:, 0], -lo[:, 1], np.zeros(len(lo))], axis=1)
    origin = np.array([grid.origin[0] - 0.5 * px, -grid.origin[1] - 0.5 * py, -1.0])
    cell = np.array([B * px, B * py, 2.0])
    dims = np.array([nbx, nby, 1], dtype=np.int64)
    # drop segments whose footprint misses the image or whose z-range misses the layers
    z_lo = grid.origin[2] - 0.5 * grid.layer_height
    z_hi = grid.origin[2] + (grid.layers - 0.5) * grid.layer_height
    x_lo, y_hi = grid.origin[0] - 0.5 * px, grid.origin[1] + 0.5 * py
    x_hi = grid.origin[0] + (W - 0.5) * px
    y_lo = grid.origin[1] - (H - 0.5) * py
    keep = (hi[:, 2] > z_lo) & (lo[:, 2] < z_hi) & (hi[:, 0] > x_lo) & (lo[:, 0] < x_hi) \
        & (hi[:, 1] > y_lo) & (lo[:, 1] < y_hi)
    cand = np.nonzero(keep)[0]
    order = cand[np.argsort(lo[cand, 2], kind="stable")].astype(np.int64)
    offsets, ids = bin_boxes(blo, bhi, order, origin, cell, dims)
    return Buckets(B, nbx, nby, offsets, ids, table, np.ascontiguousarray(np.hstack([lo, hi])))


def thread_order(todo: np.ndarray, cost: np.ndarray, nthreads: int) -> np.ndarray:
    """Order work items so that every thread schedule shares them evenly.

    A ``prange`` loop is split into ``nthreads`` contiguous blocks by a
    static schedule (Numba's OpenMP layer ignores ``parallel_chunksize``),
    or handed out one item at a time by a dynamic one. The items are sorted
    by decreasing cost and dealt to the blocks in a snake (0, 1, ..., T-1,
    T-1, ..., 0, 0, 1, ...): the blocks then hold nearly equal total cost
    and equal counts, and each block starts with its biggest items.

    Parameters
    ----------
    todo : (k,) int64
        Item (bucket) indices.
    cost : (k,) array
        Estimated cost of each item (e.g. its segment count).
    nthreads : int

    Returns
    -------
    (k,) int64
        ``todo`` reordered.
    """
    todo = np.asarray(todo, dtype=np.int64)
    order = todo[np.argsort(-np.asarray(cost), kind="stable")]
    T = int(nthreads)
    if T <= 1 or len(order) <= T:
        return order
    pos = np.arange(len(order))
    row, col = np.divmod(pos, T)
    block = np.where(row % 2 == 0, col, T - 1 - col)
    return order[np.argsort(block, kind="stable")]


__all__ = ["Buckets", "DEFAULT_BUCKET", "build_buckets", "thread_order"]
