"""Layer contours: the inside region of each layer as polygons with holes.

Marching squares runs on the layer raster, whose pixel centres the tracer
classified exactly (``F >= 1``). Every boundary edge, between an inside and an
outside pixel centre, gets its vertex by a bracketed root solve of
``F(x, y, z_k) = 1`` along that edge, to ``tol`` mm (Illinois steps with a
bisection safeguard, all edges of a layer per batch of compiled field
evaluations). Chords between neighbouring vertices are then subdivided, with
the new vertices put on the surface too, until each chord's midpoint and
quarter points are within ``tol / 2`` of the surface (in the layer plane), so
the contour error is set by ``tol``, not by the pixel size.

Conventions: coordinates in mm, seen from above (+z); outer rings are
counter-clockwise, holes clockwise. Pixels outside the grid count as
outside; where the solid reaches the grid's border, the contour follows the
border of the grid's box (half a pixel beyond the last centres).

Examples
--------
>>> from slicer import Skeleton
>>> from slicer.slicing import slice_skeleton
>>> s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
>>> r = slice_skeleton(s, 0.1)
>>> mp = layer_contours(s, r, r.grid.layers // 2)
>>> round(mp.area, 2), mp.is_valid           # a disc of radius 1
(3.14, True)
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from ._kernels.launch import serial
from .atomic import AtomicFile, check_destination
from .checks import positive_number
from .errors import GridError
from .field import evaluate
from .mesh_slicing import Sections
from .part_slicing import PartResult, PartStreamedResult
from .parts import ROLES
from .skeleton import Skeleton
from .slicing import SliceResult

#: iterations of the bracketed solver before it gives up (bisection halves
#: the bracket at least every other step, so 200 is far beyond need)
MAX_ITER = 200

# Cell corners TL, TR, BR, BL (bits 1, 2, 4, 8) and edges T, R, B, L (0..3),
# seen from above with +y up. Walking the corners counter-clockwise,
# TL -> BL -> BR -> TR -> TL, crosses the edges L, B, R, T in turn.
_CCW_CORNERS = (0, 3, 2, 1)         # TL, BL, BR, TR
_CCW_EDGES = (3, 2, 1, 0)           # edge from _CCW_CORNERS[q] to _CCW_CORNERS[q + 1]


def _case_table():
    """Oriented segments (from edge, to edge) per marching-squares case.

    A segment runs from an edge where the counter-clockwise walk leaves the
    inside to an edge where it enters it, so the inside is on its left: outer
    boundaries come out counter-clockwise, holes clockwise. In the two saddle
    cases the pairing depends on the cell centre: ``joined`` (centre inside)
    pairs each exit with the next entry, ``separate`` with the previous one.

    Returns
    -------
    (16, 2, 2, 2) int64
        ``table[case, saddle_joined, s] = (from, to)``; unused slots are -1.
    """
    table = -np.ones((16, 2, 2, 2), np.int64)
    for case in range(16):
        inside = [(case >> c) & 1 for c in _CCW_CORNERS]
        exits, entries = [], []
        for q in range(4):
            a, b = inside[q], inside[(q + 1) % 4]
            if a and not b:
                exits.append(q)
            elif b and not a:
                entries.append(q)
        for joined in (0, 1):
            for s, q in enumerate(exits):
                later = [e for e in entries if e > q] + [e for e in entries if e < q]
                partner = later[0] if (joined or len(entries) == 1) else later[-1]
                table[case, joined, s] = (_CCW_EDGES[q], _CCW_EDGES[partner])
    return table


_TABLE = _case_table()


#: chords are split until their midpoint is within this fraction of ``tol``
#: of the contour (first-order estimate); the largest deviation along a chord
#: can exceed the midpoint's when the curvature varies, so keep a margin
CHORD_FRACTION = 0.5

#: batches smaller than this are evaluated on one thread: waking the pool
#: costs more than it saves, and on a loaded machine a parallel launch can
#: wait a whole scheduler time slice for its second thread
SERIAL_BATCH = 4096


def _field(skel: Skeleton, points: np.ndarray, gradient: bool = False):
    """:func:`slicer.field.evaluate`, serial for small batches (same values)."""
    if points.shape[0] >= SERIAL_BATCH:
        return evaluate(skel, points, gradient)
    with serial():
        return evaluate(skel, points, gradient)


def _check_tol(tol) -> float:
    return positive_number(tol, "contour tolerance", GridError)


def solve_crossings(skel: Skeleton, a: np.ndarray, b: np.ndarray, tol: float,
                    fa: np.ndarray | None = None, fb: np.ndarray | None = None):
    """Points where ``F = 1`` on segments ``a -> b``, to ``tol`` mm.

    Each segment must bracket the surface: ``F(a) >= 1 > F(b)``. The bracket
    ``[lo, hi]`` is narrowed by Illinois (modified regula falsi) steps, kept
    ``tol/2`` inside the bracket, with a bisection step whenever two steps
    fail to halve it, until it is at most ``tol`` long; the answer is the
    secant point of the final bracket, so it is within ``tol`` of a root.
    Every iteration evaluates the field at all unfinished segments in one
    compiled batch.

    Parameters
    ----------
    skel : Skeleton
    a, b : (n, 3) float64, mm
        Inside and outside ends.
    tol : float, mm
    fa, fb : (n,) float64, optional
        Field at ``a`` and ``b`` if already known.

    Returns
    -------
    points : (n, 3) float64, mm
    t : (n,) float64
        Position along each segment, in [0, 1].
    bracketed : (n,) bool
        False where ``F(a) >= 1 > F(b)`` does not hold; such a segment gets
        the end whose field is closer to 1.
    evaluations : int
        Field evaluations spent.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    n = a.shape[0]
    evals = 0
    if fa is None:
        fa = _field(skel, a)[0]
        evals += n
    if fb is None:
        fb = _field(skel, b)[0]
        evals += n
    d = b - a
    length = np.sqrt((d * d).sum(axis=1))
    glo = fa - 1.0
    ghi = fb - 1.0
    bracketed = (glo >= 0.0) & (ghi < 0.0)
    lo = np.zeros(n)
    hi = np.ones(n)
    t = np.where(np.abs(glo) <= np.abs(ghi), 0.0, 1.0)
    side = np.zeros(n, np.int8)          # last end moved: +1 lo, -1 hi
    with np.errstate(divide="ignore"):
        tol_t = np.where(length > 0, tol / length, 1.0)
    width1 = hi - lo                      # bracket width one and two steps ago
    width2 = hi - lo
    act = np.flatnonzero(bracketed & (length > tol))
    t[bracketed] = np.where(glo[bracketed] == 0.0, 0.0, 0.5)
    it = 0
    while act.size and it < MAX_ITER:
        it += 1
        l, h, gl, gh = lo[act], hi[act], glo[act], ghi[act]
        w = h - l
        q = 0.5 * tol_t[act]
        ts = l + w * gl / (gl - gh)             # gl >= 0 > gh: a point in [l, h]
        # stay tol/2 inside the bracket: near the root, the next step then
        # lands on the other side and closes the bracket to ~tol
        ts = np.minimum(np.maximum(ts, l + q), h - q)
        bis = (w > 0.5 * width2[act]) & (it > 2) | ~(ts > l) | ~(ts < h)
        tm = np.where(bis, 0.5 * (l + h), ts)
        width2[act] = width1[act]
        width1[act] = w
        f = _field(skel, a[act] + tm[:, None] * d[act])[0]
        evals += act.size
        g = f - 1.0
        up = g >= 0.0                           # root above tm
        sd = side[act]
        # Illinois: halve the stale end's value when the same end moves twice
        gh_new = np.where(up & (sd == 1), 0.5 * gh, gh)
        gl_new = np.where(~up & (sd == -1), 0.5 * gl, gl)
        lo[act] = np.where(up, tm, l)
        glo[act] = np.where(up, g, gl_new)
        hi[act] = np.where(up, h, tm)
        ghi[act] = np.where(up, gh_new, g)
        side[act] = np.where(up, 1, -1)
        exact = g == 0.0
        t[act] = tm
        done = exact | ((hi[act] - lo[act]) * length[act] <= tol)
        fin = act[done & ~exact]
        if fin.size:
            gl, gh = glo[fin], ghi[fin]
            # secant point of the final bracket (Illinois-scaled values are
            # still of the right signs, so it stays inside the bracket)
            ts = lo[fin] + (hi[fin] - lo[fin]) * gl / (gl - gh)
            t[fin] = np.clip(ts, lo[fin], hi[fin])
        act = act[~done]
    if act.size:   # pragma: no cover - the bisection safeguard makes this unreachable
        t[act] = 0.5 * (lo[act] + hi[act])
    return a + t[:, None] * d, t, bracketed, evals


