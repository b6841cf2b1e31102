"""Exact self-intersection test for closed triangle meshes.

Two faces of a mesh *intersect* when they share a point they are not meant to
share. For faces with no common vertex that is any point; for faces with one
common vertex, any point but that vertex; for faces with a common edge, a
point off that edge (they overlap, folded onto each other). Touching counts:
a surface that touches itself is no boundary of a solid either.

The answers are exact. Every decision is the sign of an orientation
determinant (:func:`orient3d`, :func:`orient2d` on coordinates copied
exactly), computed in float64 with a static error bound (Shewchuk's
``o3derrboundA`` / ``ccwerrboundA``) and recomputed with integers where the
bound cannot tell the sign, so coplanar and collinear configurations (flat
CAD faces) are decided correctly. The candidate pairs are those whose
bounding boxes overlap (a sweep along x, in chunks).

Reasoning used by :func:`self_intersections`
--------------------------------------------
* Non-coplanar faces intersect exactly when an edge of one meets the other
  (the ends of their common segment lie on their boundaries).
* Coplanar faces (all orientations zero) intersect exactly when, in a
  coordinate plane where the faces project one to one, an edge of one
  crosses an edge of the other or a vertex of one lies in the other.
* Faces with one common vertex ``v``, ``(v, a, b)`` and ``(v, c, d)``: beyond
  ``v`` they meet exactly when edge ``ab`` meets the other face, edge ``cd``
  meets the first, or an edge from ``v`` runs into the other face's angle at
  ``v`` within its plane.
* Faces with a common edge meet off it exactly when they are coplanar and on
  the same side of it.
"""
from __future__ import annotations

import numpy as np

#: Shewchuk's static error bounds of the float64 determinants
_O3D_BOUND = (7.0 + 56.0 * 2.0**-53) * 2.0**-53
_O2D_BOUND = (3.0 + 16.0 * 2.0**-53) * 2.0**-53
#: below this magnitude of the determinant's terms, products may have underflowed
_TINY = 2.0**-600
#: candidate pairs examined at once (memory ~ 1 KiB per pair)
CHUNK = 200_000


# ----------------------------------------------------------------------------- exact predicates
def _exact_ints(v: np.ndarray) -> tuple[list, int]:
    """Every coordinate as an exact integer multiple of ``2**-shift``."""
    m, e = np.frexp(v.ravel())
    mant = (m * 2.0**53).astype(np.int64)            # exact: |m| in [0.5, 1)
    ex = e.astype(np.int64) - 53
    shift = int(-ex[mant != 0].min()) if np.any(mant != 0) else 0
    ints = [int(a) << int(b + shift) if b + shift >= 0 else 0 for a, b in zip(mant.tolist(), ex.tolist())]
    return ints, shift


def _det3_exact(a, b, c, d) -> np.ndarray:
    """Exact sign of det[b - a, c - a, d - a] for rows of (k, 3) arrays."""
    pts = np.stack([a, b, c, d], axis=1)                 # (k, 4, 3)
    ints, _ = _exact_ints(pts)
    out = np.zeros(pts.shape[0], np.int8)
    for q in range(pts.shape[0]):
        p = ints[12 * q:12 * q + 12]
        ax, ay, az = p[0:3]
        bx, by, bz = p[3] - ax, p[4] - ay, p[5] - az
        cx, cy, cz = p[6] - ax, p[7] - ay, p[8] - az
        dx, dy, dz = p[9] - ax, p[10] - ay, p[11] - az
        det = bx * (cy * dz - cz * dy) - by * (cx * dz - cz * dx) + bz * (cx * dy - cy * dx)
        out[q] = (det > 0) - (det < 0)
    return out


