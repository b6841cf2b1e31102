"""Independent checks of a surface mesh against the field (tests of slicer.meshing): plain
numpy, nothing of the mesher's code.

* :func:`mesh_points_near_surface`: points sampled on the triangles must have the surface
  F = 1 within ``tol`` along the field's gradient (a sign change of F - 1 on the segment
  ``p ± tol ĝ``).
* :func:`surface_points_on_lines`: points of the surface found by dense sampling and
  bisection of F on random lines through the scene's box.
* :func:`point_triangle_distance`: the distance from points to triangles (the closest point
  of each triangle: its plane's foot inside it, else the nearest edge point), brute force.
"""
from __future__ import annotations

import numpy as np

from slicer.model.field import evaluate


def mesh_points_near_surface(skel, vertices, faces, tol, k_per_face=2, seed=0):
    """Largest ``|F − 1|``-sign test failure: returns the points (q, 3) sampled on the mesh
    whose segment ``p ± tol ĝ(p)`` has no sign change of ``F − 1`` (empty: all pass)."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    w = rng.dirichlet([1.0, 1.0, 1.0], size=(len(faces), k_per_face))
    p = np.einsum("tkj,tjd->tkd", w, tri).reshape(-1, 3)
    p = np.vstack([p, tri.mean(axis=1)])
    f, g = evaluate(skel, p, gradient=True)
    u = g / np.linalg.norm(g, axis=1)[:, None]
    fp = evaluate(skel, p + tol * u)[0]
    fm = evaluate(skel, p - tol * u)[0]
    ok = ((fp >= 1.0) & (fm <= 1.0)) | ((fp <= 1.0) & (fm >= 1.0))
    return p[~ok]


def surface_points_on_lines(skel, n_lines=60, step=0.004, seed=1):
    """Points of F = 1 (each to 1e-12 mm) on random lines, each through a random point of a
    random strut's axis (so that it meets the solid), in a random direction."""
    rng = np.random.default_rng(seed)
    lo, hi = skel.support_bounds()
    ends = skel.nodes[skel.segments]
    out = []
    for _ in range(n_lines):
        s = rng.integers(len(ends))
        a = ends[s, 0] + rng.uniform() * (ends[s, 1] - ends[s, 0])
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        span = float(np.linalg.norm(hi - lo))
        t = np.arange(-span, span, step)
        pts = a + t[:, None] * d
        f = evaluate(skel, pts)[0] - 1.0
        for i in np.flatnonzero(np.sign(f[:-1]) != np.sign(f[1:])):
            t0, t1, f0 = t[i], t[i + 1], f[i]
            for _ in range(60):
                tm = 0.5 * (t0 + t1)
                fm = evaluate(skel, (a + tm * d)[None])[0][0] - 1.0
                if np.sign(fm) == np.sign(f0):
                    t0, f0 = tm, fm
                else:
                    t1 = tm
            out.append(a + 0.5 * (t0 + t1) * d)
    return np.array(out).reshape(-1, 3)


def point_triangle_distance(points, tri):
    """Distance from each point (q, 3) to the nearest of the triangles (t, 3, 3), mm."""
    best = np.full(len(points), np.inf)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    for i, p in enumerate(points):
        # triangles whose box is within the best distance so far (start with a loose cut)
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        box = np.linalg.norm(gap, axis=1)
        cand = tri[box <= np.sort(box)[min(len(box) - 1, 50)] + 0.05]
        best[i] = _distances(p, cand).min()
    return best


def _distances(p, tri):
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    s = np.einsum("ij,ij->i", p - a, n) / np.where(nn > 0, nn, 1.0)
    foot = p - s[:, None] * n
    inside = np.ones(len(tri), bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, foot - u), n) >= 0
    d = np.where(inside & (nn > 0), np.linalg.norm(p - foot, axis=1), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        ee = np.einsum("ij,ij->i", e, e)
        t = np.clip(np.einsum("ij,ij->i", p - u, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(p - (u + t[:, None] * e), axis=1))
    return d