def layer_mask(result: SliceResult, k: int) -> np.ndarray:
    """Layer ``k`` of a result as a (height, width) bool image (True inside)."""
    g = result.grid
    k = int(k)
    if not 0 <= k < g.layers:
        raise GridError(f"layer {k} is out of range (the stack has {g.layers} layers)")
    sel = (result.k0 <= k) & (k < result.k1)
    img = np.zeros(g.width * g.height, bool)
    img[result.pix[sel]] = True
    return img.reshape(g.height, g.width)


def mask_rings(skel: Skeleton, mask: np.ndarray, origin, pixel_size, z: float, tol: float = 1e-3,
               refine: bool = True, stats: dict | None = None, values: np.ndarray | None = None
               ) -> list[np.ndarray]:
    """Closed rings of the inside region of one exactly classified raster.

    Parameters
    ----------
    skel : Skeleton
    mask : (H, W) bool
        True where the pixel centre is inside (``F >= 1``).
    origin : (2,) float64, mm
        Centre of pixel (row 0, column 0); rows run toward -y.
    pixel_size : (2,) float64, mm
    z : float, mm
        Height of the layer.
    tol : float, mm
        Root tolerance along pixel edges, and chord tolerance if ``refine``.
    refine : bool
        Subdivide chords until their midpoints and quarter points are within
        ``tol / 2`` of the surface.
    stats : dict, optional
        Updated with ``evaluations``, ``vertices``, ``unbracketed``, ``refined``,
        ``unrefined_rings`` (rings whose refinement was undone to keep them
        simple and disjoint).
    values : (H, W) float64, optional
        The field at the pixel centres. Given, vertices are placed by linear
        interpolation of ``F - 1`` along the edges and saddles by the mean of
        the four corners, with no field evaluation: the classic dense-grid
        marching squares (a baseline, not the default).

    Returns
    -------
    list of (n_q, 2) float64
        Ring vertices, not repeated at the end; outer rings counter-clockwise,
        holes clockwise.
    """
    from ._kernels.contours import chain_rings

    mask = np.asarray(mask, bool)
    H, W = mask.shape
    x0, y0 = float(origin[0]), float(origin[1])
    px, py = float(pixel_size[0]), float(pixel_size[1])
    st = {"evaluations": 0, "vertices": 0, "unbracketed": 0, "refined": 0, "unrefined_rings": 0}
    if not mask.any():
        if stats is not None:
            for key, v in st.items():
                stats[key] = stats.get(key, 0) + v
        return []
    P = np.zeros((H + 2, W + 2), bool)
    P[1:-1, 1:-1] = mask
    # boundary edges: horizontal hx[j, i] joins (j, i)-(j, i+1); vertical vy[j, i] joins (j, i)-(j+1, i)
    hx = P[:, :-1] != P[:, 1:]                 # (H+2, W+1)
    vy = P[:-1, :] != P[1:, :]                 # (H+1, W+2)
    nh = hx.size
    hj, hi_ = np.nonzero(hx)
    vj, vi = np.nonzero(vy)
    # inside / outside ends of each boundary edge, padded indices
    h_in_left = P[hj, hi_]
    v_in_top = P[vj, vi]
    ej_in = np.concatenate([hj, np.where(v_in_top, vj, vj + 1)])
    ei_in = np.concatenate([np.where(h_in_left, hi_, hi_ + 1), vi])
    ej_out = np.concatenate([hj, np.where(v_in_top, vj + 1, vj)])
    ei_out = np.concatenate([np.where(h_in_left, hi_ + 1, hi_), vi])

    def world(jp, ip):
        return np.stack([x0 + (ip - 1) * px, y0 - (jp - 1) * py, np.full(jp.shape, float(z))], axis=1)

    a = world(ej_in, ei_in)
    b = world(ej_out, ei_out)
    # an edge to a pixel beyond the grid ends at the grid's box, half a pixel out
    border = (ej_out == 0) | (ei_out == 0) | (ej_out == H + 1) | (ei_out == W + 1)
    verts = np.empty((a.shape[0], 3))
    verts[border] = 0.5 * (a[border] + b[border])
    inner = ~border
    if values is not None and inner.any():
        V = np.zeros((H + 2, W + 2))
        V[1:-1, 1:-1] = values
        fa = V[ej_in, ei_in][inner]
        fb = V[ej_out, ei_out][inner]
        tt = np.clip((fa - 1.0) / (fa - fb), 1e-6, 1.0 - 1e-6)
        verts[inner] = a[inner] + tt[:, None] * (b[inner] - a[inner])
    elif inner.any():
        pts, tt, ok, ne = solve_crossings(skel, a[inner], b[inner], tol)
        # keep vertices off the pixel centres so that rings stay simple
        eps = 1e-6
        tt = np.clip(tt, eps, 1.0 - eps)
        verts[inner] = a[inner] + tt[:, None] * (b[inner] - a[inner])
        st["evaluations"] += ne
        st["unbracketed"] += int((~ok).sum())
    # compact vertex index of every boundary edge id
    edge_id = np.concatenate([hj * (W + 1) + hi_, nh + vj * (W + 2) + vi])
    lookup = np.full(nh + vy.size, -1, np.int64)
    lookup[edge_id] = np.arange(edge_id.size)
    # marching-squares cells (H+1, W+1) with corners TL, TR, BR, BL
    case = (P[:-1, :-1].astype(np.int64) | (P[:-1, 1:] << 1) | (P[1:, 1:] << 2) | (P[1:, :-1] << 3))
    cj, ci = np.nonzero((case != 0) & (case != 15))
    cc = case[cj, ci]
    joined = np.zeros(cc.shape, np.int64)
    sad = np.flatnonzero((cc == 5) | (cc == 10))
    if sad.size and values is not None:
        V = np.zeros((H + 2, W + 2))
        V[1:-1, 1:-1] = values
        mean = 0.25 * (V[cj[sad], ci[sad]] + V[cj[sad], ci[sad] + 1] + V[cj[sad] + 1, ci[sad]]
                       + V[cj[sad] + 1, ci[sad] + 1])
        joined[sad] = (mean >= 1.0).astype(np.int64)
    elif sad.size:
        cen = np.stack([x0 + (ci[sad] - 0.5) * px, y0 - (cj[sad] - 0.5) * py,
                        np.full(sad.size, float(z))], axis=1)
        joined[sad] = (_field(skel, cen)[0] >= 1.0).astype(np.int64)
        st["evaluations"] += sad.size
    # edge ids of the four cell edges T, R, B, L
    cell_edges = np.stack([cj * (W + 1) + ci, nh + cj * (W + 2) + ci + 1,
                           (cj + 1) * (W + 1) + ci, nh + cj * (W + 2) + ci], axis=1)
    seg = _TABLE[cc, joined]                   # (c, 2, 2)
    use = seg[:, :, 0] >= 0
    rows = np.nonzero(use)
    f_edge = cell_edges[rows[0], seg[rows[0], rows[1], 0]]
    t_edge = cell_edges[rows[0], seg[rows[0], rows[1], 1]]
    nxt = np.full(edge_id.size, -1, np.int64)
    nxt[lookup[f_edge]] = lookup[t_edge]
    order, starts, status = chain_rings(nxt)
    if status != 0:   # pragma: no cover - a marching-squares invariant
        raise RuntimeError("contour chaining failed: segments do not form closed rings")
    xy = verts[:, :2]
    rings = [xy[order[starts[q]:starts[q + 1]]] for q in range(starts.size - 1)]
    st["vertices"] += int(edge_id.size)
    if refine:
        rings = _keep_simple(refine_rings(skel, rings, float(z), tol, st), rings, st)
    if stats is not None:
        for key, v in st.items():
            stats[key] = stats.get(key, 0) + v
    return rings


