"""Compact certified meshes: the uniform mesh simplified, then certified again (docs/mesh.md).

The uniform mesh ``M0`` of :func:`slicer.meshing.surface.mesh_scene` has
triangles of one size everywhere. Its surface-to-mesh bound ``b0`` leaves a
budget ``tol − b0``; manifold3d's edge collapses (``Manifold.simplify``) keep a
subset of its vertices and return a closed, oriented manifold ``M1`` with far
fewer, larger triangles. Nothing is taken on trust from the simplifier;
``M1`` is certified on its own:

* **surface to mesh**: every surface point is within ``b0`` of ``M0``, and
  every point of ``M0`` within ``d01`` of ``M1`` (bounded triangle by
  triangle, :func:`slicer._kernels.meshing.nearest.distance_bounds`), so
  within ``b0 + d01`` of ``M1``;
* **mesh to surface**: each triangle of ``M1`` gets the certificate of the
  uniform mesh's triangles (the interpolation error over its enclosing ball
  and the slope along the gradient); a triangle too large for it is cut into
  four at its edges' midpoints, again and again, and certified piece by
  piece (the field is evaluated at the pieces' corners; the triangle itself
  is unchanged).

When the certified bound exceeds the tolerance, a smaller simplification
tolerance is tried; when none certifies, the uniform mesh stays.
"""
from __future__ import annotations

import numpy as np
import manifold3d

from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.meshing.nearest import distance_bounds
from slicer.meshing.certificate import SurfaceMesh, piece_distances
from slicer.parts.meshes import twin_corners

#: simplification tolerances tried, as fractions of the budget ``tol − b0``
FRACTIONS = (0.5, 0.25, 0.125, 0.0625)
#: most halvings of a triangle's edges while certifying it
DEPTH = 7
#: a simplified mesh is kept only with at most this share of the uniform mesh's triangles
GAIN = 0.9
#: a certification is abandoned when its pieces outnumber the uniform mesh's triangles this many times
PIECES = 2.0
#: most grid cells binning the simplified mesh's triangles
MAX_CELLS = 4_000_000


def simplify(vertices: np.ndarray, faces: np.ndarray, eps: float):
    """``(vertices, faces)`` of the closed mesh simplified by manifold3d to ``eps`` (mm).

    Parameters
    ----------
    vertices : (v, 3) float64, mm
    faces : (t, 3) int64
        Closed, oriented, manifold.
    eps : float, mm

    Returns
    -------
    (v', 3) float64 and (t', 3) int64: a subset of the vertices, closed and oriented.
    """
    mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices, np.float64),
                             tri_verts=np.ascontiguousarray(faces, np.uint64))
    out = manifold3d.Manifold(mesh).simplify(float(eps)).to_mesh64()
    v = np.array(out.vert_properties, dtype=np.float64)[:, :3]
    return np.ascontiguousarray(v), np.array(out.tri_verts, dtype=np.int64)


