"""Meshed reference: the iso-surface ``F = 1`` of the field itself, meshed and
sliced with manifold3d.

The field is sampled on a cubic grid with the compiled, bucketed evaluator
(:func:`slicer.model.field.evaluate`), one z-plane at a time. Each cube is split into
the six Freudenthal (Kuhn) tetrahedra that share its main diagonal, so
neighbouring cubes agree on their faces and marching tetrahedra gives a closed,
oriented, watertight mesh. Every mesh vertex sits on a grid edge between an
inside and an outside sample and is put on the surface by plain bisection
(:func:`validation.independent.bisect`: nothing of the contours' code is
shared; only the point field evaluation is), so the mesh's error is its
chordal error only: flat triangles of edge up to
``edge * sqrt(3)`` across a curved surface. Grid points on the faces of the
meshed box count as outside, so a box that cuts the solid closes it with caps.

This is not a union of capsules: free ends, tapers and blends are those of
the field (docs/math.md §1.5).

Two uses:

* :func:`reference_mesh` meshes a whole box (a :class:`manifold3d.Manifold`).
* :func:`reference_sections` slices at given heights; each height gets its
  own mesh: the band of cubes between grid planes ``z +- edge/2`` closed by
  flat caps on those planes (:func:`cap_band`), whose section at ``z`` is
  exactly that of the whole-box mesh on the same grid. It costs two field
  planes per height and grows with the contours' length, not the section's
  area, so fine edges are affordable.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from itertools import permutations

import numpy as np

from slicer.arguments import positive_number
from slicer.errors import GridError
from slicer.model.field import evaluate
from slicer.model.skeleton import Skeleton

from validation.independent import assemble, bisect, chain

# cube corner c = dx + 2 dy + 4 dz
_CORNER = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])
# the six Freudenthal tetrahedra: monotone corner paths 000 -> 111
_TETS = []
for _p in permutations(range(3)):
    _v = [np.zeros(3, int)]
    for _ax in _p:
        _v.append(_v[-1] + np.eye(3, dtype=int)[_ax])
    _TETS.append([int(v[0] + 2 * v[1] + 4 * v[2]) for v in _v])
_TETS = np.array(_TETS)                     # (6, 4) cube corner indices


def _tet_table():
    """Triangles of marching tetrahedra, oriented outward, per tet and case.

    Returns
    -------
    (6, 16, 2, 3, 2) int64
        ``[tet, case, tri, vertex] = (inside corner, outside corner)`` (cube
        corner indices); case bit q is set when tet vertex q is inside; unused
        triangles are -1.
    """
    out = -np.ones((6, 16, 2, 3, 2), np.int64)
    for t, tet in enumerate(_TETS):
        pos = _CORNER[tet].astype(float)
        for case in range(1, 15):
            ins = [q for q in range(4) if (case >> q) & 1]
            outs = [q for q in range(4) if not (case >> q) & 1]
            if len(ins) == 1 or len(outs) == 1:
                lone, others = (ins[0], outs) if len(ins) == 1 else (outs[0], ins)
                tris = [[(lone, o) for o in others]]
            else:
                a, b = ins
                c, d = outs
                quad = [(a, c), (a, d), (b, d), (b, c)]
                tris = [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
            cin = pos[ins].mean(axis=0)
            cout = pos[outs].mean(axis=0)
            for s, tri in enumerate(tris):
                edges = [(e[0], e[1]) if e[0] in ins else (e[1], e[0]) for e in tri]
                mid = np.array([0.5 * (pos[i] + pos[o]) for i, o in edges])
                nrm = np.cross(mid[1] - mid[0], mid[2] - mid[0])
                if np.dot(nrm, cout - cin) < 0:
                    edges = [edges[0], edges[2], edges[1]]
                out[t, case, s] = [(tet[i], tet[o]) for i, o in edges]
    return out


_TRI = _tet_table()


@dataclass
class MeshInfo:
    """What a reference mesh is and how good it is.

    Attributes
    ----------
    edge : float, mm
        Grid spacing (triangle edges are at most ``edge * sqrt(3)``).
    vertices, triangles : int
    evaluations : int
        Field evaluations (samples and root solves).
    seconds : float
    error_3d : float, mm
        Estimated distance of the mesh to the surface: the largest
        ``|F - 1| / |grad F|`` at triangle centroids and edge midpoints.
    vertex_error : float, mm
        Bound on the vertices' distance to the surface along their grid edge
        (the root tolerance).
    """

    edge: float
    vertices: int = 0
    triangles: int = 0
    evaluations: int = 0
    seconds: float = 0.0
    error_3d: float = 0.0
    vertex_error: float = 0.0
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("edge", "vertices", "triangles", "evaluations", "seconds",
                                             "error_3d", "vertex_error")}
        d.update(self.extra)
        return d


def march_box(skel: Skeleton, lo, edge: float, dims, tol: float = 1e-5, open_z: bool = False):
    """Marching tetrahedra of ``F = 1`` over a grid of points.

    Parameters
    ----------
    skel : Skeleton
    lo : (3,) float64, mm
        Grid point (0, 0, 0).
    edge : float, mm
        Grid spacing.
    dims : (3,) int
        Cubes along x, y, z (points: ``dims + 1``). Points on the outer faces
        count as outside (closed mesh).
    tol : float, mm
        Root tolerance of the vertices along their grid edges.
    open_z : bool
        Sample the bottom and top planes too instead of treating them as
        outside: the mesh is then open there (see :func:`cap_band`).

    Returns
    -------
    verts : (n, 3) float64, mm
    tris : (m, 3) int64
        Outward oriented (counter-clockwise seen from outside).
    info : MeshInfo
    """
    t0 = time.perf_counter()
    lo = np.asarray(lo, dtype=np.float64)
    nx, ny, nz = (int(v) for v in dims)
    NX, NY = nx + 1, ny + 1
    xs = lo[0] + edge * np.arange(NX)
    ys = lo[1] + edge * np.arange(NY)
    X, Y = np.meshgrid(xs, ys)                     # (NY, NX)
    interior = np.zeros((NY, NX), bool)
    interior[1:-1, 1:-1] = True
    evals = 0

    def plane(k):
        """Field on plane k (0 on the outside-by-decree faces)."""
        nonlocal evals
        f = np.zeros((NY, NX))
        if (k == 0 or k == nz) and not open_z:
            return f
        pts = np.column_stack([X[interior], Y[interior], np.full(interior.sum(), lo[2] + k * edge)])
        f[interior] = evaluate(skel, pts)[0]
        evals += pts.shape[0]
        return f

    keys_parts, inlow_parts, fin_parts, fout_parts = [], [], [], []
    below = plane(0)
    for k in range(nz):
        above = plane(k + 1)
        corners = []
        for c in range(8):
            dx, dy, dz = _CORNER[c]
            src = above if dz else below
            corners.append(src[dy:dy + ny, dx:dx + nx])
        below = above
        F = np.stack(corners, axis=-1)             # (ny, nx, 8)
        C = F >= 1.0
        anyin = C.any(axis=-1)
        allin = C.all(axis=-1)
        cj, ci = np.nonzero(anyin & ~allin)
        if cj.size == 0:
            continue
        Cm = C[cj, ci]                             # (q, 8)
        Fm = F[cj, ci]
        for t in range(6):
            case = (Cm[:, _TETS[t, 0]].astype(np.int64) | (Cm[:, _TETS[t, 1]] << 1)
                    | (Cm[:, _TETS[t, 2]] << 2) | (Cm[:, _TETS[t, 3]] << 3))
            for s in range(2):
                tri = _TRI[t, case, s]             # (q, 3, 2)
                use = tri[:, 0, 0] >= 0
                if not use.any():
                    continue
                tri = tri[use]
                qj, qi = cj[use], ci[use]
                ci_in, ci_out = tri[..., 0], tri[..., 1]
                rows = np.flatnonzero(use)[:, None]
                fin_parts.append(Fm[rows, ci_in])
                fout_parts.append(Fm[rows, ci_out])
                off_in = _CORNER[ci_in]            # (r, 3, 3)
                off_out = _CORNER[ci_out]
                low_is_in = off_in.sum(axis=-1) < off_out.sum(axis=-1)
                low = np.where(low_is_in[..., None], off_in, off_out)
                diff = np.abs(off_out - off_in)
                code = diff[..., 0] + 2 * diff[..., 1] + 4 * diff[..., 2] - 1
                gi = qi[:, None] + low[..., 0]
                gj = qj[:, None] + low[..., 1]
                gk = k + low[..., 2]
                flat = (gk * NY + gj) * NX + gi
                keys_parts.append(flat * 7 + code)
                inlow_parts.append(low_is_in)
    info = MeshInfo(edge=float(edge), vertex_error=float(tol))
    if not keys_parts:
        info.seconds = time.perf_counter() - t0
        info.evaluations = evals
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), info
    keys = np.concatenate(keys_parts)
    inlow = np.concatenate(inlow_parts)
    ukeys, first, inv = np.unique(keys.ravel(), return_index=True, return_inverse=True)
    tris = inv.reshape(-1, 3).astype(np.int64)
    code = ukeys % 7 + 1
    flat = ukeys // 7
    gk, rem = np.divmod(flat, NY * NX)
    gj, gi = np.divmod(rem, NX)
    p_low = np.column_stack([lo[0] + gi * edge, lo[1] + gj * edge, lo[2] + gk * edge])
    step = np.column_stack([code & 1, (code >> 1) & 1, (code >> 2) & 1]) * edge
    p_high = p_low + step
    low_in = inlow.ravel()[first]
    f_in = np.concatenate(fin_parts).ravel()[first]
    f_out = np.concatenate(fout_parts).ravel()[first]
    a = np.where(low_in[:, None], p_low, p_high)   # inside end
    b = np.where(low_in[:, None], p_high, p_low)
    # an outside end on the box faces is outside by decree: the vertex goes halfway
    bi = np.rint((b - lo) / edge).astype(np.int64)
    on_face = (bi[:, 0] == 0) | (bi[:, 0] == nx) | (bi[:, 1] == 0) | (bi[:, 1] == ny)
    if not open_z:
        on_face |= (bi[:, 2] == 0) | (bi[:, 2] == nz)
    verts = 0.5 * (a + b)
    free = ~on_face
    if free.any():
        _, tt, _, ne = bisect(skel, a[free], b[free], tol, f_in[free], f_out[free])
        evals += ne
        tt = np.clip(tt, 1e-6, 1 - 1e-6)
        verts[free] = a[free] + tt[:, None] * (b[free] - a[free])
    info.vertices = int(verts.shape[0])
    info.triangles = int(tris.shape[0])
    info.evaluations = evals
    info.seconds = time.perf_counter() - t0
    return verts, tris, info


def surface_error(skel: Skeleton, verts: np.ndarray, tris: np.ndarray) -> tuple[float, int]:
    """Estimated largest distance of a triangle mesh to the surface.

    ``|F - 1| / |grad F|`` (first order) at every triangle centroid and edge
    midpoint.

    Returns
    -------
    error : float, mm
    evaluations : int
    """
    if tris.shape[0] == 0:
        return 0.0, 0
    P = verts[tris]                                # (m, 3, 3)
    samples = np.concatenate([P.mean(axis=1), 0.5 * (P[:, 0] + P[:, 1]), 0.5 * (P[:, 1] + P[:, 2]),
                              0.5 * (P[:, 2] + P[:, 0])])
    if samples.shape[0] == 0:
        return 0.0, 0
    f, g = evaluate(skel, samples, gradient=True)
    gn = np.sqrt((g * g).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(f - 1.0) / gn
    d = d[np.isfinite(d)]
    return (float(d.max()) if d.size else 0.0), int(samples.shape[0])


def to_manifold(verts: np.ndarray, tris: np.ndarray):
    """A :class:`manifold3d.Manifold` from an oriented closed mesh (float64).

    Raises
    ------
    RuntimeError
        manifold3d does not accept the mesh as an oriented 2-manifold.
    """
    import manifold3d

    if tris.shape[0] == 0:
        return manifold3d.Manifold()
    mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(verts, dtype=np.float64),
                             tri_verts=np.ascontiguousarray(tris, dtype=np.uint64))
    man = manifold3d.Manifold(mesh)
    status = man.status()
    if status != manifold3d.Error.NoError:
        raise RuntimeError(f"manifold3d refused the reference mesh: {status}")
    return man


def _check_edge(edge) -> float:
    return positive_number(edge, "mesh edge", GridError)


def _xy_box(skel: Skeleton, edge: float):
    lo, hi = skel.support_bounds()
    # the support box contains every point with F > 0; one more cube of margin
    # keeps the outside-by-decree faces genuinely outside
    lo = lo - edge
    hi = hi + edge
    n = np.ceil((hi - lo) / edge).astype(np.int64)
    return lo, n


def reference_mesh(skel: Skeleton, edge: float, tol: float = 1e-5, with_error: bool = True):
    """Mesh the whole surface ``F = 1``.

    Parameters
    ----------
    skel : Skeleton
    edge : float, mm
        Grid spacing; its cost grows as ``edge**-3``.
    tol : float, mm
        Vertex root tolerance.
    with_error : bool
        Estimate :attr:`MeshInfo.error_3d`.

    Returns
    -------
    manifold : manifold3d.Manifold
    info : MeshInfo
    """
    edge = _check_edge(edge)
    lo, n = _xy_box(skel, edge)
    verts, tris, info = march_box(skel, lo, edge, n, tol)
    if with_error:
        info.error_3d, ne = surface_error(skel, verts, tris)
        info.evaluations += ne
    return to_manifold(verts, tris), info


def cap_band(verts: np.ndarray, tris: np.ndarray, z_planes) -> np.ndarray:
    """Close a band of marching tetrahedra (``open_z``) with flat caps.

    The band's edges that lie in a bottom or top plane and belong to one
    triangle only are its open boundary there; they are chained into loops
    and triangulated by :func:`manifold3d.triangulate`, which follows the
    given edge directions, so the caps are oriented like the band. The cost
    grows with the loops' length, not with the area they enclose.

    Parameters
    ----------
    verts : (n, 3) float64, mm
    tris : (m, 3) int64
    z_planes : (2,) float, mm
        Heights of the band's bottom and top sample planes.

    Returns
    -------
    (m', 3) int64
        ``tris`` plus the cap triangles.
    """
    import manifold3d

    if tris.shape[0] == 0:
        return tris
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    # an edge used once (its reverse absent) is on the open boundary
    n = verts.shape[0]
    fwd = e[:, 0] * n + e[:, 1]
    rev = e[:, 1] * n + e[:, 0]
    lone = ~np.isin(fwd, rev)
    caps = [tris]
    for zp, flip in zip(z_planes, (-1.0, 1.0)):
        on = lone & (verts[e[:, 0], 2] == zp) & (verts[e[:, 1], 2] == zp)
        if not on.any():
            continue
        be = e[on]
        ids = np.unique(be)
        local = np.searchsorted(ids, be)
        nxt = np.full(ids.size, -1, np.int64)
        nxt[local[:, 1]] = local[:, 0]              # caps run against the band's edges
        try:
            loops = [ids[np.asarray(c)] for c in chain(nxt)]
        except RuntimeError:
            raise RuntimeError("reference mesh: the band's boundary is not a set of closed loops") from None
        # the top cap (flip +1) is seen from above, the bottom cap from below
        polys = [np.column_stack([verts[lp, 0], flip * verts[lp, 1]]) for lp in loops]
        t = np.asarray(manifold3d.triangulate(polys), dtype=np.int64)
        caps.append(np.concatenate(loops)[t])
    return np.concatenate(caps)


@dataclass
class Section:
    """Reference cross-section at one height."""

    z: float
    polygons: object                  # shapely.MultiPolygon
    info: MeshInfo
    rings: list = field(default_factory=list)


def reference_sections(skel: Skeleton, zs, edge: float, tol: float = 1e-5) -> list[Section]:
    """Cross-sections of the meshed surface at heights ``zs``.

    Each height gets its own mesh: the band of marching tetrahedra between
    grid planes at ``z - edge/2`` and ``z + edge/2`` (the only cubes the plane
    cuts, so its section is that of the whole-box mesh on this grid), closed
    by flat caps on those planes (:func:`cap_band`), turned into a
    :class:`manifold3d.Manifold` and cut with ``Manifold.slice(z)``.

    Parameters
    ----------
    skel : Skeleton
    zs : (k,) float64, mm
    edge : float, mm
    tol : float, mm
        Vertex root tolerance.

    Returns
    -------
    list of Section
        ``info.error_3d`` is the band's estimated distance to the surface.
    """
    out = []
    for z in np.asarray(zs, dtype=np.float64).reshape(-1):
        t0 = time.perf_counter()
        band, info = reference_band(skel, float(z), edge, tol)
        cs = band.slice(float(z))
        rings = [np.asarray(r, dtype=np.float64) for r in cs.to_polygons()]
        info.seconds = time.perf_counter() - t0
        out.append(Section(float(z), assemble(rings), info, rings))
    return out


def reference_band(skel: Skeleton, z: float, edge: float, tol: float = 1e-5):
    """The closed band of the meshed surface around height ``z`` (see :func:`reference_sections`).

    Returns
    -------
    band : manifold3d.Manifold
        Marching tetrahedra between grid planes ``z -+ edge/2``, capped there.
    info : MeshInfo
        ``error_3d`` is the band's estimated distance to the surface.
    """
    edge = _check_edge(edge)
    lo, n = _xy_box(skel, edge)
    zlo = z - 0.5 * edge
    verts, tris, info = march_box(skel, (lo[0], lo[1], zlo), edge, (n[0], n[1], 1), tol, open_z=True)
    info.error_3d, ne = surface_error(skel, verts, tris)
    info.evaluations += ne
    tris = cap_band(verts, tris, (zlo, zlo + edge))
    info.triangles = int(tris.shape[0])
    return to_manifold(verts, tris), info


__all__ = ["reference_mesh", "reference_sections", "reference_band", "march_box", "cap_band", "surface_error",
           "to_manifold", "MeshInfo", "Section"]