def plane_distance(skel: Skeleton, xy: np.ndarray, z: float):
    """First-order distance of points to the contour of layer ``z``, in its plane.

    Parameters
    ----------
    skel : Skeleton
    xy : (n, 2) float64, mm
    z : float, mm

    Returns
    -------
    dist : (n,) float64, mm
        ``|F - 1| / |grad_xy F|`` (inf where the in-plane gradient vanishes).
    f : (n,) float64
    gxy : (n, 2) float64, 1/mm
    """
    p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
    f, g = _field(skel, p, gradient=True)
    gxy = g[:, :2]
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
    return dist, f, gxy


def project_to_contour(skel: Skeleton, xy: np.ndarray, z: float, tol: float, reach=None):
    """Points of the contour of layer ``z`` on the in-plane gradient line through each point.

    The root of ``F = 1`` is bracketed on the segment ``xy +- r n`` (``n`` the
    unit in-plane gradient, ``r`` three first-order distances plus ``tol``, or
    ``reach``) and solved to ``tol``. ``|xy - root|`` is then an upper bound (to
    ``tol``) of the in-plane distance of ``xy`` to the contour.

    Parameters
    ----------
    skel : Skeleton
    xy : (n, 2) float64, mm
    z : float, mm
    tol : float, mm
    reach : (n,) float64, optional, mm
        Upper limit of the half-length of each search segment.

    Returns
    -------
    roots : (n, 2) float64, mm
        ``xy`` itself where no root was bracketed.
    ok : (n,) bool
    first_order : (n,) float64, mm
        :func:`plane_distance` of the points.
    evaluations : int
    """
    n = xy.shape[0]
    dist, f, gxy = plane_distance(skel, xy, z)
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    usable = np.isfinite(dist)
    r = np.where(usable, 3.0 * np.where(usable, dist, 0.0) + tol, 0.0)
    if reach is not None:
        r = np.minimum(r, reach)
    nrm = gxy / np.where(gn > 0, gn, 1.0)[:, None]          # toward growing F: inward
    zz = np.full(n, float(z))
    A = np.column_stack([xy + r[:, None] * nrm, zz])
    B = np.column_stack([xy - r[:, None] * nrm, zz])
    roots = xy.copy()
    ok = np.zeros(n, bool)
    evals = n
    idx = np.flatnonzero(usable & (r > 0))
    if idx.size:
        pts, _, br, ne = solve_crossings(skel, A[idx], B[idx], tol)
        evals += ne
        roots[idx[br]] = pts[br, :2]
        ok[idx[br]] = True
    return roots, ok, dist, evals