def mesh_to_mesh(v0: np.ndarray, f0: np.ndarray, v1: np.ndarray, f1: np.ndarray, target: float,
                 reach: float, wedges: bool | None = True) -> np.ndarray:
    """Per triangle of mesh 0, a bound of its points' distance to mesh 1 (mm; inf when mesh 1 is
    farther than ``reach``); pieces are split while above ``target``. With ``wedges``, where
    mesh 1's flat regions (a part's faces) were triangulated anew, wedges of its triangles
    bound the pieces straddling their edges (:func:`slicer._kernels.meshing.nearest.distance_bounds`);
    False: none (the same compiled kernel); None: none, and a kernel without their code (a
    lattice's mesh has no flat faces: its job does not compile them)."""
    tri = v1[f1]
    lo = tri.min(axis=1) - reach
    hi = tri.max(axis=1) + reach
    box_lo, box_hi = lo.min(axis=0), hi.max(axis=0)
    ext = np.maximum(box_hi - box_lo, 1e-9)
    side = max(2.0 * reach, float(np.cbrt(np.prod(ext) / MAX_CELLS)))
    dims = np.maximum(1, np.ceil(ext / side)).astype(np.int64)
    cell = np.full(3, side)
    offsets, ids = bin_boxes(lo, hi, np.arange(len(f1), dtype=np.int64), box_lo, cell, dims)
    f1 = np.ascontiguousarray(f1, np.int64)
    if wedges is None:
        across = None
    elif wedges:
        across = np.ascontiguousarray(twin_corners(f1).reshape(-1, 3) // 3)
    else:
        across = np.zeros((0, 3), np.int64)
    return distance_bounds(np.ascontiguousarray(v0, np.float64), np.ascontiguousarray(f0, np.int64),
                           np.ascontiguousarray(v1, np.float64), f1, across,
                           offsets, ids, box_lo, cell, dims, float(target), float(reach))


def _quarters(p: np.ndarray) -> np.ndarray:
    """(k, 3, 3) triangles -> (4 k, 3, 3): each cut at its edges' midpoints."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
    q = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                  np.stack([ab, bc, ca], 1)], 1)
    return q.reshape(-1, 3, 3)


def triangle_bounds(fld, vertices: np.ndarray, faces: np.ndarray, tol: float, limit: int | None = None):
    """Certified distance from each triangle's points to the surface (mm; inf: not certified
    within ``tol``), and the pieces certified.

    Each triangle, or each piece of it (quarters, up to :data:`DEPTH` times), is
    certified as the uniform mesh's triangles are
    (:func:`slicer.meshing.certificate.piece_distances`). With ``limit``, the work stops
    (and the triangles left are not certified) once a level has more pieces than that.
    """
    pieces = vertices[faces]
    owner = np.arange(len(faces))
    out = np.zeros(len(faces))
    n_pieces = 0
    for depth in range(DEPTH + 1):
        if not len(pieces):
            break
        n_pieces += len(pieces)
        d = piece_distances(fld, pieces, tol)
        ok = np.isfinite(d)
        np.maximum.at(out, owner[ok], d[ok])
        if depth == DEPTH or (limit is not None and 4 * int((~ok).sum()) > limit):
            out[owner[~ok]] = np.inf
            break
        pieces = _quarters(pieces[~ok])
        owner = np.repeat(owner[~ok], 4)
    return out, n_pieces


def simplified(uniform, tol: float, budget: float, reach: float, mesh_to_surface, target: float | None = None,
               wedges: bool | None = None):
    """The loop of :func:`compact` (and of a part's, :mod:`slicer.meshing.composite`): ``uniform`` simplified to
    fractions of ``budget``; surface to mesh by the distances from ``uniform`` to the result
    (pieces split while above ``target``, by default ``reach − uniform.surface_to_mesh``; nothing
    farther than ``reach`` found; ``wedges`` as :func:`mesh_to_mesh`'s, None by default: a
    lattice's); mesh to surface by
    ``mesh_to_surface(v1, f1, row)`` (a bound, mm; ``row`` takes its counts)."""
    if not budget > 0.0 or not len(uniform.faces):
        return None
    tried = []
    for frac in FRACTIONS:
        v1, f1 = simplify(uniform.vertices, uniform.faces, frac * budget)
        row = {"eps": frac * budget, "triangles": int(len(f1)), "kept": False}
        tried.append(row)
        if len(f1) > GAIN * len(uniform.faces) or not len(f1):
            break
        d01 = float(mesh_to_mesh(uniform.vertices, uniform.faces, v1, f1,
                                 reach - uniform.surface_to_mesh if target is None else target, reach, wedges).max())
        b1 = uniform.surface_to_mesh + d01
        row["uniform_to_compact"] = d01
        if not b1 <= tol:
            continue
        a1 = mesh_to_surface(v1, f1, row)
        row.update(mesh_to_surface=a1, kept=bool(a1 <= tol))
        if row["kept"]:
            stats = dict(uniform.stats, uniform_triangles=int(len(uniform.faces)), uniform_bound=uniform.bound,
                         simplify=tried, triangles=int(len(f1)))
            return SurfaceMesh(v1, f1, tol, max(a1, b1), a1, b1, uniform.cell, stats)
    uniform.stats["simplify"] = tried
    return None


def compact(fld, uniform, tol: float):
    """The uniform certified mesh ``uniform`` (a :class:`slicer.meshing.certificate.SurfaceMesh`)
    simplified and certified again within ``tol``, or None when no simplification certifies
    or saves triangles. Mesh to surface: each triangle certified on the field (:func:`triangle_bounds`)."""
    # the certificate reaches no farther than the thinnest strut (certificate.distances_to_surface)
    reach = min(tol, float(fld.skel.radii.min()))

    def on_field(v1, f1, row):
        d, n_pieces = triangle_bounds(fld, v1, f1, tol, int(PIECES * len(uniform.faces)))
        row["certified_pieces"] = int(n_pieces)
        return float(d.max())

    return simplified(uniform, tol, reach - uniform.surface_to_mesh, reach, on_field)


__all__ = ["compact", "simplified", "simplify", "mesh_to_mesh", "triangle_bounds"]
