"""Bounds of the distance from each triangle of one mesh to another mesh (docs/mesh.md).

For a triangle ``T`` and a triangle ``S``, ``p ↦ d(p, S)`` is convex (the
distance to a convex set), so over ``T`` it is largest at a corner:
``sup_{p∈T} d(p, S) = max_v d(v, S)``. Hence, for a mesh ``M``,
``sup_{p∈T} d(p, M) <= min_S max_v d(v, S)``. Where no single ``S`` gives a
bound below the target (``T`` straddles an edge of ``M``), ``T`` is cut into
four at its edges' midpoints and each quarter is bounded alone, up to
``DEPTH`` times; the quarters cover ``T`` up to the rounding of the
midpoints, which ``SLACK`` covers.

Flat regions of ``M`` (a part's faces) are triangulated anew by a
simplification, so pieces of ``T`` straddle their new edges however small
they are cut. There, the triangles of ``M`` round one of their vertices ``V``
serve together (:func:`_wedge_bound`): taken across edges at ``V``, one after
the other, while their corners are within ``ε`` of the plane ``P`` of the
first (with ``V`` at its origin; ``h`` the signed distance to ``P``, affine).
A point q of ``P`` in the projection of one of them is within ``ε`` of it
along the normal, so a point p of the piece whose projection ``p_P`` is
within D of such a q has ``d(p, M) <= √((|h(p)| + ε)² + D²)``; ``|h|`` is
largest at a corner of the piece. Two ways to bound D:

* a *wedge*: the triangles taken while their projections tile a convex
  polygon Π (an angle below π at ``V``); D is the distance from ``p_P`` to
  Π, convex, so largest at a corner of the piece;
* a *fan*: the triangles taken while the angle at ``V`` stays below 2π (a
  flat face's corner at a hole is wider than π); each triangle's cone from
  ``V`` holds the points whose D is their distance to that triangle, and the
  cone the fan leaves out, halved, holds points whose distance to the
  triangle of ``M`` across the fan's end edge (which has ``V`` as a corner)
  bounds theirs. Over the piece's part in one cone (a convex polygon) each
  of these distances is largest at a corner of that part: a corner of the
  piece, where one of its edges crosses a ray of the cone, or its point over
  ``V`` (within ``|h|`` of ``V``, a corner of all these triangles).

They are tried only for a piece that no single ``S`` bounds within the target,
round each corner of the best ``S`` and of the triangle nearest each corner of
the piece, when that triangle is at least 1/``WEDGE_REACH`` of the piece's size,
taking triangles within ``WEDGE_FLAT`` times the target of ``P``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, parallel_kernel, unrefcounted_kernel

#: most halvings of a triangle's edges
DEPTH = 6
#: triangles per task (each task owns one stamp array)
CHUNK = 256
#: relative widening of a computed distance (rounding of the corner and distance arithmetic)
SLACK = 1e-9
#: absolute widening, mm: the quarters' midpoints are rounded, so they cover a triangle up to
#: gaps of a few units in the last place of its coordinates (1e-14 mm at 100 mm)
GAP = 1e-9
#: a triangle whose corners' angle at ``a`` has a squared sine below this is treated as its edges
FLAT = 1e-24
#: most triangles a wedge grows by each way around its vertex (:func:`_wedge_bound`)
WEDGE_STEPS = 64
#: a wedge takes triangles whose corners are within this share of the target of its plane
WEDGE_FLAT = 0.5
#: wedges are tried round a triangle whose longest edge is at least the piece's over this (a fan
#: of triangles far smaller than the piece, as a lattice's mesh has, cannot hold it)
WEDGE_REACH = 4.0
#: wedges kept for the next pieces, per task (:func:`_fan_of`)
WEDGE_CACHE = 64


@inline_kernel
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@unrefcounted_kernel
def point_triangle_sq(p, a, b, c):
    """Squared distance from point ``p`` to the triangle ``a b c`` (each a 3-tuple, mm):
    the closest point by the Voronoi region of ``p`` (a corner, an edge or the face); an
    edge's distance is that to the segment, so two equal corners need no division by zero."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    if not _dot(nx, ny, nz, nx, ny, nz) > FLAT * _dot(abx, aby, abz, abx, aby, abz) * _dot(acx, acy, acz, acx, acy, acz):
        # a degenerate triangle (corners equal or in line): its three edges hold it
        return min(_edge_sq(p, a, b), _edge_sq(p, b, c), _edge_sq(p, c, a))
    apx, apy, apz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = _dot(abx, aby, abz, apx, apy, apz)
    d2 = _dot(acx, acy, acz, apx, apy, apz)
    if d1 <= 0.0 and d2 <= 0.0:
        return _dot(apx, apy, apz, apx, apy, apz)
    bpx, bpy, bpz = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = _dot(abx, aby, abz, bpx, bpy, bpz)
    d4 = _dot(acx, acy, acz, bpx, bpy, bpz)
    if d3 >= 0.0 and d4 <= d3:
        return _dot(bpx, bpy, bpz, bpx, bpy, bpz)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _edge_sq(p, a, b)
    cpx, cpy, cpz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = _dot(abx, aby, abz, cpx, cpy, cpz)
    d6 = _dot(acx, acy, acz, cpx, cpy, cpz)
    if d6 >= 0.0 and d5 <= d6:
        return _dot(cpx, cpy, cpz, cpx, cpy, cpz)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _edge_sq(p, a, c)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return _edge_sq(p, b, c)
    den = va + vb + vc
    if not den > 0.0:       # a degenerate triangle: its three edges hold it
        return min(_edge_sq(p, a, b), _edge_sq(p, b, c), _edge_sq(p, c, a))
    v = vb / den
    w = vc / den
    return _sq_to(p, a[0] + v * abx + w * acx, a[1] + v * aby + w * acy, a[2] + v * abz + w * acz)