def refine_rings(skel: Skeleton, rings: list[np.ndarray], z: float, tol: float,
                 stats: dict | None = None, max_rounds: int = 8) -> list[np.ndarray]:
    """Subdivide chords that stray more than ``tol / 2`` from the surface.

    The distance of a chord's quarter points and midpoint to the contour is
    estimated in the layer plane (:func:`plane_distance`). A chord above ``tol`` is split
    into about ``sqrt(dist / tol)`` pieces whose new vertices are put on the
    contour (:func:`project_to_contour`, at most a quarter of the chord away,
    so rings stay simple); a point whose root cannot be bracketed is dropped.

    Parameters
    ----------
    skel : Skeleton
    rings : list of (n_q, 2) float64, mm
    z : float, mm
    tol : float, mm
    stats : dict, optional
        ``refined`` and ``evaluations`` are increased.
    max_rounds : int
        Rounds of splitting (each re-checks the new chords' midpoints).

    Returns
    -------
    list of (n_q', 2) float64
    """
    if not rings:
        return rings
    sizes = np.array([r.shape[0] for r in rings])
    xy = np.concatenate(rings)
    ring_of = np.repeat(np.arange(len(rings)), sizes)
    added = 0
    evals = 0
    for _ in range(max_rounds):
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        nxt = np.arange(xy.shape[0]) + 1
        nxt[starts + sizes - 1] = starts
        p, q = xy, xy[nxt]
        chord = np.hypot(*(q - p).T)
        # quarter points too: on a chord across varying curvature the largest
        # deviation need not be at the midpoint
        fr = np.array([0.25, 0.5, 0.75])[None, :, None]
        m3 = (p[:, None, :] + fr * (q - p)[:, None, :]).reshape(-1, 2)
        dist, _, _ = plane_distance(skel, m3, z)
        dist = dist.reshape(-1, 3).max(axis=1)
        evals += m3.shape[0]
        bad = np.flatnonzero(~(dist <= CHORD_FRACTION * tol) & (chord > 2 * tol))
        if bad.size == 0:
            break
        # a chord's sagitta shrinks as its length squared: split it into
        # about sqrt(dist / tol) pieces at once (fewer rounds, fewer launches)
        with np.errstate(invalid="ignore"):
            goal = CHORD_FRACTION * tol
            nsub = np.clip(np.ceil(1.2 * np.sqrt(np.where(np.isfinite(dist[bad]), dist[bad], 4 * goal) / goal)),
                           2, 64).astype(np.int64)
        owner = np.repeat(bad, nsub - 1)
        j = np.arange(owner.size) - np.repeat(np.cumsum(nsub - 1) - (nsub - 1), nsub - 1) + 1
        frac = j / np.repeat(nsub, nsub - 1)
        cand = p[owner] + frac[:, None] * (q[owner] - p[owner])
        roots, ok, _, ne = project_to_contour(skel, cand, z, tol, reach=0.25 * chord[owner])
        evals += ne
        if not ok.any():
            break
        ins = owner[ok]
        # insert the new vertices after vertex ``ins``, in order along the chord
        pos = np.concatenate([np.arange(xy.shape[0]), ins])
        sub = np.concatenate([np.zeros(xy.shape[0], np.int64), j[ok]])
        order = np.lexsort((sub, pos))
        xy = np.concatenate([xy, roots[ok]])[order]
        ring_of = np.concatenate([ring_of, ring_of[ins]])[order]
        sizes = np.bincount(ring_of, minlength=len(rings))
        added += ins.size
    if stats is not None:
        stats["refined"] = stats.get("refined", 0) + added
        stats["evaluations"] = stats.get("evaluations", 0) + evals
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    return [xy[bounds[q]:bounds[q + 1]] for q in range(len(rings))]


