"""A lattice meshed tile by tile, for a band of cubes too large to hold at once (docs/mesh.md, step 5).

One grid of cubes covers the lattice (:func:`slicer.meshing.cubes._grid`); it is
cut into *tiles*, boxes of its coarse cubes, each meshed on its own:

1. the band cubes of the tile's box widened by an *overlap* (:func:`overlap`);
   marching tetrahedra on all of them; the tile's own cubes certified (the
   others give their residuals, and hold faces that serve the tile's surface
   points), with finer cubes where they fall short, as
   :func:`slicer.meshing.surface.uniform_mesh` does;
2. the widened box's solid closed by *caps* on its faces (:func:`caps`):
   marching triangles on the faces' grid points, triangulated again from their
   boundaries;
3. simplified, its faces by the box's planes held as they are (:func:`seam_faces`:
   neighbouring tiles are then cut along the same curve), cut by the tile's own box
   (:func:`cut`) and certified (:func:`slicer.meshing.compact.simplified`) against
   its triangles off the box's faces, within (1 − :data:`SEAM_SHARE`) of the
   tolerance. What the simplifier does by the caps stays in the overlap.

The tiles' solids ``A_i`` are united (manifold3d). The result ``U`` is certified
as a whole:

* ``A_i`` lies in its box; the boxes meet only on their faces, so inside a box
  the surface of ``U`` is that of ``A_i``, and every triangle of ``A_i`` not
  lying in a face of its box is on the surface of ``U``. A tile's faces
  measured against those triangles are within that distance of ``U`` too;
* the faces out of a tile's box that serve its surface points are measured
  against ``U`` once it is made;
* every triangle of ``U`` that is not one of the ``A_i``'s certified ones
  (pieces of the cuts where two tiles' cuts differ) is certified on the field.

Everything is deterministic: the tiles are meshed on threads (:func:`tile_threads`), each on its
own, and united in their order.
"""
from __future__ import annotations

import math
import threading
import time
from typing import NamedTuple

import manifold3d
import numpy as np

from slicer._kernels.runtime.launch import numba_threads
from slicer.errors import OptionError
from slicer.meshing.certificate import MeshField, SurfaceMesh
from slicer.meshing.compact import PIECES, mesh_to_mesh, simplified, triangle_bounds, typical_bound
from slicer.meshing.cubes import (CHUNK, FINER_SHARE, MAX_BAND, _band, _cube_bounds, _face_bounds, _finer, _Grid, _grid,
                                  _mesh_band, _surface_to_mesh, edge_keys, point_keys)
from slicer.scale.ordered_map import map_in_order

#: a tile's band, estimated, is at most this share of MAX_BAND (its finer cubes and triangles take the rest)
TILE_SHARE = 1 / 8
#: the lattice is meshed in tiles when its band, estimated, exceeds this share of MAX_BAND
TILED_SHARE = 1 / 4
#: the share of the tolerance a tile's simplification leaves for the union: it cuts the tiles'
#: triangles where their cuts by a box's face differ, and can move them (by about a micrometre)
SEAM_SHARE = 0.03
#: the octree level whose cubes estimate the band (each counts for 4**level finest cubes)
ESTIMATE_LEVEL = 2


def estimated_band(fld: MeshField, grid: _Grid) -> float:
    """About how many finest cubes the band has: the octree's cubes left at level
    :data:`ESTIMATE_LEVEL` (side ``4 h``), each standing for 4**level finest cubes (the
    band's cubes cover the surface, so their count goes as ``1 / h²``). Its cubes are a
    sixteenth of the band's, so the band's limit does not hold them back."""
    level = min(ESTIMATE_LEVEL, grid.levels)
    return float(len(_band(fld, grid, last=level, limit=4.0 ** level * MAX_BAND)[0])) * 4.0 ** level


def coarse_per_tile(fld: MeshField, grid: _Grid) -> int | None:
    """Coarse cubes per tile side: as many as keep a tile's band, estimated, within
    :data:`TILE_SHARE` of MAX_BAND; None when the whole band is within :data:`TILED_SHARE`
    of it (no tiles)."""
    band = estimated_band(fld, grid)
    if band <= TILED_SHARE * MAX_BAND:
        return None
    per_coarse = band / float(np.prod(grid.coarse))
    return max(1, int(np.cbrt(TILE_SHARE * MAX_BAND / per_coarse)))


