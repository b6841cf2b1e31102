"""The mesh of a part: the lattice's certified mesh trimmed by, and united with, the part's meshes,
and certified again (docs/mesh.md, "Parts").

The true solid is ``T = ((S ∩ CI) − CO) ∪ M`` (:mod:`slicer.parts.part`): ``S`` the
lattice's solid ``F >= 1``, ``CI``, ``CO`` and ``M`` the unions of the clip-inside,
clip-outside and solid meshes. :func:`mesh_part`

1. meshes the lattice uniformly (:func:`slicer.meshing.surface.uniform_mesh`): a mesh
   ``L`` whose surface is within ``a`` of the surface ``F = 1`` (mesh to surface) and
   the surface within ``s`` of it, and whose solid equals ``S`` off the *band* ``U``,
   the closed cubes it could not settle;
2. computes ``R = ((L ∩ CI) − CO) ∪ M`` with manifold3d's booleans;
3. certifies ``R`` against ``T``. Off ``U``, ``R = T`` (the same booleans of equal
   sets), so their surfaces agree there. Let ``P`` be the meshes' surfaces.

   *Mesh to surface.* A triangle of ``R`` whose points are all farther than ``a`` from
   ``P`` lies on ``L`` (near it the meshes are constant, and ``R`` has a surface there,
   so ``R = L``) and has ``F = 1`` within ``a``, where ``T = S``: within ``a`` of
   ``T``'s surface. Any other triangle is cut into pieces; a piece whose box meets no
   band cube needs nothing (there ``R = T``); a piece of radius ``ρ`` about its
   centroid ``c`` is certified within ``ρ + t`` when two of ``c``, ``c ± t n`` (``n``
   its normal) are on opposite sides of ``T`` (then ``T``'s surface meets the segment):
   membership of ``S`` by ``F`` at the point, of the meshes by winding numbers
   (:func:`slicer._kernels.meshing.winding.winding_numbers`), both only where they
   cannot be wrong (``|F − 1|`` above :data:`F_MARGIN`, the meshes farther than
   :data:`NEAR`).

   *Surface to mesh.* A point of ``T``'s surface off ``U`` is on ``R``'s. In a band
   cube (centre ``c``, circumradius ``r``) farther than ``r + s`` from ``P``, ``T = S``
   and ``R = L`` within ``r + s`` of ``c`` (else ``T = R`` is constant there): a
   surface point has ``L``'s surface within ``s``, which is ``R``'s. A band cube
   nearer ``P`` is *covered* when ``R``'s surface is within ``tol − r`` of ``c``, or
   cut into eight, whose pieces are covered or *free*: no ``P`` within ``r'`` and
   either the field's bounds settle ``S`` over the piece's ball or the meshes alone
   decide ``T`` there (inside ``M``, or outside ``CI`` or inside ``CO``).

   The bound is the largest of these distances, plus :data:`SLACK` for the rounding of
   the booleans' new vertices.
4. simplifies ``R`` as the lattice's mesh is (:mod:`slicer.meshing.compact`) and
   certifies the simplified mesh ``R'`` by the distances from ``R`` to ``R'`` and back
   (the Hausdorff distance is a metric).

When the bound exceeds the tolerance, the lattice is meshed again at half its
tolerance (smaller cubes, a closer surface), up to :data:`ROUNDS` times.
"""
from __future__ import annotations

import math
import time

import manifold3d
import numpy as np

from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.meshing.nearest import GAP, distance_bounds
from slicer._kernels.meshing.nearest import SLACK as DISTANCE_SLACK
from slicer._kernels.meshing.winding import winding_numbers
from slicer.arguments import integer, positive_number
from slicer.errors import SceneError
from slicer.meshing.certificate import MeshField, SurfaceMesh
from slicer.meshing.compact import MAX_CELLS, PIECES, mesh_to_mesh, simplified, triangle_bounds
from slicer.meshing.surface import ATTEMPTS, DEFAULT_TOL, Band, lattice_of, mesh_scene, settle, uniform_mesh
from slicer.parts.part import Part, as_part