@inline_kernel
def _sq_to(p, x, y, z):
    dx, dy, dz = p[0] - x, p[1] - y, p[2] - z
    return dx * dx + dy * dy + dz * dz


@unrefcounted_kernel
def _edge_sq(p, a, b):
    """Squared distance from ``p`` to the segment ``a b``."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ll = _dot(abx, aby, abz, abx, aby, abz)
    s = 0.0
    if ll > 0.0:
        s = min(max(_dot(abx, aby, abz, p[0] - a[0], p[1] - a[1], p[2] - a[2]) / ll, 0.0), 1.0)
    return _sq_to(p, a[0] + s * abx, a[1] + s * aby, a[2] + s * abz)


@inline_kernel
def _corner(v, f, t, k):
    i = f[t, k]
    return (v[i, 0], v[i, 1], v[i, 2])


@inline_kernel
def _cell(x, o, c, n):
    return min(max(int(math.floor((x - o) / c)), 0), n - 1)


@unrefcounted_kernel
def _piece_bound(p0, p1, p2, mesh, across, grid, target, reach, stamp, tag, wedge):
    """``min_S max_v d(v, S)`` over the triangles ``S`` of the second mesh listed in the
    grid cells the piece's box touches (inf when there are none), or a wedge's bound when
    that is smaller (:func:`_wedge_bound`, round the best ``S`` and each corner's nearest
    triangle; only while above ``target``; ``across`` None: no wedges, and none compiled;
    empty: none), and a lower bound of the largest distance from a corner to the second
    mesh. ``wedge``: the scratch of :func:`_fan_of`.

    Every triangle within ``reach`` of a corner is listed, so a corner's smallest
    distance over the listed ones is its distance to the mesh when at most ``reach``,
    and the mesh is at least ``reach`` away from it otherwise."""
    v1, f1 = mesh
    offsets, ids, origin, cell, dims = grid
    lo = (min(p0[0], p1[0], p2[0]), min(p0[1], p1[1], p2[1]), min(p0[2], p1[2], p2[2]))
    hi = (max(p0[0], p1[0], p2[0]), max(p0[1], p1[1], p2[1]), max(p0[2], p1[2], p2[2]))
    best = np.inf
    best_s = s0 = s1 = s2 = -1
    r2 = reach * reach
    n0 = n1 = n2 = r2
    for iz in range(_cell(lo[2], origin[2], cell[2], dims[2]), _cell(hi[2], origin[2], cell[2], dims[2]) + 1):
        for iy in range(_cell(lo[1], origin[1], cell[1], dims[1]), _cell(hi[1], origin[1], cell[1], dims[1]) + 1):
            for ix in range(_cell(lo[0], origin[0], cell[0], dims[0]),
                            _cell(hi[0], origin[0], cell[0], dims[0]) + 1):
                q = (iz * dims[1] + iy) * dims[0] + ix
                for e in range(offsets[q], offsets[q + 1]):
                    s = ids[e]
                    if stamp[s] == tag:
                        continue
                    stamp[s] = tag
                    a, b, c = _corner(v1, f1, s, 0), _corner(v1, f1, s, 1), _corner(v1, f1, s, 2)
                    d0 = point_triangle_sq(p0, a, b, c)
                    d1 = point_triangle_sq(p1, a, b, c)
                    d2 = point_triangle_sq(p2, a, b, c)
                    if d0 < n0:
                        n0, s0 = d0, s
                    if d1 < n1:
                        n1, s1 = d1, s
                    if d2 < n2:
                        n2, s2 = d2, s
                    far = max(d0, d1, d2)
                    if far < best:
                        best, best_s = far, s
    out = math.sqrt(best)
    if across is not None:
        if across.shape[0] > 0:
            # wedges around the best triangle and each corner's nearest one, as large as the piece
            size = _diameter(p0, p1, p2)
            seeds = (best_s, s0, s1, s2)
            for i in range(4):
                seed = seeds[i]
                if seed < 0 or out <= target:
                    break
                if _seen(seeds, i) or size > WEDGE_REACH * _diameter(
                        _corner(v1, f1, seed, 0), _corner(v1, f1, seed, 1), _corner(v1, f1, seed, 2)):
                    continue
                out = min(out, _wedge_bound(p0, p1, p2, seed, v1, f1, across, WEDGE_FLAT * target, wedge))
    return out, math.sqrt(max(n0, n1, n2))


@unrefcounted_kernel
def _turn(ax, ay, bx, by, cx, cy):
    """The turn ``(b − a) × (c − b)`` of the path a, b, c in the plane."""
    return (bx - ax) * (cy - by) - (by - ay) * (cx - bx)


@unrefcounted_kernel
def _in_plane(p, a, frame):
    """``(x, y, h)`` of point ``p``: its coordinates along the plane's axes from ``a`` and its
    signed distance ``h`` to the plane; ``frame = (e1, e2, n)``, orthonormal."""
    e1, e2, n = frame
    x, y, z = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    return _dot(x, y, z, e1[0], e1[1], e1[2]), _dot(x, y, z, e2[0], e2[1], e2[2]), _dot(x, y, z, n[0], n[1], n[2])


@unrefcounted_kernel
def _slot(f1, t, v):
    """The corner of triangle ``t`` that is vertex ``v`` (-1: none)."""
    for k in range(3):
        if f1[t, k] == v:
            return k
    return -1


@unrefcounted_kernel
def _grow(v1, f1, across, s, j, forward, origin, frame, flat, convex, link, ends):
    """Grow the wedge around vertex ``f1[s, j]`` one way (``forward``: across the edges
    leaving the vertex, appending to ``link``; else across the edges reaching it,
    prepending), while the triangle across is within ``flat`` of the plane and turns the
    polygon's way, and the angle at the vertex stays below 2π; with ``convex``, also while
    the polygon stays convex (straight at the old end corner at most) with an angle below π.

    ``link[lo..hi]`` holds the polygon's other corners in the plane, ``ends = (lo, hi,
    angle, eps, stop)`` (``eps`` the largest ``|h|`` of its corners) is returned updated, with
    ``stop`` the triangle across the last edge (-1: none, or the growth ran out of steps); the
    polygon is the vertex (the plane's origin, at (0, 0)) followed by ``link[lo..hi]``."""
    lo, hi, angle, eps, _ = ends
    v = f1[s, j]
    stop = -1
    sign = 1.0 if _turn(0.0, 0.0, link[lo, 0], link[lo, 1], link[lo + 1, 0], link[lo + 1, 1]) > 0.0 else -1.0
    t = s
    k = j
    for _ in range(WEDGE_STEPS):
        g = across[t, k if forward else (k + 2) % 3]
        stop = g
        if g < 0 or g == s:
            break
        kg = _slot(f1, g, v)
        if kg < 0:
            break
        w = f1[g, (kg + 1) % 3] if forward else f1[g, (kg + 2) % 3]      # the new corner
        x, y, h = _in_plane((v1[w, 0], v1[w, 1], v1[w, 2]), origin, frame)
        if not abs(h) <= flat:
            break
        if forward:
            px, py = link[hi, 0], link[hi, 1]
            qx, qy = link[hi - 1, 0], link[hi - 1, 1]
            ok = (sign * _turn(qx, qy, px, py, x, y) >= 0.0 and sign * _turn(px, py, x, y, 0.0, 0.0) > 0.0
                  and sign * _turn(x, y, 0.0, 0.0, link[lo, 0], link[lo, 1]) > 0.0)
            step = math.atan2(abs(px * y - py * x), px * x + py * y)
        else:
            px, py = link[lo, 0], link[lo, 1]
            qx, qy = link[lo + 1, 0], link[lo + 1, 1]
            ok = (sign * _turn(x, y, px, py, qx, qy) >= 0.0 and sign * _turn(0.0, 0.0, x, y, px, py) > 0.0
                  and sign * _turn(link[hi, 0], link[hi, 1], 0.0, 0.0, x, y) > 0.0)
            step = math.atan2(abs(x * py - y * px), px * x + py * y)
        # the new triangle turns the polygon's way at the vertex, and the wedge stays below π (2π)
        turns = sign * (px * y - py * x) > 0.0 if forward else sign * (x * py - y * px) > 0.0
        if not ((ok or not convex) and turns and angle + step < (1.0 if convex else 2.0) * math.pi * (1.0 - 1e-9)):
            break
        if forward:
            hi += 1
            link[hi, 0], link[hi, 1] = x, y
        else:
            lo -= 1
            link[lo, 0], link[lo, 1] = x, y
        angle += step
        eps = max(eps, abs(h))
        t, k = g, kg
        stop = -1
    return lo, hi, angle, eps, stop


@unrefcounted_kernel
def _polygon_corner(link, lo, i):
    """Corner ``i`` of the polygon (0, 0), ``link[lo]``, ``link[lo + 1]``, ..."""
    if i == 0:
        return 0.0, 0.0
    return link[lo + i - 1, 0], link[lo + i - 1, 1]


@unrefcounted_kernel
def _polygon_distance(x, y, link, lo, hi):
    """The distance from ``(x, y)`` to the convex polygon (0, 0), ``link[lo..hi]`` (0 inside:
    on the inner side of every edge's line, either orientation; outside, the nearest edge's)."""
    sign = 1.0 if _turn(0.0, 0.0, link[lo, 0], link[lo, 1], link[lo + 1, 0], link[lo + 1, 1]) > 0.0 else -1.0
    n = hi - lo + 2
    inside = True
    best = np.inf
    for i in range(n):
        ax, ay = _polygon_corner(link, lo, i)
        bx, by = _polygon_corner(link, lo, (i + 1) % n)
        ex, ey = bx - ax, by - ay
        if sign * (ex * (y - ay) - ey * (x - ax)) < 0.0:
            inside = False
        ll = ex * ex + ey * ey
        t = min(max(((x - ax) * ex + (y - ay) * ey) / ll, 0.0), 1.0) if ll > 0.0 else 0.0
        dx, dy = x - (ax + t * ex), y - (ay + t * ey)
        best = min(best, dx * dx + dy * dy)
    return 0.0 if inside else math.sqrt(best)


@unrefcounted_kernel
def _cone_max(pts, piece, u, w, sign, link, i, tri):
    """The largest, over the part of the piece in the cone from ray ``u`` round to ray ``w``
    (angle below π, turning by ``sign``), of its projection's distance to the triangle
    (0, link[i], link[i + 1]) in the plane, or (``i`` < 0) of its distance to the triangle
    ``tri`` in space; 0 when the part is empty. ``pts``: the piece's corners in the plane,
    ``piece``: in space.

    Both distances are convex and the part is a convex polygon, so the largest is at a corner
    of it: a corner of the piece in the cone, where an edge of the piece crosses a ray, or the
    piece's point over the origin (the vertex), which is left out: its projection is a corner of
    the fan's triangle, and it is within ``|h|`` of the vertex, a corner of ``tri``, so the
    height term of :func:`_wedge_bound` covers it."""
    ux, uy = u
    wx, wy = w
    out = 0.0
    for k in range(3):
        x, y = pts[k]
        nx, ny = pts[(k + 1) % 3]
        for c in range(3):
            t = 0.0
            if c == 0:                       # the corner itself, if in the cone
                qx, qy = x, y
                if not (sign * (ux * qy - uy * qx) >= 0.0 and sign * (qx * wy - qy * wx) >= 0.0):
                    continue
            else:                            # where the edge to the next corner crosses ray u or w
                rx, ry = (ux, uy) if c == 1 else (wx, wy)
                den = rx * (ny - y) - ry * (nx - x)
                if den == 0.0:
                    continue
                t = -(rx * y - ry * x) / den
                if not 0.0 <= t <= 1.0:
                    continue
                qx, qy = x + t * (nx - x), y + t * (ny - y)
                if qx * rx + qy * ry < 0.0:
                    continue
            if i >= 0:
                g = _polygon_distance(qx, qy, link, i, i + 1)
            else:
                a, b = piece[k], piece[(k + 1) % 3]
                q = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2]))
                g = math.sqrt(point_triangle_sq(q, tri[0], tri[1], tri[2]))
            out = max(out, g)
    return out