def tile_boxes(grid: _Grid, coarse_per_tile: int) -> list:
    """The tiles, (lo, hi) (3,) int64 boxes of finest cubes (half open), ``coarse_per_tile``
    coarse cubes a side (fewer at the grid's far ends), in (z, y, x) order."""
    k = int(coarse_per_tile)
    steps = [range(0, int(n), k) for n in grid.coarse]
    out = []
    for z in steps[2]:
        for y in steps[1]:
            for x in steps[0]:
                lo = np.array([x, y, z], np.int64)
                hi = np.minimum(lo + k, grid.coarse)
                out.append((lo << grid.levels, hi << grid.levels))
    return out


def _face_triangles(grid: _Grid, lo: np.ndarray, hi: np.ndarray):
    """The grid's triangles on the box's six faces: corner indices (m, 3, 3) int64, counter-clockwise
    seen from outside the box, and each one's face (m,) (1 + 2 axis + (0: low, 1: high)). Each
    face square is cut along its diagonal from its lowest to its highest corner, as the
    tetrahedra round the cubes' main diagonals cut it."""
    out, which = [], []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        iu, iv = np.meshgrid(np.arange(lo[u], hi[u]), np.arange(lo[v], hi[v]), indexing="ij")
        iu, iv = iu.ravel(), iv.ravel()
        for plane, outward, number in ((lo[axis], -1, 1 + 2 * axis), (hi[axis], 1, 2 + 2 * axis)):
            def corner(du, dv):
                c = np.empty((len(iu), 3), np.int64)
                c[:, axis], c[:, u], c[:, v] = plane, iu + du, iv + dv
                return c
            c00, c10, c11, c01 = corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)
            tri = np.concatenate([np.stack([c00, c10, c11], 1), np.stack([c00, c11, c01], 1)])
            # (u, v, axis) is a right-handed frame for axis x and z, left-handed for y
            if outward * (1 if axis != 1 else -1) < 0:
                tri = tri[:, ::-1]
            out.append(tri)
            which.append(np.full(len(tri), number, np.int64))
    return np.concatenate(out), np.concatenate(which)


def caps(fld: MeshField, grid: _Grid, lo: np.ndarray, hi: np.ndarray, verts: np.ndarray, keys: np.ndarray):
    """The caps closing a tile's surface on its box's faces: marching triangles on the faces' grid.

    Parameters
    ----------
    lo, hi : (3,) int64
        The box, in finest cubes (half open).
    verts : (v, 3) float64, mm
        The tile's mesh's vertices: the caps' vertices on the grid's edges are those; the caps'
        own vertices (grid points inside on the box's edges) follow them.
    keys : (v,) int64
        Their grid edges (:func:`slicer.meshing.cubes.edge_keys`), sorted.

    Returns
    -------
    points : (c, 3) float64, mm
        The grid points inside the surface on the box's faces (those off the caps' boundaries are
        not used: the caps are triangulated from their boundaries, :func:`_triangulated`).
    faces : (k, 3) int64
        Outward (out of the box) triangles, in positions of ``verts`` then ``points``.
    planes : (k,) int64
        Each one's face of the box, 1 to 6.
    """
    tri, plane = _face_triangles(grid, lo, hi)
    if not len(tri):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    pkey, inv = np.unique(point_keys(grid, tri), return_inverse=True)
    idx = tri.reshape(-1, 3)[np.unique(inv.ravel(), return_index=True)[1]]      # the points, in pkey's order
    val = np.concatenate([fld.values(grid.points(idx[i:i + CHUNK]))[0] for i in range(0, len(idx), CHUNK)])
    inside_pt = val >= 1.0
    inv = inv.reshape(-1, 3)
    inside = inside_pt[inv]
    n_in = inside.sum(axis=1)
    own = np.cumsum(inside_pt) - 1 + len(verts)        # a point's vertex, when inside

    def root(a, b):
        k = edge_keys(grid, a, b)
        if not len(k):
            return np.zeros(0, np.int64)
        j = np.minimum(np.searchsorted(keys, k), max(len(keys) - 1, 0))
        if not len(keys) or not (keys[j] == k).all():
            raise RuntimeError("a cap's edge crosses the surface where the tile's mesh has no vertex")
        return j

    faces = [own[inv[n_in == 3]]]
    planes = [plane[n_in == 3]]
    for count, pick in ((1, np.argmax), (2, np.argmin)):
        sel = np.flatnonzero(n_in == count)
        planes += [plane[sel]] * count
        r = pick(inside[sel], axis=1)                  # the corner alone on its side
        order = (r[:, None] + np.arange(3)[None]) % 3   # rotated to come first (orientation kept)
        t = tri[sel[:, None], order]
        i = inv[sel[:, None], order]
        if count == 1:       # a inside: a, ab, ac
            faces.append(np.stack([own[i[:, 0]], root(t[:, 0], t[:, 1]), root(t[:, 0], t[:, 2])], 1))
        else:                # a outside, b and c inside: the quad b, c, ca, ab
            ab, ca = root(t[:, 0], t[:, 1]), root(t[:, 2], t[:, 0])
            faces.append(np.stack([own[i[:, 1]], own[i[:, 2]], ca], 1))
            faces.append(np.stack([own[i[:, 1]], ca, ab], 1))
    points = grid.points(idx[inside_pt])
    faces, planes = np.concatenate(faces).astype(np.int64), np.concatenate(planes)
    return points, *_triangulated(np.concatenate([verts, points]), faces, planes)