#: lattice meshes tried, each at half the tolerance of the one before
ROUNDS = 3
#: ... while the certified bound is above this share of the tolerance (the rest is the simplification's)
ROOM = 0.75
#: a piece of a triangle is probed once its radius is at most this share of the tolerance
PIECE_SHARE = 0.5
#: most halvings of a triangle near the meshes
PIECE_DEPTH = 30
#: probe distances ``t = (tol − ρ) / 2**k``, k from this down to 0
PROBE_STEPS = 6
#: probe distances along the normal, spaced evenly in log, for the pieces the first ones miss or
#: find only beyond DENSE_ABOVE times the reach
DENSE = 256
DENSE_ABOVE = 0.125
#: most cuttings of a band cube into eight near the meshes
CUBE_DEPTH = 4
#: a cube near the meshes is covered by R's surface within this share of the tolerance (but the last
#: cut's pieces, within the tolerance)
COVER_SHARE = 0.5
#: mm: a point this near a mesh's surface is not decided inside or outside it
NEAR = 1e-7
#: ``|F − 1|`` below this is not decided (the rounding of the field's point value is far less)
F_MARGIN = 1e-10
#: mm: the rounding of the booleans' new vertices (manifold3d computes them in float64)
SLACK = 1e-9
#: the roles' order in :class:`_Meshes`
ROLES = ("clip-inside", "clip-outside", "solid")


class _Meshes:
    """A part's meshes: per role, the union of its meshes (manifold3d) as a manifold and as
    (vertices, faces); and all the unions' surfaces as one (vertices, faces)."""

    def __init__(self, part: Part):
        self.manifolds, self.roles = {}, {}
        for role in ROLES:
            ms = part.of_role(role)
            if ms:
                self.manifolds[role] = _union(ms)
                self.roles[role] = _arrays(self.manifolds[role])
        self.all = _joined(list(self.roles.values()))
        self.reach = -1.0

    def index(self, reach: float) -> None:
        """Bin the surfaces for distance queries up to ``reach`` (mm)."""
        if reach > self.reach:
            self.reach = reach
            self.near = _Index(self.all, reach)
            self.near_role = {role: _Index(mesh, reach) for role, mesh in self.roles.items()}

    def farther(self, points: np.ndarray, x) -> np.ndarray:
        """Whether each point is farther than ``x`` (scalar or (n,), mm) from every mesh's surface
        (never proved beyond the reach of :meth:`index`)."""
        return self.near.farther(points, x)

    def inside(self, points: np.ndarray):
        """``(known, inside)``: whether each point is farther than :data:`NEAR` from every mesh
        (else nothing is decided for it), and per role whether it is in the role's union."""
        known = self.farther(points, NEAR)
        inside = {}
        for role, mesh in self.roles.items():
            w = np.zeros(len(points))
            if known.any():
                w[known] = winding_numbers(np.ascontiguousarray(points[known]), *mesh)
            inside[role] = w > 0.5
        return known, inside

    def decided(self, points: np.ndarray):
        """``(known, kept, filled)``: as :meth:`inside`, whether the lattice is kept at each point
        (inside CI, outside CO) and whether a solid fills it."""
        known, inside = self.inside(points)
        n = len(points)
        kept = inside.get("clip-inside", np.ones(n, bool)) & ~inside.get("clip-outside", np.zeros(n, bool))
        return known, kept, inside.get("solid", np.zeros(n, bool))


def _joined(meshes):
    if not meshes:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    vs, fs, n = [], [], 0
    for v, f in meshes:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f, np.int64) + n)
        n += len(v)
    return np.ascontiguousarray(np.concatenate(vs)), np.ascontiguousarray(np.concatenate(fs))


