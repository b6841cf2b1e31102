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
   is made again. A mesh to be simplified shrinks it only where the cubes
   fail (:func:`_finer`): those cubes, cut into eight, are meshed and
   certified on a finer grid of their own, whose mesh (a *patch*) the
   simplified mesh's certificate counts too.

Everything is float64; the field's bounds carry the relative slack of
:mod:`slicer._kernels.contours.cellbounds`. Degree-2 kernels (no curvature bound)
are refused; unions (supports, the union blend) and parts with meshes are
:func:`slicer.meshing.mesh_part`'s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
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
#: most band cubes (about 0.4 kB of memory each, with their triangles, once the mesh is made)
MAX_BAND = 12_000_000
#: most candidate cubes at a coarser level, as a multiple of MAX_BAND (24 bytes each)
CANDIDATES = 4
#: cubes (or triangles, or vertices) handled at once: the working memory's unit
CHUNK = 200_000

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
        A part with solid or clipping meshes (:func:`slicer.meshing.mesh_part` meshes those),
        no lattice, groups of struts (supports), or a degree-2 kernel.
    """
    if isinstance(scene, Part):
        if scene.meshes:
            raise SceneError(f"the scene has {len(scene.meshes)} solid or clipping meshes ({scene.describe()}); "
                             f"mesh_scene meshes lattices alone: use slicer.meshing.mesh_part", scene.source)
        scene = scene.skeleton
    if not isinstance(scene, Skeleton) or scene.n_segments == 0:
        raise SceneError("nothing to mesh: the scene has no lattice")
    if getattr(scene, "groups", ()):
        raise SceneError(f"the scene's struts fall in {len(scene.groups)} groups that unite (supports and a pad); "
                         f"mesh_scene meshes one summed lattice: use slicer.meshing.mesh_part", scene.source)
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


def settle(fld: MeshField, c: np.ndarray, r: float):
    """Cube verdicts from their balls ``B(c, r)``: ``(inside, outside)`` boolean arrays."""
    f, g = fld.values(c, gradient=True)
    U, L, H, _ = fld.balls_bounds(c, np.full(len(c), r))
    reach = np.linalg.norm(g, axis=1) * r + 0.5 * H * r * r
    hi = np.minimum(U, f + reach)
    lo = np.maximum(L, f - reach)
    return lo > 1.0, hi < 1.0


def _chunks(arrays, size: int):
    """The rows of a list of arrays, in slices of at most ``size``."""
    for arr in arrays:
        for lo in range(0, len(arr), size):
            yield arr[lo:lo + size]


def _band(fld: MeshField, grid: _Grid):
    """The finest cubes the octree cannot settle, (b, 3) int64 indices, and the settled counts.

    Cubes are settled :data:`CHUNK` at a time, and the survivors of each level split into
    their eight children, so the memory in use stays a few bytes per candidate cube.
    """
    cubes = [np.stack(np.meshgrid(*[np.arange(n) for n in grid.coarse], indexing="ij"), -1).reshape(-1, 3)]
    counts = {"inside": 0, "outside": 0}
    for level in range(grid.levels, -1, -1):
        side = grid.h * (1 << level)
        kept, n = [], 0
        for part in _chunks(cubes, CHUNK if level == 0 else CHUNK // 8):
            ins, out = settle(fld, grid.centres(part, level), 0.5 * math.sqrt(3.0) * side)
            counts["inside"] += int(ins.sum())
            counts["outside"] += int(out.sum())
            part = part[~(ins | out)]
            if level:
                part = (2 * part[:, None, :] + _CORNERS[None]).reshape(-1, 3)
            n += len(part)
            if n > MAX_BAND * (CANDIDATES if level else 1):
                raise OptionError(f"the mesh needs more than {MAX_BAND:,} cubes of {grid.h:.4g} mm near the "
                                  f"surface, more than this version keeps in memory")
            kept.append(part)
        cubes = kept
    idx = np.concatenate(cubes) if cubes else np.zeros((0, 3), np.int64)
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
    variant of regula falsi, which keeps the root bracketed. Each segment is iterated
    until its bracket is at most about 1e-12 mm long (or holds an exact root), at
    most :data:`ROOT_STEPS` times; the segments still open are the only ones evaluated."""
    a, b = a.copy(), b.copy()
    fa, fb = fa - 1.0, fb - 1.0
    side = np.zeros(len(a), np.int8)
    act = np.arange(len(a))
    for _ in range(ROOT_STEPS):
        aa, bb = a[act], b[act]
        act = act[np.abs(bb - aa).max(axis=1) > 1e-12 * (1.0 + np.abs(aa).max(axis=1))]
        if not len(act):
            break
        fa_, fb_ = fa[act], fb[act]
        w = fa_ / (fa_ - fb_)
        w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 0.5)
        x = a[act] + w[:, None] * (b[act] - a[act])
        fx = fld.values(x)[0] - 1.0
        hit, miss = act[fx >= 0.0], act[fx < 0.0]
        a[hit], fa[hit] = x[fx >= 0.0], fx[fx >= 0.0]
        b[miss], fb[miss] = x[fx < 0.0], fx[fx < 0.0]
        fb[hit[side[hit] == 1]] *= 0.5
        fa[miss[side[miss] == -1]] *= 0.5
        side[hit], side[miss] = 1, -1
        act = act[fx != 0.0]
    w = fa / (fa - fb)
    w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 0.5)
    return a + w[:, None] * (b - a)