def _loops(faces: np.ndarray) -> list:
    """The boundary of a set of triangles (k, 3) as closed loops of vertex numbers, each going the
    triangles' way round (where loops touch at a vertex, they are joined there in the order met)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    n = int(faces.max()) + 1
    boundary = e[~np.isin(e[:, 1] * n + e[:, 0], e[:, 0] * n + e[:, 1])]
    leaving = {}                            # vertex -> the boundary edges' ends out of it, not yet followed
    for a, b in boundary.tolist():
        leaving.setdefault(a, []).append(b)
    loops = []
    for start in list(leaving):
        while leaving[start]:
            loop, a = [start], leaving[start].pop()
            while a != start:
                loop.append(a)
                a = leaving[a].pop()
            loops.append(loop)
    return loops


def _triangulated(positions: np.ndarray, faces: np.ndarray, planes: np.ndarray):
    """The caps triangulated again from their boundaries alone, face by face of the box
    (manifold3d's polygon triangulation): the same regions, with no grid point inside them, so
    no cap triangle by the surface has a corner off it (the simplifier's clean-up of triangles
    thinner than its tolerance swaps edges, and would join such a corner to the surface)."""
    out_f, out_p = [], []
    for number in np.unique(planes):
        axis, high = divmod(int(number) - 1, 2)
        u, v = [a for a in range(3) if a != axis]
        # seen from outside, (u, v) turns counter-clockwise for +x, +z and -y
        if (1 if high else -1) * (1 if axis != 1 else -1) < 0:
            u, v = v, u
        loops = _loops(faces[planes == number])
        ids = np.concatenate([np.array(loop, np.int64) for loop in loops])
        tri = manifold3d.triangulate([positions[np.array(loop)][:, [u, v]] for loop in loops])
        out_f.append(ids[np.asarray(tri, np.int64)])
        out_p.append(np.full(len(tri), number, np.int64))
    if not out_f:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_f), np.concatenate(out_p)


#: a vertex is on a face of a tile's box when this close to its plane, relative to the coordinates' size
#: (the cut by the box, manifold3d's, computes the points on its faces)
ON_FACE = 1e-12


def off_box_faces(lo: np.ndarray, hi: np.ndarray):
    """``on_surface(v, f)`` for a tile: whether each triangle is off the faces of the box ``lo``,
    ``hi`` (3,) mm (does not lie in one of them)."""
    near = ON_FACE * float(np.abs(np.concatenate([lo, hi])).max() + (hi - lo).max())

    def off(v: np.ndarray, f: np.ndarray) -> np.ndarray:
        flat = np.zeros(len(f), bool)
        for axis in range(3):
            c = v[f][:, :, axis]
            for plane in (lo[axis], hi[axis]):
                flat |= (np.abs(c - plane) <= near).all(axis=1)
        return ~flat
    return off


def box_solid(lo: np.ndarray, hi: np.ndarray):
    """The box ``lo``, ``hi`` (3,) mm as a manifold3d solid whose corners are those very numbers
    (two tiles' boxes then share their faces exactly)."""
    corners = np.array([[(hi if k >> a & 1 else lo)[a] for a in range(3)] for k in range(8)], np.float64)
    # the cube's faces, outward: corner k has x, y, z from the bits 1, 2, 4 of k
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.uint64)
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=corners, tri_verts=faces))


