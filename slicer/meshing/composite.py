"""The mesh of a part: the lattice's certified mesh trimmed by, and united with, the part's meshes,
and certified again (docs/mesh.md, "Parts").

The true solid is ``T = ((S ∩ CI) − CO) ∪ M`` (:mod:`slicer.parts.part`): ``S`` the
lattice's solid ``F >= 1``, ``CI``, ``CO`` and ``M`` the unions of the clip-inside,
clip-outside and solid meshes. :func:`mesh_part`

1. meshes the lattice uniformly (:func:`slicer.meshing.surface.uniform_mesh`): a mesh
   ``L`` whose surface is within ``a`` of the surface ``F = 1`` (mesh to surface) and
   the surface within ``s`` of it, and whose solid equals ``S`` off the *band* ``U``,
   the closed cubes it could not settle;
2. computes ``R = ((L ∩ CI) − CO) ∪ M`` with manifold3d's booleans (each triangle of
   ``L`` a face of its own, so ``R``'s triangles are pieces of ``L``'s);
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
   (:func:`slicer._kernels.meshing.winding.winding_numbers`; shared by the points of a
   cell far enough from a large mesh), both only where they cannot be wrong (``|F − 1|``
   above :data:`F_MARGIN`, the meshes farther than :data:`NEAR`).

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
   certifies the simplified mesh ``R'``: surface to mesh by the distances from ``R`` to ``R'``
   (the Hausdorff distance is a metric); mesh to surface on the field where ``T`` is one
   lattice's solid, else by the distance back to ``R``, else by probes as above.

``S`` may be a union of summed lattices (a supported scene, the union blend:
:mod:`slicer.meshing.unions`): each is meshed with its band, ``L`` is their union, and the
rules above hold with "the meshes" read as "the meshes and the other lattices' bands"
(docs/mesh.md, "Unions").

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
from slicer.errors import OptionError, SceneError
from slicer.meshing.certificate import MeshField, SurfaceMesh
from slicer.meshing.compact import MAX_CELLS, PIECES, mesh_to_mesh, simplified, triangle_bounds
from slicer.meshing.cubes import Band, settle
from slicer.meshing.surface import ATTEMPTS, DEFAULT_TOL, lattice_of, mesh_scene, uniform_mesh
from slicer.meshing.unions import united_lattices
from slicer.model.blend import check_blend
from slicer.parts.part import Part, as_part

#: the mesh-to-mesh distances of the compaction are refined until each piece's bound is within this
#: share of the room the uniform mesh's bound leaves
DISTANCE_SHARE = 0.5
#: lattice meshes tried, each at half the tolerance of the one before
ROUNDS = 3
#: ... while the certified bound is above this share of the tolerance (the rest is the simplification's)
ROOM = 0.75
#: a piece of a triangle is probed once its radius is at most this share of the tolerance
PIECE_SHARE = 0.5
#: a wider piece, up to this share of the goal below, is probed along its normal first
EARLY_SHARE = 0.875
#: a probed piece of the mesh to simplify whose bound is above this share of the tolerance is halved
#: again (room for the simplification) ...
GOAL_SHARE = 0.5
#: ... while its radius is above this share
FINEST_SHARE = 1.0 / 32.0
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
#: mm: the smallest cell whose centre decides the membership of the points in it (:meth:`_Meshes.inside`)
MEMBER_CELL = 1e-5
#: ... for unions of at least this many triangles (fewer: each point's own winding number is cheaper)
MEMBER_FACES = 256
#: ``|F − 1|`` below this is not decided (the rounding of the field's point value is far less)
F_MARGIN = 1e-10
#: mm: the rounding of the booleans' new vertices (manifold3d computes them in float64)
SLACK = 1e-9
#: the roles' order in :class:`_Meshes`
ROLES = ("clip-inside", "clip-outside", "solid")
#: lattices united at most (a bit each in :class:`_Occupancy`)
MAX_LATTICES = 64
#: the side of :class:`_Occupancy`'s cells, in the largest band cube side
OCCUPANCY_CELLS = 2
_CELL_RANGE = 1 << 21
_CELL_SLACK = 1e-7
_LEVELS = 21
_QUERY_ROWS = 200_000
#: points have no pieces to straddle a mesh's edges: no wedges (slicer._kernels.meshing.nearest; empty,
#: not None, so the part's job compiles one distance kernel, as for the distance back below)
_NO_WEDGES = np.zeros((0, 3), np.int64)
_STEPS = np.stack(np.meshgrid(*[np.arange(3)] * 3, indexing="ij"), -1).reshape(-1, 3)


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
            inside[role] = np.zeros(len(points), bool)
            if known.any():
                inside[role][known] = self._members(role, np.ascontiguousarray(points[known]))
        return known, inside

    def _members(self, role: str, points: np.ndarray) -> np.ndarray:
        """Whether each point (none within :data:`NEAR` of the meshes) is in the role's union.

        A union of at least :data:`MEMBER_FACES` triangles: a point proved farther than ``e``
        from its surface has the membership of every point within ``e`` of it, so such points
        share the winding number of their cell's centre (cells of a power of two times
        :data:`MEMBER_CELL`, at most a quarter of the point's distance bound); the others get
        their own."""
        index, mesh = self.near_role[role], self.roles[role]
        if len(mesh[1]) < MEMBER_FACES:
            return winding_numbers(points, *mesh) > 0.5
        d = index.distances(points)
        level = np.floor(np.log2(np.maximum(np.minimum(d, index.reach), 1e-300) / (4.0 * MEMBER_CELL)))
        shared = level >= 0
        side = MEMBER_CELL * np.exp2(np.maximum(level, 0.0))
        cell = np.floor(points / side[:, None])
        centre = (cell + 0.5) * side[:, None]
        shared &= index.beyond(d, np.linalg.norm(points - centre, axis=1))
        out = np.zeros(len(points), bool)
        own = np.flatnonzero(~shared)
        if len(own):
            out[own] = winding_numbers(points[own], *mesh) > 0.5
        rows = np.flatnonzero(shared)
        if len(rows):
            key = np.concatenate([level[rows, None], cell[rows]], axis=1)
            order = np.lexsort(key.T[::-1])
            new = np.ones(len(rows), bool)
            new[1:] = (key[order[1:]] != key[order[:-1]]).any(axis=1)
            inverse = np.empty(len(rows), np.int64)
            inverse[order] = np.cumsum(new) - 1
            w = winding_numbers(np.ascontiguousarray(centre[rows[order[new]]]), *mesh)
            out[rows] = (w > 0.5)[inverse]
        return out

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
        return distance_bounds(p, np.repeat(np.arange(len(p)), 3).reshape(-1, 3), self.v, self.f, _NO_WEDGES,
                               self.offsets, self.ids, self.origin, self.cell, self.dims, 1e-300, self.reach)

    def farther(self, points: np.ndarray, x) -> np.ndarray:
        """Whether each point is proved farther than ``x`` (mm, scalar or (n,)) from the surface
        (never for ``x`` beyond the reach)."""
        x = np.broadcast_to(np.asarray(x, np.float64), (len(points),))
        if not len(self.f):
            return np.ones(len(points), bool)
        return self.beyond(self.distances(points), x)

    def beyond(self, d: np.ndarray, x) -> np.ndarray:
        """Whether distances ``d`` of :meth:`distances` prove their points farther than ``x``."""
        # the kernel returns d (1 + DISTANCE_SLACK) + GAP for every distance d up to the reach
        return (d > x * (1.0 + DISTANCE_SLACK) + GAP) & (x <= self.reach)


class _Lattices:
    """The lattice's solid ``S`` as the union of summed lattices (:func:`slicer.meshing.unions.united_lattices`:
    one for a lattice; the model and classes of support struts for a supported scene), each
    with its field, and once meshed (:meth:`mesh`) its certified uniform mesh and band."""

    def __init__(self, skeletons):
        if len(skeletons) > MAX_LATTICES:
            raise SceneError(f"the struts that unite fall in {len(skeletons)} classes of struts with disjoint "
                             f"supports; the mesher unites at most {MAX_LATTICES} (docs/mesh.md, 'Unions')",
                             skeletons[0].source)
        self.fields = [MeshField(lattice_of(s)) for s in skeletons]

    def __len__(self) -> int:
        return len(self.fields)

    def mesh(self, tol: float, cell: float | None, attempts: int) -> None:
        """Mesh each lattice uniformly (:func:`slicer.meshing.surface.uniform_mesh`)."""
        self.meshes, self.bands = [], []
        for fld in self.fields:
            m, band = uniform_mesh(fld, tol, cell, attempts)
            self.meshes.append(m)
            self.bands.append(band)
        self.a = np.array([m.mesh_to_surface for m in self.meshes])
        self.s = np.array([m.surface_to_mesh for m in self.meshes])
        self.h = max(b.h for b in self.bands)
        if len(self) > 1:
            self.occupancy = _Occupancy(self.bands, OCCUPANCY_CELLS * self.h)

    @property
    def certified(self) -> bool:
        return all(m.certified for m in self.meshes)

    def stats(self) -> dict:
        """The meshes' counts: the first lattice's, with sums of the counts and the largest bound."""
        out = dict(self.meshes[0].stats)
        for m in self.meshes[1:]:
            for k, v in m.stats.items():
                if isinstance(v, int) and k != "attempts":
                    out[k] = out.get(k, 0) + v
                elif k == "attempts":
                    out[k] = max(out[k], v)
        out.update(lattices=len(self), lattice_bound=max(m.bound for m in self.meshes))
        return out

    def inside(self, points: np.ndarray):
        """``(known, inside)`` of each point in ``S``: inside when some field is above
        ``1 + F_MARGIN``, outside when all are below ``1 − F_MARGIN``, else not known."""
        inside = np.zeros(len(points), bool)
        below = np.ones(len(points), bool)
        for fld in self.fields:
            f = fld.values(points)[0]
            inside |= f > 1.0 + F_MARGIN
            below &= f < 1.0 - F_MARGIN
        return inside | below, inside

    def settle(self, centres: np.ndarray, radius: float):
        """``(inside, outside)``: ``S`` proved to fill, or to miss, each ball ``B(c, radius)``."""
        ins = np.zeros(len(centres), bool)
        out = np.ones(len(centres), bool)
        for fld in self.fields:
            i, o = settle(fld, centres, radius)
            ins |= i
            out &= o
        return ins, out

    def meets(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each box ``[lo, hi]`` ((n, 3) each, mm) may meet a band cube (False:
        proved not to)."""
        if len(self) == 1:
            return _meets_band(self.bands[0], lo, hi)
        return self.occupancy.masks(lo, hi) != 0

    def owner(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n,) int64: the one lattice whose band each box may meet (-1: none, or several)."""
        if len(self) == 1:
            return np.where(_meets_band(self.bands[0], lo, hi), 0, -1)
        m = self.occupancy.masks(lo, hi)
        single = (m != 0) & ((m & (m - np.uint64(1))) == 0)
        g = np.full(len(lo), -1, np.int64)
        g[single] = np.round(np.log2(m[single].astype(np.float64))).astype(np.int64)
        return g

    def outside_others(self, g: int, points: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each point is outside the solid of every lattice but ``g``
        (its field below ``1 − F_MARGIN``)."""
        out = np.ones(len(points), bool)
        for k, fld in enumerate(self.fields):
            if k != g and len(points):
                out &= fld.values(points)[0] < 1.0 - F_MARGIN
        return out

    def others_meet(self, g: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each box may meet a band cube of a lattice other than ``g``."""
        if len(self) == 1:
            return np.zeros(len(lo), bool)
        return (self.occupancy.masks(lo, hi) & ~np.uint64(1 << g)) != 0


class _Occupancy:
    """Which lattices' bands reach each cell of a coarse grid common to them: per cell (side
    ``side``, mm), a bit per lattice whose band cubes meet it (at most :data:`MAX_LATTICES`),
    and the same for cells ``2**level`` times larger.

    A box's bits are those of the cells it meets, at the finest level where it meets at most
    three per axis: a superset of the lattices whose band cubes it meets, so a box with no bit
    meets no band, and a box with one bit meets no other band.
    """

    def __init__(self, bands, side: float):
        self.side = float(side)         # more than the bands' cube sides, so a cube meets at most 2 cells per axis
        self.origin = np.min([b.grid.origin for b in bands], axis=0) - self.side
        keys, bits = [], []
        corners = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 3)
        for g, band in enumerate(bands):
            lo = band.grid.origin + band.cubes * band.h
            a = self._cells(lo, -_CELL_SLACK)
            b = self._cells(lo + band.h, _CELL_SLACK)       # at most one more per axis (h < side)
            k = np.unique(np.concatenate([self._key(a + c * (b - a)) for c in corners]))
            keys.append(k)
            bits.append(np.full(len(k), np.uint64(1 << g), np.uint64))
        keys, bits = np.concatenate(keys), np.concatenate(bits)
        self.levels = []
        for level in range(_LEVELS):       # each level's cells from the one below's
            if level:
                keys = self._key(self._unkey(keys) >> 1)
            keys, inverse = np.unique(keys, return_inverse=True)
            merged = np.zeros(len(keys), np.uint64)
            np.bitwise_or.at(merged, inverse.ravel(), bits)
            bits = merged
            self.levels.append((keys, bits))

    def _cells(self, p: np.ndarray, slack: float = 0.0) -> np.ndarray:
        """The cells holding points (n, 3), mm, moved by ``slack`` cells (rounding, outward)."""
        return np.clip(np.floor((p - self.origin) / self.side + slack), 0, _CELL_RANGE - 1).astype(np.int64)

    @staticmethod
    def _key(idx: np.ndarray) -> np.ndarray:
        return (idx[..., 2] * _CELL_RANGE + idx[..., 1]) * _CELL_RANGE + idx[..., 0]

    @staticmethod
    def _unkey(k: np.ndarray) -> np.ndarray:
        return np.stack([k % _CELL_RANGE, (k // _CELL_RANGE) % _CELL_RANGE, k // (_CELL_RANGE * _CELL_RANGE)], -1)

    def masks(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n,) uint64: the bits of each box ``[lo, hi]`` ((n, 3) each, mm)."""
        out = np.zeros(len(lo), np.uint64)
        for s in range(0, len(lo), _QUERY_ROWS):
            out[s:s + _QUERY_ROWS] = self._masks(self._cells(lo[s:s + _QUERY_ROWS], -_CELL_SLACK),
                                                 self._cells(hi[s:s + _QUERY_ROWS], _CELL_SLACK))
        return out

    def _masks(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = np.zeros(len(a), np.uint64)
        todo = np.arange(len(a))
        for level, (keys, bits) in enumerate(self.levels):
            if not len(todo):
                break
            a_k, b_k = a[todo] >> level, b[todo] >> level
            fits = ((b_k - a_k) <= 2).all(axis=1) | (level == _LEVELS - 1)
            if fits.any() and len(keys):
                idx = a_k[fits][:, None, :] + _STEPS[None]
                real = (idx <= b_k[fits][:, None, :]).all(axis=2)
                k = self._key(idx)
                j = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
                hit = (keys[j] == k) & real
                out[todo[fits]] = np.bitwise_or.reduce(np.where(hit, bits[j], np.uint64(0)), axis=1)
                # the top level holds everything in at most 3 cells per axis (_LEVELS covers the range)
            todo = todo[~fits]
        return out


def _manifold(vertices: np.ndarray, faces: np.ndarray, name: str, first_face: int | None = None) -> manifold3d.Manifold:
    """A closed mesh as manifold3d's; ``first_face``: its triangles are faces of their own, numbered
    from there (the booleans then keep every triangle's edges, not merging coplanar neighbours)."""
    face_id = None if first_face is None else np.arange(first_face, first_face + len(faces), dtype=np.uint64)
    m = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.array(vertices, np.float64, order="C"),
                                              tri_verts=np.array(faces, np.uint64, order="C"), face_id=face_id))
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