@unrefcounted_kernel
def _fan_reach(pts, piece, link, lo, hi, angle, sides):
    """For a fan around the origin of angle ``angle`` below 2π (its triangles (0, link[i],
    link[i + 1]), i = lo .. hi − 1, one orientation): ``(G, G_C)``, G the largest distance from
    the projection of a point of the piece in a triangle's cone to that triangle, ``G_C`` the
    largest distance from a point of the piece in the cone C the fan leaves out to the
    triangle ``sides[0]`` (in C's half next to ``link[hi]``) or ``sides[1]`` (next to
    ``link[lo]``): the mesh's triangles across the fan's end edges, or the vertex alone.

    The cones tile the plane around the origin; each point of the piece is in one of them
    (a point on a ray shared by two cones passes one cone's tests or the other's: the two
    cross products are the same number negated)."""
    sign = 1.0 if _turn(0.0, 0.0, link[lo, 0], link[lo, 1], link[lo + 1, 0], link[lo + 1, 1]) > 0.0 else -1.0
    g = 0.0
    for i in range(lo, hi):
        g = max(g, _cone_max(pts, piece, (link[i, 0], link[i, 1]), (link[i + 1, 0], link[i + 1, 1]), sign, link, i,
                             sides[0]))
    # C's bisector: link[hi] turned by half of C's angle 2π − A (each half is below π)
    hx, hy, lx, ly = link[hi, 0], link[hi, 1], link[lo, 0], link[lo, 1]
    half = 0.5 * (2.0 * math.pi - angle)
    cs, sn = math.cos(half), sign * math.sin(half)
    mx, my = cs * hx - sn * hy, sn * hx + cs * hy
    gc = max(_cone_max(pts, piece, (hx, hy), (mx, my), sign, link, -1, sides[0]),
             _cone_max(pts, piece, (mx, my), (lx, ly), sign, link, -1, sides[1]))
    return g, gc


