"""Plain, independent geometry for the references: nothing here comes from
:mod:`slicer` except the point field evaluation (:func:`slicer.model.field.evaluate`,
itself checked against the brute-force quadrature of
:mod:`validation.reference_field`).

* :func:`bisect` -- roots of ``F = 1`` on segments, by plain bisection;
* :func:`plane_distance`, :func:`project` -- first-order distance to a layer's
  contour and a bracketed root along the in-plane gradient line;
* :func:`chain` -- a successor map split into its cycles;
* :func:`assemble` -- disjoint rings to a MultiPolygon (symmetric difference
  of their interiors, so orientation does not matter);
* :func:`dense_section` -- a layer's section sampled on a fine grid: the union
  of the inside samples' squares (its boundary is within ``step`` of the exact
  one wherever the section is wider than ``step``).

Written for clarity, not speed: the references are slow on purpose.
"""
from __future__ import annotations

import numpy as np
import shapely

from slicer.model.field import evaluate


def bisect(skel, a: np.ndarray, b: np.ndarray, tol: float, fa=None, fb=None):
    """Points where ``F = 1`` on segments from an inside ``a`` to an outside ``b``.

    Plain bisection until the bracket is at most ``tol`` long; the answer is
    its midpoint (within ``tol / 2`` of a root). Segments that do not bracket
    (``F(a) >= 1 > F(b)`` false) return the end whose ``|F - 1|`` is smaller.

    Returns
    -------
    points : (n, 3) float64, mm
    t : (n,) float64
    bracketed : (n,) bool
    evaluations : int
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    n = a.shape[0]
    ev = 0
    if fa is None:
        fa = evaluate(skel, a)[0]
        ev += n
    if fb is None:
        fb = evaluate(skel, b)[0]
        ev += n
    ok = (fa >= 1.0) & (fb < 1.0)
    lo = np.zeros(n)
    hi = np.ones(n)
    length = np.linalg.norm(b - a, axis=1)
    act = np.flatnonzero(ok & (length > tol))
    while act.size:
        mid = 0.5 * (lo[act] + hi[act])
        f = evaluate(skel, a[act] + mid[:, None] * (b[act] - a[act]))[0]
        ev += act.size
        inside = f >= 1.0
        lo[act] = np.where(inside, mid, lo[act])
        hi[act] = np.where(inside, hi[act], mid)
        act = act[(hi[act] - lo[act]) * length[act] > tol]
    t = np.where(ok, 0.5 * (lo + hi), np.where(np.abs(fa - 1.0) <= np.abs(fb - 1.0), 0.0, 1.0))
    return a + t[:, None] * (b - a), t, ok, ev


def plane_distance(skel, xy: np.ndarray, z: float):
    """``|F - 1| / |grad_xy F|`` at points of the plane ``z`` (first order), with F and grad_xy."""
    p = np.column_stack([xy, np.full(len(xy), float(z))])
    f, g = evaluate(skel, p, gradient=True)
    gxy = g[:, :2]
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
    return d, f, gxy


def project(skel, xy: np.ndarray, z: float, tol: float, reach_factor: float = 4.0, steps: int = 4):
    """A point of the contour of plane ``z`` on the in-plane gradient line through each point.

    The line ``xy + s n`` (``n`` the unit in-plane gradient) is sampled at
    ``steps`` points on each side up to ``reach_factor`` first-order distances
    (plus ``tol``); the sign change nearest to ``xy`` is bisected to ``tol``.
    ``|xy - root|`` is then an upper bound (to ``tol / 2``) of the point's
    distance to the contour.

    Returns
    -------
    roots : (n, 2) float64, mm
    ok : (n,) bool
    first_order : (n,) float64, mm
    """
    xy = np.asarray(xy, np.float64)
    n = len(xy)
    d, f, gxy = plane_distance(skel, xy, z)
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    nrm = gxy / np.where(gn > 0, gn, 1.0)[:, None]
    reach = np.where(np.isfinite(d), reach_factor * np.where(np.isfinite(d), d, 0) + tol, 0.0)
    roots = xy.copy()
    ok = np.zeros(n, bool)
    use = np.flatnonzero(reach > 0)
    if use.size == 0:
        return roots, ok, d
    s = np.linspace(-1.0, 1.0, 2 * steps + 1)
    pts = xy[use, None, :] + (s[None, :, None] * reach[use, None, None]) * nrm[use, None, :]
    fs = evaluate(skel, np.column_stack([pts.reshape(-1, 2), np.full(pts.shape[0] * pts.shape[1], float(z))]))[0]
    ins = fs.reshape(len(use), -1) >= 1.0
    change = ins[:, 1:] != ins[:, :-1]                        # (u, 2 steps)
    mid = np.abs(0.5 * (s[1:] + s[:-1]))
    score = np.where(change, mid[None, :], np.inf)
    best = np.argmin(score, axis=1)
    has = np.isfinite(score[np.arange(len(use)), best])
    u = use[has]
    k = best[has]
    pa = pts[has, k, :]
    pb = pts[has, k + 1, :]
    a_in = ins[has, k]
    A = np.where(a_in[:, None], pa, pb)
    B = np.where(a_in[:, None], pb, pa)
    zz = np.full(len(u), float(z))
    r, _, br, _ = bisect(skel, np.column_stack([A, zz]), np.column_stack([B, zz]), tol)
    roots[u[br]] = r[br, :2]
    ok[u[br]] = True
    return roots, ok, d


def chain(nxt) -> list[list[int]]:
    """Cycles of a successor map (a permutation), each from its smallest index.

    Raises
    ------
    RuntimeError
        When ``nxt`` is not a permutation.
    """
    nxt = [int(v) for v in nxt]
    seen = [False] * len(nxt)
    cycles = []
    for v0 in range(len(nxt)):
        if seen[v0]:
            continue
        cyc = []
        v = v0
        while not seen[v]:
            seen[v] = True
            cyc.append(v)
            v = nxt[v]
            if not 0 <= v < len(nxt):
                raise RuntimeError("chain: successor out of range")
        if v != v0:
            raise RuntimeError("chain: the successor map is not a permutation")
        cycles.append(cyc)
    return cycles


def assemble(rings) -> shapely.MultiPolygon:
    """Disjoint simple rings (any orientation) to a valid MultiPolygon: the
    symmetric difference of their interiors (a point is inside when an odd
    number of rings encloses it)."""
    region = shapely.Polygon()
    for r in rings:
        r = np.asarray(r, np.float64)
        if len(r) >= 3:
            region = region.symmetric_difference(shapely.make_valid(shapely.Polygon(r)))
    return _multi(region)


def _multi(geom) -> shapely.MultiPolygon:
    polys = []
    for g in shapely.get_parts(geom):
        if g.geom_type == "Polygon" and not g.is_empty:
            polys.append(shapely.geometry.polygon.orient(g, 1.0))
        elif g.geom_type == "MultiPolygon":
            polys.extend(shapely.geometry.polygon.orient(p, 1.0) for p in g.geoms)
    return shapely.MultiPolygon(polys)


def dense_section(skel, z: float, box, step: float) -> shapely.MultiPolygon:
    """The section of plane ``z`` sampled every ``step`` mm over ``box``.

    Each sample ``F >= 1`` owns the ``step`` square around it; the result is
    the union of the inside squares (row runs merged). Its boundary is within
    ``step * sqrt(2)`` of the exact boundary where the section is wider than
    ``step``; thinner parts may be missing.

    Parameters
    ----------
    box : (xmin, ymin, xmax, ymax), mm
    step : float, mm
    """
    x0, y0, x1, y1 = (float(v) for v in box)
    nx = int(np.ceil((x1 - x0) / step))
    ny = int(np.ceil((y1 - y0) / step))
    edge_x = x0 + np.arange(nx + 1) * step          # square edges: shared exactly by neighbours
    edge_y = y0 + np.arange(ny + 1) * step
    xs = 0.5 * (edge_x[1:] + edge_x[:-1])
    boxes = []
    for j0 in range(0, ny, 64):
        rows = np.arange(j0, min(j0 + 64, ny))
        yy = 0.5 * (edge_y[rows + 1] + edge_y[rows])
        X, Y = np.meshgrid(xs, yy)
        f = evaluate(skel, np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, float(z))]))[0]
        inside = (f >= 1.0).reshape(len(yy), len(xs))
        pad = np.zeros((len(yy), len(xs) + 2), np.int8)
        pad[:, 1:-1] = inside
        d = np.diff(pad, axis=1)
        for q, j in enumerate(rows):
            starts = np.flatnonzero(d[q] == 1)
            stops = np.flatnonzero(d[q] == -1)
            for a, b in zip(starts, stops):
                boxes.append(shapely.box(edge_x[a], edge_y[j], edge_x[b], edge_y[j + 1]))
    if not boxes:
        return shapely.MultiPolygon()
    return _multi(shapely.union_all(boxes))


def boundary_hausdorff(a, b, densify: float = 0.25) -> float:
    """Hausdorff distance between the boundaries of two MultiPolygons (mm),
    every segment densified into pieces of ``densify`` of its length; inf if
    only one is empty."""
    if a.is_empty and b.is_empty:
        return 0.0
    if a.is_empty or b.is_empty:
        return float("inf")
    return float(shapely.hausdorff_distance(a.boundary, b.boundary, densify=densify))


__all__ = ["bisect", "plane_distance", "project", "chain", "assemble", "dense_section", "boundary_hausdorff"]