def cut(lo: np.ndarray, hi: np.ndarray):
    """``tidy(v, f)`` for a tile: the closed mesh's solid cut by the box ``lo``, ``hi`` (3,) mm
    (manifold3d's intersection), as (vertices, faces). The points the cut makes on the box's
    faces are put on them exactly (they come within a few units in the last place): the two
    tiles on either side of a face then share its plane, as their union needs."""
    box = box_solid(lo, hi)
    near = ON_FACE * float(np.abs(np.concatenate([lo, hi])).max() + (hi - lo).max())

    def in_box(v: np.ndarray, f: np.ndarray):
        solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v, np.float64),
                                                      tri_verts=np.ascontiguousarray(f, np.uint64)))
        if solid.status() != manifold3d.Error.NoError:
            raise RuntimeError(f"a tile's closed mesh is not a manifold ({solid.status()})")
        out = (solid ^ box).to_mesh64()
        v = np.array(out.vert_properties, dtype=np.float64)[:, :3]
        for axis in range(3):
            for plane in (lo[axis], hi[axis]):
                v[np.abs(v[:, axis] - plane) <= near, axis] = plane
        return v, np.array(out.tri_verts, dtype=np.int64)
    return in_box


def _compact_vertices(v: np.ndarray, f: np.ndarray):
    """The vertices ``f`` uses, and ``f`` renumbered."""
    used, inv = np.unique(f, return_inverse=True)
    return v[used], inv.reshape(f.shape).astype(np.int64)


def _part(v: np.ndarray, f: np.ndarray, bounds: np.ndarray, which: np.ndarray):
    """The faces ``which`` of a mesh with their bounds, and the vertices they use: (v', f', bounds')."""
    return _compact_vertices(v, f[which]) + (bounds[which],)


def _in_box(v: np.ndarray, f: np.ndarray, box_mm: np.ndarray) -> np.ndarray:
    """Whether each face's centroid is in the box (2, 3) mm (its faces included)."""
    c = v[f].mean(axis=1)
    return ((c >= box_mm[0]) & (c <= box_mm[1])).all(axis=1)


def overlap(h: float, tol: float) -> int:
    """Cubes a tile's mesh reaches past its box on each side for its simplification: more than
    the largest simplification tolerance (half of ``tol``), so what the simplifier does by the
    caps (it swaps edges of triangles thinner than its tolerance, across a cap's rim too) stays
    out of the box, and at least one (the cubes round a tile's cubes serve its surface points)."""
    return int(math.ceil(tol / h)) + 1


