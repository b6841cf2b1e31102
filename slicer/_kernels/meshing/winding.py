"""Winding numbers of points with respect to closed triangle meshes (docs/mesh.md, "Parts").

The winding number of a point ``p`` about a closed, oriented mesh is the sum of
the signed solid angles of its triangles seen from ``p``, over ``4π``: 1 inside,
0 outside (an integer for a closed mesh, up to rounding). Each solid angle is
Van Oosterom and Strackee's (1983)
``tan(Ω/2) = a·(b × c) / (|a||b||c| + (a·b)|c| + (b·c)|a| + (c·a)|b|)``,
with ``a, b, c`` the corners less ``p``. The rounding stays far below ``1/2`` for
points not within a few units in the last place of a triangle, which is all
the callers ask (they keep away from the surfaces).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel

#: points per task
CHUNK = 64


@inline_kernel
def _norm(x, y, z):
    return math.sqrt(x * x + y * y + z * z)


@inline_kernel
def _solid_angle(p, v, f, t):
    """Signed solid angle of triangle ``t`` (counter-clockwise seen from outside: positive
    seen from inside) seen from point ``p``."""
    i, j, k = f[t, 0], f[t, 1], f[t, 2]
    ax, ay, az = v[i, 0] - p[0], v[i, 1] - p[1], v[i, 2] - p[2]
    bx, by, bz = v[j, 0] - p[0], v[j, 1] - p[1], v[j, 2] - p[2]
    cx, cy, cz = v[k, 0] - p[0], v[k, 1] - p[1], v[k, 2] - p[2]
    la, lb, lc = _norm(ax, ay, az), _norm(bx, by, bz), _norm(cx, cy, cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
           + (cx * ax + cy * ay + cz * az) * lb)
    return 2.0 * math.atan2(det, den)


@parallel_kernel
def winding_numbers(points, vertices, faces):
    """The winding number of each point about a closed mesh.

    Parameters
    ----------
    points : (n, 3) float64, mm
    vertices : (v, 3) float64, mm
    faces : (t, 3) int64
        Closed, counter-clockwise seen from outside.

    Returns
    -------
    (n,) float64
        About 1 inside, 0 outside (k inside k nested or overlapping shells).
    """
    n = points.shape[0]
    out = np.zeros(n)
    for ch in prange((n + CHUNK - 1) // CHUNK):
        for q in range(ch * CHUNK, min(n, (ch + 1) * CHUNK)):
            p = (points[q, 0], points[q, 1], points[q, 2])
            s = 0.0
            for t in range(faces.shape[0]):
                s += _solid_angle(p, vertices, faces, t)
            out[q] = s / (4.0 * math.pi)
    return out