@unrefcounted_kernel
def _side(v1, f1, t, vertex):
    """Triangle ``t``'s corners, or (``t`` < 0) the vertex three times."""
    if t < 0:
        return vertex, vertex, vertex
    return _corner(v1, f1, t, 0), _corner(v1, f1, t, 1), _corner(v1, f1, t, 2)


@unrefcounted_kernel
def _fan_of(v1, f1, across, s, j, convex, origin, frame, flat, first, wedge):
    """The wedge (``convex``) or fan round corner ``j`` of triangle ``s`` (:func:`_grow`, both
    ways), its corners in ``link``: ``(lo, hi, angle, eps, ahead, behind)``, ``ahead`` and
    ``behind`` the triangles where it stopped growing. ``first = (xa, ya, xb, yb, eps)``: the
    corners of ``s`` after the vertex in the plane, and their largest ``|h|``.

    ``wedge = (link, links, keys)``: a fan depends on ``(s, j, convex)`` alone (the mesh and
    ``flat`` are the call's), so the last ones are kept in ``links`` (one slot per key's hash,
    ``keys`` holding each slot's key and results) for the pieces that share them."""
    link, links, keys = wedge
    code = 2 * j + (1 if convex else 0)
    slot = (6 * s + code) % keys.shape[0]
    if keys[slot, 0] == s and keys[slot, 1] == code:
        lo, hi = int(keys[slot, 2]), int(keys[slot, 3])
        for i in range(lo, hi + 1):
            link[i, 0], link[i, 1] = links[slot, i, 0], links[slot, i, 1]
        return lo, hi, keys[slot, 4], keys[slot, 5], int(keys[slot, 6]), int(keys[slot, 7])
    xa, ya, xb, yb, eps = first
    mid = WEDGE_STEPS + 1
    link[mid, 0], link[mid, 1] = xb, yb
    link[mid + 1, 0], link[mid + 1, 1] = xa, ya
    ang = math.atan2(abs(xb * ya - yb * xa), xb * xa + yb * ya)
    lo, hi, angle, eps, ahead = _grow(v1, f1, across, s, j, True, origin, frame, flat, convex, link,
                                      (mid, mid + 1, ang, eps, -1))
    lo, hi, angle, eps, behind = _grow(v1, f1, across, s, j, False, origin, frame, flat, convex, link,
                                       (lo, hi, angle, eps, -1))
    for i in range(lo, hi + 1):
        links[slot, i, 0], links[slot, i, 1] = link[i, 0], link[i, 1]
    keys[slot, 0], keys[slot, 1], keys[slot, 2], keys[slot, 3] = s, code, lo, hi
    keys[slot, 4], keys[slot, 5], keys[slot, 6], keys[slot, 7] = angle, eps, ahead, behind
    return lo, hi, angle, eps, ahead, behind