def orient3d(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exact sign of the orientation of ``d`` against the plane ``a, b, c``.

    Parameters
    ----------
    a, b, c, d : (k, 3) float64

    Returns
    -------
    (k,) int8
        +1, 0 or -1: the sign of ``det[b - a, c - a, d - a]``.
    """
    ad, bd, cd = a - d, b - d, c - d
    m1 = bd[:, 1] * cd[:, 2] - bd[:, 2] * cd[:, 1]
    m2 = cd[:, 1] * ad[:, 2] - cd[:, 2] * ad[:, 1]
    m3 = ad[:, 1] * bd[:, 2] - ad[:, 2] * bd[:, 1]
    det = ad[:, 0] * m1 + bd[:, 0] * m2 + cd[:, 0] * m3
    perm = (np.abs(ad[:, 0]) * (np.abs(bd[:, 1] * cd[:, 2]) + np.abs(bd[:, 2] * cd[:, 1]))
            + np.abs(bd[:, 0]) * (np.abs(cd[:, 1] * ad[:, 2]) + np.abs(cd[:, 2] * ad[:, 1]))
            + np.abs(cd[:, 0]) * (np.abs(ad[:, 1] * bd[:, 2]) + np.abs(ad[:, 2] * bd[:, 1])))
    # det[a-d, b-d, c-d] = -det[b-a, c-a, d-a]
    sign = -np.sign(det).astype(np.int8)
    # the static bound assumes no underflow: tiny magnitudes are recomputed exactly
    unsure = (np.abs(det) <= _O3D_BOUND * perm) | (perm < _TINY)
    if unsure.any():
        sign[unsure] = _det3_exact(a[unsure], b[unsure], c[unsure], d[unsure])
    return sign


def _det2_exact(a, b, c) -> np.ndarray:
    pts = np.stack([a, b, c], axis=1)
    ints, _ = _exact_ints(pts)
    out = np.zeros(pts.shape[0], np.int8)
    for q in range(pts.shape[0]):
        p = ints[6 * q:6 * q + 6]
        det = (p[2] - p[0]) * (p[5] - p[1]) - (p[3] - p[1]) * (p[4] - p[0])
        out[q] = (det > 0) - (det < 0)
    return out


def orient2d(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a]`` for rows of (k, 2) arrays (+1: counter-clockwise)."""
    l = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
    r = (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    det = l - r
    sign = np.sign(det).astype(np.int8)
    perm = np.abs(l) + np.abs(r)
    unsure = (np.abs(det) <= _O2D_BOUND * perm) | (perm < _TINY)
    if unsure.any():
        sign[unsure] = _det2_exact(a[unsure], b[unsure], c[unsure])
    return sign


def collinear(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exactly: are the points ``a, b, c`` ((k, 3) float64) on one line (or equal)?"""
    out = np.ones(a.shape[0], bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        out &= orient2d(a[:, [i, j]], b[:, [i, j]], c[:, [i, j]]) == 0
    return out


# ----------------------------------------------------------------------------- geometric tests
def _drop_axis(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Project points onto the coordinate plane where a face with normal ``n`` is one to one."""
    ax = np.argmax(np.abs(n), axis=1)
    keep = np.array([[1, 2], [2, 0], [0, 1]])[ax]          # cyclic: keeps orientation for n[ax] > 0
    return np.take_along_axis(p, keep, axis=1)


def _seg_tri_3d(p, q, a, b, c) -> np.ndarray:
    """Does the closed segment pq meet the closed triangle abc (non-degenerate)? Exact.

    A segment lying in the triangle's plane is handled in 2-D.
    """
    sp = orient3d(a, b, c, p)
    sq = orient3d(a, b, c, q)
    hit = np.zeros(p.shape[0], bool)
    cross = (sp * sq <= 0) & ~((sp == 0) & (sq == 0))
    if cross.any():
        i = np.flatnonzero(cross)
        s1 = orient3d(p[i], q[i], a[i], b[i])
        s2 = orient3d(p[i], q[i], b[i], c[i])
        s3 = orient3d(p[i], q[i], c[i], a[i])
        hit[i] = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    flat = (sp == 0) & (sq == 0)
    if flat.any():
        i = np.flatnonzero(flat)
        n = np.cross(b[i] - a[i], c[i] - a[i])
        P, Q, A, B, C = (_drop_axis(x[i], n) for x in (p, q, a, b, c))
        hit[i] = _seg_tri_2d(P, Q, A, B, C)
    return hit


def _point_in_tri_2d(p, a, b, c) -> np.ndarray:
    s1, s2, s3 = orient2d(a, b, p), orient2d(b, c, p), orient2d(c, a, p)
    return ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))


def _seg_seg_2d(p, q, a, b) -> np.ndarray:
    """Do closed segments pq and ab meet (2-D, exact)?"""
    d1, d2 = orient2d(a, b, p), orient2d(a, b, q)
    d3, d4 = orient2d(p, q, a), orient2d(p, q, b)
    proper = (d1 * d2 <= 0) & (d3 * d4 <= 0) & ~((d1 == 0) & (d2 == 0))
    col = (d1 == 0) & (d2 == 0)                       # collinear: overlap of the projections
    if col.any():
        i = np.flatnonzero(col)
        ax = np.where(np.abs(q[i, 0] - p[i, 0]) + np.abs(b[i, 0] - a[i, 0])
                      >= np.abs(q[i, 1] - p[i, 1]) + np.abs(b[i, 1] - a[i, 1]), 0, 1)
        r = np.arange(i.size)
        lo1 = np.minimum(p[i][r, ax], q[i][r, ax])
        hi1 = np.maximum(p[i][r, ax], q[i][r, ax])
        lo2 = np.minimum(a[i][r, ax], b[i][r, ax])
        hi2 = np.maximum(a[i][r, ax], b[i][r, ax])
        proper[i] = (lo1 <= hi2) & (lo2 <= hi1)
    return proper


def _seg_tri_2d(p, q, a, b, c) -> np.ndarray:
    hit = _point_in_tri_2d(p, a, b, c) | _point_in_tri_2d(q, a, b, c)
    for u, v in ((a, b), (b, c), (c, a)):
        hit |= _seg_seg_2d(p, q, u, v)
    return hit


def _tri_tri_disjoint_vertices(A, B) -> np.ndarray:
    """Do closed triangles A[k] and B[k] ((k, 3, 3)) with no common vertex meet? Exact."""
    a0, a1, a2 = A[:, 0], A[:, 1], A[:, 2]
    b0, b1, b2 = B[:, 0], B[:, 1], B[:, 2]
    sb = np.stack([orient3d(a0, a1, a2, b0), orient3d(a0, a1, a2, b1), orient3d(a0, a1, a2, b2)], axis=1)
    sa = np.stack([orient3d(b0, b1, b2, a0), orient3d(b0, b1, b2, a1), orient3d(b0, b1, b2, a2)], axis=1)
    apart = np.all(sb > 0, axis=1) | np.all(sb < 0, axis=1) | np.all(sa > 0, axis=1) | np.all(sa < 0, axis=1)
    hit = np.zeros(A.shape[0], bool)
    coplanar = np.all(sb == 0, axis=1)
    todo = ~apart & ~coplanar
    if todo.any():
        i = np.flatnonzero(todo)
        h = np.zeros(i.size, bool)
        for p, q in ((0, 1), (1, 2), (2, 0)):
            h |= _seg_tri_3d(A[i, p], A[i, q], b0[i], b1[i], b2[i])
            h |= _seg_tri_3d(B[i, p], B[i, q], a0[i], a1[i], a2[i])
        hit[i] = h
    if coplanar.any():
        i = np.flatnonzero(coplanar)
        n = np.cross(a1[i] - a0[i], a2[i] - a0[i])
        P = [_drop_axis(A[i, k], n) for k in range(3)]
        Q = [_drop_axis(B[i, k], n) for k in range(3)]
        h = np.zeros(i.size, bool)
        for k in range(3):
            h |= _point_in_tri_2d(P[k], *Q) | _point_in_tri_2d(Q[k], *P)
            for m in range(3):
                h |= _seg_seg_2d(P[k], P[(k + 1) % 3], Q[m], Q[(m + 1) % 3])
        hit[i] = h
    return hit


def _ray_in_angle_2d(v, x, c, d) -> np.ndarray:
    """Does the direction v->x point into the closed angle c-v-d (< 180 degrees)? 2-D, exact."""
    o = orient2d(v, c, d)                      # orientation of the angle
    s1 = orient2d(v, c, x)
    s2 = orient2d(v, x, d)
    inside = (s1 * o >= 0) & (s2 * o >= 0)
    # on the line of vc or vd: also the right way along it
    on_c = (s1 == 0)
    on_d = (s2 == 0)
    same_c = np.einsum("ij,ij->i", x - v, c - v) > 0
    same_d = np.einsum("ij,ij->i", x - v, d - v) > 0
    return inside & (~on_c | same_c) & (~on_d | same_d)


def _tri_tri_one_vertex(A, B) -> np.ndarray:
    """Triangles ``(v, a, b)`` and ``(v, c, d)`` sharing vertex 0 only: do they meet beyond v?"""
    v, a, b = A[:, 0], A[:, 1], A[:, 2]
    c, d = B[:, 1], B[:, 2]
    hit = _seg_tri_3d(a, b, v, c, d) | _seg_tri_3d(c, d, v, a, b)
    # an edge from v lying in the other face's plane and running into its angle
    for x, (p, q) in ((a, (c, d)), (b, (c, d)), (c, (a, b)), (d, (a, b))):
        on = orient3d(v, p, q, x) == 0
        if on.any():
            i = np.flatnonzero(on)
            n = np.cross(p[i] - v[i], q[i] - v[i])
            V, X, P, Q = (_drop_axis(y[i], n) for y in (v, x, p, q))
            hit[i] |= _ray_in_angle_2d(V, X, P, Q)
    return hit


def _tri_tri_one_edge(u, w, a, c) -> np.ndarray:
    """Faces ``(u, w, a)`` and ``(w, u, c)`` sharing edge uw: folded onto each other?"""
    flat = orient3d(u, w, a, c) == 0
    hit = np.zeros(u.shape[0], bool)
    if flat.any():
        i = np.flatnonzero(flat)
        n = np.cross(w[i] - u[i], a[i] - u[i])
        U, W, A, C = (_drop_axis(y[i], n) for y in (u, w, a, c))
        hit[i] = orient2d(U, W, A) * orient2d(U, W, C) > 0
    return hit


# ----------------------------------------------------------------------------- candidate pairs
def _box_pairs(lo: np.ndarray, hi: np.ndarray):
    """Pairs i < j of boxes that overlap (closed), in chunks of about :data:`CHUNK`.

    A uniform grid of cells about the size of the median box: each box is
    entered in every cell it covers, pairs are formed within cells, and a
    pair is kept in the one cell holding the lowest corner of the two boxes'
    overlap (so it is reported once).
    """
    n = lo.shape[0]
    if n < 2:
        return
    ext = hi - lo
    span = hi.max(axis=0) - lo.min(axis=0)
    cell = max(float(np.median(ext.max(axis=1))), float(span.max()) / 256.0, 1e-300)
    origin = lo.min(axis=0)
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    dims = c1.max(axis=0) + 1
    size = c1 - c0 + 1
    per = size.prod(axis=1)
    box = np.repeat(np.arange(n), per)
    # the cells of each box, enumerated
    local = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    sx, sy = size[box, 0], size[box, 1]
    cx = c0[box, 0] + local % sx
    cy = c0[box, 1] + (local // sx) % sy
    cz = c0[box, 2] + local // (sx * sy)
    key = (cz * dims[1] + cy) * dims[0] + cx
    order = np.argsort(key, kind="stable")
    key, box = key[order], box[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, key.size])
    npairs = counts * (counts - 1) // 2
    g = 0
    while g < starts.size:
        csum = np.cumsum(npairs[g:])
        stop = min(starts.size, g + max(1, int(np.searchsorted(csum, CHUNK, side="right"))))
        st, ct, npr = starts[g:stop], counts[g:stop], npairs[g:stop]
        g = stop
        if npr.sum() == 0:
            continue
        # pair (a, b), a < b, of each cell's entries
        grp = np.repeat(np.arange(st.size), npr)
        r = np.arange(npr.sum()) - np.repeat(np.cumsum(npr) - npr, npr)
        c = ct[grp]
        # invert r = a (2c - a - 1) / 2 + (b - a - 1)
        a = np.floor(((2 * c - 1) - np.sqrt((2.0 * c - 1) ** 2 - 8.0 * r)) / 2).astype(np.int64)
        a = np.clip(a, 0, c - 2)
        base = a * (2 * c - a - 1) // 2
        fix = base > r
        a[fix] -= 1
        base = a * (2 * c - a - 1) // 2
        nxt = (a + 1) * (2 * c - a - 2) // 2
        up = r >= nxt
        a[up] += 1
        base = a * (2 * c - a - 1) // 2
        b = a + 1 + (r - base)
        i = box[st[grp] + a]
        j = box[st[grp] + b]
        ok = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
        i, j, kcell = i[ok], j[ok], key[st[grp[ok]]]
        corner = np.floor((np.maximum(lo[i], lo[j]) - origin) / cell).astype(np.int64)
        own = (corner[:, 2] * dims[1] + corner[:, 1]) * dims[0] + corner[:, 0] == kcell
        i, j = i[own], j[own]
        swap = i > j
        i[swap], j[swap] = j[swap], i[swap]
        yield i, j


def self_intersections(vertices: np.ndarray, faces: np.ndarray, limit: int = 10) -> tuple[int, list]:
    """Count the pairs of faces of a closed mesh that intersect improperly (exactly).

    Parameters
    ----------
    vertices : (n, 3) float64
        Finite coordinates.
    faces : (m, 3) int64
        Non-degenerate faces (distinct, non-collinear corners), each edge
        shared by exactly two faces.
    limit : int
        Face pairs returned as examples.

    Returns
    -------
    count : int
        Intersecting face pairs.
    examples : list of (int, int)
        The first ``limit`` of them (face indices, ascending).
    """
    tri = vertices[faces]                                      # (m, 3, 3)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    count = 0
    examples: list[tuple[int, int]] = []
    for i, j in _box_pairs(lo, hi):
        fi, fj = faces[i], faces[j]
        eq = fi[:, :, None] == fj[:, None, :]                   # (k, 3, 3): corner p of i is corner q of j
        shared = eq.sum(axis=(1, 2))
        hit = np.zeros(i.size, bool)
        s0 = shared == 0
        if s0.any():
            hit[s0] = _tri_tri_disjoint_vertices(tri[i[s0]], tri[j[s0]])
        s1 = np.flatnonzero(shared == 1)
        if s1.size:
            pi = np.argmax(eq[s1].any(axis=2), axis=1)          # the shared corner in face i
            pj = np.argmax(eq[s1].any(axis=1), axis=1)
            rot = (np.arange(3)[None, :] + np.stack([pi, pj])[:, :, None]) % 3    # shared corner first
            rows = np.arange(s1.size)[:, None]
            A = tri[i[s1]][rows, rot[0]]
            B = tri[j[s1]][rows, rot[1]]
            hit[s1] = _tri_tri_one_vertex(A, B)
        s2 = np.flatnonzero(shared == 2)
        if s2.size:
            # the corner of each face not on the shared edge
            ni = np.argmin(eq[s2].any(axis=2), axis=1)
            nj = np.argmin(eq[s2].any(axis=1), axis=1)
            u = tri[i[s2], (ni + 1) % 3]
            w = tri[i[s2], (ni + 2) % 3]
            hit[s2] = _tri_tri_one_edge(u, w, tri[i[s2], ni], tri[j[s2], nj])
        if shared.max(initial=0) == 3:
            hit |= shared == 3                                  # the same face twice
        if hit.any():
            count += int(hit.sum())
            pairs = np.sort(np.stack([i[hit], j[hit]], axis=1), axis=1)
            examples.extend(map(tuple, pairs[: max(0, limit - len(examples))].tolist()))
    examples.sort()
    return count, examples[:limit]


__all__ = ["orient3d", "orient2d", "collinear", "self_intersections"]
