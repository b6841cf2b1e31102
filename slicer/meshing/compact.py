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
  within ``b0 + d01`` of ``M1``; a graded ``M0`` (finer cubes where struts
  meet) bounds each face T for the surface points it serves, ``b_T``, and
  has finer patches bounded alike: then ``b_T + d01(T)`` over the faces of
  both;
* **mesh to surface**: each triangle of ``M1`` gets the certificate of the
  uniform mesh's triangles (the interpolation error over its enclosing ball
  and the slope along the gradient); a triangle too large for it is cut into
  four at its edges' midpoints, again and again, and certified piece by
  piece (the field is evaluated at the pieces' corners; the triangle itself
  is unchanged).

When the certified bound exceeds the tolerance, a smaller simplification
tolerance is tried (one whose simplification has no fewer triangles than the
next one's is tried last); when none certifies, the uniform mesh stays.
"""
from __future__ import annotations

import math
import time

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


def simplify(vertices: np.ndarray, faces: np.ndarray, eps: float, hold: np.ndarray | None = None,
             planes: np.ndarray | None = None):
    """``(vertices, faces)`` of the closed mesh simplified by manifold3d to ``eps`` (mm).

    Parameters
    ----------
    vertices : (v, 3) float64, mm
    faces : (t, 3) int64
        Closed, oriented, manifold.
    eps : float, mm
    hold : (t,) bool, optional
        Triangles to hold as they are: each is passed as a face of its own, and manifold3d
        collapses no edge between two faces (only its clean-up of triangles degenerate
        within ``eps`` may still change them).
    planes : (t,) int64, optional
        Triangles with the same positive number are one flat face of their own (a tile's cap on
        a face of its box, :mod:`slicer.meshing.tiles`): no edge between it and another face
        is collapsed, so no triangle joins it. 0: the surface.

    Returns
    -------
    (v', 3) float64 and (t', 3) int64: a subset of the vertices, closed and oriented.
    """
    face_id = None
    if planes is not None and planes.any():
        face_id = planes.astype(np.uint64)
    if hold is not None and hold.any():
        base = np.zeros(len(faces), np.uint64) if face_id is None else face_id
        face_id = np.where(hold, 1 + int(base.max()) + np.arange(len(faces), dtype=np.uint64), base)
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices, np.float64),
                                                  tri_verts=np.ascontiguousarray(faces, np.uint64),
                                                  face_id=face_id))
    # the input's copies are freed before the simplification makes its own (the peak of a dense lattice's job)
    face_id = None
    result = solid.simplify(float(eps))
    del solid
    out = result.to_mesh64()
    del result
    v = np.array(out.vert_properties, dtype=np.float64)[:, :3]
    return np.ascontiguousarray(v), np.array(out.tri_verts, dtype=np.int64)


def within(points: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Whether each point is in a grid cell meeting the box of some ball (a superset of the
    balls' union; the cells' side is twice the median radius, or an eighth of the largest).

    Parameters
    ----------
    points : (n, 3) float64, mm
    centres : (k, 3) float64, mm
    radii : (k,) float64, mm

    Returns
    -------
    (n,) bool
    """
    if not len(centres) or not len(points):
        return np.zeros(len(points), bool)
    side = max(2.0 * float(np.median(radii)), float(radii.max()) / 8.0, 1e-9)
    origin = points.min(axis=0) - side
    span = np.ceil((np.maximum(points.max(axis=0), (centres + radii[:, None]).max(axis=0)) - origin) / side) + 2

    def key(ijk):
        return (ijk[..., 2] * span[1] + ijk[..., 1]) * span[0] + ijk[..., 0]

    lo = np.maximum(np.floor((centres - radii[:, None] - origin) / side), 0).astype(np.int64)
    hi = np.floor((centres + radii[:, None] - origin) / side).astype(np.int64)
    marked = []
    for n in np.unique(hi - lo + 1, axis=0):         # the cells of each ball's box, by box size
        group = (hi - lo + 1 == n).all(axis=1)
        steps = np.stack(np.meshgrid(*[np.arange(int(c)) for c in n], indexing="ij"), -1).reshape(-1, 3)
        marked.append(key(lo[group][:, None, :] + steps[None]).ravel())
    marked = np.unique(np.concatenate(marked))
    if not len(marked):
        return np.zeros(len(points), bool)
    cells = key(np.floor((points - origin) / side).astype(np.int64))
    j = np.minimum(np.searchsorted(marked, cells), len(marked) - 1)
    return marked[j] == cells


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


#: pieces certified at a time (their corners are made per batch, :func:`_pieces`)
BATCH = 200_000


def _quarters(p: np.ndarray, which: np.ndarray) -> np.ndarray:
    """(k, 3, 3) triangles -> (k, 3, 3): quarter ``which`` (k,) of each, cut at its edges' midpoints
    (0, 1, 2: at corner a, b, c; 3: the middle one)."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    points = np.stack([a, b, c, 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)], 1)
    return points[np.arange(len(p))[:, None], _QUARTER[which]]


#: each quarter's corners among a, b, c, ab, bc, ca
_QUARTER = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def _pieces(corners: np.ndarray, path: np.ndarray, depth: int) -> np.ndarray:
    """(k, 3, 3) pieces: the quarters named by ``path`` (two bits per level, the first level
    highest) of the triangles ``corners`` (k, 3, 3), ``depth`` levels down."""
    for level in range(depth - 1, -1, -1):
        corners = _quarters(corners, (path >> (2 * level)) & 3)
    return corners


def triangle_bounds(fld, vertices: np.ndarray, faces: np.ndarray, tol: float, limit: int | None = None,
                    first_failure: bool = False):
    """Certified distance from each triangle's points to the surface (mm; inf: not certified
    within ``tol``), and the pieces certified.

    Each triangle, or each piece of it (quarters, up to :data:`DEPTH` times), is
    certified as the uniform mesh's triangles are
    (:func:`slicer.meshing.certificate.piece_distances`). With ``limit``, the work stops
    (and the triangles left are not certified) once a level has more pieces than that.
    A piece is kept as its triangle and its path of quarters (16 bytes); its corners are
    made :data:`BATCH` pieces at a time. With ``first_failure``, the triangles go
    :data:`BATCH` // 64 at a time through every level, and the work stops at the first batch
    with a triangle not certified (the rest are then inf; ``limit`` counts per batch, in
    proportion).
    """
    if not first_failure:
        return _triangle_bounds(fld, vertices, faces, tol, limit)
    out = np.full(len(faces), np.inf)
    n_pieces = 0
    step = BATCH // 64
    for lo in range(0, len(faces), step):
        part = faces[lo:lo + step]
        share = None if limit is None else max(1, limit * len(part) // max(len(faces), 1))
        out[lo:lo + step], n = _triangle_bounds(fld, vertices, part, tol, share)
        n_pieces += n
        if not np.isfinite(out[lo:lo + step]).all():
            break
    return out, n_pieces


def _triangle_bounds(fld, vertices: np.ndarray, faces: np.ndarray, tol: float, limit: int | None):
    """:func:`triangle_bounds` of all the triangles, level by level."""
    owner = np.arange(len(faces))
    path = np.zeros(len(faces), np.int64)
    out = np.zeros(len(faces))
    n_pieces = 0
    for depth in range(DEPTH + 1):
        if not len(owner):
            break
        n_pieces += len(owner)
        d = np.empty(len(owner))
        for lo in range(0, len(owner), BATCH):
            part = slice(lo, lo + BATCH)
            d[part] = piece_distances(fld, _pieces(vertices[faces[owner[part]]], path[part], depth), tol)
        ok = np.isfinite(d)
        np.maximum.at(out, owner[ok], d[ok])
        if depth == DEPTH or (limit is not None and 4 * int((~ok).sum()) > limit):
            out[owner[~ok]] = np.inf
            break
        owner = np.repeat(owner[~ok], 4)
        path = (np.repeat(path[~ok], 4) << 2) | np.tile(np.arange(4), int((~ok).sum()))
    return out, n_pieces


#: rounds, per simplification tolerance, that hold the uniform triangles where the last did not certify
HOLD_ROUNDS = 1
#: ... while the uniform triangles held are at most this share of the simplified mesh's
HOLD_SHARE = 0.5


def _balls(tri: np.ndarray, margin: float):
    """Centres and radii (mm) of balls round triangles (k, 3, 3), widened by ``margin``."""
    c = tri.mean(axis=1)
    return c, np.linalg.norm(tri - c[:, None, :], axis=2).max(axis=1) + margin


def simplified(uniform, tol: float, budget: float, reach: float, mesh_to_surface, target: float | None = None,
               wedges: bool | None = None, hold_rounds: int = HOLD_ROUNDS, on_surface=None, planes=None,
               as_is: bool = False, tidy=None, surface_first: bool = False, seam: np.ndarray | None = None):
    """The loop of :func:`compact` (and of a part's, :mod:`slicer.meshing.composite`): ``uniform`` simplified to
    fractions of ``budget``; surface to mesh by the distances from ``uniform`` to the result
    (pieces split while above ``target``, by default ``reach − uniform.surface_to_mesh``; nothing
    farther than ``reach`` found; ``wedges`` as :func:`mesh_to_mesh`'s, None by default: a
    lattice's); mesh to surface by ``mesh_to_surface(v1, f1, row)`` (a bound per triangle, mm;
    ``row`` takes its counts). Where ``uniform`` has finer patches (:func:`slicer.meshing.surface.uniform_mesh`,
    ``graded``), their distances to the result count too. Uniform faces whose bound is nan serve no
    surface point (a tile's caps, :mod:`slicer.meshing.tiles`) and are not measured;
    ``on_surface(v1, f1)``, a (t1,) bool mask, names the result's triangles the distances are
    measured to (default: all); ``planes`` as :func:`simplify`'s. With ``as_is``, when no
    simplification is kept, ``uniform`` itself is checked the same way and kept if it certifies
    (a tile's mesh, whose small pieces a simplification can erase). ``tidy(v1, f1)`` returns what
    is kept of each simplification (and of ``uniform`` as it is), (v1, f1): a tile's, cut by its box.
    With ``surface_first``, a simplification's own triangles are certified first, and its
    distances from ``uniform`` bounded only when they are (a tile's: where the curvature bounds
    are large, most tolerances fail there, and the distances cost more). The faces of ``seam``, a
    (t,) bool mask over ``uniform``'s faces, are held as they are in every simplification (a
    tile's, by the faces of its box: the tiles on either side then meet along the same curve);
    rows count them apart (``seam``) from the faces held where a round did not certify (``held``).

    Where a simplification is not certified (uniform triangles too far from it, or its own
    triangles not certified on the surface), the uniform triangles near those places are held
    as they are and the same tolerance is tried again, up to ``hold_rounds`` times, before
    a smaller one: the rest of the mesh keeps the larger triangles.

    The next tolerance's simplification is made before one is checked: manifold3d's edge
    collapses can leave more triangles at a larger tolerance (dense lattices), and a
    simplification with no fewer triangles than the next one's is passed over (its row says
    ``dominated``), to be checked only when no smaller tolerance is kept."""
    if not budget > 0.0 or not len(uniform.faces):
        return None
    tried = []
    v0, f0 = uniform.vertices, uniform.faces
    patches = [(vp, fp, sp) for vp, fp, sp in uniform.patches if len(fp)]
    # the surface points a uniform face serves are within its bound of it (one bound for all, or each face's)
    s0 = np.full(len(f0), uniform.surface_to_mesh) if uniform.face_bounds is None else uniform.face_bounds
    # a tile's faces with a nan bound serve none of its surface points (without on_surface, a nan is kept: it fails)
    serves = ~np.isnan(s0) if on_surface is not None else np.ones(len(f0), bool)
    f0s, s0s = (f0, s0) if serves.all() else (f0[serves], s0[serves])
    centroids = None
    ahead = {}      # the next tolerance's simplification (nothing held), made to compare with this one's

    def made(v, f):
        return (v, f) if tidy is None else tidy(v, f)

    def plain(i):
        if i not in ahead:
            start = time.perf_counter()
            mesh = (v0, f0) if i == len(FRACTIONS) else simplify(v0, f0, FRACTIONS[i] * budget, seam, planes)
            ahead[i] = made(*mesh) + (time.perf_counter() - start,)
        return ahead[i]

    passed = []     # tolerances passed over for the next one's simplification

    def rounds(i, look_ahead):
        """The rounds of tolerance ``i``: the mesh kept, or None and whether smaller tolerances are
        not worth trying."""
        nonlocal centroids
        eps = FRACTIONS[i] * budget if i < len(FRACTIONS) else 0.0
        hold = np.zeros(len(f0), bool)
        for rnd in range(hold_rounds + 1):
            if hold.any():
                start = time.perf_counter()
                v1, f1 = made(*simplify(v0, f0, eps, hold if seam is None else hold | seam, planes))
            else:                   # made now, or ahead while the last tolerance was looked at
                v1, f1, took = plain(i)
                ahead.pop(i, None)
                start = time.perf_counter() - took
            row = {"eps": eps, "triangles": int(len(f1)), "held": int(hold.sum()), "kept": False}
            if seam is not None:
                row["seam"] = int(seam.sum())
            tried.append(row)
            small = 0 < len(f1) <= GAIN * len(f0) or (eps == 0.0 and len(f1) > 0)
            if rnd == 0 and look_ahead and i + 1 < len(FRACTIONS) and len(f1):
                mark = time.perf_counter()
                nxt = len(plain(i + 1)[1])
                start += time.perf_counter() - mark         # counted in the next tolerance's row
                if 0 < nxt <= len(f1):
                    # manifold3d's edge collapses can leave more triangles at a larger tolerance (dense
                    # lattices): the next tolerance is checked first, this one only if no other is kept
                    row.update(dominated=True, seconds=time.perf_counter() - start)
                    if small:
                        passed.append(i)
                    return None, False
            if not small:
                # a smaller tolerance saves fewer triangles still; with triangles held, it may not
                return None, not hold.any()
            a = a1 = None

            def own_triangles():
                """Mesh to surface (a round that holds nothing more after it only needs to know
                whether it certifies)."""
                row["first_failure"] = rnd == hold_rounds and rnd > 0
                a = mesh_to_surface(v1, f1, row)
                a1 = float(a.max()) if len(a) else 0.0
                row.update(mesh_to_surface=a1, kept=bool(a1 <= tol), seconds=time.perf_counter() - start)
                return a, a1

            if surface_first:
                a, a1 = own_triangles()
            b1 = math.inf
            if a1 is None or a1 <= tol:
                aim = reach - uniform.surface_to_mesh if target is None else target
                f1s = f1 if on_surface is None else f1[on_surface(v1, f1)]

                def distances(v, f):
                    """Bounds of the distances from the faces f to the result (none of it: inf)."""
                    if not len(f1s) or not len(f):
                        return np.full(len(f), np.inf)
                    return mesh_to_mesh(v, f, v1, f1s, aim, reach, wedges)

                d01 = distances(v0, f0s)
                # the surface is within surface_to_mesh of the uniform mesh and its finer patches together
                d_patches = [distances(vp, fp) for vp, fp, _ in patches]
                far = max([float(d01.max(initial=0.0))] + [float(d.max()) for d in d_patches])
                b1 = max([float((s0s + d01).max(initial=0.0))]
                         + [float((sp + d).max()) for (_, _, sp), d in zip(patches, d_patches)])
                row.update(uniform_to_compact=far, kept=False, seconds=time.perf_counter() - start)
                if b1 <= tol and a is None:
                    a, a1 = own_triangles()
            if a1 is not None and a1 <= tol and b1 <= tol:
                row["kept"] = True
                stats = dict(uniform.stats, uniform_triangles=int(len(f0)),
                             uniform_surface_to_mesh=uniform.surface_to_mesh, simplify=tried,
                             triangles=int(len(f1)))
                return SurfaceMesh(v1, f1, tol, max(a1, b1), a1, b1, uniform.cell, stats), True
            if rnd == hold_rounds or eps == 0.0:
                break
            if a1 is not None and a1 > tol:      # its own triangles not certified
                where = _balls(v1[f1[~(a <= tol)]], 2.0 * eps)
            else:
                bad = np.zeros(len(f0), bool)
                bad[serves] = ~(s0s + d01 <= tol)
                far_p = [(vp, fp[~(sp + d <= tol)]) for (vp, fp, sp), d in zip(patches, d_patches)]
                # a triangle of the k-th level's patch has about 4**-k of a uniform one's area
                n_far = int((hold | bad).sum()) + sum(len(f) / 4.0 ** k for k, (_, f) in enumerate(far_p, 1))
                if n_far > HOLD_SHARE * len(f1):     # all held below: too many
                    break
                balls = [_balls(v[f], 2.0 * eps) for v, f in [(v0, f0[bad])] + far_p if len(f)]
                where = (tuple(np.concatenate(parts) for parts in zip(*balls)) if balls
                         else (np.zeros((0, 3)), np.zeros(0)))
            if centroids is None:
                centroids = v0[f0].mean(axis=1)
            # (the seam's faces are held in every round already)
            more = within(centroids, *where) & ~(hold if seam is None else hold | seam)
            # held uniform triangles stay small: worth it only while they are few beside the
            # simplified mesh's (a smaller tolerance roughly doubles its count instead)
            if not more.any() or int(hold.sum() + more.sum()) > HOLD_SHARE * len(f1):
                break
            hold |= more
        return None, False

    for i in range(len(FRACTIONS)):
        kept, stop = rounds(i, True)
        if kept is not None:
            return kept
        if stop:
            break
    ahead.clear()
    for i in passed + ([len(FRACTIONS)] if as_is else []):    # the tolerances passed over, when none
        kept, _ = rounds(i, False)                                  # after them was kept; the mesh as it is
        if kept is not None:
            return kept
    uniform.stats["simplify"] = tried
    return None


def compact(fld, uniform, tol: float):
    """The uniform mesh ``uniform`` (its cubes certified) (a :class:`slicer.meshing.certificate.SurfaceMesh`)
    simplified and certified again within ``tol``, or None when no simplification certifies
    or saves triangles. Mesh to surface: each triangle certified on the field (:func:`triangle_bounds`)."""
    # the certificate reaches no farther than the thinnest strut (certificate.distances_to_surface)
    reach = min(tol, float(fld.skel.radii.min()))

    def on_field(v1, f1, row):
        d, n_pieces = triangle_bounds(fld, v1, f1, tol, int(PIECES * len(uniform.faces)), row["first_failure"])
        row["certified_pieces"] = int(n_pieces)
        return d

    return simplified(uniform, tol, reach - typical_bound(uniform), reach, on_field)


#: the quantile of the faces' bounds that sets a graded uniform mesh's simplification budget
BUDGET_QUANTILE = 0.5


def typical_bound(uniform) -> float:
    """The surface-to-mesh bound the simplification's budget is set from (mm): the mesh's, or
    with bounds per face (a graded uniform mesh), their :data:`BUDGET_QUANTILE` over its faces
    and its patches' (the faces whose bound leaves less are held where they need it)."""
    if uniform.face_bounds is None:
        return uniform.surface_to_mesh
    every = np.concatenate([uniform.face_bounds] + [patch[2] for patch in uniform.patches])
    every = every[~np.isnan(every)]         # faces that serve no surface point (a tile's caps)
    return float(np.quantile(every, BUDGET_QUANTILE)) if len(every) else uniform.surface_to_mesh


__all__ = ["compact", "simplified", "simplify", "within", "mesh_to_mesh", "triangle_bounds"]
