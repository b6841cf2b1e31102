"""The band of cubes round the surface, its marching tetrahedra and their certificate.

The machinery of :func:`slicer.meshing.surface.mesh_scene` (steps 1-3 of
:mod:`slicer.meshing.surface`'s docstring, where the argument is): the grid of
cubes and its octree (:func:`_band`), the triangles (:func:`_triangles`), the
cubes' certified surface-to-mesh distances (:func:`_surface_to_mesh`) and the
finer cubes where they fall short (:func:`_finer`). A cube is known by its
integer index on a :class:`_Grid`; a grid edge, a vertex of the mesh, by a key
of the whole grid, so meshes made in pieces join.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import permutations

import numpy as np

from slicer.errors import OptionError
from slicer.meshing.certificate import MeshField, distances_to_surface, piece_distances
from slicer.model.skeleton import Skeleton

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


def _meets(cubes: np.ndarray, level: int, clip) -> np.ndarray:
    """Whether the cubes (k, 3) of a level meet the box ``clip`` = (lo, hi) of finest cubes (half open)."""
    return ((cubes + 1) << level > clip[0]).all(axis=1) & (cubes << level < clip[1]).all(axis=1)


def _band(fld: MeshField, grid: _Grid, start: np.ndarray | None = None, clip=None, last: int = 0,
          limit: float | None = None):
    """The finest cubes the octree cannot settle, (b, 3) int64 indices, and the settled counts.

    Cubes are settled :data:`CHUNK` at a time, and the survivors of each level split into
    their eight children, so the memory in use stays a few bytes per candidate cube.
    ``start``: the coarse cubes to begin with (default: all); ``clip``: (lo, hi) (3,) int64,
    a box of finest cubes (half open) outside which no cube is kept; ``last``: the level
    whose cubes are returned (0: the finest); ``limit``: the most cubes kept (default
    :data:`MAX_BAND`; at coarser levels, :data:`CANDIDATES` times as many).
    """
    limit = MAX_BAND if limit is None else limit
    if start is None:
        start = np.stack(np.meshgrid(*[np.arange(n) for n in grid.coarse], indexing="ij"), -1).reshape(-1, 3)
    cubes = [start if clip is None else start[_meets(start, grid.levels, clip)]]
    counts = {"inside": 0, "outside": 0}
    for level in range(grid.levels, last - 1, -1):
        side = grid.h * (1 << level)
        kept, n = [], 0
        for part in _chunks(cubes, CHUNK if level == 0 else CHUNK // 8):
            ins, out = settle(fld, grid.centres(part, level), 0.5 * math.sqrt(3.0) * side)
            counts["inside"] += int(ins.sum())
            counts["outside"] += int(out.sum())
            part = part[~(ins | out)]
            if level > last:
                part = (2 * part[:, None, :] + _CORNERS[None]).reshape(-1, 3)
                if clip is not None:
                    part = part[_meets(part, level - 1, clip)]
            n += len(part)
            if n > limit * (CANDIDATES if level else 1):
                raise OptionError(f"the mesh needs more than {int(limit):,} cubes of {grid.h:.4g} mm near the "
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
        The crossed grid edges, by a key of the whole grid (:func:`edge_keys`), sorted.
    points : (e, 3) float64, mm
        Their roots of F = 1.
    faces : (t, 3) int64
        Outward triangles, in positions of ``keys``.
    owner : (t,) int64
        The position in ``cubes`` of each face's cube.
    """
    dims = grid.coarse * (1 << grid.levels) + 1
    corners = cubes[:, None, :] + _CORNERS[None]                                   # (b, 8, 3)
    ckey = point_keys(grid, corners)
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


def point_keys(grid: _Grid, idx: np.ndarray) -> np.ndarray:
    """Keys (...) int64 of grid points ``idx`` (..., 3) int64 in the whole grid."""
    dims = grid.coarse * (1 << grid.levels) + 1
    return (idx[..., 2] * dims[1] + idx[..., 1]) * dims[0] + idx[..., 0]


def edge_keys(grid: _Grid, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Keys (n,) int64 of the grid edges from points ``a`` to ``b`` (n, 3) int64, one step of
    0 or 1 on each axis apart (a cube's edge or diagonal, either way round): the lower end's
    :func:`point_keys` times 7 plus the step's bits (1: x, 2: y, 4: z) less one, as
    :func:`_chunk_triangles` numbers the edges its vertices are on."""
    step = np.abs(b - a)
    return point_keys(grid, np.minimum(a, b)) * 7 + (step[:, 0] + 2 * step[:, 1] + 4 * step[:, 2] - 1)


def _triangles(fld: MeshField, grid: _Grid, band: np.ndarray):
    """Marching tetrahedra on the band's cubes, :data:`CHUNK` cubes at a time: vertices
    (v, 3), outward faces (t, 3), the band cube of each face (t,) and the vertices' grid
    edges (v,) (:func:`edge_keys`).

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
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    keys = np.concatenate(keys)
    ukeys, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    verts = np.concatenate(points)[first]
    return verts, inv[np.concatenate(faces)].astype(np.int64), np.concatenate(owner), ukeys


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
    (t, 3) int64, each face's cube (t,), the vertices' residuals ``|F(v) − 1|`` (v,), each
    cube's largest (b,) and the vertices' grid edges (v,) (:func:`edge_keys`)."""
    verts, faces, owner, keys = _triangles(fld, grid, band)
    resid = _residuals(fld, verts)
    worst = np.zeros(len(band))
    if len(faces):
        np.maximum.at(worst, owner, resid[faces].max(axis=1))
    return verts, faces, owner, resid, worst, keys


def _mesh_band(fld: MeshField, grid: _Grid, band: np.ndarray, g: np.ndarray, Hr: np.ndarray, d_cell: np.ndarray,
               tol: float):
    """Marching tetrahedra on the band (:func:`_triangles`), and the cubes next to a vertex
    residual above :data:`RESIDUAL` certified again with it.

    Returns
    -------
    vertices (v, 3) float64 mm, faces (t, 3) int64, each face's cube (t,), residuals (v,),
    the cubes' distances (b,) mm, ``d_cell`` updated, and the vertices' grid edges (v,).
    """
    verts, faces, owner, resid, worst, keys = _meshed(fld, grid, band)
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
    return verts, faces, owner, resid, d_cell, keys


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
        verts, faces, owner, _, worst, _ = _meshed(fld, fine, band)
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
