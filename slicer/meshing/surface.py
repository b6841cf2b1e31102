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

A lattice whose band would not fit in memory is meshed tile by tile
(:mod:`slicer.meshing.tiles`, docs/mesh.md step 5); the machinery of steps 1-3 is
:mod:`slicer.meshing.cubes`'s.

Everything is float64; the field's bounds carry the relative slack of
:mod:`slicer._kernels.contours.cellbounds`. Degree-2 kernels (no curvature bound)
are refused; unions (supports, the union blend) and parts with meshes are
:func:`slicer.meshing.mesh_part`'s.
"""
from __future__ import annotations

import math
import time

import numpy as np

from slicer.arguments import integer, positive_number
from slicer.errors import OptionError, SceneError
from slicer.meshing.certificate import MeshField, SurfaceMesh
from slicer.meshing.compact import compact as simplified
from slicer.meshing.tiles import coarse_per_tile, mesh_tiles
from slicer.meshing.cubes import (FINER_SHARE, Band, _band, _check_band_estimate, _cube_bounds, _face_bounds,
                                   _finer, _finer_region, _grid, _mesh_band, _next_cell, _residuals,
                                   _surface_to_mesh, _triangle_distances)
from slicer.parts.part import Part
from slicer.model.skeleton import Skeleton

#: default tolerance, mm: the certified two-sided Hausdorff distance asked for
DEFAULT_TOL = 0.01
#: meshing attempts (each with a smaller cell) before giving up on the tolerance
ATTEMPTS = 6




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



def first_cell(skel: Skeleton, tol: float, cell: float | None) -> float:
    """The first attempt's cube side (mm): ``cell``, or ``0.4 sqrt(tol r_min)`` and at most half the
    thinnest radius (cubes wider see no more of it); refused at once when its band would be far
    beyond the memory's (:func:`slicer.meshing.cubes._check_band_estimate`)."""
    r_min = float(skel.radii.min())
    h = positive_number(cell, "cell") if cell is not None else min(0.4 * math.sqrt(tol * r_min), 0.5 * r_min)
    _check_band_estimate(skel, h)
    return h


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
    h = first_cell(skel, tol, cell)
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
            verts, faces, owner, resid, d_meshed, _ = _mesh_band(fld, grid, band, g, Hr, d_cell, tol)
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
            verts, faces, _, resid, d_cell, _ = _mesh_band(fld, grid, band, g, Hr, d_cell, tol)
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


def tiles_for(fld: MeshField, tol: float, cell: float | None, tile: float | None) -> int | None:
    """Coarse cubes per tile side for a lattice meshed in tiles (``tile`` mm wide, or sized to the
    memory when its band, estimated, needs it), or None: in one piece."""
    h = first_cell(fld.skel, tol, cell)
    grid = _grid(fld.skel, h)
    side = grid.h * (1 << grid.levels)
    if tile is not None:
        return max(1, int(round(tile / side)))
    return coarse_per_tile(fld, grid)


def mesh_scene(scene, tol: float = DEFAULT_TOL, cell: float | None = None, attempts: int = ATTEMPTS,
               compact: bool = True, tile: float | None = None, progress=None) -> SurfaceMesh:
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
    tile : float, mm, optional
        Mesh in tiles about this wide, as many at once as this thread's Numba threads
        (:mod:`slicer.meshing.tiles`; the simplified mesh only). By default a lattice whose
        band of cubes, estimated, is more than :data:`slicer.meshing.tiles.TILED_SHARE` of the
        memory's is meshed in tiles sized to it; others in one piece, with smaller cubes at
        each attempt.
    progress : callable, optional
        Called with a line of text as each tile is done.

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
    if tile is not None:
        tile = positive_number(tile, "tile")
        if not compact:
            raise OptionError("tiles make the simplified mesh: --tile cannot go with --uniform")
    start = time.perf_counter()
    fld = MeshField(skel)
    per_tile = tiles_for(fld, tol, cell, tile) if compact else None
    if per_tile is not None:
        out = mesh_tiles(fld, tol, first_cell(skel, tol, cell), per_tile, progress)
        out.stats["seconds"] = time.perf_counter() - start
        return out
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


__all__ = ["mesh_scene", "uniform_mesh", "certify_triangles", "SurfaceMesh", "DEFAULT_TOL", "lattice_of"]
