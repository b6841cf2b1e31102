"""Binning of axis-aligned boxes into a regular grid, as CSR arrays."""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import kernel


@kernel
def _cell_range(lo, hi, origin, cell, dims, i, axis):
    a = int(math.floor((lo[i, axis] - origin[axis]) / cell[axis]))
    b = int(math.floor((hi[i, axis] - origin[axis]) / cell[axis]))
    if a < 0:
        a = 0
    if b > dims[axis] - 1:
        b = dims[axis] - 1
    return a, b


@kernel
def bin_boxes(lo, hi, order, origin, cell, dims):
    """Assign boxes to the grid cells they overlap.

    Parameters
    ----------
    lo, hi : (m, 3) float64
        Box corners (mm).
    order : (m,) int64
        Order in which boxes are appended; each cell's list keeps it.
    origin : (3,) float64
        Corner of cell (0, 0, 0).
    cell : (3,) float64
        Cell size per axis.
    dims : (3,) int64
        Cells per axis; cell (i, j, k) has flat index ``(k*dims[1] + j)*dims[0] + i``.

    Returns
    -------
    offsets : (ncell + 1,) int64
    ids : (offsets[-1],) int64
        Box indices of cell c are ``ids[offsets[c]:offsets[c+1]]``.
    """
    ncell = dims[0] * dims[1] * dims[2]
    counts = np.zeros(ncell + 1, dtype=np.int64)
    for r in range(order.shape[0]):
        i = order[r]
        x0, x1 = _cell_range(lo, hi, origin, cell, dims, i, 0)
        y0, y1 = _cell_range(lo, hi, origin, cell, dims, i, 1)
        z0, z1 = _cell_range(lo, hi, origin, cell, dims, i, 2)
        for k in range(z0, z1 + 1):
            for j in range(y0, y1 + 1):
                for c in range(x0, x1 + 1):
                    counts[(k * dims[1] + j) * dims[0] + c + 1] += 1
    for c in range(ncell):
        counts[c + 1] += counts[c]
    ids = np.empty(counts[ncell], dtype=np.int64)
    fill = counts[:ncell].copy()
    for r in range(order.shape[0]):
        i = order[r]
        x0, x1 = _cell_range(lo, hi, origin, cell, dims, i, 0)
        y0, y1 = _cell_range(lo, hi, origin, cell, dims, i, 1)
        z0, z1 = _cell_range(lo, hi, origin, cell, dims, i, 2)
        for k in range(z0, z1 + 1):
            for j in range(y0, y1 + 1):
                for c in range(x0, x1 + 1):
                    f = (k * dims[1] + j) * dims[0] + c
                    ids[fill[f]] = i
                    fill[f] += 1
    return counts, ids