class _Index:
    """A mesh's triangles binned for distance queries from points up to ``reach`` (mm) away."""

    def __init__(self, mesh, reach: float):
        self.v, self.f = (np.ascontiguousarray(a) for a in mesh)
        self.reach = float(reach)
        tri = self.v[self.f]
        if not len(tri):
            return
        lo, hi = tri.min(axis=1) - self.reach, tri.max(axis=1) + self.reach
        self.origin = lo.min(axis=0)
        ext = np.maximum(hi.max(axis=0) - self.origin, 1e-9)
        side = max(self.reach, float(np.cbrt(np.prod(ext) / MAX_CELLS)))
        self.cell = np.full(3, side)
        self.dims = np.maximum(1, np.ceil(ext / side)).astype(np.int64)
        self.offsets, self.ids = bin_boxes(lo, hi, np.arange(len(self.f), dtype=np.int64), self.origin, self.cell,
                                           self.dims)

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Bounds of the distance from each point (n, 3) to the surface, mm: within a relative
        1e-9 and 1e-9 mm of it up to the reach; beyond it, at least the reach (inf: nothing
        near)."""
        if not len(self.f):
            return np.full(len(points), np.inf)
        if not len(points):
            return np.zeros(0)
        p = np.ascontiguousarray(points, np.float64)
        return distance_bounds(p, np.repeat(np.arange(len(p)), 3).reshape(-1, 3), self.v, self.f, self.offsets,
                               self.ids, self.origin, self.cell, self.dims, 1e-300, self.reach)

    def farther(self, points: np.ndarray, x) -> np.ndarray:
        """Whether each point is proved farther than ``x`` (mm, scalar or (n,)) from the surface
        (never for ``x`` beyond the reach)."""
        x = np.broadcast_to(np.asarray(x, np.float64), (len(points),))
        if not len(self.f):
            return np.ones(len(points), bool)
        d = self.distances(points)
        # the kernel returns d (1 + DISTANCE_SLACK) + GAP for every distance d up to the reach
        return (d > x * (1.0 + DISTANCE_SLACK) + GAP) & (x <= self.reach)


def _manifold(vertices: np.ndarray, faces: np.ndarray, name: str) -> manifold3d.Manifold:
    m = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.array(vertices, np.float64, order="C"),
                                              tri_verts=np.array(faces, np.uint64, order="C")))
    if m.status() != manifold3d.Error.NoError:
        raise SceneError(f"{name}: not a closed manifold mesh for the booleans ({m.status().name})")
    return m


def _union(meshes) -> manifold3d.Manifold:
    return manifold3d.Manifold.batch_boolean([_manifold(m.vertices, m.faces, m.name) for m in meshes],
                                             manifold3d.OpType.Add)


def _arrays(m: manifold3d.Manifold):
    mesh = m.to_mesh64()
    v = np.array(mesh.vert_properties, dtype=np.float64)[:, :3]
    return np.ascontiguousarray(v), np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)


def _combine(lattice, meshes: _Meshes):
    """``((L ∩ CI) − CO) ∪ M`` by manifold3d: (v, 3) float64 and (t, 3) int64, outward.

    Parameters
    ----------
    lattice : (vertices, faces) or None
        The lattice's closed mesh ``L`` (None: no lattice).
    meshes : _Meshes
        The part's meshes by role.
    """
    out = None
    ms = meshes.manifolds
    if lattice is not None and len(lattice[1]):
        out = _manifold(lattice[0], lattice[1], "the lattice's mesh")
        if "clip-inside" in ms:
            out = out ^ ms["clip-inside"]
        if "clip-outside" in ms:
            out = out - ms["clip-outside"]
    if "solid" in ms:
        out = ms["solid"] if out is None else out + ms["solid"]
    if out is None:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return _arrays(out)


def _inside_solid(fld: MeshField, meshes: _Meshes, points: np.ndarray):
    """``(known, inside)`` of each point in the true solid ``T``."""
    f = fld.values(points)[0]
    known, kept, filled = meshes.decided(points)
    known &= np.abs(f - 1.0) > F_MARGIN
    return known, filled | (kept & (f >= 1.0))


def _halves(p: np.ndarray) -> np.ndarray:
    """(k, 3, 3) triangles -> (2 k, 3, 3): each cut at its longest edge's midpoint (slivers
    become well shaped, where quarters would keep their shape)."""
    length = np.stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, i], axis=1) for i in range(3)], 1)
    i = length.argmax(axis=1)
    rows = np.arange(len(p))
    a, b, c = p[rows, i], p[rows, (i + 1) % 3], p[rows, (i + 2) % 3]
    m = 0.5 * (a + b)
    return np.stack([np.stack([a, m, c], 1), np.stack([m, b, c], 1)], 1).reshape(-1, 3, 3)


def _meets_band(band: Band, pieces: np.ndarray) -> np.ndarray:
    """Whether each piece's box (k, 3, 3 corners) meets a band cube: looked up among the cubes
    ``2**level`` times the band's side that hold band cubes, at the finest level where the box
    spans at most 4 of them per axis."""
    g = band.grid
    lo = np.floor((pieces.min(axis=1) - g.origin) / g.h - 1e-7).astype(np.int64)
    hi = np.floor((pieces.max(axis=1) - g.origin) / g.h + 1e-7).astype(np.int64)
    out = np.zeros(len(pieces), bool)
    todo = np.arange(len(pieces))
    steps = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    level = 0
    while len(todo):
        lo_k, hi_k = lo[todo] >> level, hi[todo] >> level
        fits = ((hi_k - lo_k) <= 3).all(axis=1)
        if fits.any():
            idx = lo_k[fits][:, None, :] + steps[None]
            inside = (idx <= hi_k[fits][:, None, :]).all(axis=2)
            out[todo[fits]] = (band.contains(idx, level) & inside).any(axis=1)
        todo = todo[~fits]
        level += 1
    return out


def _probe(fld: MeshField, meshes: _Meshes, centres: np.ndarray, normals: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Per point ``c`` with unit normal ``n``: a probe distance ``t <= reach`` such that two points
    of ``B(c, t)`` are on opposite sides of T, which puts T's surface in the ball (inf: none found).

    The points tried, in turn while none is found: ``c`` and ``c ± t n`` for ``t = reach / 2**k``,
    k from :data:`PROBE_STEPS` down to 0; then, where that found nothing or only beyond
    ``DENSE_ABOVE reach``, :data:`DENSE` distances along ``± n`` spaced evenly in log from
    ``reach / 1e9`` (a thin wedge of T or of its complement, where two surfaces meet at a small
    angle); then, where nothing was found, ``c + t u`` for u in the 256 directions of
    :func:`_directions` and the first ``t``'s.
    """
    out = np.full(len(centres), np.inf)
    k0, m0 = _inside_solid(fld, meshes, centres)
    todo = np.flatnonzero(reach > 0)

    def found(ts, pts):
        """Where the points (pieces, m, 3) with ``c`` show both sides: record ``ts``."""
        kk, mm = _inside_solid(fld, meshes, pts.reshape(-1, 3))
        kk = np.concatenate([kk.reshape(len(todo), -1), k0[todo, None]], axis=1)
        mm = np.concatenate([mm.reshape(len(todo), -1), m0[todo, None]], axis=1)
        ok = (kk & mm).any(axis=1) & (kk & ~mm).any(axis=1)
        out[todo[ok]] = ts[ok]
        return todo[~ok]

    for k in range(PROBE_STEPS, -1, -1):
        if not len(todo):
            return out
        t = reach[todo] * 0.5 ** k
        todo = found(t, centres[todo, None, :] + t[:, None, None] * np.stack([normals[todo], -normals[todo]], 1))
    # along the normal, densely, where nothing was found or only far: the least t with both sides
    # among c, c ± t' n (t' <= t)
    todo = np.flatnonzero((reach > 0) & ~(out <= DENSE_ABOVE * reach))
    if len(todo):
        frac = np.logspace(-9.0, 0.0, DENSE)
        t = reach[todo, None] * frac[None]
        pts = centres[todo, None, None, :] + t[:, :, None, None] * np.stack([normals[todo], -normals[todo]], 1)[:, None]
        kk, mm = _inside_solid(fld, meshes, pts.reshape(-1, 3))
        kk, mm = kk.reshape(len(todo), DENSE, 2), mm.reshape(len(todo), DENSE, 2)
        seen_in = np.logical_or.accumulate((kk & mm).any(axis=2), axis=1) | (k0[todo] & m0[todo])[:, None]
        seen_out = np.logical_or.accumulate((kk & ~mm).any(axis=2), axis=1) | (k0[todo] & ~m0[todo])[:, None]
        both = seen_in & seen_out
        ok = both.any(axis=1)
        first = both.argmax(axis=1)
        out[todo[ok]] = np.minimum(out[todo[ok]], t[ok, first[ok]])
        todo = todo[~ok & np.isinf(out[todo])]
    for k in list(range(PROBE_STEPS, -1, -1)):
        if not len(todo):
            return out
        t = reach[todo] * 0.5 ** k
        todo = found(t, centres[todo, None, :] + t[:, None, None] * _DIRECTIONS[None])
    return out


