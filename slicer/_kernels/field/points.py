"""Field evaluation at arbitrary points through a uniform grid of supports."""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.field.segment import (AX, AY, AZ, LANE_TAG, LANES, LEN, SCRATCH, TAU1, UX, UY, UZ, lane_load, lane_result, segment_eval,
                    segment_first_lanes)
from slicer.constants import REACH_SLACK


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
        CSR cell lists from :func:`slicer._kernels.field.binning.bin_boxes`.
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
    seg = borrow(seg)        # slicer._kernels.runtime.borrow: arguments outlive the launch
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


#: fewest segments in a point's list for which the default kernel (n = 6)
#: evaluates them side by side in vector lanes (:func:`_lanes_sum`)
POINT_LANES_FROM = 2


@inline_kernel
def point_field(seg, offsets, ids, origin, cell, dims, m, inv_s2, norm, grad, scratch, px, py, pz):
    """Field and gradient ``(f, gx, gy, gz)`` at one point: the sum over the
    segments binned in its grid cell (:func:`field_at_points`; zeros outside
    the grid). With the default kernel (``m = 3``) and ``POINT_LANES_FROM`` or
    more segments listed, they are evaluated in vector lanes
    (:func:`_lanes_sum`): the same values to the bit.

    ``grad`` reaches the compiled callees as a run-time flag (``bool(grad)``):
    a constant ``True`` or ``False`` at a call site would make Numba compile
    them once more for each constant (docs/development.md, "Cache")."""
    flag = bool(grad)
    ix = int(math.floor((px - origin[0]) / cell[0]))
    iy = int(math.floor((py - origin[1]) / cell[1]))
    iz = int(math.floor((pz - origin[2]) / cell[2]))
    if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= dims[1] or iz >= dims[2]:
        return 0.0, 0.0, 0.0, 0.0
    cidx = (iz * dims[1] + iy) * dims[0] + ix
    a = offsets[cidx]
    b = offsets[cidx + 1]
    if m == 3 and b - a >= POINT_LANES_FROM:
        return _lanes_sum(seg, ids, a, b, inv_s2, norm, flag, scratch, (px, py, pz))
    sf = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for r in range(a, b):
        fi, gx, gy, gz = segment_eval(seg, ids[r], px, py, pz, m, inv_s2, norm, flag, scratch)
        sf += fi
        sx += gx
        sy += gy
        sz += gz
    return sf, sx, sy, sz




@inline_kernel
def may_reach(seg, i, px, py, pz, inv_s2):
    """False only where ``p`` is farther from segment ``i``'s axis than its
    largest support radius ``σ τ1`` (the radius grows from ``a`` to ``b``):
    every support ball misses ``p``, whose field and gradient from this
    segment are then exactly zero. The margin ``REACH_SLACK (σ² τ1² + |p − a|²)``
    on the squared distance is far above its rounding."""
    wx = px - seg[i, AX]
    wy = py - seg[i, AY]
    wz = pz - seg[i, AZ]
    t = min(max(wx * seg[i, UX] + wy * seg[i, UY] + wz * seg[i, UZ], 0.0), seg[i, LEN])
    dx = wx - t * seg[i, UX]
    dy = wy - t * seg[i, UY]
    dz = wz - t * seg[i, UZ]
    big2 = seg[i, TAU1] * seg[i, TAU1] / inv_s2
    return dx * dx + dy * dy + dz * dz - big2 <= REACH_SLACK * (big2 + wx * wx + wy * wy + wz * wz)


@unrefcounted_kernel
def _lanes_sum(seg, ids, a, b, inv_s2, norm, grad, scratch, p):
    """The sum of :func:`point_field` over the segments ``ids[a:b]`` (n = 6) at
    ``p``: those that :func:`may_reach` it (the others add exactly zero) are
    loaded in list order and evaluated ``LANES`` at a time, a last group of
    ``HALF_LANES`` or fewer in half the lanes, a last lone one by
    :func:`segment_eval` (lanes flagged ``redo`` too), and summed in list
    order, so the values are the loop's to the bit. The gradient is summed
    only with ``grad`` (the lanes always compute it; the loop's is then zero)."""
    px, py, pz = p
    acc = (0.0, 0.0, 0.0, 0.0)
    k = 0
    for r in range(a, b):
        i = ids[r]
        if not may_reach(seg, i, px, py, pz, inv_s2):
            continue
        lane_load(scratch, k, seg, i)
        scratch[LANE_TAG + k] = i
        k += 1
        if k == LANES:
            acc = _lanes_done(seg, k, inv_s2, norm, grad, scratch, p, acc)
            k = 0
    if k > 0:
        acc = _lanes_done(seg, k, inv_s2, norm, grad, scratch, p, acc)
    return acc


@inline_kernel
def _lanes_done(seg, k, inv_s2, norm, grad, scratch, p, acc):
    """``acc = (f, gx, gy, gz)`` plus the first ``k`` loaded lanes' values
    (:func:`_lanes_sum`), in lane order."""
    px, py, pz = p
    sf, sx, sy, sz = acc
    if k == 1:
        fi, gx, gy, gz = segment_eval(seg, int(scratch[LANE_TAG]), px, py, pz, 3, inv_s2, norm, grad, scratch)
        return sf + fi, sx + gx, sy + gy, sz + gz
    segment_first_lanes(scratch, k, px, py, pz, inv_s2, norm)
    for j in range(k):
        fi, gx, gy, gz, redo = lane_result(scratch, j)
        if redo:
            fi, gx, gy, gz = segment_eval(seg, int(scratch[LANE_TAG + j]), px, py, pz, 3, inv_s2, norm, grad,
                                          scratch)
        sf += fi
        if grad:
            sx += gx
            sy += gy
            sz += gz
    return sf, sx, sy, sz