def _keep_simple(refined: list[np.ndarray], raw: list[np.ndarray], stats: dict) -> list[np.ndarray]:
    """Undo the refinement of rings that it made self-intersecting or made
    touch another ring (a thin neck, a projection across a gap). Marching
    squares rings are simple and disjoint, so the result is too; the undone
    rings keep their vertices on the surface but not the chord tolerance
    (counted in ``stats["unrefined_rings"]``)."""
    import shapely

    if not refined:
        return refined
    lr = np.array([shapely.LinearRing(r) for r in refined], dtype=object)
    bad = ~shapely.is_simple(lr)
    tree = shapely.STRtree(lr)
    i, j = tree.query(lr, predicate="intersects")
    cross = i != j
    bad[i[cross]] = True
    bad[j[cross]] = True
    stats["unrefined_rings"] = stats.get("unrefined_rings", 0) + int(bad.sum())
    return [raw[q] if bad[q] else refined[q] for q in range(len(refined))]


def signed_areas(rings: list[np.ndarray]) -> np.ndarray:
    """Shoelace area of each ring, mm^2 (positive: counter-clockwise)."""
    out = np.empty(len(rings))
    for q, r in enumerate(rings):
        x, y = r[:, 0], r[:, 1]
        out[q] = 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))
    return out