@unrefcounted_kernel
def _wedge_bound(p0, p1, p2, s, v1, f1, across, flat, wedge):
    """A bound of the distance from the piece ``p0 p1 p2`` to the second mesh by a wedge around a
    corner of the second mesh's triangle ``s`` (module docstring; inf when ``s`` is degenerate).

    For each corner V of ``s``: the plane of ``s`` with V at its origin; a wedge and a fan
    grow round V (:func:`_fan_of`) through triangles within ``flat`` of the plane; the wedge's
    bound is ``√((max |h| + ε)² + D²)`` with ``max |h|`` over the piece's corners and D the
    largest distance from their projections to its convex polygon (both convex over the
    piece: largest at a corner), the fan's is bounded cone by cone (:func:`_fan_reach`)."""
    link = wedge[0]
    a, b, c = _corner(v1, f1, s, 0), _corner(v1, f1, s, 1), _corner(v1, f1, s, 2)
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    nn = math.sqrt(_dot(nx, ny, nz, nx, ny, nz))
    lab = math.sqrt(_dot(abx, aby, abz, abx, aby, abz))
    if not (nn > 0.0 and lab > 0.0):
        return np.inf
    n = (nx / nn, ny / nn, nz / nn)
    e1 = (abx / lab, aby / lab, abz / lab)
    e2 = (n[1] * e1[2] - n[2] * e1[1], n[2] * e1[0] - n[0] * e1[2], n[0] * e1[1] - n[1] * e1[0])
    frame = (e1, e2, n)
    best = np.inf
    for j in range(3):
        origin = _corner(v1, f1, s, j)
        # s itself: (V, next, after), its link ordered after, next (see _grow)
        xa, ya, ha = _in_plane(_corner(v1, f1, s, (j + 1) % 3), origin, frame)
        xb, yb, hb = _in_plane(_corner(v1, f1, s, (j + 2) % 3), origin, frame)
        if _turn(0.0, 0.0, xb, yb, xa, ya) == 0.0:
            continue
        first = (xa, ya, xb, yb, max(abs(ha), abs(hb)))
        x0, y0, h0 = _in_plane(p0, origin, frame)
        x1, y1, h1 = _in_plane(p1, origin, frame)
        x2, y2, h2 = _in_plane(p2, origin, frame)
        top = max(abs(h0), abs(h1), abs(h2))
        for convex in (True, False):
            lo, hi, angle, eps, ahead, behind = _fan_of(v1, f1, across, s, j, convex, origin, frame, flat, first,
                                                        wedge)
            if convex:
                off = max(_polygon_distance(x0, y0, link, lo, hi), _polygon_distance(x1, y1, link, lo, hi),
                          _polygon_distance(x2, y2, link, lo, hi))
                best = min(best, math.sqrt((top + eps) ** 2 + off * off))
            else:
                # any fan (a flat face's corner at a hole is wider than π): cone by cone; in the
                # cone it leaves out, the mesh's triangles across its end edges (or the vertex)
                sides = (_side(v1, f1, ahead, origin), _side(v1, f1, behind, origin))
                g, gc = _fan_reach(((x0, y0), (x1, y1), (x2, y2)), (p0, p1, p2), link, lo, hi, angle, sides)
                best = min(best, max(math.sqrt((top + eps) ** 2 + g * g), gc))
    return best


