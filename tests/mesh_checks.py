"""Independent checks of a surface mesh against the field (tests of slicer.meshing): plain
numpy, nothing of the mesher's code.

* :func:`mesh_points_near_surface`: points sampled on the triangles must have the surface
  F = 1 within ``tol`` along the field's gradient (a sign change of F - 1 on the segment
  ``p ± tol ĝ``).
* :func:`surface_points_on_lines`: points of the surface found by dense sampling and
  bisection of F on random lines through the scene's box.
* :func:`point_triangle_distance`: the distance from points to triangles (the closest point
  of each triangle: its plane's foot inside it, else the nearest edge point), brute force.
* :func:`assert_certified_mesh`: the acceptance check of a lattice's mesh, all of the above
  and the winding numbers of points well inside and outside.
"""
from __future__ import annotations

import numpy as np
import trimesh

from parts_helpers import winding_number
from slicer.model.field import evaluate


def assert_certified_mesh(skel, m, tol, n_lines=40):
    """A lattice's certified mesh ``m`` (a SurfaceMesh) passes the acceptance check at ``tol``:
    closed, consistently wound, outward; points on it have the surface within ``tol``; surface
    points on random lines are within ``tol`` of it; points with F >= 1.2 are inside it (winding
    number 1), points with F <= 0.8 outside (0)."""
    assert m.certified and m.bound <= tol and max(m.mesh_to_surface, m.surface_to_mesh) == m.bound
    t = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert t.is_watertight and t.is_winding_consistent and t.volume > 0
    # every edge in exactly two faces, once each way (oriented 2-manifold)
    e = np.concatenate([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]])
    assert len(np.unique(e, axis=0)) == len(e)
    assert len(mesh_points_near_surface(skel, m.vertices, m.faces, tol)) == 0
    surf = surface_points_on_lines(skel, n_lines=n_lines)
    assert len(surf) >= n_lines // 2
    d = point_triangle_distance(surf, m.vertices[m.faces])
    assert d.max() <= tol, d.max()
    lo, hi = skel.support_bounds()
    p = np.random.default_rng(5).uniform(lo, hi, (400, 3))
    f = evaluate(skel, p)[0]
    p = p[np.abs(f - 1) > 0.2]
    w = winding_number(m.vertices[m.faces], p, chunk=4)
    assert np.allclose(w, np.rint(w), atol=1e-6) and np.array_equal(np.rint(w) == 1, evaluate(skel, p)[0] > 1)


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
        best[i] = point_to_triangles(p, cand).min()
    return best


def point_to_triangles(p, tri):
    """Distance from the point p (3,) to each of the triangles (t, 3, 3), mm."""
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


# --- parts: the solid ((S ∩ CI) − CO) ∪ M with convex meshes ---

def convex_inside(vertices, faces, points):
    """Whether each point (q, 3) is in the convex mesh (closed, outward): on the inner side of
    every face's plane (its surface counts as inside)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    offset = np.einsum("tj,tj->t", n, tri[:, 0]) + 1e-12 * np.linalg.norm(n, axis=1)
    out = np.ones(len(points), bool)
    for t in range(len(faces)):
        out &= points @ n[t] <= offset[t]
    return out


def lattice_field(skel, points, blend="sum"):
    """The scene's field at points: a supported scene's largest group field (its own
    ``field``), else the field of ``blend``."""
    if getattr(skel, "groups", ()):
        return skel.field(points, blend)
    return evaluate(skel, points, blend=blend)[0]


def part_inside(skel, roles, points, blend="sum"):
    """Whether each point is in ``((S ∩ CI) − CO) ∪ M``: ``roles`` maps a role to a list of convex
    (vertices, faces); S is ``F >= 1`` (:func:`lattice_field`)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    s = lattice_field(skel, points, blend) >= 1.0 if skel is not None else np.zeros(len(points), bool)

    def any_of(role, empty):
        ms = roles.get(role, [])
        if not ms:
            return np.full(len(points), empty)
        return np.any([convex_inside(v, f, points) for v, f in ms], axis=0)

    return (s & any_of("clip-inside", True) & ~any_of("clip-outside", False)) | any_of("solid", False)


def part_mesh_points_off_surface(skel, roles, vertices, faces, tol, k_per_face=2, seed=0, steps=41,
                                 blend="sum"):
    """Points sampled on the mesh with no change of :func:`part_inside` on any of 54 segments
    ``p ± tol u`` (u: the face's normal, 13 axes of a cube's neighbours, 40 random), sampled
    ``steps`` times; empty:
    all pass (a change found is a true point of the solid's surface within tol)."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    w = rng.dirichlet([1.0, 1.0, 1.0], size=(len(faces), k_per_face))
    p = np.concatenate([np.einsum("tkj,tjd->tkd", w, tri), tri.mean(axis=1)[:, None]], axis=1)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    n = np.repeat(n, p.shape[1], axis=0)
    p = p.reshape(-1, 3)
    fixed = np.concatenate([[[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (0, 1) if z or y > 0 or
                             (y == 0 and x > 0)], np.random.default_rng(seed + 1).normal(size=(40, 3))])
    fixed /= np.linalg.norm(fixed, axis=1)[:, None]
    t = np.linspace(-tol, tol, steps)
    ok = np.zeros(len(p), bool)
    for u in [n] + [np.broadcast_to(d, p.shape) for d in fixed]:
        todo = np.flatnonzero(~ok)
        if not len(todo):
            break
        pts = p[todo, None, :] + t[None, :, None] * u[todo, None, :]
        inside = part_inside(skel, roles, pts.reshape(-1, 3), blend).reshape(len(todo), steps)
        ok[todo] = inside.any(axis=1) & ~inside.all(axis=1)
    return p[~ok]


def part_surface_points_on_lines(skel, roles, lo, hi, n_lines=40, step=0.004, seed=1, blend="sum"):
    """Points of the part's surface (each to 1e-12 mm) on random lines through random points of
    the box ``lo``..``hi``: changes of :func:`part_inside` found by dense sampling and bisection."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    span = float(np.linalg.norm(hi - lo))
    out = []
    for _ in range(n_lines):
        a = lo + rng.uniform(size=3) * (hi - lo)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        t = np.arange(-span, span, step)
        ins = part_inside(skel, roles, a + t[:, None] * d, blend)
        for i in np.flatnonzero(ins[:-1] != ins[1:]):
            t0, t1, s0 = t[i], t[i + 1], ins[i]
            for _ in range(50):
                tm = 0.5 * (t0 + t1)
                if part_inside(skel, roles, (a + tm * d)[None], blend)[0] == s0:
                    t0 = tm
                else:
                    t1 = tm
            out.append(a + 0.5 * (t0 + t1) * d)
    return np.array(out).reshape(-1, 3)
