"""Field evaluation at arbitrary points through a uniform grid of supports."""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from .._jit import inline_kernel, parallel_kernel
from .borrow import borrow, keep_alive
from .field import SCRATCH, segment_eval


@parallel_kernel
def field_at_points(points, seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad):
    """Sum of segment fields at each point, visiting only the segments binned
    in the point's grid cell (those whose support box can reach it).

    Parameters
    ----------
    points : (k, 3) float64, mm
    seg : (n, 10) float64
        Segment table.
    offsets, ids : int64
        CSR cell lists from :func:`slicer._kernels.binning.bin_boxes`.
    origin, cell : (3,) float64
    dims : (3,) int64
    m : int
        Half the kernel degree.
    inv_s2, norm : float
        1/sigma^2 and the kernel normalisation.
    grad : bool

    Returns
    -------
    f : (k,) float64
    g : (k, 3) float64
        Zeros unless ``grad``.
    """
    k = points.shape[0]
    f = np.zeros(k)
    g = np.zeros((k, 3))
    nchunk = (k + 255) // 256
    seg = borrow(seg)        # slicer._kernels.borrow: arguments outlive the launch
    for c in prange(nchunk):
        own = np.empty(SCRATCH)
        scratch = borrow(own)
        for p in range(c * 256, min(k, (c + 1) * 256)):
            sf, sx, sy, sz = point_field(seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad, scratch,
                                         points[p, 0], points[p, 1], points[p, 2])
            f[p] = sf
            g[p, 0] = sx
            g[p, 1] = sy
            g[p, 2] = sz
        keep_alive((own,))
    return f, g


@inline_kernel
def point_field(seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad, scratch, px, py, pz):
    """Field and gradient ``(f, gx, gy, gz)`` at one point: the sum over the
    segments binned in its grid cell (:func:`field_at_points`; zeros outside
    the grid)."""
    ix = int(math.floor((px - origin[0]) / cell[0]))
    iy = int(math.floor((py - origin[1]) / cell[1]))
    iz = int(math.floor((pz - origin[2]) / cell[2]))
    sf = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= dims[1] or iz >= dims[2]:
        return sf, sx, sy, sz
    cidx = (iz * dims[1] + iy) * dims[0] + ix
    for r in range(offsets[cidx], offsets[cidx + 1]):
        fi, gx, gy, gz = segment_eval(seg, ids[r], px, py, pz, m, inv_s2, norm, grad, scratch)
        sf += fi
        sx += gx
        sy += gy
        sz += gz
    return sf, sx, sy, sz