def _directions(n: int) -> np.ndarray:
    """The 26 directions of a cube's neighbours and ``n`` spread evenly over the sphere (a
    Fibonacci spiral), unit vectors (26 + n, 3)."""
    cube = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if x or y or z],
                    np.float64)
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (3.0 - math.sqrt(5.0)) * k
    rho = np.sqrt(1.0 - z * z)
    out = np.concatenate([cube, np.stack([rho * np.cos(phi), rho * np.sin(phi), z], 1)])
    return out / np.linalg.norm(out, axis=1)[:, None]


_DIRECTIONS = _directions(230)


def _mesh_to_surface(fld, meshes: _Meshes, band: Band, v: np.ndarray, f: np.ndarray, a_lattice: float, tol: float):
    """Per triangle of R, a bound of its points' distance to T's surface, and the pieces probed."""
    tri = v[f]
    cen = tri.mean(axis=1)
    rho = np.linalg.norm(tri - cen[:, None], axis=2).max(axis=1)
    out = np.zeros(len(f))
    far = meshes.farther(cen, rho + a_lattice)
    out[far] = a_lattice
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    normal = np.where(length[:, None] > 0, normal / np.where(length > 0, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    owner = np.flatnonzero(~far)
    pieces = tri[owner]
    probed = 0
    for depth in range(PIECE_DEPTH + 1):
        if not len(pieces):
            break
        c = pieces.mean(axis=1)
        r = np.linalg.norm(pieces - c[:, None], axis=2).max(axis=1)
        # off the band R = T; farther than a from the meshes a piece is on L's surface
        meets = _meets_band(band, pieces)
        out[owner[~meets]] = np.maximum(out[owner[~meets]], SLACK)
        far = meets & meshes.farther(c, r + a_lattice)
        out[owner[far]] = np.maximum(out[owner[far]], a_lattice)
        keep = meets & ~far
        pieces, owner, c, r = pieces[keep], owner[keep], c[keep], r[keep]
        small = r <= PIECE_SHARE * tol
        if small.any():
            t = _probe(fld, meshes, c[small], normal[owner[small]], tol - r[small] - SLACK)
            np.maximum.at(out, owner[small], r[small] + t + SLACK)
            probed += int(small.sum())
            if np.isinf(t).any():       # not certified: the rest cannot change that
                return out, probed
        pieces, owner = pieces[~small], owner[~small]
        if depth == PIECE_DEPTH:
            out[owner] = np.inf
        else:
            pieces, owner = _halves(pieces), np.repeat(owner, 2)
    return out, probed


def _constant(fld, meshes: _Meshes, centres: np.ndarray, radius: float) -> np.ndarray:
    """Whether T = (S ∧ kept) ∨ filled is proved constant over each ball ``B(c, radius)``: inside
    when a solid fills it or S fills it where the lattice is kept; outside when no solid reaches it
    and S is outside or the lattice removed. A mesh's membership is constant over the ball when
    its union's surface is farther than the radius."""
    ins, out = settle(fld, centres, radius)
    known, inside = meshes.inside(centres)
    away = {role: index.farther(centres, radius) for role, index in meshes.near_role.items()}
    n = len(centres)
    yes, no = np.ones(n, bool), np.zeros(n, bool)

    def const(role, absent):
        """(constant true, constant false) of a role's membership over the balls."""
        if role not in meshes.roles:
            return (yes, no) if absent else (no, yes)
        a = known & away[role]
        return a & inside[role], a & ~inside[role]

    ci_true, ci_false = const("clip-inside", True)
    co_true, co_false = const("clip-outside", False)
    filled_true, filled_false = const("solid", False)
    kept_true, kept_false = ci_true & co_false, ci_false | co_true
    return filled_true | (ins & kept_true) | (filled_false & (out | kept_false))


def _surface_to_mesh(fld, meshes: _Meshes, band: Band, result, s_lattice: float, tol: float):
    """Per band cube near the meshes, a bound of the distance from T's surface points in it to R's
    surface; the bound elsewhere (``s_lattice`` or 0); the cubes near the meshes."""
    c = band.centres()
    r = 0.5 * math.sqrt(3.0) * band.h
    surface = _Index(result, tol)
    near = ~meshes.farther(c, r + s_lattice)
    plain = bool((~near).any())
    worst = 0.0
    cubes, radius, side = c[near], r, band.h
    for depth in range(CUBE_DEPTH + 1):
        if not len(cubes):
            break
        free = _constant(fld, meshes, cubes, radius)
        d = surface.distances(cubes)
        goal = tol if depth == CUBE_DEPTH else COVER_SHARE * tol
        covered = ~free & (d + radius + SLACK <= goal)
        if covered.any():
            worst = max(worst, float((d[covered] + radius).max()) + SLACK)
        rest = cubes[~free & ~covered]
        if depth == CUBE_DEPTH and len(rest):
            return math.inf, plain, int(near.sum())
        offs = (np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 3) - 0.5) * 0.5 * side
        cubes = (rest[:, None, :] + offs[None]).reshape(-1, 3)
        radius, side = 0.5 * radius, 0.5 * side
    return worst, plain, int(near.sum())


def _certify(fld, meshes: _Meshes, band: Band, lattice: SurfaceMesh, v, f, tol: float):
    """R = (v, f) against T: the bounds mesh to surface and surface to mesh, and counts."""
    meshes.index(2.0 * tol + math.sqrt(3.0) * band.h)
    d_tri, probed = _mesh_to_surface(fld, meshes, band, v, f, lattice.mesh_to_surface, tol)
    a = float(d_tri.max()) if len(d_tri) else 0.0
    if not a <= tol:
        return a, math.inf, {"probed_pieces": probed, "cubes_near_meshes": 0}
    s_near, plain, n_near = _surface_to_mesh(fld, meshes, band, (v, f), lattice.surface_to_mesh, tol)
    s = max(s_near, lattice.surface_to_mesh if plain else 0.0)
    return a, s, {"probed_pieces": probed, "cubes_near_meshes": n_near}


def _compact(fld, meshes: _Meshes, uniform: SurfaceMesh, tol: float) -> SurfaceMesh | None:
    """``uniform`` (R, certified) simplified and certified again (:func:`slicer.meshing.compact.simplified`).

    Mesh to surface, per triangle of the simplified mesh: farther than ``ρ + tol`` from every mesh,
    where the lattice is kept and no solid fills, ``T = S`` within the tolerance, so the
    triangle's certificate on the field holds (as a lattice's); any other triangle, by its
    distance back to ``uniform`` plus ``uniform``'s bound (the Hausdorff distance is a metric).
    """
    room = tol - uniform.mesh_to_surface

    def mesh_to_surface(v1, f1, row):
        tri = v1[f1]
        cen = tri.mean(axis=1)
        rho = np.linalg.norm(tri - cen[:, None], axis=2).max(axis=1)
        plain = meshes.farther(cen, rho + tol)
        if plain.any():
            known, kept, filled = meshes.decided(cen[plain])
            plain[plain] = known & kept & ~filled
        out = np.zeros(len(f1))
        if plain.any():
            out[plain], n_pieces = triangle_bounds(fld, v1, f1[plain], tol, int(PIECES * len(uniform.faces)))
            row["certified_pieces"] = int(n_pieces)
            plain[plain] = np.isfinite(out[plain])
        rest = ~plain
        if rest.any():
            d10 = mesh_to_mesh(v1, f1[rest], uniform.vertices, uniform.faces, room, room)
            out[rest] = uniform.mesh_to_surface + d10
        row["by_distance"] = int(rest.sum())
        return float(out.max()) if len(out) else 0.0

    return simplified(uniform, tol, tol - uniform.bound, tol, mesh_to_surface)


def mesh_part(scene, tol: float = DEFAULT_TOL, cell: float | None = None, attempts: int = ATTEMPTS,
              compact: bool = True) -> SurfaceMesh:
    """Mesh a part's solid, lattice and meshes together, with a certified Hausdorff bound.

    Parameters
    ----------
    scene : Skeleton or Part
        A lattice (blend ``sum``, degree >= 4) with solid and clipping meshes, or solid
        meshes alone; without meshes this is :func:`slicer.meshing.surface.mesh_scene`.
    tol : float, mm
        The two-sided Hausdorff distance to certify between the mesh's surface and the
        printed solid's ``((S ∩ CI) − CO) ∪ M`` (:mod:`slicer.parts.part`).
    cell : float, mm, optional
        The lattice's first cube side (:func:`slicer.meshing.surface.mesh_scene`).
    attempts : int
        The lattice's attempts per round.
    compact : bool
        Simplify the certified mesh and certify it again.

    Returns
    -------
    SurfaceMesh
        Closed, consistently wound, manifold; ``bound`` certified (the last round's
        when none certifies). ``stats`` adds ``rounds``, ``probed_pieces`` and
        ``cubes_near_meshes``.

    Raises
    ------
    SceneError
        As :func:`slicer.meshing.surface.lattice_of` for the lattice.
    OptionError
        As :func:`slicer.meshing.surface.mesh_scene`.

    Examples
    --------
    >>> import trimesh
    >>> from slicer import Skeleton
    >>> from slicer.parts.meshes import make_mesh
    >>> from slicer.parts.part import Part, PartMesh
    >>> box = trimesh.creation.box((4, 4, 2))
    >>> clip = make_mesh(box.vertices, box.faces, "box")
    >>> s = Skeleton([[0, 0, -2], [0, 0, 2]], [[0, 1]], [[1.0, 1.0]])
    >>> m = mesh_part(Part(s, (PartMesh(clip, "clip-inside"),)), tol=0.05)
    >>> m.certified, m.trimesh().is_watertight
    (True, True)
    """
    part = as_part(scene)
    tol = positive_number(tol, "tol")
    attempts = integer(attempts, "attempts", lo=1)
    if not part.meshes:
        return mesh_scene(part, tol=tol, cell=cell, attempts=attempts, compact=compact)
    start = time.perf_counter()
    meshes = _Meshes(part)
    if part.skeleton is None or part.skeleton.n_segments == 0:
        v, f = _combine(None, meshes)
        out = SurfaceMesh(v, f, tol, SLACK, SLACK, SLACK, math.nan, {"rounds": 0, "triangles": int(len(f))})
    else:
        fld = MeshField(lattice_of(part.skeleton))
        tol_lattice = tol
        best = None
        for rnd in range(1, ROUNDS + 1):
            lattice, band = uniform_mesh(fld, tol_lattice, cell if rnd == 1 else None, attempts)
            stats = dict(lattice.stats, rounds=rnd, lattice_tol=tol_lattice, lattice_bound=lattice.bound)
            v, f = _combine((lattice.vertices, lattice.faces), meshes)
            a, s, more = _certify(fld, meshes, band, lattice, v, f, tol)
            stats.update(more, triangles=int(len(f)))
            out = SurfaceMesh(v, f, tol, max(a, s), a, s, lattice.cell, stats)
            if best is None or out.bound < best.bound:
                best = out
            # certified with room to simplify, or a finer lattice would fail as this one did
            if best.bound <= ROOM * tol or not lattice.certified or (best.certified and not compact):
                break
            tol_lattice *= 0.5
        out = best
        if not len(out.faces):
            raise SceneError("nothing to mesh: the part's clipping meshes leave none of its lattice (to within "
                             f"{out.bound:.3g} mm) and it has no solid meshes", part.source)
    if compact and out.certified and part.skeleton is not None:
        out = _compact(fld, meshes, out, tol) or out
    out.stats["seconds"] = time.perf_counter() - start
    return out


__all__ = ["mesh_part"]