def tile_mesh(fld: MeshField, grid: _Grid, lo: np.ndarray, hi: np.ndarray, tol: float, stats: dict):
    """A tile's closed uniform mesh, over its box and :func:`overlap` cubes round it (steps 1 and 2
    of the module's docstring).

    Returns
    -------
    SurfaceMesh or None
        None when there is no solid in the larger box; else its closed solid (faces of its
        cubes, then the caps on the larger box), ``face_bounds`` per face (nan but on the tile's
        own faces: the others serve none of its surface points, or are measured against the
        union), the finer patches in the box, and ``surface_to_mesh`` its cubes' largest
        certified distance.
    planes : (t,) int64 or None
        Per face, 0 (the surface) or its cap's face of the larger box (1 to 6, :func:`caps`).
    margin : list of ((p, 3) float64 mm, (q, 3) int64, (q,) float64 mm)
        The faces out of the box (and of its patches) that serve the tile's surface points, with
        their bounds.

    Raises
    ------
    OptionError
        Cubes not certified even by the finest finer cubes, or a band beyond :data:`MAX_BAND`.
    """
    m = overlap(grid.h, tol)
    elo, ehi = np.maximum(lo - m, 0), np.minimum(hi + m, grid.coarse << grid.levels)
    start = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in
                                   zip(elo >> grid.levels, ((ehi - 1) >> grid.levels) + 1)], indexing="ij"),
                     -1).reshape(-1, 3)
    band, _ = _band(fld, grid, start, (elo, ehi))
    stats.update(band_cubes=0, margin_cubes=int(len(band)), triangles=0, refined_cubes=0)
    if not len(band):       # no surface: the box is inside the solid (caps all round) or outside it
        return _closed(fld, grid, elo, ehi, tol, stats, np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0),
                       np.zeros(0, np.int64), [], 0.0, [])
    mine = ((band >= lo) & (band < hi)).all(axis=1)
    g, Hr = _cube_bounds(fld, grid, band)
    d = _surface_to_mesh(fld, grid, band, g, Hr, np.zeros(len(band)), tol, mine)
    verts, faces, owner, _, d, keys = _mesh_band(fld, grid, band, g, Hr, d, tol)
    d = np.where(mine, d, 0.0)          # the cubes out of the box are certified by their own tile
    bad = mine & ~(d <= FINER_SHARE * tol)
    patches, b_finer = [], 0.0
    if bad.any():
        finer = _finer(fld, grid, band, bad, tol, stats)
        if finer is None:
            raise OptionError(f"a tile's {int(bad.sum()):,} cubes of {grid.h:.4g} mm next to the surface could not "
                              f"be certified within {FINER_SHARE * tol:.4g} mm even with finer cubes (the "
                              f"curvature bounds are large where struts meet: docs/mesh.md, 'Where struts meet'); "
                              f"ask for a larger --tol")
        patches, b_finer = finer
    bounds = _face_bounds(band, np.where(bad, 0.0, d), owner)
    box_mm = grid.points(np.stack([lo, hi]))
    here = mine[owner]
    # the faces out of the box that serve the tile's surface points (bound > 0) are measured against the union
    margins = [_part(verts, faces, bounds, ~here & (bounds > 0))]
    inner = []
    for vp, fp, sp in patches:
        box = _in_box(vp, fp, box_mm)
        inner.append(_part(vp, fp, sp, box))
        margins.append(_part(vp, fp, sp, ~box & (sp > 0)))
    stats.update(band_cubes=int(mine.sum()), margin_cubes=int((~mine).sum()), triangles=int(here.sum()),
                 refined_cubes=int(bad.sum()))
    return _closed(fld, grid, elo, ehi, tol, stats, verts, faces, np.where(here, bounds, np.nan), keys, inner,
                   max(float(d[mine & ~bad].max(initial=0.0)), b_finer), margins)


def _closed(fld: MeshField, grid: _Grid, lo: np.ndarray, hi: np.ndarray, tol: float, stats: dict, verts: np.ndarray,
            faces: np.ndarray, bounds: np.ndarray, keys: np.ndarray, patches: list, b: float, margins: list):
    """:func:`tile_mesh`'s result: the ``faces`` (on ``verts``, with their ``bounds``) closed by the
    caps on the box (lo, hi); None when there are neither (no solid in the box)."""
    cap_points, cap_faces, planes = caps(fld, grid, lo, hi, verts, keys)
    margins = [m for m in margins if len(m[1])]
    stats.update(cap_triangles=int(len(cap_faces)))
    if not len(faces) and not len(cap_faces):     # no solid: finer patches (if any) measured against the union
        return None, None, margins + [p for p in patches if len(p[1])]
    # the closed mesh: the faces, then the caps; unused vertices dropped
    vc, fc = _compact_vertices(np.concatenate([verts, cap_points]), np.concatenate([faces, cap_faces]))
    face_bounds = np.concatenate([bounds, np.full(len(cap_faces), np.nan)])
    closed = SurfaceMesh(vc, fc, tol, math.nan, math.nan, b, grid.h, stats, [p for p in patches if len(p[1])],
                         face_bounds)
    return closed, np.concatenate([np.zeros(len(faces), np.int64), planes]), margins


def _rows(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Each triangle's corners as one (72-byte) row, from its smallest corner on (the same
    triangle, however numbered, gives the same row)."""
    tri = v[f]
    first = np.zeros(len(f), np.int64)
    for k in (1, 2):
        a, b = tri[np.arange(len(f)), first], tri[:, k]
        less = (b[:, 0] < a[:, 0]) | ((b[:, 0] == a[:, 0])
                                      & ((b[:, 1] < a[:, 1]) | ((b[:, 1] == a[:, 1]) & (b[:, 2] < a[:, 2]))))
        first = np.where(less, k, first)
    rot = tri[np.arange(len(f))[:, None], (first[:, None] + np.arange(3)[None]) % 3]
    return np.ascontiguousarray(rot.reshape(len(f), 9)).view(np.dtype((np.void, 72))).ravel()


def frozen(planes: np.ndarray) -> np.ndarray:
    """The faces :func:`slicer.meshing.compact.simplify` keeps apart (its ``planes``): each cap
    triangle one of its own, so no edge of a cap is collapsed and no surface vertex near a
    cap's plane joins the cap as one flat face would take it in."""
    return np.where(planes > 0, np.arange(1, len(planes) + 1), 0)


