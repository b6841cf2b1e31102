"""Exact area of polygons inside each pixel square (signed-area accumulation).

Each directed edge adds, to every pixel it passes, the signed area between
the edge and the pixel row's left end (trapezoids, clipped to the row), in
an accumulation buffer one column wider than the image; a running sum along
each row then gives every pixel's covered area. Summed over closed rings the
contributions are the exact area of the region inside the pixel (rings of
opposite orientation subtract), up to float64 rounding. The scheme is the
accumulation rasteriser of font renderers (docs/contours.md).
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import kernel


@kernel
def _add_row_span(acc, W, j, x, xn, d):
    """Add the signed area of an edge piece within row ``j`` from ``x`` to
    ``xn`` (pixel units, already clipped to ``[0, W]``) and of height ``d``."""
    base = j * (W + 1)
    x0 = min(x, xn)
    x1 = max(x, xn)
    x0f = math.floor(x0)
    x0i = int(x0f)
    x1i = int(math.ceil(x1))
    if x1i <= x0i + 1:
        xm = 0.5 * (x + xn) - x0f
        acc[base + x0i] += d - d * xm
        acc[base + x0i + 1] += d * xm
        return
    s = 1.0 / (x1 - x0)
    a0f = x0 - x0f
    a0 = 0.5 * s * (1.0 - a0f) * (1.0 - a0f)
    x1f = x1 - x1i + 1.0
    am = 0.5 * s * x1f * x1f
    acc[base + x0i] += d * a0
    if x1i == x0i + 2:
        acc[base + x0i + 1] += d * (1.0 - a0 - am)
    else:
        a1 = s * (1.5 - a0f)
        acc[base + x0i + 1] += d * (a1 - a0)
        for xi in range(x0i + 2, x1i - 1):
            acc[base + xi] += d * s
        a2 = a1 + (x1i - x0i - 3) * s
        acc[base + x1i - 1] += d * (1.0 - a2 - am)
    acc[base + x1i] += d * am


@kernel
def ring_coverage(xs, ys, starts, W, H):
    """Covered fraction of each pixel of a (H, W) image by closed rings.

    Parameters
    ----------
    xs, ys : (v,) float64
        Ring vertices in pixel units: pixel (row j, column i) is the square
        ``[i, i+1] x [j, j+1]``; rings not closed (the last vertex joins the
        first).
    starts : (r + 1,) int64
        Ring ``q`` is ``xs[starts[q]:starts[q + 1]]``.
    W, H : int

    Returns
    -------
    (H, W) float64
        Signed coverage (outer rings of one orientation give positive or
        negative area, holes the opposite): the caller takes its absolute value.
    """
    acc = np.zeros(H * (W + 1) + 1)
    for q in range(starts.shape[0] - 1):
        a, b = starts[q], starts[q + 1]
        for v in range(a, b):
            w = v + 1 if v + 1 < b else a
            px, py, qx, qy = xs[v], ys[v], xs[w], ys[w]
            px = min(max(px, 0.0), float(W))
            qx = min(max(qx, 0.0), float(W))
            if py == qy:
                continue
            sgn = 1.0
            if py > qy:
                px, py, qx, qy = qx, qy, px, py
                sgn = -1.0
            dxdy = (qx - px) / (qy - py)
            y_lo = max(py, 0.0)
            y_hi = min(qy, float(H))
            if not y_hi > y_lo:
                continue
            j = int(math.floor(y_lo))
            while j < H and j < y_hi:
                ya = max(float(j), y_lo)
                yb = min(float(j + 1), y_hi)
                if yb > ya:
                    x = px + (ya - py) * dxdy
                    xn = px + (yb - py) * dxdy
                    x = min(max(x, 0.0), float(W))
                    xn = min(max(xn, 0.0), float(W))
                    _add_row_span(acc, W, j, x, xn, sgn * (yb - ya))
                j += 1
    out = np.empty((H, W))
    for j in range(H):
        s = 0.0
        base = j * (W + 1)
        for i in range(W):
            s += acc[base + i]
            out[j, i] = s
    return out