def rings_to_multipolygon(rings: list[np.ndarray]):
    """Assemble disjoint simple rings into a MultiPolygon.

    Counter-clockwise rings are outer boundaries, clockwise rings holes; each
    hole goes to the smallest outer ring that contains it. Orientation is kept
    as given.

    Parameters
    ----------
    rings : list of (n_q, 2) float64, mm

    Returns
    -------
    shapely.MultiPolygon
    """
    import shapely

    rings = [r for r in rings if r.shape[0] >= 3]
    if not rings:
        return shapely.MultiPolygon()
    area = signed_areas(rings)
    outer = np.flatnonzero(area > 0)
    holes = np.flatnonzero(area < 0)
    shells = [shapely.Polygon(rings[q]) for q in outer]
    owned: list[list[np.ndarray]] = [[] for _ in outer]
    if holes.size and outer.size:
        tree = shapely.STRtree(shells)
        probe = shapely.points(np.array([rings[q][0] for q in holes]))
        hi, oi = tree.query(probe, predicate="within")
        best = np.full(holes.size, -1)
        for h, o in zip(hi, oi):
            if best[h] < 0 or area[outer[o]] < area[outer[best[h]]]:
                best[h] = o
        for h, o in enumerate(best):
            if o >= 0:
                owned[o].append(rings[holes[h]])
    polys = [shapely.Polygon(rings[q], owned[s]) for s, q in enumerate(outer)]
    return shapely.MultiPolygon(polys)


def layer_contours(skel: Skeleton, result: SliceResult, k: int, tol: float = 1e-3):
    """Contours of layer ``k`` of a slicing result.

    Parameters
    ----------
    skel : Skeleton
        The skeleton that was sliced.
    result : SliceResult
    k : int
        Layer index; the layer lies at ``z = z0 + k h``.
    tol : float, mm
        Distance of every vertex (and chord midpoint) to the surface, in the
        layer plane; default 1 um.

    Returns
    -------
    shapely.MultiPolygon
        mm; valid, outer rings counter-clockwise, holes clockwise.
    """
    tol = _check_tol(tol)
    g = result.grid
    mask = layer_mask(result, k)
    z = g.origin[2] + int(k) * g.layer_height
    rings = mask_rings(skel, mask, g.origin[:2], g.pixel_size, z, tol)
    return rings_to_multipolygon(rings)


