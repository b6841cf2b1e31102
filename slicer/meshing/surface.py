"""The integral surface as a closed triangle mesh with a certified Hausdorff bound.

:func:`mesh_scene` meshes the solid ``F >= 1`` of a lattice (docs/mesh.md):

1. **Cells.** A grid of cubes of side ``h`` over the supports' box is
   explored as an octree: a cube is settled *inside* when a lower bound of F
   over it exceeds 1, *outside* when an upper bound is below 1, and split
   otherwise; the cubes of side ``h`` left unsettled are the *band*. The
   bounds over a cube are those over its circumscribed ball ``B(c, r)``: the
   tighter of the ball bounds of
   :func:`slicer._kernels.meshing.ballbounds.ball_bounds` and of the
   expansion ``F(c) ± (‖∇F(c)‖ r + H r²/2)`` (H bounds ‖∇²F‖ over the ball).
2. **Triangles.** Marching tetrahedra on the band's cubes, each cut into the
   six tetrahedra around its main diagonal (neighbouring cubes agree on
   their faces, so the mesh is closed; settled cubes have no sign change on
   their faces). Each vertex is the root of F on its grid edge, found by a
   bracketing secant (Illinois) iteration, shared by every tetrahedron on
   the edge. Triangles face from the edges' inside corners to their outside
   ones. The mesh's solid is the union of the settled-inside cubes and, in
   each band tetrahedron, the part on its inside corners' side.
3. **Certificate** (docs/mesh.md, "Why the bound holds").
   *Mesh to surface:* for each triangle T, with ``B(c, ρ)`` its smallest
   enclosing ball, linear interpolation on a simplex errs by at most ``ρ²/2``
   times the second derivatives along it (Waldron, 1998), so
   ``|F − 1| <= e_T = max_v |F(v) − 1| + H_T ρ²/2`` on T, with ``H_T``
   bounding them in T's plane over the ball; along ``∇F(c)`` the slope is at
   least ``g_T = ‖∇F(c)‖ − H (ρ + s)`` within ``s`` of T (``s <= tol``, a
   few sizes tried: :func:`slicer.meshing.certificate.distances_to_surface`), so every point of T is within
   ``e_T / g_T`` of the surface when that is at most s.
   *Surface to mesh:* in a band tetrahedron, the outside part is in the
   convex hull of its outside corners (F < 1) and its vertices
   (``F <= 1 + |F(v) − 1|``), so there ``F <= 1 + δ`` with
   ``δ = max_v |F(v) − 1| + H r²/2`` (r: the cube's circumradius, which
   holds the tetrahedron); likewise ``F >= 1 − δ`` in the inside part. A
   point with ``F > 1 + δ`` is thus in the solid, one with ``F < 1 − δ``
   outside it. For a surface point x in a band cube C with slope
   ``g_C = ‖∇F(c)‖ − H (r + s) > 0`` along ``∇F(c)`` (``s <= min(h, tol)``),
   and δ_C the largest δ of the 27 cubes around C, the points
   ``x ± (δ_C / g_C) ∇F(c)/‖∇F(c)‖`` are on either side of the mesh when
   ``δ_C / g_C <= s`` (they stay in those cubes and in the slope's ball): the
   mesh is within ``δ_C / g_C`` of x.
   The bound is the largest of these distances; it is certified only when
   every one is finite and at most ``tol``, else ``h`` shrinks and the mesh
   is made again.

Everything is float64; the field's bounds carry the relative slack of
:mod:`slicer._kernels.contours.cellbounds`. Degree-2 kernels (no curvature bound),
the union blend and parts with meshes are refused.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from itertools import permutations

import numpy as np

from slicer.arguments import integer, positive_number
from slicer.errors import OptionError, SceneError
from slicer.meshing.certificate import MeshField, SurfaceMesh, distances_to_surface, piece_distances
from slicer.meshing.compact import compact as simplified
from slicer.parts.part import Part
from slicer.model.skeleton import Skeleton

#: default tolerance, mm: the certified two-sided Hausdorff distance asked for
DEFAULT_TOL = 0.01
#: meshing attempts (each with a smaller cell) before giving up on the tolerance
ATTEMPTS = 6
#: finest cubes per coarse cube edge is 2**levels, with about this many coarse cubes along the longest side
COARSE = 16
#: most bracketing secant (Illinois) iterations per edge root
ROOT_STEPS = 40
#: most band cubes (about 1.5 kB of memory each while triangles are made)
MAX_BAND = 4_000_000

# cube corner k = dx + 2 dy + 4 dz; the six tetrahedra around the main diagonal 000 -> 111
_CORNERS = np.array([[(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=np.int64)


def _tetrahedra() -> np.ndarray:
    out = []
    for perm in permutations(range(3)):
        path = [np.zeros(3, np.int64)]
        for ax in perm:
            path.append(path[-1] + np.eye(3, dtype=np.int64)[ax])
        out.append([int(p[0] + 2 * p[1] + 4 * p[2]) for p in path])
    return np.array(out, dtype=np.int64)


_TETS = _tetrahedra()            # (6, 4) corner numbers


def lattice_of(scene) -> Skeleton:
    """The skeleton to mesh: a :class:`Skeleton`, or a :class:`Part` without meshes.

    Raises
    ------
    SceneError
        A part with solid or clipping meshes, no lattice, or a degree-2 kernel.
    """
    if isinstance(scene, Part):
        if scene.meshes:
            raise SceneError(f"the scene has {len(scene.meshes)} solid or clipping meshes ({scene.describe()}); "
                             f"mesh output covers lattices only so far (docs/mesh.md)", scene.source)
        scene = scene.skeleton
    if not isinstance(scene, Skeleton) or scene.n_segments == 0:
        raise SceneError("nothing to mesh: the scene has no lattice")
    if scene.degree < 4:
        raise SceneError(f"kernel degree {scene.degree}: the field's curvature is unbounded at the supports' "
                         f"edge, so no mesh can be certified; use degree 4 or more", scene.source)
    return scene


@dataclass
class _Grid:
    origin: np.ndarray      # (3,) float64, mm
    h: float                # finest cube side, mm
    levels: int             # coarse cube = 2**levels finest cubes
    coarse: np.ndarray      # (3,) int64 coarse cubes per axis

    def centres(self, idx: np.ndarray, level: int) -> np.ndarray:
        s = self.h * (1 << level)
        return self.origin + (idx + 0.5) * s

    def points(self, idx: np.ndarray) -> np.ndarray:
        return self.origin + idx * self.h


def _grid(skel: Skeleton, h: float) -> _Grid:
    box = skel.support_bounds()
    ext = box[1] - box[0]
    pad = 0.5 * h + 1e-9 * float(np.abs(box).max())
    levels = max(0, int(math.ceil(math.log2(max(float(ext.max()) + 2 * pad, h) / (COARSE * h)))))
    side = h * (1 << levels)
    coarse = np.maximum(1, np.ceil((ext + 2 * pad) / side)).astype(np.int64)
    centre = 0.5 * (box[0] + box[1])
    return _Grid(centre - 0.5 * coarse * side, h, levels, coarse)


def _settle(fld: MeshField, c: np.ndarray, r: float):
    """Cube verdicts from their balls ``B(c, r)``: ``(inside, outside)`` boolean arrays."""
    f, g = fld.values(c, gradient=True)
    U, L, H, _ = fld.balls_bounds(c, np.full(len(c), r))
    reach = np.linalg.norm(g, axis=1) * r + 0.5 * H * r * r
    hi = np.minimum(U, f + reach)
    lo = np.maximum(L, f - reach)
    return lo > 1.0, hi < 1.0


def _band(fld: MeshField, grid: _Grid):
    """The finest cubes the octree cannot settle, (b, 3) int64 indices, and the settled counts."""
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in grid.coarse], indexing="ij"), -1).reshape(-1, 3)
    counts = {"inside": 0, "outside": 0}
    for level in range(grid.levels, -1, -1):
        side = grid.h * (1 << level)
        ins, out = _settle(fld, grid.centres(idx, level), 0.5 * math.sqrt(3.0) * side)
        counts["inside"] += int(ins.sum())
        counts["outside"] += int(out.sum())
        idx = idx[~(ins | out)]
        if len(idx) > MAX_BAND:
            raise OptionError(f"the tolerance needs more than {MAX_BAND:,} cubes of {side:.4g} mm near the "
                              f"surface, more than this version keeps in memory; ask for a larger --tol")
        if level and len(idx):
            idx = (2 * idx[:, None, :] + _CORNERS[None]).reshape(-1, 3)
    order = np.lexsort((idx[:, 0], idx[:, 1], idx[:, 2]))
    return idx[order], counts


#: the band's size is estimated before any work; a job estimated at this many times
#: MAX_BAND is refused at once (the octree would refuse it later, after the work)
ESTIMATE_SLACK = 16


def _check_band_estimate(skel: Skeleton, h: float) -> None:
    """Refuse at once a cube side whose band would be far beyond :data:`MAX_BAND`.

    Every vertical line through the solid's shadow meets the surface, so the band's
    cubes (side h) cover that shadow: there are at least shadow / h² of them. The
    shadow is estimated from each strut's own tube (its thinner radius, projected
    length; the largest one), not bounded, hence the slack.
    """
    a = skel.nodes[skel.segments[:, 0], :2]
    b = skel.nodes[skel.segments[:, 1], :2]
    r = skel.radii.min(axis=1)
    shadow = float((2.0 * r * np.linalg.norm(b - a, axis=1) + np.pi * r * r).max())
    if shadow / (h * h) > ESTIMATE_SLACK * MAX_BAND:
        raise OptionError(f"the tolerance needs cubes of {h:.4g} mm: about {shadow / (h * h):.3g} of them near the "
                          f"surface, far more than the {MAX_BAND:,} this version keeps in memory; ask for a larger "
                          f"--tol")


def _roots(fld: MeshField, a: np.ndarray, b: np.ndarray, fa: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """Points of F = 1 on the segments ``a``..``b`` (``fa >= 1 > fb``): the Illinois
    variant of regula falsi, which keeps the root bracketed."""
    a, b = a.copy(), b.copy()
    fa, fb = fa - 1.0, fb - 1.0
    side = np.zeros(len(a), np.int8)
    for _ in range(ROOT_STEPS):
        w = fa / (fa - fb)
        w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 0.5)
        x = a + w[:, None] * (b - a)
        live = np.abs(b - a).max(axis=1) > 1e-12 * (1.0 + np.abs(a).max(axis=1))
        if not live.any():
            break
        fx = np.zeros(len(a))
        fx[live] = fld.values(x[live])[0] - 1.0
        hit = live & (fx >= 0.0)
        miss = live & (fx < 0.0)
        a[hit], fa[hit] = x[hit], fx[hit]
        b[miss], fb[miss] = x[miss], fx[miss]
        fb[hit & (side == 1)] *= 0.5
        fa[miss & (side == -1)] *= 0.5
        side = np.where(hit, 1, np.where(miss, -1, side)).astype(np.int8)
    w = fa / (fa - fb)
    w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 0.5)
    return a + w[:, None] * (b - a)


def _triangles(fld: MeshField, grid: _Grid, band: np.ndarray):
    """Marching tetrahedra on the band's cubes: vertices (v, 3), outward faces (t, 3) and
    the band cube of each face (t,)."""
    dims = grid.coarse * (1 << grid.levels) + 1
    corners = (band[:, None, :] + _CORNERS[None]).reshape(-1, 3)
    key = (corners[:, 2] * dims[1] + corners[:, 1]) * dims[0] + corners[:, 0]
    ukey, inv = np.unique(key, return_inverse=True)
    upts = np.stack([ukey % dims[0], (ukey // dims[0]) % dims[1], ukey // (dims[0] * dims[1])], -1)
    fval = fld.values(grid.points(upts))[0]
    ids = inv.reshape(-1, 8)[:, _TETS].reshape(-1, 4)           # (6 b, 4) vertex numbers
    cube = np.repeat(np.arange(len(band)), 6)
    inside = fval[ids] >= 1.0
    n_in = inside.sum(axis=1)
    keep = (n_in > 0) & (n_in < 4)
    ids, inside, n_in, cube = ids[keep], inside[keep], n_in[keep], cube[keep]
    # the tetrahedron's corners reordered: inside ones first (stable)
    order = np.argsort(~inside, axis=1, kind="stable")
    v = np.take_along_axis(ids, order, axis=1)
    tris, owner = [], []
    for k, pairs in ((1, ((0, 1), (0, 2), (0, 3))), (3, ((0, 3), (1, 3), (2, 3)))):
        sel = v[n_in == k]
        tris.append(np.stack([np.stack([sel[:, i], sel[:, j]], -1) for i, j in pairs], 1))
        owner.append(cube[n_in == k])
    sel = v[n_in == 2]                       # inside a, b; outside c, d: quad ac, ad, bd, bc
    quad = [np.stack([sel[:, i], sel[:, j]], -1) for i, j in ((0, 2), (0, 3), (1, 3), (1, 2))]
    tris.append(np.stack([quad[0], quad[1], quad[2]], 1))
    tris.append(np.stack([quad[0], quad[2], quad[3]], 1))
    owner += [cube[n_in == 2]] * 2
    edges = np.concatenate(tris)             # (t, 3, 2): per corner, the (inside, outside) grid vertex
    owner = np.concatenate(owner)
    if not len(edges):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), owner
    ekey = edges[..., 0] * len(ukey) + edges[..., 1]
    uedge, einv = np.unique(ekey.reshape(-1), return_inverse=True)
    ein, eout = uedge // len(ukey), uedge % len(ukey)
    pin, pout = grid.points(upts[ein]), grid.points(upts[eout])
    verts = _roots(fld, pin, pout, fval[ein], fval[eout])
    faces = einv.reshape(-1, 3).astype(np.int64)
    # orient each triangle from inside to outside, judged on the edges' midpoints (never degenerate)
    mid = 0.5 * (upts[edges[..., 0]] + upts[edges[..., 1]]).astype(np.float64)
    normal = np.cross(mid[:, 1] - mid[:, 0], mid[:, 2] - mid[:, 0])
    outward = (upts[edges[..., 1]] - upts[edges[..., 0]]).sum(axis=1)
    flip = np.einsum("ij,ij->i", normal, outward) < 0
    faces[flip] = faces[flip][:, ::-1]
    return verts, faces, owner


def _neighbourhood_max(band: np.ndarray, value: np.ndarray) -> np.ndarray:
    """For each band cube, the largest ``value`` over the band cubes of its 3 x 3 x 3 block."""
    span = band.max(axis=0) + 3 if len(band) else np.ones(3, np.int64)
    key = ((band[:, 2] + 1) * span[1] + band[:, 1] + 1) * span[0] + band[:, 0] + 1
    order = np.argsort(key)
    skey = key[order]
    out = value.copy()
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                k = key + (dz * span[1] + dy) * span[0] + dx
                j = np.minimum(np.searchsorted(skey, k), len(skey) - 1)
                hit = skey[j] == k
                out[hit] = np.maximum(out[hit], value[order[j[hit]]])
    return out


def _certify(fld: MeshField, grid: _Grid, band: np.ndarray, verts: np.ndarray, faces: np.ndarray, owner: np.ndarray,
             tol: float):
    """The two sides of the certified bound (module docstring, step 3)."""
    resid = np.abs(fld.values(verts)[0] - 1.0)
    d_tri = piece_distances(fld, verts[faces], tol, resid[faces])
    # surface to mesh: per band cube, from its 3 x 3 x 3 block's deviation bounds
    r = 0.5 * math.sqrt(3.0) * grid.h
    cc = grid.centres(band, 0)
    _, gc = fld.values(cc, gradient=True)
    _, _, Hr, _ = fld.balls_bounds(cc, np.full(len(cc), r))
    worst = np.zeros(len(band))
    if len(faces):
        np.maximum.at(worst, owner, resid[faces].max(axis=1))
    delta = _neighbourhood_max(band, (worst + 0.5 * Hr * r * r) * (1.0 + 1e-9))
    d_cell = distances_to_surface(fld, cc, np.full(len(cc), r), delta, np.linalg.norm(gc, axis=1), min(tol, grid.h))
    a = float(d_tri.max()) if len(d_tri) else 0.0
    b = float(d_cell.max()) if len(d_cell) else 0.0
    return a, b, {"uncertified_triangles": int(np.isinf(d_tri).sum()),
                  "uncertified_cubes": int(np.isinf(d_cell).sum())}


def mesh_scene(scene, tol: float = DEFAULT_TOL, cell: float | None = None, attempts: int = ATTEMPTS,
               compact: bool = True) -> SurfaceMesh:
    """Mesh the solid ``F >= 1`` of a lattice, with a certified Hausdorff bound.

    Parameters
    ----------
    scene : Skeleton or Part
        A lattice (a part without meshes), blend ``sum``, degree >= 4.
    tol : float, mm
        The two-sided Hausdorff distance to certify between the mesh and the
        surface ``F = 1``.
    cell : float, mm, optional
        Side of the band's cubes for the first attempt (default: from ``tol``
        and the thinnest radius, ``0.4 sqrt(tol r_min)``).
    attempts : int
        Attempts, each with a smaller cube when the bound is not certified.
    compact : bool
        Simplify the certified uniform mesh and certify the result again
        (:mod:`slicer.meshing.compact`): far fewer triangles within the same
        tolerance. False keeps the uniform mesh of marching tetrahedra.

    Returns
    -------
    SurfaceMesh
        Closed, consistently wound, manifold (watertight); ``bound`` is the
        certified Hausdorff distance (``certified``: ``bound <= tol``). The
        last attempt is returned even when it is not certified.

    Raises
    ------
    OptionError
        A tolerance or cell that is not a positive number, or a tolerance so
        fine the band of cubes would not fit in memory.
    SceneError
        As :func:`lattice_of`.

    Examples
    --------
    >>> from slicer import Skeleton
    >>> s = Skeleton([[0, 0, 0], [0, 0, 3]], [[0, 1]], [[1.0, 0.6]])
    >>> m = mesh_scene(s, tol=0.05)
    >>> m.certified, m.bound <= 0.05
    (True, True)
    >>> t = m.trimesh()
    >>> t.is_watertight, t.is_winding_consistent, bool(t.volume > 0)
    (True, True, True)
    """
    tol = positive_number(tol, "tol")
    attempts = integer(attempts, "attempts", lo=1)
    skel = lattice_of(scene)
    r_min = float(skel.radii.min())
    # cubes wider than half the thinnest strut see no more of it: a coarse tolerance starts there
    h = positive_number(cell, "cell") if cell is not None else min(0.4 * math.sqrt(tol * r_min), 0.5 * r_min)
    _check_band_estimate(skel, h)
    fld = MeshField(skel)
    start = time.perf_counter()
    out = None
    for attempt in range(1, attempts + 1):
        grid = _grid(skel, h)
        band, counts = _band(fld, grid)
        verts, faces, owner = _triangles(fld, grid, band)
        a, b, extra = _certify(fld, grid, band, verts, faces, owner, tol)
        bound = max(a, b)
        stats = {"attempts": attempt, "band_cubes": int(len(band)), "settled_inside": counts["inside"],
                 "settled_outside": counts["outside"], "field_points": fld.points, "field_balls": fld.balls,
                 "triangles": int(len(faces)), **extra}
        out = SurfaceMesh(verts, faces, tol, bound, a, b, h, stats)
        if bound <= tol:
            break
        h *= min(0.85, max(0.5, 0.95 * math.sqrt(tol / bound))) if math.isfinite(bound) else 0.7
    if compact and out.certified:
        out = simplified(fld, out, tol) or out
    out.stats["seconds"] = time.perf_counter() - start
    return out


__all__ = ["mesh_scene", "SurfaceMesh", "DEFAULT_TOL", "lattice_of"]
