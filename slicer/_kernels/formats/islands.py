"""Islands of a raster layer: 8-connected components of its non-zero pixels.

Printer formats store per-layer statistics (NanoDLP ``info.json``: island
count, largest and smallest island area). Components are found on the
layer's row runs joined by :func:`slicer._kernels.raster.labels.joined_runs`: two runs in
adjacent rows belong to the same island when they overlap or touch diagonally (8-connectivity, as
OpenCV's ``findContours`` counts outer contours, which UVtools uses).
"""
from __future__ import annotations

import numpy as np

from slicer._jit import kernel
from slicer._kernels.raster.labels import _root, joined_runs


@kernel
def island_sizes(img):
    """Pixel counts of the 8-connected islands of the non-zero pixels.

    Parameters
    ----------
    img : (h, w) uint8

    Returns
    -------
    sizes : (n,) int64
        Pixels of each island, islands in the row-major order of their first
        pixel (n = 0 for an empty image).
    """
    start, stop, _, parent = joined_runs(img, True)
    n = start.shape[0]
    size = np.zeros(n, np.int64)
    m = 0
    for i in range(n):
        ri = _root(parent, i)
        if ri == i:
            m += 1
        size[ri] += stop[i] - start[i]
    out = np.empty(m, np.int64)
    m = 0
    for i in range(n):
        if parent[i] == i:
            out[m] = size[i]
            m += 1
    return out