@unrefcounted_kernel
def _seen(seeds, i):
    """Whether ``seeds[i]`` is one of ``seeds[:i]``."""
    for k in range(i):
        if seeds[k] == seeds[i]:
            return True
    return False


@unrefcounted_kernel
def _diameter(a, b, c):
    """The longest edge of the triangle ``a b c``, mm."""
    return math.sqrt(max(_sq_to(a, b[0], b[1], b[2]), _sq_to(b, c[0], c[1], c[2]), _sq_to(c, a[0], a[1], a[2])))


@inline_kernel
def _mid(a, b):
    return (0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2]))


@unrefcounted_kernel
def _triangle_bound(p0, p1, p2, mesh, across, grid, target, reach, stamp, tag, scratch):
    """The bound of one triangle: its own, or the largest of its quarters' (recursively,
    while above ``target`` and a corner's own distance does not already exceed it, at
    most ``DEPTH`` deep); ``mesh = (v1, f1)``; ``across`` as :func:`_piece_bound`'s;
    ``scratch = (stack, wedge)``: ``stack`` holds pieces (9 coordinates and a depth per row),
    ``wedge`` a wedge's polygon and the last ones (:func:`_fan_of`); ``tag`` is advanced per
    piece and returned."""
    stack, wedge = scratch
    out = 0.0
    stack[0, 0], stack[0, 1], stack[0, 2] = p0
    stack[0, 3], stack[0, 4], stack[0, 5] = p1
    stack[0, 6], stack[0, 7], stack[0, 8] = p2
    stack[0, 9] = 0.0
    sp = 1
    while sp > 0:
        sp -= 1
        a = (stack[sp, 0], stack[sp, 1], stack[sp, 2])
        b = (stack[sp, 3], stack[sp, 4], stack[sp, 5])
        c = (stack[sp, 6], stack[sp, 7], stack[sp, 8])
        depth = stack[sp, 9]
        tag += 1
        d, corner = _piece_bound(a, b, c, mesh, across, grid, target, reach, stamp, tag, wedge)
        if d <= target or depth >= DEPTH or corner > target:
            out = max(out, d)
            continue
        ab, bc, ca = _mid(a, b), _mid(b, c), _mid(c, a)
        for q in range(4):
            if q == 0:
                x, y, z = a, ab, ca
            elif q == 1:
                x, y, z = ab, b, bc
            elif q == 2:
                x, y, z = ca, bc, c
            else:
                x, y, z = ab, bc, ca
            stack[sp, 0], stack[sp, 1], stack[sp, 2] = x
            stack[sp, 3], stack[sp, 4], stack[sp, 5] = y
            stack[sp, 6], stack[sp, 7], stack[sp, 8] = z
            stack[sp, 9] = depth + 1.0
            sp += 1
    return out, tag