def _combine(lattices, meshes: _Meshes):
    """``((L ∩ CI) − CO) ∪ M`` by manifold3d: (v, 3) float64 and (t, 3) int64, outward.

    Parameters
    ----------
    lattices : list of SurfaceMesh
        Closed meshes whose union is the lattice's mesh ``L`` (empty: no lattice).
    meshes : _Meshes
        The part's meshes by role.
    """
    out = None
    ms = meshes.manifolds
    # each lattice triangle a face of its own: coplanar strips (a strut along a grid axis) would
    # merge into slivers millimetres long, each certified piece by piece
    first = np.cumsum([0] + [len(m.faces) for m in lattices])
    parts = [_manifold(m.vertices, m.faces, "the lattice's mesh", int(k))
             for m, k in zip(lattices, first) if len(m.faces)]
    if parts:
        out = parts[0] if len(parts) == 1 else manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
        if "clip-inside" in ms:
            out = out ^ ms["clip-inside"]
        if "clip-outside" in ms:
            out = out - ms["clip-outside"]
    if "solid" in ms:
        out = ms["solid"] if out is None else out + ms["solid"]
    if out is None:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return _arrays(out)


def _inside_solid(lat: _Lattices, meshes: _Meshes, points: np.ndarray):
    """``(known, inside)`` of each point in the true solid ``T``."""
    known_s, in_s = lat.inside(points)
    known, kept, filled = meshes.decided(points)
    return known & known_s, filled | (kept & in_s)