def _tile_simplified(fld: MeshField, closed: SurfaceMesh, planes: np.ndarray, lo_mm: np.ndarray,
                     hi_mm: np.ndarray, tol: float, reach: float):
    """A tile's closed mesh simplified and certified (step 3): the SurfaceMesh kept, or None.
    Certified within (1 − :data:`SEAM_SHARE`) ``tol``: the rest is room for what the union changes
    by the boxes' faces."""
    on_surface = off_box_faces(lo_mm, hi_mm)
    inner = (1.0 - SEAM_SHARE) * tol

    def on_field(v1, f1, row):
        keep = on_surface(v1, f1)
        out = np.zeros(len(f1))
        # pieces split until certified within the tile's own tolerance, not the job's
        out[keep], n_pieces = triangle_bounds(fld, v1, f1[keep], inner, int(PIECES * len(closed.faces)),
                                              row["first_failure"])
        row["certified_pieces"] = int(n_pieces)
        return out

    # the distances from the uniform faces are bounded within the tile's tolerance too
    reach = min(reach, inner)
    return simplified(closed, inner, reach - typical_bound(closed), reach, on_field, on_surface=on_surface,
                      planes=frozen(planes), as_is=True, tidy=cut(lo_mm, hi_mm), surface_first=True,
                      seam=seam_faces(closed.vertices, closed.faces, lo_mm, hi_mm, closed.cell))


#: a uniform face is on a tile's seam when it comes this share of a cube's side near a face of its box
SEAM_REACH = 0.01


def seam_faces(v: np.ndarray, f: np.ndarray, lo: np.ndarray, hi: np.ndarray, h: float) -> np.ndarray:
    """The uniform faces a tile holds as they are (:func:`slicer.meshing.compact.simplified`'s ``seam``):
    those that touch or cross a plane of its box's faces, the whole plane (those out of the box
    are cut away with the overlap) (vertices ``v`` (p, 3) mm, faces ``f`` (t, 3), box ``lo``,
    ``hi`` (3,) mm, cubes of ``h`` mm); (t,) bool. The box's faces are planes of the grid, and the cubes'
    marching tetrahedra meet such a plane along the marching triangles of its grid points: so
    two tiles that both hold these faces are cut along the same curve, and their union adds no
    sliver of cap there (that it would certify on the field)."""
    tri = v[f]
    low, high = tri.min(axis=1), tri.max(axis=1)
    near = SEAM_REACH * h
    out = np.zeros(len(f), bool)
    for plane in (lo, hi):
        out |= ((low <= plane + near) & (high >= plane - near)).any(axis=1)
    return out


class _Tile(NamedTuple):
    """What one tile gives the union (:func:`_one_tile`)."""
    #: the tile's stats row
    row: dict
    #: faces out of its box, and finer patches, measured against the union ((vertices, faces, bounds) each)
    margins: list
    #: its cut solid, or None (no solid in the box)
    kept: SurfaceMesh | None
    #: its certified triangles' rows (:func:`_rows`) and corners (k, 3, 3) mm, or None (none certified)
    certified: tuple | None