def iter_contours(skel: Skeleton, result: SliceResult, tol: float = 1e-3,
                  stats: dict | None = None, placement=None) -> Iterator[tuple[int, float, object]]:
    """Contours of every layer, bottom first.

    Parameters
    ----------
    skel : Skeleton
    result : SliceResult
    tol : float, mm
    stats : dict, optional
        Filled with totals (``evaluations``, ``vertices``, ``refined``,
        ``unbracketed``).
    placement : formats.printers.Placement, optional
        Put the contours on a printer's plate, as the images are: only the
        placed layers (``k_first`` on), numbered from 0, translated by
        :meth:`~formats.printers.Placement.offset` (plate mm, z of plate
        layer centres).

    Yields
    ------
    k : int
    z : float, mm
    polys : shapely.MultiPolygon
    """
    tol = _check_tol(tol)
    if isinstance(result, (PartResult, PartStreamedResult)):     # a lattice with meshes
        yield from iter_part_contours(result, tol, stats, placement)
        return
    g = result.grid
    k_lo, k_hi = 0, g.layers
    if placement is not None:
        k_lo, k_hi = placement.k_first, placement.k_first + placement.layers
        dx, dy, _ = placement.offset(g)
    for k, img in enumerate(result.iter_layers(1)):
        if k < k_lo:
            continue
        if k >= k_hi:
            break
        z = g.origin[2] + k * g.layer_height
        rings = mask_rings(skel, img.astype(bool), g.origin[:2], g.pixel_size, z, tol, stats=stats)
        polys = rings_to_multipolygon(rings)
        if placement is None:
            yield k, z, polys
        else:
            import shapely.affinity

            yield k - k_lo, (k - k_lo + 0.5) * g.layer_height, shapely.affinity.translate(polys, dx, dy)


def _polygons_only(geom):
    """The polygons of a shapely geometry as an oriented MultiPolygon (outer rings
    counter-clockwise, holes clockwise)."""
    import shapely
    from shapely.geometry.polygon import orient

    polys = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and not g.is_empty]
    polys += [p for g in shapely.get_parts(geom) if g.geom_type == "MultiPolygon" for p in g.geoms]
    return shapely.MultiPolygon([orient(p, 1.0) for p in polys])


def _part_sections(part) -> dict:
    return {role: Sections(part.of_role(role)) for role in ROLES if part.of_role(role)}


def _part_layer(result, sections: dict, img, k: int, tol: float, stats: dict | None):
    """Contours of layer ``k`` of a sliced part; ``img`` is the lattice's raster of that layer."""
    import shapely

    g, lat = result.grid, result.lattice
    z = g.origin[2] + k * g.layer_height
    geom = shapely.MultiPolygon()
    if img is not None and img.any():          # the lattice's own contours, on its own (uncut) grid
        lz = lat.grid.origin[2] + (k + result.lattice_offset[2]) * lat.grid.layer_height
        geom = rings_to_multipolygon(mask_rings(result.part.skeleton, img.astype(bool), lat.grid.origin[:2],
                                                lat.grid.pixel_size, lz, tol, stats=stats))
    for role, op in (("clip-inside", "intersection"), ("clip-outside", "difference"), ("solid", "union")):
        if role in sections:
            geom = getattr(geom, op)(rings_to_multipolygon(sections[role].rings(z)))
    return z, _polygons_only(geom)


def part_layer_contours(result, k: int, tol: float = 1e-3):
    """Contours of layer ``k`` of a sliced part (:class:`slicer.part_slicing.PartResult`):
    a valid MultiPolygon, mm, as :func:`layer_contours` gives for a lattice."""
    tol = _check_tol(tol)
    lat = result.lattice
    img = layer_mask(lat, int(k) + result.lattice_offset[2]) if lat is not None else None
    return _part_layer(result, _part_sections(result.part), img, int(k), tol, None)[1]