def _halves(p: np.ndarray) -> np.ndarray:
    """(k, 3, 3) triangles -> (2 k, 3, 3): each cut at its longest edge's midpoint (slivers
    become well shaped, where quarters would keep their shape)."""
    length = np.stack([np.linalg.norm(p[:, (i + 1) % 3] - p[:, i], axis=1) for i in range(3)], 1)
    i = length.argmax(axis=1)
    rows = np.arange(len(p))
    a, b, c = p[rows, i], p[rows, (i + 1) % 3], p[rows, (i + 2) % 3]
    m = 0.5 * (a + b)
    return np.stack([np.stack([a, m, c], 1), np.stack([m, b, c], 1)], 1).reshape(-1, 3, 3)


def _meets_band(band: Band, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """Whether each box ``[box_lo, box_hi]`` ((k, 3) each, mm) meets a band cube: looked up among
    the cubes ``2**level`` times the band's side that hold band cubes, at the finest level where
    the box spans at most 4 of them per axis."""
    g = band.grid
    lo = np.floor((box_lo - g.origin) / g.h - 1e-7).astype(np.int64)
    hi = np.floor((box_hi - g.origin) / g.h + 1e-7).astype(np.int64)
    out = np.zeros(len(lo), bool)
    todo = np.arange(len(lo))
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


def _probe(lat: _Lattices, meshes: _Meshes, centres: np.ndarray, normals: np.ndarray, reach: np.ndarray,
           along_normal_only: bool = False) -> np.ndarray:
    """Per point ``c`` with unit normal ``n``: a probe distance ``t <= reach`` such that two points
    of ``B(c, t)`` are on opposite sides of T, which puts T's surface in the ball (inf: none found).

    The points tried, in turn while none is found: ``c`` and ``c ± t n`` for ``t = reach / 2**k``,
    k from :data:`PROBE_STEPS` down to 0; then, where that found nothing or only beyond
    ``DENSE_ABOVE reach``, :data:`DENSE` distances along ``± n`` spaced evenly in log from
    ``reach / 1e9`` (a thin wedge of T or of its complement, where two surfaces meet at a small
    angle); then, where that found nothing or only beyond ``DENSE_ABOVE reach`` (a surface nearly
    tangent to the normal), ``c + t u`` for u in the 256 directions of :func:`_directions` and the
    first ``t``'s below the distance found. ``along_normal_only``: the first points only.
    """
    out = np.full(len(centres), np.inf)
    k0, m0 = _inside_solid(lat, meshes, centres)
    todo = np.flatnonzero(reach > 0)

    def found(ts, pts):
        """Where the points (pieces, m, 3) with ``c`` show both sides: record ``ts``."""
        kk, mm = _inside_solid(lat, meshes, pts.reshape(-1, 3))
        kk = np.concatenate([kk.reshape(len(todo), -1), k0[todo, None]], axis=1)
        mm = np.concatenate([mm.reshape(len(todo), -1), m0[todo, None]], axis=1)
        ok = (kk & mm).any(axis=1) & (kk & ~mm).any(axis=1)
        out[todo[ok]] = np.minimum(out[todo[ok]], ts[ok])
        return todo[~ok]

    for k in range(PROBE_STEPS, -1, -1):
        if not len(todo):
            return out
        t = reach[todo] * 0.5 ** k
        todo = found(t, centres[todo, None, :] + t[:, None, None] * np.stack([normals[todo], -normals[todo]], 1))
    if along_normal_only:
        return out
    # along the normal, densely, where nothing was found or only far: the least t with both sides
    # among c, c ± t' n (t' <= t)
    todo = np.flatnonzero((reach > 0) & ~(out <= DENSE_ABOVE * reach))
    if len(todo):
        frac = np.logspace(-9.0, 0.0, DENSE)
        t = reach[todo, None] * frac[None]
        pts = centres[todo, None, None, :] + t[:, :, None, None] * np.stack([normals[todo], -normals[todo]], 1)[:, None]
        kk, mm = _inside_solid(lat, meshes, pts.reshape(-1, 3))
        kk, mm = kk.reshape(len(todo), DENSE, 2), mm.reshape(len(todo), DENSE, 2)
        seen_in = np.logical_or.accumulate((kk & mm).any(axis=2), axis=1) | (k0[todo] & m0[todo])[:, None]
        seen_out = np.logical_or.accumulate((kk & ~mm).any(axis=2), axis=1) | (k0[todo] & ~m0[todo])[:, None]
        both = seen_in & seen_out
        ok = both.any(axis=1)
        first = both.argmax(axis=1)
        out[todo[ok]] = np.minimum(out[todo[ok]], t[ok, first[ok]])
    # in all directions, where nothing was found or only far (T's surface nearly tangent to the
    # normal, as where a strut's surface grazes another's)
    todo = np.flatnonzero((reach > 0) & ~(out <= DENSE_ABOVE * reach))
    for k in list(range(PROBE_STEPS, -1, -1)):
        t = reach[todo] * 0.5 ** k
        nearer = t < out[todo]
        todo, t = todo[nearer], t[nearer]
        if not len(todo):
            return out
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


def _mesh_to_surface(lat: _Lattices, meshes: _Meshes, v: np.ndarray, f: np.ndarray, tol: float,
                     of_lattices: bool = True, goal: float | None = None):
    """Per triangle of R, a bound of its points' distance to T's surface, and the pieces probed.
    ``of_lattices=False``: triangles of another mesh (the simplified one), on no lattice's mesh
    and not R's off the bands, certified by probes alone. ``goal`` (mm, default the tolerance):
    a probed piece certified above it is halved again, down to ``FINEST_SHARE tol`` (a
    tighter bound leaves the simplification room)."""
    goal = tol if goal is None else goal
    tri = v[f]
    cen = tri.mean(axis=1)
    rho = np.linalg.norm(tri - cen[:, None], axis=2).max(axis=1)
    out = np.zeros(len(f))
    one = len(lat) == 1
    # one lattice: a triangle far from the meshes is on L's surface (several: see the loop)
    far = meshes.farther(cen, rho + lat.a[0]) if one and of_lattices else np.zeros(len(f), bool)
    out[far] = lat.a[0]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    normal = np.where(length[:, None] > 0, normal / np.where(length > 0, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    owner = np.flatnonzero(~far)
    pieces = tri[owner]
    probed = 0
    a_max = float(lat.a.max())
    for depth in range(PIECE_DEPTH + 1):
        if not len(pieces):
            break
        c = pieces.mean(axis=1)
        r = np.linalg.norm(pieces - c[:, None], axis=2).max(axis=1)
        lo, hi = pieces.min(axis=1), pieces.max(axis=1)
        # off the bands R = T; farther than a_g from the meshes and from the other lattices' bands,
        # a piece is on L_g's surface
        if not of_lattices:
            meets, g = np.ones(len(pieces), bool), np.full(len(pieces), -1, np.int64)
        else:
            meets = lat.meets(lo, hi)
            g = np.zeros(len(pieces), np.int64) if one else lat.owner(lo - a_max, hi + a_max)
        out[owner[~meets]] = np.maximum(out[owner[~meets]], SLACK)
        a_g = lat.a[np.maximum(g, 0)]
        far = meets & (g >= 0) & meshes.farther(c, r + a_g)
        out[owner[far]] = np.maximum(out[owner[far]], a_g[far])
        keep = meets & ~far
        pieces, owner, c, r = pieces[keep], owner[keep], c[keep], r[keep]
        # wider pieces, up to EARLY_SHARE of the goal, are tried along the normal first (a flat face
        # is certified at once); those not certified within the goal are halved
        early = (r > PIECE_SHARE * tol) & (r <= EARLY_SHARE * goal)
        if early.any():
            t = _probe(lat, meshes, c[early], normal[owner[early]], goal - r[early] - SLACK, along_normal_only=True)
            d = r[early] + t + SLACK
            probed += int(early.sum())
            ok = d <= goal
            np.maximum.at(out, owner[early][ok], d[ok])
            early[early] = ok
        small = r <= PIECE_SHARE * tol
        if small.any():
            t = _probe(lat, meshes, c[small], normal[owner[small]], tol - r[small] - SLACK)
            d = r[small] + t + SLACK
            probed += int(small.sum())
            # a piece certified above the goal is halved again, while it is wider than FINEST_SHARE tol
            done = (d <= goal) | (r[small] <= FINEST_SHARE * tol) | np.isinf(d)
            np.maximum.at(out, owner[small][done], d[done])
            if np.isinf(d).any():       # not certified: the rest cannot change that
                return np.full(len(f), np.inf), probed
            small[small] = done
        small |= early
        pieces, owner = pieces[~small], owner[~small]
        if depth == PIECE_DEPTH:
            out[owner] = np.inf
        else:
            pieces, owner = _halves(pieces), np.repeat(owner, 2)
    return out, probed


def _constant(lat: _Lattices, meshes: _Meshes, centres: np.ndarray, radius: float) -> np.ndarray:
    """Whether T = (S ∧ kept) ∨ filled is proved constant over each ball ``B(c, radius)``: inside
    when a solid fills it or S fills it where the lattice is kept; outside when no solid reaches it
    and S is outside or the lattice removed. A mesh's membership is constant over the ball when
    its union's surface is farther than the radius."""
    ins, out = lat.settle(centres, radius)
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


def _surface_to_mesh(lat: _Lattices, meshes: _Meshes, result, tol: float):
    """A bound of the distance from T's surface points in the band cubes near the meshes or near
    another lattice's band to R's surface; the largest bound ``s_g`` of the lattices with cubes
    elsewhere (0: none); the cubes near."""
    surface = _Index(result, tol)
    worst, plain, n_near = 0.0, 0.0, 0
    offs = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 3) - 0.5
    for g, band in enumerate(lat.bands):
        c = band.centres()
        r = 0.5 * math.sqrt(3.0) * band.h
        reach = r + float(lat.s[g])
        near = ~meshes.farther(c, reach)
        if len(lat) > 1:
            near |= lat.others_meet(g, c - reach, c + reach)
        if (~near).any():
            plain = max(plain, float(lat.s[g]))
        n_near += int(near.sum())
        cubes, radius, side = c[near], r, band.h
        for depth in range(CUBE_DEPTH + 1):
            if not len(cubes):
                break
            free = _constant(lat, meshes, cubes, radius)
            d = surface.distances(cubes)
            goal = tol if depth == CUBE_DEPTH else COVER_SHARE * tol
            covered = ~free & (d + radius + SLACK <= goal)
            if covered.any():
                worst = max(worst, float((d[covered] + radius).max()) + SLACK)
            rest = cubes[~free & ~covered]
            if depth == CUBE_DEPTH and len(rest):
                return math.inf, plain, n_near
            cubes = (rest[:, None, :] + 0.5 * side * offs[None]).reshape(-1, 3)
            radius, side = 0.5 * radius, 0.5 * side
    return worst, plain, n_near


def _certify(lat: _Lattices, meshes: _Meshes, v, f, tol: float, compact: bool = True):
    """R = (v, f) against T: the bounds mesh to surface and surface to mesh, and counts
    (``compact``: pieces are probed down to ``GOAL_SHARE tol`` where they can, room for the
    simplification)."""
    if not (np.isfinite(lat.a).all() and np.isfinite(lat.s).all()):      # a lattice not certified at all
        return math.inf, math.inf, {"probed_pieces": 0, "cubes_near_meshes": 0}
    meshes.index(2.0 * tol + math.sqrt(3.0) * lat.h)
    d_tri, probed = _mesh_to_surface(lat, meshes, v, f, tol, goal=GOAL_SHARE * tol if compact else tol)
    a = float(d_tri.max()) if len(d_tri) else 0.0
    if not a <= tol:
        return a, math.inf, {"probed_pieces": probed, "cubes_near_meshes": 0}
    s_near, s_plain, n_near = _surface_to_mesh(lat, meshes, (v, f), tol)
    return a, max(s_near, s_plain), {"probed_pieces": probed, "cubes_near_meshes": n_near}


def _compact(lat: _Lattices, meshes: _Meshes, uniform: SurfaceMesh, tol: float) -> SurfaceMesh | None:
    """``uniform`` (R, certified) simplified and certified again (:func:`slicer.meshing.compact.simplified`).

    Mesh to surface, per triangle of the simplified mesh: farther than ``ρ + tol`` from every mesh,
    where the lattice is kept and no solid fills, and (several lattices) from the bands of all
    lattices but one, ``g``, outside the others' solids, ``T = S_g`` within the tolerance, so the
    triangle's certificate on ``g``'s field holds (as a lattice's); any other triangle, by its
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
        g = np.zeros(len(f1), np.int64)
        if len(lat) > 1 and plain.any():
            g[plain] = lat.owner(tri[plain].min(axis=1) - tol, tri[plain].max(axis=1) + tol)
            plain &= g >= 0
            for k in range(len(lat)):
                mine = np.flatnonzero(plain & (g == k))
                plain[mine] = lat.outside_others(k, cen[mine])
        out = np.zeros(len(f1))
        row["certified_pieces"] = 0
        for k in range(len(lat)):
            mine = np.flatnonzero(plain & (g == k))
            if len(mine):
                out[mine], n_pieces = triangle_bounds(lat.fields[k], v1, f1[mine], tol,
                                                      int(PIECES * len(uniform.faces)))
                row["certified_pieces"] += int(n_pieces)
                plain[mine] = np.isfinite(out[mine])
        rest = ~plain
        if rest.any():
            # no wedges: what they would certify, the probes below do for less (the hole of
            # benchmarks/mesh_parts_bench.py: this distance took 81 s without them, 165 s with)
            d10 = mesh_to_mesh(v1, f1[rest], uniform.vertices, uniform.faces, DISTANCE_SHARE * room, room,
                               wedges=False)
            out[rest] = uniform.mesh_to_surface + d10
        # what the distance back leaves above the tolerance (large triangles on a part's mesh), by probes
        over = np.flatnonzero(rest & ~(out <= tol))
        if len(over):
            d, n_probed = _mesh_to_surface(lat, meshes, v1, f1[over], tol, of_lattices=False)
            out[over] = np.minimum(out[over], d)
            row["probed_pieces"] = n_probed
        row["by_distance"] = int(rest.sum())
        return out

    # no held rounds here yet: each would certify the whole part again (minutes on benchmarks/mesh_parts_bench.py)
    return simplified(uniform, tol, tol - uniform.bound, tol, mesh_to_surface,
                      target=DISTANCE_SHARE * (tol - uniform.surface_to_mesh), wedges=True, hold_rounds=0)


def mesh_part(scene, tol: float = DEFAULT_TOL, cell: float | None = None, attempts: int = ATTEMPTS,
              compact: bool = True, blend: str = "sum", tile: float | None = None, progress=None) -> SurfaceMesh:
    """Mesh a part's solid, lattice and meshes together, with a certified Hausdorff bound.

    Parameters
    ----------
    scene : Skeleton, GroupedSkeleton or Part
        A lattice (degree >= 4) with solid and clipping meshes, or solid meshes alone; a
        supported scene (the model's struts, supports and pad unite); without meshes, a
        summed lattice is :func:`slicer.meshing.surface.mesh_scene`'s.
    tol : float, mm
        The two-sided Hausdorff distance to certify between the mesh's surface and the
        printed solid's ``((S ∩ CI) − CO) ∪ M`` (:mod:`slicer.parts.part`).
    cell : float, mm, optional
        The lattices' first cube side (:func:`slicer.meshing.surface.mesh_scene`).
    attempts : int
        The lattices' attempts per round.
    compact : bool
        Simplify the certified mesh and certify it again.
    blend : {"sum", "union"}
        The model's blend (:mod:`slicer.model.blend`); with ``union`` every strut's own
        solid unites (:mod:`slicer.meshing.unions`).
    tile : float, mm, optional
        A summed lattice without meshes: :func:`slicer.meshing.surface.mesh_scene`'s tiles
        (others are meshed in one piece; asking for tiles there is an error).
    progress : callable, optional
        Called with a line of text as each tile is done.

    Returns
    -------
    SurfaceMesh
        Closed, consistently wound, manifold; ``bound`` certified (the last round's
        when none certifies). ``stats`` adds ``rounds``, ``lattices`` (the summed
        lattices united), ``probed_pieces`` and ``cubes_near_meshes``.

    Raises
    ------
    SceneError
        As :func:`slicer.meshing.surface.lattice_of` for the lattice.
    OptionError
        As :func:`slicer.meshing.surface.mesh_scene`, or an unknown blend.

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
    blend = check_blend(blend, "blend")
    skel = part.skeleton if part.skeleton is not None and part.skeleton.n_segments else None
    unites = skel is not None and (bool(getattr(skel, "groups", ())) or blend == "union")
    if not part.meshes and not unites:
        return mesh_scene(part, tol=tol, cell=cell, attempts=attempts, compact=compact, tile=tile, progress=progress)
    if tile is not None:
        raise OptionError(f"tiles mesh a summed lattice alone; this part has {part.describe()}"
                          + (" with struts that unite" if unites else "") + ": mesh it without --tile")
    start = time.perf_counter()
    meshes = _Meshes(part)
    if skel is None:
        v, f = _combine([], meshes)
        out = SurfaceMesh(v, f, tol, SLACK, SLACK, SLACK, math.nan, {"rounds": 0, "triangles": int(len(f))})
    else:
        lat = _Lattices(united_lattices(skel, blend))
        tol_lattice = tol
        best = None
        for rnd in range(1, ROUNDS + 1):
            lat.mesh(tol_lattice, cell if rnd == 1 else None, attempts)
            stats = dict(lat.stats(), rounds=rnd, lattice_tol=tol_lattice)
            v, f = _combine(lat.meshes, meshes)
            a, s, more = _certify(lat, meshes, v, f, tol, compact)
            stats.update(more, triangles=int(len(f)))
            out = SurfaceMesh(v, f, tol, max(a, s), a, s, min(m.cell for m in lat.meshes), stats)
            if best is None or out.bound < best.bound:
                best = out
            # certified with room to simplify, or a finer lattice would fail as this one did
            if best.bound <= ROOM * tol or not lat.certified or (best.certified and not compact):
                break
            tol_lattice *= 0.5
        out = best
        if not len(out.faces):
            raise SceneError("nothing to mesh: the part's clipping meshes leave none of its lattice (to within "
                             f"{out.bound:.3g} mm) and it has no solid meshes", part.source)
        if compact and out.certified:
            out = _compact(lat, meshes, out, tol) or out
    out.stats["seconds"] = time.perf_counter() - start
    return out


__all__ = ["mesh_part"]