@parallel_kernel
def distance_bounds(v0, f0, v1, f1, across, offsets, ids, origin, cell, dims, target, reach):
    """For each triangle of the first mesh, a bound of the largest distance from its
    points to the second mesh.

    Parameters
    ----------
    v0 : (n0, 3) float64, mm
    f0 : (t0, 3) int64
        The first mesh.
    v1 : (n1, 3) float64, mm
    f1 : (t1, 3) int64
        The second mesh.
    across : (t1, 3) int64, or None
        The second mesh's triangle across each edge (edge k runs from corner k to
        corner k + 1; -1: none), for wedges (:func:`_wedge_bound`); None: no wedges
        (and their code is not compiled); (0, 3): no wedges.
    offsets, ids, origin, cell, dims
        The second mesh's triangles binned by their boxes widened by the search
        reach (:func:`slicer._kernels.field.binning.bin_boxes`): a triangle of
        the second mesh closer than the reach to a piece is in a cell the
        piece's box touches.
    target : float, mm
        Pieces are split while their bound is above it (and no corner of theirs is
        farther than it from the second mesh: splitting could not bring them below).
    reach : float, mm
        The widening of the binned boxes.

    Returns
    -------
    (t0,) float64, mm
        ``sup_{p∈T} d(p, M1)`` is at most this, for each triangle T of the first
        mesh (inf: no triangle of the second mesh within the reach).
    """
    t0 = f0.shape[0]
    out = np.empty(t0)
    grid = (offsets, ids, origin, cell, dims)
    for ch in prange((t0 + CHUNK - 1) // CHUNK):
        stamp = np.full(f1.shape[0], -1, np.int64)
        keys = np.full((WEDGE_CACHE, 8), -1.0)
        wedge = (np.empty((2 * WEDGE_STEPS + 3, 2)), np.empty((WEDGE_CACHE, 2 * WEDGE_STEPS + 3, 2)), keys)
        scratch = (np.empty((3 * DEPTH + 2, 10)), wedge)
        tag = np.int64(0)
        for t in range(ch * CHUNK, min(t0, (ch + 1) * CHUNK)):
            d, tag = _triangle_bound(_corner(v0, f0, t, 0), _corner(v0, f0, t, 1), _corner(v0, f0, t, 2),
                                     (v1, f1), across, grid, target, reach, stamp, tag, scratch)
            out[t] = d * (1.0 + SLACK) + GAP
    return out