def _one_tile(fld: MeshField, grid: _Grid, lo: np.ndarray, hi: np.ndarray, tol: float, reach: float,
              stop=None) -> _Tile | None:
    """The tile (lo, hi) meshed, simplified, cut and certified (steps 1 to 3 of the module's
    docstring); None when ``stop()`` is true before its simplification (a tile before it was
    refused)."""
    row = {"box": [lo.tolist(), hi.tolist()]}
    closed, planes, margins = tile_mesh(fld, grid, lo, hi, tol, row)
    if stop is not None and stop():
        return None
    if closed is None:
        return _Tile(row, margins, None, None)
    lo_mm, hi_mm = grid.points(np.stack([lo, hi]))
    certified = None
    if np.isnan(closed.face_bounds).all():
        # none of the tile's own faces: its solid is cut, not simplified; its finer patches (the
        # surface the cubes missed) are measured against the union, and its triangles certified there
        margins = margins + closed.patches
        v1, f1 = cut(lo_mm, hi_mm)(closed.vertices, closed.faces)
        if not len(f1):
            return _Tile(row, margins, None, None)
        kept = SurfaceMesh(v1, f1, tol, 0.0, 0.0, 0.0, grid.h, {})
    else:
        kept = _tile_simplified(fld, closed, planes, lo_mm, hi_mm, tol, reach)
        if kept is None:
            raise OptionError(f"the tile {row['box']} of {grid.h:.4g} mm cubes: no simplification of its mesh "
                              f"could be certified within {(1.0 - SEAM_SHARE) * tol:.4g} mm ({1.0 - SEAM_SHARE:.0%} "
                              f"of the tolerance, the rest left for the seams); ask for a larger --tol")
        surface = off_box_faces(lo_mm, hi_mm)(kept.vertices, kept.faces)
        certified = (_rows(kept.vertices, kept.faces[surface]), kept.vertices[kept.faces[surface]])
    row.update(triangles_kept=int(len(kept.faces)), mesh_to_surface=kept.mesh_to_surface,
               surface_to_mesh=kept.surface_to_mesh, simplify=kept.stats.get("simplify"))
    return _Tile(row, margins, kept, certified)


#: most tiles meshed at once: each holds its band (estimated at most TILE_SHARE of MAX_BAND) and its
#: finer cubes, so the memory's limit is shared between them
TILES_AT_ONCE = 2


def tile_threads(tiles: int) -> tuple[int, int]:
    """Tiles meshed at once, and Numba threads each: as many tiles as this thread's Numba threads
    (``--threads``), at most ``tiles`` and :data:`TILES_AT_ONCE`; the threads shared between
    them. The threads pay where the Numba kernels and numpy release the GIL (manifold3d's
    simplifications and cuts hold it: they go one at a time)."""
    with numba_threads(None) as threads:
        workers = max(1, min(int(threads), int(tiles), TILES_AT_ONCE))
    return workers, max(1, int(threads) // workers)


def mesh_tiles(fld: MeshField, tol: float, h: float, per_tile: int, progress=None) -> SurfaceMesh:
    """The lattice's compact certified mesh, made tile by tile (the module's docstring).

    The tiles are meshed on :func:`tile_threads` threads and united in their order: the mesh is
    the same on any thread count.

    Parameters
    ----------
    fld : MeshField
    tol : float, mm
    h : float, mm
        The cubes' side.
    per_tile : int
        Coarse cubes per tile side (:func:`coarse_per_tile`).
    progress : callable, optional
        Called with a line of text as each tile is done, in the tiles' order.

    Raises
    ------
    OptionError
        A tile not certified (:func:`tile_mesh`), or its simplification not certified within its
        share of ``tol`` (1 − :data:`SEAM_SHARE`); the first such tile in the tiles' order.
    """
    start = time.perf_counter()
    grid = _grid(fld.skel, h)
    reach = min(tol, float(fld.skel.radii.min()))
    solids, certified_rows, margins, rows = [], [], [], []
    boxes = tile_boxes(grid, per_tile)
    workers, each = tile_threads(len(boxes))
    # the first tile refused: the tiles after it stop at their next step (those before it go on,
    # so the error raised is the first tile's in order, as on one thread)
    refused, lock = [len(boxes)], threading.Lock()

    def one(item):
        number, (lo, hi) = item

        def stop():
            return refused[0] < number
        if stop():
            return None
        try:
            with numba_threads(each):
                return _one_tile(fld, grid, lo, hi, tol, reach, stop)
        except BaseException:
            with lock:
                refused[0] = min(refused[0], number)
            raise

    # ``workers`` tiles (and bands) in the making at once; finished ones wait to be united in order
    for number, (_, tile) in enumerate(map_in_order(one, enumerate(boxes), workers, name="tile"), 1):
        if tile is None:            # stopped: a tile before it was refused, and raises at its turn
            continue
        margins += tile.margins     # measured against the union, whatever the tile keeps
        if tile.kept is None:
            continue
        kept = tile.kept
        if tile.certified is not None:
            certified_rows.append(tile.certified)
        solids.append(manifold3d.Manifold(manifold3d.Mesh64(vert_properties=kept.vertices,
                                                            tri_verts=kept.faces.astype(np.uint64))))
        rows.append(tile.row)
        if progress is not None:
            progress(f"tile {number} of {len(boxes)}: {tile.row['band_cubes']:,} band cubes, {len(kept.faces):,} "
                     f"triangles kept, {time.perf_counter() - start:.0f} s")
    united = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add) if solids else manifold3d.Manifold()
    if united.status() != manifold3d.Error.NoError:
        raise RuntimeError(f"manifold3d could not unite the tiles: {united.status()}")
    out = united.to_mesh64()
    v = np.array(out.vert_properties, dtype=np.float64)[:, :3]
    f = np.array(out.tri_verts, dtype=np.int64)
    del united, solids, out
    rows_u = _rows(v, f)
    every = np.concatenate([r for r, _ in certified_rows]) if certified_rows else rows_u[:0]
    # the union's triangles that are not the tiles' certified ones
    fresh = ~np.isin(rows_u, every)
    # the tiles' distances were measured to their triangles off the boxes' faces: those the union
    # does not keep as they are (it cuts them where the tiles' cuts differ, and triangulates flat
    # regions anew) are measured against it
    gone = ~np.isin(every, rows_u)
    corners = np.concatenate([t for _, t in certified_rows])[gone] if certified_rows else np.zeros((0, 3, 3))
    b_gone = _margins_to([(corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3),
                           np.zeros(len(corners)))], v, f, reach, CUT_TARGET * tol, wedges=True)
    b_margin = _margins_to(margins, v, f, reach)
    # (the work stops at the first batch with one not certified: the mesh is then not certified)
    a_fresh, _ = triangle_bounds(fld, v, f[fresh], tol, int(PIECES * max(len(f), 1)), first_failure=True)
    a = max([r["mesh_to_surface"] for r in rows] + [float(a_fresh.max(initial=0.0))])
    b = max(max([r["surface_to_mesh"] for r in rows], default=0.0) + b_gone, b_margin)
    stats = {"tiles": rows, "coarse_per_tile": int(per_tile), "margin_faces": int(sum(len(m[1]) for m in margins)),
             "fresh_triangles": int(fresh.sum()), "certified_not_kept": int(gone.sum()), "not_kept_distance": b_gone,
             "triangles": int(len(f)),
             "band_cubes": int(sum(r["band_cubes"] for r in rows)), "attempts": 1,
             "uniform_triangles": int(sum(r["triangles"] for r in rows)), "finer": _finer_levels(rows),
             "field_points": fld.points, "field_balls": fld.balls, "seconds": time.perf_counter() - start}
    return SurfaceMesh(v, f, tol, max(a, b), a, b, h, stats)