def _chunk_triangles(fld: MeshField, grid: _Grid, cubes: np.ndarray):
    """Marching tetrahedra on some band cubes (module docstring, step 2).

    Returns
    -------
    keys : (e,) int64
        The crossed grid edges, by a key of the whole grid (:func:`_edge_keys`), sorted.
    points : (e, 3) float64, mm
        Their roots of F = 1.
    faces : (t, 3) int64
        Outward triangles, in positions of ``keys``.
    owner : (t,) int64
        The position in ``cubes`` of each face's cube.
    """
    dims = grid.coarse * (1 << grid.levels) + 1
    corners = cubes[:, None, :] + _CORNERS[None]                                   # (b, 8, 3)
    ckey = (corners[..., 2] * dims[1] + corners[..., 1]) * dims[0] + corners[..., 0]
    ukey, inv = np.unique(ckey.reshape(-1), return_inverse=True)
    inv = inv.reshape(-1, 8)
    upts = np.stack([ukey % dims[0], (ukey // dims[0]) % dims[1], ukey // (dims[0] * dims[1])], -1)
    fval = fld.values(grid.points(upts))[0]
    cube = np.repeat(np.arange(len(cubes)), 6)
    corner = np.tile(_TETS, (len(cubes), 1))                                      # (6 b, 4) corner numbers
    inside = fval[inv[cube[:, None], corner]] >= 1.0
    n_in = inside.sum(axis=1)
    keep = (n_in > 0) & (n_in < 4)
    corner, inside, n_in, cube = corner[keep], inside[keep], n_in[keep], cube[keep]
    # the tetrahedron's corners reordered: inside ones first (stable)
    corner = np.take_along_axis(corner, np.argsort(~inside, axis=1, kind="stable"), axis=1)
    tris, owner = [], []
    for k, pairs in ((1, ((0, 1), (0, 2), (0, 3))), (3, ((0, 3), (1, 3), (2, 3)))):
        sel = corner[n_in == k]
        tris.append(np.stack([np.stack([sel[:, i], sel[:, j]], -1) for i, j in pairs], 1))
        owner.append(cube[n_in == k])
    sel = corner[n_in == 2]                  # inside a, b; outside c, d: quad ac, ad, bd, bc
    quad = [np.stack([sel[:, i], sel[:, j]], -1) for i, j in ((0, 2), (0, 3), (1, 3), (1, 2))]
    tris.append(np.stack([quad[0], quad[1], quad[2]], 1))
    tris.append(np.stack([quad[0], quad[2], quad[3]], 1))
    owner += [cube[n_in == 2]] * 2
    edges = np.concatenate(tris)             # (t, 3, 2): per corner, the (inside, outside) corner numbers
    owner = np.concatenate(owner)
    if not len(edges):
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.int64), owner
    c_in, c_out = edges[..., 0], edges[..., 1]
    tcube = owner[:, None]
    # two corners of one tetrahedron are on a monotone path: the lower is their AND, the step their XOR
    gkey = ckey[tcube, c_in & c_out] * 7 + ((c_in ^ c_out) - 1)
    keys, first, einv = np.unique(gkey.reshape(-1), return_index=True, return_inverse=True)
    fc, fi, fo = tcube.repeat(3, 1).reshape(-1)[first], c_in.reshape(-1)[first], c_out.reshape(-1)[first]
    v_in, v_out = inv[fc, fi], inv[fc, fo]
    points = _roots(fld, grid.points(upts[v_in]), grid.points(upts[v_out]), fval[v_in], fval[v_out])
    faces = einv.reshape(-1, 3).astype(np.int64)
    # orient each triangle from inside to outside, judged on the edges' midpoints (never degenerate)
    p_in = cubes[tcube] + _CORNERS[c_in]
    p_out = cubes[tcube] + _CORNERS[c_out]
    mid = 0.5 * (p_in + p_out).astype(np.float64)
    normal = np.cross(mid[:, 1] - mid[:, 0], mid[:, 2] - mid[:, 0])
    flip = np.einsum("ij,ij->i", normal, (p_out - p_in).sum(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return keys, points, faces, owner


def _triangles(fld: MeshField, grid: _Grid, band: np.ndarray):
    """Marching tetrahedra on the band's cubes, :data:`CHUNK` cubes at a time: vertices
    (v, 3), outward faces (t, 3) and the band cube of each face (t,).

    A vertex is known by its grid edge's key in the whole grid, so the chunks' meshes
    join where they meet (an edge on a chunk's border has the same root from either
    side: the same end points and values); vertices come sorted by that key.
    """
    keys, points, faces, owner = [], [], [], []
    n_keys = 0
    for lo in range(0, len(band), CHUNK):
        k, p, f, o = _chunk_triangles(fld, grid, band[lo:lo + CHUNK])
        faces.append(f + n_keys)
        n_keys += len(k)
        keys.append(k)
        points.append(p)
        owner.append(o + lo)
    if not n_keys:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    keys = np.concatenate(keys)
    _, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    verts = np.concatenate(points)[first]
    return verts, inv[np.concatenate(faces)].astype(np.int64), np.concatenate(owner)


def _neighbourhood_max(band: np.ndarray, value: np.ndarray) -> np.ndarray:
    """For each band cube, the largest ``value`` over the band cubes of its 3 x 3 x 3 block."""
    span = band.max(axis=0) + 3 if len(band) else np.ones(3, np.int64)
    key = ((band[:, 2] + 1) * span[1] + band[:, 1] + 1) * span[0] + band[:, 0] + 1
    order = np.argsort(key)
    skey = key[order]
    out = value.copy()
    for lo in range(0, len(band), CHUNK):
        part = slice(lo, lo + CHUNK)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    k = key[part] + (dz * span[1] + dy) * span[0] + dx
                    j = np.minimum(np.searchsorted(skey, k), len(skey) - 1)
                    hit = skey[j] == k
                    o = out[part]
                    o[hit] = np.maximum(o[hit], value[order[j[hit]]])
                    out[part] = o
    return out


#: safety factor on the cube side a failed attempt predicts (:func:`_next_cell`)
NEXT_CELL_MARGIN = 0.9


#: levels of sub cubes a cube's curvature bounds are taken over again when it is not certified
SPLIT_LEVELS = 2
#: ... only while the cubes not certified are at most this share of the band (per level)
SPLIT_SHARE = (0.2, 0.02)
#: the vertices' residual ``|F(v) − 1|`` the cubes are first certified with, before the
#: triangles exist (roots are iterated to about 1e-12 mm, so residuals are near 1e-12);
#: cubes next to a larger residual are certified again once it is known
RESIDUAL = 1e-9


def _cube_bounds(fld: MeshField, grid: _Grid, band: np.ndarray):
    """Per band cube: ``‖∇F(c)‖`` at its centre and the bound H over its ball, :data:`CHUNK` at a time."""
    r = 0.5 * math.sqrt(3.0) * grid.h
    g = np.zeros(len(band))
    Hr = np.zeros(len(band))
    for lo in range(0, len(band), CHUNK):
        cc = grid.centres(band[lo:lo + CHUNK], 0)
        g[lo:lo + CHUNK] = np.linalg.norm(fld.values(cc, gradient=True)[1], axis=1)
        Hr[lo:lo + CHUNK] = fld.balls_bounds(cc, np.full(len(cc), r))[2]
    return g, Hr


def _sub_cubes(grid: _Grid, cubes: np.ndarray, level: int) -> np.ndarray:
    """Centres (k, 8**level, 3) of the cubes of side ``h / 2**level`` making up each cube, mm
    (their balls, of radius ``√3 h / 2**(level + 1)``, cover the cube)."""
    q = 1 << level
    grid_pts = np.stack(np.meshgrid(*[np.arange(q)] * 3, indexing="ij"), -1).reshape(-1, 3)
    offs = (grid_pts + 0.5) / q - 0.5
    return grid.centres(cubes, 0)[:, None, :] + offs[None] * grid.h


def _split_bounds(fld: MeshField, grid: _Grid, band: np.ndarray, which: np.ndarray, level: int) -> np.ndarray:
    """H over the cubes ``which`` as the largest of their sub cubes' ball bounds (level 1:
    halves, 2: quarters; tighter than the whole cube's ball, as the bounds loosen with the
    ball's radius)."""
    idx = np.flatnonzero(which)
    out = np.zeros(len(idx))
    q = 8 ** level
    rho = math.sqrt(3.0) * grid.h / (2 << level)
    step = max(1, CHUNK // q)
    for lo in range(0, len(idx), step):
        sub = _sub_cubes(grid, band[idx[lo:lo + step]], level).reshape(-1, 3)
        out[lo:lo + step] = fld.balls_bounds(sub, np.full(len(sub), rho))[2].reshape(-1, q).max(axis=1)
    return out


def _cube_distances(fld: MeshField, grid: _Grid, band: np.ndarray, g: np.ndarray, Hr: np.ndarray, worst: np.ndarray,
                    tol: float, which: np.ndarray | None = None, split: int = 0) -> np.ndarray:
    """Surface to mesh (module docstring, step 3): per band cube (or the cubes ``which``), the
    certified distance from its surface points to the mesh, from the deviation bounds of its
    3 x 3 x 3 block, with ``worst`` each cube's largest vertex residual (inf: not certified);
    ``split`` > 0: the slope's curvature bound over the balls of the sub cubes of that level
    (:func:`_sub_cubes`)."""
    r = 0.5 * math.sqrt(3.0) * grid.h
    delta = _neighbourhood_max(band, (np.maximum(worst, RESIDUAL) + 0.5 * Hr * r * r) * (1.0 + 1e-9))
    idx = np.arange(len(band)) if which is None else np.flatnonzero(which)
    out = np.zeros(len(idx))
    step = max(1, CHUNK // 8 ** split)
    for lo in range(0, len(idx), step):
        k = idx[lo:lo + step]
        cover = (_sub_cubes(grid, band[k], split), math.sqrt(3.0) * grid.h / (2 << split)) if split else None
        # without a split the balls tried hold the cube's ball, over which H is Hr
        out[lo:lo + step] = distances_to_surface(fld, grid.centres(band[k], 0), np.full(len(k), r), delta[k], g[k],
                                                 min(tol, grid.h), cover, floor=None if split else Hr[k])
    return out


def _surface_to_mesh(fld: MeshField, grid: _Grid, band: np.ndarray, g: np.ndarray, Hr: np.ndarray, worst: np.ndarray,
                     tol: float, which: np.ndarray | None = None) -> np.ndarray:
    """:func:`_cube_distances` of every band cube (or of the cubes ``which``; the others get 0);
    where a cube is not certified within ``tol``, its block's curvature bounds are taken again
    over half cubes, then quarter cubes (``Hr`` is updated in place), and the cube certified
    again with them, as long as such cubes are at most :data:`SPLIT_SHARE` of those certified
    (else the attempt fails at once)."""
    todo = np.ones(len(band), bool) if which is None else which
    d = np.zeros(len(band))
    d[todo] = _cube_distances(fld, grid, band, g, Hr, worst, tol, which)
    for level in range(1, SPLIT_LEVELS + 1):
        bad = todo & ~(d <= tol)
        if not bad.any() or bad.sum() > SPLIT_SHARE[level - 1] * todo.sum():
            break
        near = _neighbourhood_max(band, bad.astype(np.float64)) > 0
        Hr[near] = np.minimum(Hr[near], _split_bounds(fld, grid, band, near, level))
        d[bad] = _cube_distances(fld, grid, band, g, Hr, worst, tol, bad, split=level)
    return d


def _residuals(fld: MeshField, verts: np.ndarray) -> np.ndarray:
    """Each vertex's residual ``|F(v) − 1|``, :data:`CHUNK` at a time."""
    return np.concatenate([np.abs(fld.values(verts[lo:lo + CHUNK])[0] - 1.0) for lo in range(0, len(verts), CHUNK)]
                          or [np.zeros(0)])


def _triangle_distances(fld: MeshField, verts: np.ndarray, faces: np.ndarray, tol: float, resid: np.ndarray):
    """Mesh to surface (module docstring, step 3): per triangle, the certified distance from
    its points to the surface (inf: not certified), given the vertices' residuals."""
    return np.concatenate([piece_distances(fld, verts[f], tol, resid[f])
                           for f in _chunks([faces], CHUNK)] or [np.zeros(0)])


def _next_cell(h: float, g: np.ndarray, H: np.ndarray) -> float:
    """The cube side at which cubes of slope ``g`` and curvature bound ``H`` (over their
    ball) could be certified, or inf when none is given.

    A surface point is certified when some reach s has ``δ / (g − H (r + s)) <= s``
    (step 3), with ``δ`` about ``H r²/2``; the best s gives ``(g − H r)² >= 2 H² r²``,
    that is ``r <= g / ((1 + √2) H)`` (``H`` as measured at the larger cube, an
    optimistic guess, hence :data:`NEXT_CELL_MARGIN`).
    """
    ok = H > 0
    if not ok.any():
        return math.inf
    r = float((g[ok] / ((1.0 + math.sqrt(2.0)) * H[ok])).min())
    return NEXT_CELL_MARGIN * 2.0 * r / math.sqrt(3.0) if r > 0 else math.inf


@dataclass
class Band:
    """The band of a uniform mesh: the cubes of side ``h`` not settled inside or outside.

    Off these cubes the mesh's solid and the surface's are the same (docs/mesh.md, "Parts").

    Attributes
    ----------
    grid : the cubes' grid (origin, side ``h``)
    cubes : (b, 3) int64
        Indices of the band's cubes, sorted by (z, y, x).
    """

    grid: _Grid
    cubes: np.ndarray
    #: sorted keys of the cubes holding band cubes, per level (filled as :meth:`contains` asks)
    _keys_by_level: dict = field(default_factory=dict, init=False, repr=False)

    @property
    def h(self) -> float:
        """The cubes' side, mm."""
        return self.grid.h

    def centres(self) -> np.ndarray:
        """(b, 3) float64, mm."""
        return self.grid.centres(self.cubes, 0)

    def _keys(self, idx: np.ndarray, level: int) -> np.ndarray:
        """A key per cube index triple (..., 3) of cubes ``2**level`` times the side (any
        integers: those off the grid fall on a ring around it that holds no band cube)."""
        span = ((self.grid.coarse << self.grid.levels) >> level) + 3
        idx = np.clip(idx + 1, 0, span - 1)
        return (idx[..., 2] * span[1] + idx[..., 1]) * span[0] + idx[..., 0]

    def contains(self, idx: np.ndarray, level: int = 0) -> np.ndarray:
        """Whether each cube index triple (..., 3) is a band cube, or (``level`` > 0) a cube
        ``2**level`` times the side, ``idx >> level``, holding one."""
        own = self._keys_by_level.get(level)
        if own is None:
            own = self._keys_by_level[level] = np.unique(self._keys(self.cubes >> level, level))
        k = self._keys(idx, level)
        if not len(own):
            return np.zeros(k.shape, bool)
        j = np.minimum(np.searchsorted(own, k), len(own) - 1)
        return own[j] == k


def _meshed(fld: MeshField, grid: _Grid, band: np.ndarray):
    """Marching tetrahedra on the band (:func:`_triangles`): vertices (v, 3) float64 mm, faces
    (t, 3) int64, each face's cube (t,), the vertices' residuals ``|F(v) − 1|`` (v,) and each
    cube's largest (b,)."""
    verts, faces, owner = _triangles(fld, grid, band)
    resid = _residuals(fld, verts)
    worst = np.zeros(len(band))
    if len(faces):
        np.maximum.at(worst, owner, resid[faces].max(axis=1))
    return verts, faces, owner, resid, worst


def _mesh_band(fld: MeshField, grid: _Grid, band: np.ndarray, g: np.ndarray, Hr: np.ndarray, d_cell: np.ndarray,
               tol: float):
    """Marching tetrahedra on the band (:func:`_triangles`), and the cubes next to a vertex
    residual above :data:`RESIDUAL` certified again with it.

    Returns
    -------
    vertices (v, 3) float64 mm, faces (t, 3) int64, each face's cube (t,), residuals (v,) and
    the cubes' distances (b,) mm, ``d_cell`` updated.
    """
    verts, faces, owner, resid, worst = _meshed(fld, grid, band)
    d_cell = d_cell.copy()
    if (worst > RESIDUAL).any():      # certified again with the residuals found
        redo = _neighbourhood_max(band, worst) > RESIDUAL
        d_redo = _cube_distances(fld, grid, band, g, Hr, worst, tol, redo)
        again = ~(d_redo <= tol)
        if again.any():
            which = np.zeros(len(band), bool)
            which[np.flatnonzero(redo)[again]] = True
            d_redo[again] = _cube_distances(fld, grid, band, g, Hr, worst, tol, which, split=SPLIT_LEVELS)
        d_cell[redo] = d_redo
    return verts, faces, owner, resid, d_cell


def _face_bounds(band: np.ndarray, d: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Per face, the largest certified distance ``d`` (per band cube, mm) of the cubes around its
    cube ``owner``: a surface point in a cube C is within ``d[C]`` of a face of C's 3 x 3 x 3
    block (step 3), so a face serves the surface points of the cubes around its own."""
    return _neighbourhood_max(band, d)[owner] if len(owner) else np.zeros(0)


#: levels of finer cubes (each half the last's side) certifying the surface where the band's
#: cubes cannot, before a smaller cube everywhere is tried (a mesh made for simplifying)
FINER_LEVELS = 3
#: ... where a cube's certified distance exceeds this share of the tolerance (the rest is the simplification's)
FINER_SHARE = 0.5


#: finer cubes near the surface per cube cut into eight (about four where the surface is flat at their scale)
FINER_PER_CUBE = 4


def _finer_region(band: np.ndarray, bad: np.ndarray, n_cubes: int) -> np.ndarray | None:
    """The band cubes ``bad`` with their neighbours (positions in ``band``), or None when, cut
    into eight, they are likely to leave more than :data:`MAX_BAND` finer cubes near the
    surface (with ``n_cubes`` made already): an estimate made before any work, which
    :func:`_finer` checks once they are made."""
    region = np.flatnonzero(_neighbourhood_max(band, bad.astype(np.float64)) > 0)
    return region if n_cubes + FINER_PER_CUBE * len(region) <= MAX_BAND else None


def _finer(fld: MeshField, grid: _Grid, band: np.ndarray, bad: np.ndarray, tol: float, stats: dict):
    """Finer meshes certifying the surface in the band cubes ``bad`` (docs/mesh.md, step 3, "Finer cubes").

    The cubes ``bad`` and their 26 neighbours are cut into eight; those the octree's bounds
    cannot settle are meshed by marching tetrahedra on their own grid (half the side, the
    same origin), and the halves of ``bad`` certified with the surface-to-mesh argument of
    step 3 on that mesh: their 3 x 3 x 3 blocks of half cubes lie in the cubes cut, so the
    points on either side of a surface point are on either side of the finer mesh, whose
    triangles there are all made. Halves not certified go to the next level, up to
    :data:`FINER_LEVELS`.

    Returns
    -------
    (patches, bound), or None when some cubes are still not certified at the last level or
    the finer cubes outnumber :data:`MAX_BAND`: each patch (vertices (p, 3) float64 mm,
    faces (q, 3) int64, bounds (q,) mm: :func:`_face_bounds`) is a level's mesh, and ``bound``
    (mm) the largest distance certified.
    """
    patches, bound, n_cubes = [], 0.0, 0
    levels = []
    for level in range(1, FINER_LEVELS + 1):
        region = _finer_region(band, bad, n_cubes)
        if region is None:
            return None
        fine = _Grid(grid.origin, 0.5 * grid.h, grid.levels + 1, grid.coarse)
        r = 0.5 * math.sqrt(3.0) * fine.h
        cubes, inner = [], []
        for lo in range(0, len(region), CHUNK // 8):
            part = region[lo:lo + CHUNK // 8]
            sub = (2 * band[part][:, None, :] + _CORNERS[None]).reshape(-1, 3)
            ins, out = settle(fld, fine.centres(sub, 0), r)
            keep = ~(ins | out)
            cubes.append(sub[keep])
            inner.append(np.repeat(bad[part], 8)[keep])
        band = np.concatenate(cubes) if cubes else np.zeros((0, 3), np.int64)
        inner = np.concatenate(inner) if inner else np.zeros(0, bool)
        n_cubes += len(band)
        if n_cubes > MAX_BAND:
            return None
        g, Hr = _cube_bounds(fld, fine, band)
        verts, faces, owner, _, worst = _meshed(fld, fine, band)
        d = _surface_to_mesh(fld, fine, band, g, Hr, worst, tol, inner)
        certified = inner & (d <= FINER_SHARE * tol)
        bound = max(bound, float(d[certified].max(initial=0.0)))
        patches.append((verts, faces, _face_bounds(band, np.where(certified, d, 0.0), owner)))
        bad = inner & ~certified
        levels.append({"cube": fine.h, "cubes": int(len(band)), "certified": int(certified.sum()),
                       "triangles": int(len(faces))})
        grid = fine
        if not bad.any():
            stats["finer"] = levels
            return patches, bound
    stats["finer"] = levels
    return None


def uniform_mesh(fld: MeshField, tol: float, cell: float | None, attempts: int, triangles: bool = True,
                 graded: bool = False):
    """The certified uniform mesh of marching tetrahedra (steps 1-3), with smaller cubes at
    each attempt until the bound is at most ``tol``, and its band.

    ``triangles=False`` leaves out the certificate of the triangles (mesh to surface), which
    a mesh simplified next does not need (it certifies its own): the attempts stop once the
    cubes are certified, and ``mesh_to_surface`` and ``bound`` are nan
    (:func:`certify_triangles` adds them). With ``graded`` too (it needs ``triangles=False``),
    an attempt (but the last) whose cubes are not all certified is kept when finer meshes
    certify the surface in those with a bound above ``FINER_SHARE * tol``
    (:func:`_finer`, the result's ``patches``): the mesh is then certified only together with
    them, as its simplification is (:func:`slicer.meshing.compact.simplified`).

    Returns
    -------
    SurfaceMesh
        The last attempt's (certified or not).
    Band
        Its cubes not settled.
    """
    skel = fld.skel
    r_min = float(skel.radii.min())
    # cubes wider than half the thinnest strut see no more of it: a coarse tolerance starts there
    h = positive_number(cell, "cell") if cell is not None else min(0.4 * math.sqrt(tol * r_min), 0.5 * r_min)
    _check_band_estimate(skel, h)
    out = None
    for attempt in range(1, attempts + 1):
        grid = _grid(skel, h)
        try:
            band, counts = _band(fld, grid)
        except OptionError as err:
            if out is None:
                raise OptionError(f"{err}; ask for a larger --tol") from None
            raise OptionError(f"{err}: at cubes of {out.cell:.4g} mm, {out.stats['uncertified_cubes']:,} of the "
                              f"{out.stats['band_cubes']:,} band cubes could not be certified (the curvature bounds "
                              f"are large where struts meet), and a larger --tol does not make them larger "
                              f"(docs/mesh.md, 'Where struts meet')") from None
        # the cubes first: an attempt they cannot certify is not triangulated (but the last)
        g, Hr = _cube_bounds(fld, grid, band)
        d_cell = _surface_to_mesh(fld, grid, band, g, Hr, np.zeros(len(band)), tol)
        b = float(d_cell.max()) if len(d_cell) else 0.0
        stats = {"attempts": attempt, "band_cubes": int(len(band)), "settled_inside": counts["inside"],
                 "settled_outside": counts["outside"]}
        if b > tol and graded and not triangles and attempt < attempts \
                and _finer_region(band, ~(d_cell <= FINER_SHARE * tol), 0) is not None:
            # the next attempt's cube side, as an attempt without finer meshes would choose it
            next_cell = _smaller_cell(h, tol, b, g[~np.isfinite(d_cell)], Hr[~np.isfinite(d_cell)])
            verts, faces, owner, resid, d_meshed = _mesh_band(fld, grid, band, g, Hr, d_cell, tol)
            bad = ~(d_meshed <= FINER_SHARE * tol)
            finer = _finer(fld, grid, band, bad, tol, stats)
            if finer is not None:
                patches, b_finer = finer
                b = max(float(d_meshed[~bad].max(initial=0.0)), b_finer)
                stats.update(triangles=int(len(faces)), refined_cubes=int(bad.sum()), field_points=fld.points,
                             field_balls=fld.balls, next_cell=next_cell)
                out = SurfaceMesh(verts, faces, tol, math.nan, math.nan, b, h, stats, patches,
                                  _face_bounds(band, np.where(bad, 0.0, d_meshed), owner))
                return out, Band(grid, band)
            # not kept: the next cube side is the one an attempt without finer meshes chooses
        if b <= tol or attempt == attempts:
            verts, faces, _, resid, d_cell = _mesh_band(fld, grid, band, g, Hr, d_cell, tol)
            b = float(d_cell.max()) if len(d_cell) else 0.0
            stats.update(triangles=int(len(faces)))
            a = _triangles_bound(fld, verts, faces, tol, resid, stats) if triangles or not len(faces) else math.nan
        else:
            verts, faces, a = np.zeros((0, 3)), np.zeros((0, 3), np.int64), math.nan
        bad = ~np.isfinite(d_cell)
        stats.update(uncertified_cubes=int(bad.sum()), field_points=fld.points, field_balls=fld.balls)
        bound = max(a, b) if len(faces) and triangles else b
        out = SurfaceMesh(verts, faces, tol, bound if triangles or not len(faces) else math.nan, a, b, h, stats)
        if bound <= tol:
            break
        h = _smaller_cell(h, tol, bound, g[bad], Hr[bad])
    return out, Band(grid, band)


def _triangles_bound(fld: MeshField, verts: np.ndarray, faces: np.ndarray, tol: float, resid: np.ndarray,
                     stats: dict) -> float:
    """The mesh-to-surface bound of the triangles (mm; inf: some not certified); counts them in ``stats``."""
    d_tri = _triangle_distances(fld, verts, faces, tol, resid)
    stats.update(uncertified_triangles=int(np.isinf(d_tri).sum()))
    return float(d_tri.max()) if len(d_tri) else 0.0


def _smaller_cell(h: float, tol: float, bound: float, g: np.ndarray, H: np.ndarray) -> float:
    """The next attempt's cube side after a bound above ``tol``; where it is inf (some cubes or
    triangles not certified at all), as small as the cubes not certified (slopes ``g``, curvature
    bounds ``H``) ask, at least half."""
    if math.isfinite(bound):
        return h * min(0.85, max(0.5, 0.95 * math.sqrt(tol / bound)))
    wish = _next_cell(h, g, H)
    return h * (min(0.85, max(0.5, wish / h)) if math.isfinite(wish) else 0.7)


def certify_triangles(fld: MeshField, out: SurfaceMesh, attempts: int) -> SurfaceMesh:
    """A uniform mesh made with ``triangles=False`` (:func:`uniform_mesh`) with its triangles
    certified too; when they are not within its tolerance, the attempts go on with smaller
    cubes (``attempts`` in all), as :func:`uniform_mesh` would have."""
    tol = out.tol
    if out.patches:     # certified with finer meshes: alone, the mesh's cubes are not, so smaller ones everywhere
        again, _ = uniform_mesh(fld, tol, out.stats["next_cell"], attempts - out.stats["attempts"])
        again.stats["attempts"] += out.stats["attempts"]
        # the finer cubes of the graded attempt are not in this mesh: kept under a name of their own
        again.stats["graded_attempt"] = out.stats["finer"]
        if "simplify" in out.stats:
            again.stats["simplify"] = out.stats["simplify"]
        return again
    if not len(out.faces):
        return out
    stats = dict(out.stats)
    a = _triangles_bound(fld, out.vertices, out.faces, tol, _residuals(fld, out.vertices), stats)
    stats.update(field_points=fld.points, field_balls=fld.balls)
    bound = max(a, out.surface_to_mesh)
    if bound <= tol or stats["attempts"] >= attempts:
        return SurfaceMesh(out.vertices, out.faces, tol, bound, a, out.surface_to_mesh, out.cell, stats)
    again, _ = uniform_mesh(fld, tol, _smaller_cell(out.cell, tol, bound, np.zeros(0), np.zeros(0)),
                            attempts - stats["attempts"])
    again.stats["attempts"] += stats["attempts"]
    if "simplify" in stats:
        again.stats["simplify"] = stats["simplify"]
    return again


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
        Simplify the uniform mesh (its cubes certified) and certify the result
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
    start = time.perf_counter()
    fld = MeshField(skel)
    # a mesh simplified next certifies its own triangles: the uniform mesh's are certified only
    # when it is kept
    out, _ = uniform_mesh(fld, tol, cell, attempts, triangles=not compact, graded=compact)
    if compact:
        kept = simplified(fld, out, tol) if out.surface_to_mesh <= tol and len(out.faces) else None
        if kept is None:
            first = out.stats["attempts"]
            out = certify_triangles(fld, out, attempts)
            if out.stats["attempts"] > first and out.certified:     # smaller cubes: simplified again
                kept = simplified(fld, out, tol)
        out = kept or out
    out.stats["seconds"] = time.perf_counter() - start
    return out


__all__ = ["mesh_scene", "uniform_mesh", "certify_triangles", "Band", "SurfaceMesh", "DEFAULT_TOL", "lattice_of"]