def iter_part_contours(result, tol: float = 1e-3, stats: dict | None = None,
                       placement=None) -> Iterator[tuple[int, float, object]]:
    """Contours of a sliced part (:mod:`slicer.part_slicing`), every layer, bottom first.

    Each layer's lattice contours (from the lattice's own raster, vertices on
    its surface to ``tol``) are combined with the meshes' exact cross-sections
    (:class:`slicer.mesh_slicing.Sections`) by polygon booleans:
    ``((lattice ∩ CI) − CO) ∪ S``. Arguments and conventions as
    :func:`iter_contours`.
    """
    import shapely.affinity

    if isinstance(result, PartStreamedResult):
        if placement is not None:
            raise GridError("contours on a printer's plate need the whole job in memory: raise --max-memory")
        k = 0
        for slab in result.iter_slabs():
            for kk, z, mp in iter_part_contours(slab, tol, stats):
                yield k + kk, z, mp
            k += slab.grid.layers
        return
    g = result.grid
    sections = _part_sections(result.part)
    k_lo, k_hi = 0, g.layers
    if placement is not None:
        k_lo, k_hi = placement.k_first, placement.k_first + placement.layers
        dx, dy, _ = placement.offset(g)
    lat = result.lattice
    lat_layers = lat.iter_layers(1) if lat is not None else None
    for _ in range(result.lattice_offset[2] if lat is not None else 0):
        next(lat_layers)
    for k in range(g.layers):
        img = next(lat_layers) if lat_layers is not None else None
        if k < k_lo:
            continue
        if k >= k_hi:
            break
        z, polys = _part_layer(result, sections, img, k, tol, stats)
        if placement is None:
            yield k, z, polys
        else:
            yield k - k_lo, (k - k_lo + 0.5) * g.layer_height, shapely.affinity.translate(polys, dx, dy)


def write_contours(skel: Skeleton, result: SliceResult, path, tol: float = 1e-3, force: bool = False,
                   meta: dict | None = None, placement=None) -> dict:
    """Write the contours of every layer to one GeoJSON or JSON file, atomically.

    ``.geojson``: a FeatureCollection, one Feature per layer (a MultiPolygon
    in mm, properties ``layer`` and ``z``). Any other suffix: plain JSON,
    ``{"layers": [{"layer", "z", "polygons": [[outer, hole, ...], ...]}]}``
    with each ring a list of ``[x, y]`` (mm, not repeated at the end). Both
    carry the grid and ``meta`` (key ``skelslice``). Outer rings are
    counter-clockwise seen from +z, holes clockwise. Layers are streamed: the
    file is written to a temporary file beside ``path`` and renamed when
    complete. With ``placement`` (a printer job) the layers and coordinates
    are the plate's, as in the images (see :func:`iter_contours`), and the
    grid written is the plate's.

    Returns
    -------
    dict
        ``layers``, ``vertices``, ``seconds``, ``path``.
    """
    import json
    import time
    from pathlib import Path

    tol = _check_tol(tol)
    path = Path(path)
    check_destination(path, force)
    geo = path.suffix.lower() == ".geojson"
    grid = result.grid if placement is None else placement.grid
    head = {"generator": "skelslice", "units": "mm", "tolerance": tol, "grid": grid.to_dict(),
            **(meta or {})}
    t0 = time.perf_counter()
    out = AtomicFile(path)    # published after the last layer
    nv = 0
    n = 0
    try:
        fh = out.fh
        if geo:
            fh.write(b'{"type": "FeatureCollection", "skelslice": ' + json.dumps(head).encode()
                     + b', "features": [\n')
        else:
            fh.write(b'{"skelslice": ' + json.dumps(head).encode() + b', "layers": [\n')
        for k, z, mp in iter_contours(skel, result, tol, placement=placement):
            polys = []
            for poly in mp.geoms:
                rs = [poly.exterior, *poly.interiors]
                coords = [np.asarray(r.coords)[:, :2] for r in rs]
                nv += sum(c.shape[0] - 1 for c in coords)
                polys.append([(c if geo else c[:-1]).tolist() for c in coords])
            if geo:
                item = {"type": "Feature", "properties": {"layer": k, "z": z},
                        "geometry": {"type": "MultiPolygon", "coordinates": polys}}
            else:
                item = {"layer": k, "z": z, "polygons": polys}
            fh.write((b",\n" if n else b"") + json.dumps(item).encode())
            n += 1
        fh.write(b"\n]}\n")
        out.publish(force)
    except BaseException:
        out.discard()
        raise
    return {"layers": n, "vertices": nv, "seconds": time.perf_counter() - t0, "path": str(path)}


__all__ = ["layer_contours", "iter_contours", "iter_part_contours", "part_layer_contours", "layer_mask", "mask_rings", "refine_rings",
           "rings_to_multipolygon", "signed_areas", "solve_crossings", "plane_distance",
           "project_to_contour", "write_contours"]