#: the distance from a tile's triangles the union does not keep to the union is bounded to this share of
#: the tolerance (pieces split while above it: they lie in the union's triangles, bar rounding)
CUT_TARGET = 1e-3


def _margins_to(margins: list, v: np.ndarray, f: np.ndarray, reach: float, target: float | None = None,
                wedges: bool | None = None) -> float:
    """The largest ``bound + distance`` from the margins' faces (a list of (vertices, faces,
    bounds), mm) to the mesh ``v``, ``f`` (:func:`slicer.meshing.compact.mesh_to_mesh`; pieces
    split while above ``target``, by default ``reach`` less the largest bound; 0 without margins)."""
    margins = [m for m in margins if len(m[1])]
    if not margins:
        return 0.0
    if not len(f):
        return math.inf
    offsets = np.cumsum([0] + [len(m[0]) for m in margins[:-1]])
    vm = np.concatenate([m[0] for m in margins])
    fm = np.concatenate([m[1] + o for m, o in zip(margins, offsets)])
    sm = np.concatenate([m[2] for m in margins])
    aim = max(reach - float(sm.max()), 0.25 * reach) if target is None else target
    d = mesh_to_mesh(vm, fm, v, f, aim, reach, wedges)
    return float((sm + d).max())


def _finer_levels(rows: list) -> list:
    """The tiles' finer cubes, level by level, added up (as :func:`slicer.meshing.cubes._finer` counts them)."""
    levels = []
    for row in rows:
        for k, level in enumerate(row.get("finer", [])):
            if k == len(levels):
                levels.append({"cube": level["cube"], "cubes": 0, "certified": 0, "triangles": 0})
            for name in ("cubes", "certified", "triangles"):
                levels[k][name] += level[name]
    return levels
