"""Union blend at points: the maximum of the segments' fields (see :mod:`slicer.model.blend`)."""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import parallel_kernel
from slicer._kernels.field.segment import SCRATCH, segment_eval


@parallel_kernel
def field_max_at_points(points, seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad):
    """Largest segment field at each point (and that segment's gradient).

    Same arguments and grid as :func:`slicer._kernels.field.points.field_at_points`;
    only the combination differs: ``F = max_i f_i`` instead of the sum. A point
    outside every support gets 0.

    Returns
    -------
    f : (k,) float64
    g : (k, 3) float64
        Gradient of the segment with the largest field (zeros unless ``grad``);
        where two segments tie, the first one in the cell's list.
    """
    k = points.shape[0]
    f = np.zeros(k)
    g = np.zeros((k, 3))
    nchunk = (k + 255) // 256
    for c in prange(nchunk):
        scratch = np.empty(SCRATCH)
        for p in range(c * 256, min(k, (c + 1) * 256)):
            px = points[p, 0]
            py = points[p, 1]
            pz = points[p, 2]
            ix = int(math.floor((px - origin[0]) / cell[0]))
            iy = int(math.floor((py - origin[1]) / cell[1]))
            iz = int(math.floor((pz - origin[2]) / cell[2]))
            if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= dims[1] or iz >= dims[2]:
                continue
            cidx = (iz * dims[1] + iy) * dims[0] + ix
            best = 0.0
            for r in range(offsets[cidx], offsets[cidx + 1]):
                fi, gx, gy, gz = segment_eval(seg, ids[r], px, py, pz, m, inv_s2, norm, grad, scratch)
                if fi > best:
                    best = fi
                    g[p, 0] = gx
                    g[p, 1] = gy
                    g[p, 2] = gz
            f[p] = best
    return f, g
