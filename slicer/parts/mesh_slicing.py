"""Triangle meshes at the voxel centres: exact cross-sections, classified like the lattice.

For every layer plane ``z_k`` the faces of a mesh that reach it are cut by the
plane; the cuts are oriented segments (inside on their left, seen from above)
that close into the cross-section's loops. Each pixel row ``y_j`` is then
crossed with those segments and the *positive fill rule* of the 3MF core
specification is applied along the row: a point is inside where the winding
number of the loops around it is at least 1 (for a valid closed mesh, simply
"inside the mesh"; for overlapping shells of a 3MF file, their union).

Convention on the surface (the lattice counts ``F = 1`` as inside): a closed
mesh's boundary counts as inside. A pixel centre is inside when it lies in
the closure of the filled region:

* along a row, filled intervals are closed ``[x_a, x_b]``;
* a plane through mesh vertices is cut twice, as if moved up and as if moved
  down by an infinitesimal amount (vertices on the plane count as above, then
  as below; the cut of an edge is computed from its two ends in a fixed order,
  so both faces of an edge get the very same point), and the two results are
  joined: a layer through a horizontal top face includes the face, as one
  through a bottom face does;
* the same is done along y for rows that pass exactly through a cut's end;
* where a cut shrinks to a point or a segment (an apex or a ridge on the
  plane), the centres exactly on the mesh's vertices and edges in the plane
  are inside (exact on-segment tests).

Everything is plain float64 arithmetic on the input coordinates (no snapping
or tolerance): the only rounding is that of the cut points and row crossings,
so only centres within a few ulps of the surface can depend on it, and the
answer is deterministic. Where the cuts are exact -- faces parallel to an
axis, the mesh's own vertices and edges -- a centre on the surface is always
inside; on a slanted face through a centre, rounding decides (as it does for
the lattice's ``F = 1``). Pixel centres are ``x0 + i px``, ``y0 - j py``,
``z0 + k h`` of the grid given, as everywhere in skelslice.

Vertical spans (:func:`column_spans`), for exact sub-layer coverage
(``--aa-z``): every pixel column is a vertical ray; faces whose projection
contains the column's centre (a shared edge or vertex is owned by exactly
one face, by a fixed tie rule on edge functions evaluated the same way from
both sides) give the heights where it crosses the surface, and the positive
fill rule along the column gives its inside spans.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from slicer.tracer.grid import SliceGrid
from slicer.parts.mesh_intersect import orient2d
from slicer.raster.ordering import lexsort2

#: layers cut at once (bounds the memory of the face-layer pairs)
LAYER_BATCH = 32


@dataclass(frozen=True, eq=False)
class Soup:
    """The faces of one or more closed meshes, filled together by the positive rule.

    Attributes
    ----------
    tri : (m, 3, 3) float64, mm
        Face corners, counter-clockwise seen from outside.
    zmin, zmax : (m,) float64, mm
    """

    tri: np.ndarray
    zmin: np.ndarray
    zmax: np.ndarray

    @classmethod
    def of(cls, meshes) -> "Soup":
        """The soup of :class:`slicer.parts.meshes.Mesh` objects (empty list: no faces)."""
        parts = [m.triangles() for m in meshes]
        tri = np.concatenate(parts) if parts else np.zeros((0, 3, 3))
        tri = np.ascontiguousarray(tri, dtype=np.float64)
        return cls(tri, tri[:, :, 2].min(axis=1), tri[:, :, 2].max(axis=1))

    @property
    def empty(self) -> bool:
        return self.tri.shape[0] == 0

    def bounds(self) -> np.ndarray:
        """(2, 3) float64, mm."""
        return np.array([self.tri.reshape(-1, 3).min(axis=0), self.tri.reshape(-1, 3).max(axis=0)])


# ----------------------------------------------------------------------------- cuts
def _cut_points(a: np.ndarray, b: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Points at height ``z`` on edges from ``a`` (below) to ``b`` (at or above), (k, 2).

    Computed from the ends in this order whichever face asks, so both faces of
    an edge get bit-equal points; an end on the plane is returned exactly.
    """
    t = (z - a[:, 2]) / (b[:, 2] - a[:, 2])
    p = a[:, :2] + t[:, None] * (b[:, :2] - a[:, :2])
    p = np.where((b[:, 2] == z)[:, None], b[:, :2], p)
    return np.where((a[:, 2] == z)[:, None], a[:, :2], p)


def _segments(tri: np.ndarray, z: np.ndarray, up: bool):
    """Oriented cuts of faces ``tri`` ((k, 3, 3)) by planes ``z`` ((k,)).

    ``up``: vertices on the plane count as below (the plane moved up);
    otherwise as above. Returns ``(keep, p, q)``: which faces are cut and the
    cut's start and end (inside on the left), each (k', 2).
    """
    vz = tri[:, :, 2]
    above = vz > z[:, None] if up else vz >= z[:, None]
    n_above = above.sum(axis=1)
    keep = (n_above == 1) | (n_above == 2)
    tri, z, above = tri[keep], z[keep], above[keep]
    lone_above = above.sum(axis=1) == 1
    # index of the lone corner: the one whose flag differs from the other two
    lone = np.where(lone_above, np.argmax(above, axis=1), np.argmin(above, axis=1))
    r = np.arange(tri.shape[0])
    w0 = tri[r, lone]
    w1 = tri[r, (lone + 1) % 3]
    w2 = tri[r, (lone + 2) % 3]
    la = lone_above[:, None]
    # edge (w0, w1) and edge (w2, w0), each cut from its lower end to its upper end
    e01 = _cut_points(np.where(la, w1, w0), np.where(la, w0, w1), z)
    e20 = _cut_points(np.where(la, w2, w0), np.where(la, w0, w2), z)
    # lone above: from edge w0w1 to edge w2w0; lone below: the other way
    p = np.where(la, e01, e20)
    q = np.where(la, e20, e01)
    return keep, p, q


def _row_crossings(p: np.ndarray, q: np.ndarray, layer: np.ndarray, y0: float, py: float, height: int,
                   down: bool, rows_only: np.ndarray | None = None):
    """Crossings of segments with pixel rows ``y_j = y0 - j py``.

    A segment crosses row j when ``y_j`` lies in ``[ylo, yhi)`` (the rows moved
    up an infinitesimal amount) or, with ``down``, in ``(ylo, yhi]``.
    ``rows_only`` ((k,) bool per segment row key, optional) restricts the
    output to the (layer, row) keys in it.

    Returns
    -------
    key : (c,) int64
        ``layer * height + row``.
    x : (c,) float64, mm
    sign : (c,) int8
        +1 where the segment runs toward +y.
    """
    ylo = np.minimum(p[:, 1], q[:, 1])
    yhi = np.maximum(p[:, 1], q[:, 1])
    jmin = np.clip(np.floor((y0 - yhi) / py).astype(np.int64) - 1, 0, height)
    jmax = np.clip(np.ceil((y0 - ylo) / py).astype(np.int64) + 2, 0, height)
    cnt = np.maximum(jmax - jmin, 0)
    e = np.repeat(np.arange(p.shape[0]), cnt)
    j = np.repeat(jmin - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
    yj = y0 - j * py
    if down:
        ok = (ylo[e] < yj) & (yj <= yhi[e])
    else:
        ok = (ylo[e] <= yj) & (yj < yhi[e])
    e, j, yj = e[ok], j[ok], yj[ok]
    key = layer[e] * height + j
    if rows_only is not None:
        sel = np.isin(key, rows_only)
        e, j, yj, key = e[sel], j[sel], yj[sel], key[sel]
    pe, qe = p[e], q[e]
    x = pe[:, 0] + (yj - pe[:, 1]) * (qe[:, 0] - pe[:, 0]) / (qe[:, 1] - pe[:, 1])
    sign = np.where(qe[:, 1] > pe[:, 1], 1, -1).astype(np.int8)
    return key, x, sign


def _filled_intervals(key: np.ndarray, x: np.ndarray, sign: np.ndarray):
    """Closed intervals where the winding number along each row is >= 1.

    Crossings at equal ``x`` are ordered downward ones first, so that a point
    where loops touch is inside when any region next to it is filled.

    Returns
    -------
    key, xa, xb : (s,) arrays
    """
    if key.size == 0:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e
    order = np.lexsort((sign, x, key))
    key, x, sign = key[order], x[order], sign[order]
    w = _per_group_cumsum(key, -sign.astype(np.int64))         # winding just after each crossing
    nxt_same = np.r_[key[1:] == key[:-1], False]
    fill = (w >= 1) & nxt_same
    i = np.flatnonzero(fill)
    return key[i], x[i], x[i + 1]


def _per_group_cumsum(group: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cumulative sums of ``v`` restarting where the (sorted) ``group`` changes."""
    cs = np.cumsum(v)
    first = np.r_[True, group[1:] != group[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(group.size), 0))
    return cs - cs[start] + v[start]


def _columns(xa: np.ndarray, xb: np.ndarray, x0: float, px: float, width: int):
    """First and last column whose centre ``x0 + i px`` lies in ``[xa, xb]`` (may be empty: ia > ib)."""
    ia = np.ceil((xa - x0) / px).astype(np.int64)
    ib = np.floor((xb - x0) / px).astype(np.int64)
    # exact against the centres as the grid computes them
    for _ in range(2):
        ia = np.where(x0 + (ia - 1) * px >= xa, ia - 1, ia)
        ia = np.where(x0 + ia * px < xa, ia + 1, ia)
        ib = np.where(x0 + (ib + 1) * px <= xb, ib + 1, ib)
        ib = np.where(x0 + ib * px > xb, ib - 1, ib)
    return np.clip(ia, 0, width), np.clip(ib, -1, width - 1)


def _rows_through_ends(p: np.ndarray, q: np.ndarray, layer: np.ndarray, y0: float, py: float,
                       height: int) -> np.ndarray:
    """(layer, row) keys of rows passing exactly through a segment end."""
    ends = np.concatenate([p[:, 1], q[:, 1]])
    lay = np.concatenate([layer, layer])
    j = np.rint((y0 - ends) / py).astype(np.int64)
    hit = (j >= 0) & (j < height) & (y0 - j * py == ends)
    return np.unique(lay[hit] * height + j[hit])


def _in_plane(tri: np.ndarray, z: np.ndarray, layer: np.ndarray, grid: SliceGrid):
    """Pixel centres on the vertices and edges of faces that lie in their layer's plane.

    A cut can shrink to such a point or segment (an apex, a ridge); the
    surface there is the boundary of the solid, so its centres are inside.
    On-segment tests are exact (:func:`slicer.parts.mesh_intersect.orient2d`).

    Returns
    -------
    key, ia, ib : (s,) int64
        ``layer * height + row`` and closed column ranges.
    """
    H, W = grid.height, grid.width
    x0, y0, _ = grid.origin
    px, py = grid.pixel_size
    keys, ias, ibs = [], [], []
    on = tri[:, :, 2] == z[:, None]
    # vertices on the plane
    f, c = np.nonzero(on)
    v = tri[f, c, :2]
    i = np.rint((v[:, 0] - x0) / px).astype(np.int64)
    j = np.rint((y0 - v[:, 1]) / py).astype(np.int64)
    hit = (i >= 0) & (i < W) & (j >= 0) & (j < H) & (x0 + i * px == v[:, 0]) & (y0 - j * py == v[:, 1])
    keys.append(layer[f[hit]] * H + j[hit])
    ias.append(i[hit])
    ibs.append(i[hit])
    # edges on the plane: each row they cross, the one or two centres next to the crossing
    for u, w in ((0, 1), (1, 2), (2, 0)):
        e = np.flatnonzero(on[:, u] & on[:, w])
        if not e.size:
            continue
        a, b, lay = tri[e, u, :2], tri[e, w, :2], layer[e]
        ylo, yhi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
        j0 = np.clip(np.ceil((y0 - yhi) / py).astype(np.int64) - 1, 0, H)
        j1 = np.clip(np.floor((y0 - ylo) / py).astype(np.int64) + 1, -1, H - 1)
        cnt = np.maximum(j1 - j0 + 1, 0)
        q = np.repeat(np.arange(e.size), cnt)
        jj = np.repeat(j0 - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
        yj = y0 - jj * py
        ok = (yj >= ylo[q]) & (yj <= yhi[q])
        q, jj, yj = q[ok], jj[ok], yj[ok]
        flat = a[q, 1] == b[q, 1]
        # a horizontal edge on the row: all of it
        fa, fb = _columns(np.minimum(a[q, 0], b[q, 0])[flat], np.maximum(a[q, 0], b[q, 0])[flat], x0, px, W)
        keys.append(lay[q[flat]] * H + jj[flat])
        ias.append(fa)
        ibs.append(fb)
        q, jj, yj = q[~flat], jj[~flat], yj[~flat]
        x = a[q, 0] + (yj - a[q, 1]) * (b[q, 0] - a[q, 0]) / (b[q, 1] - a[q, 1])
        base = np.floor((x - x0) / px).astype(np.int64)
        for d in (-1, 0, 1, 2):
            ii = base + d
            cx = x0 + ii * px
            cand = (ii >= 0) & (ii < W) & (cx >= np.minimum(a[q, 0], b[q, 0])) & (cx <= np.maximum(a[q, 0], b[q, 0]))
            if not cand.any():
                continue
            r = np.flatnonzero(cand)
            pt = np.stack([cx[r], yj[r]], axis=1)
            line = orient2d(a[q[r]], b[q[r]], pt) == 0
            r = r[line]
            keys.append(lay[q[r]] * H + jj[r])
            ias.append(ii[r])
            ibs.append(ii[r])
    return np.concatenate(keys), np.concatenate(ias), np.concatenate(ibs)


def layer_masks(soup: Soup, grid: SliceGrid, k_start: int = 0, k_stop: int | None = None
                ) -> Iterator[tuple[int, np.ndarray]]:
    """Inside masks of the pixel centres of layers ``[k_start, k_stop)`` of ``grid``.

    Parameters
    ----------
    soup : Soup
    grid : SliceGrid
        Centres ``x0 + i px``, ``y0 - j py``, ``z0 + k h``.
    k_start, k_stop : int
        Layer range (default: all layers).

    Yields
    ------
    k : int
    mask : (height, width) bool
        True where the centre is inside or on the surface (positive fill rule).
    """
    K = grid.layers if k_stop is None else int(k_stop)
    H, W = grid.height, grid.width
    x0, y0, z0 = grid.origin
    px, py = grid.pixel_size
    h = grid.layer_height
    if soup.empty or H == 0 or W == 0:
        for k in range(k_start, K):
            yield k, np.zeros((H, W), bool)
        return
    # layers each face can reach (one extra on each side; the exact test is below)
    klo = np.maximum(np.floor((soup.zmin - z0) / h).astype(np.int64), k_start)
    khi = np.minimum(np.ceil((soup.zmax - z0) / h).astype(np.int64), K - 1)
    for b0 in range(k_start, K, LAYER_BATCH):
        b1 = min(b0 + LAYER_BATCH, K)
        lo, hi = np.maximum(klo, b0), np.minimum(khi, b1 - 1)
        cnt = np.maximum(hi - lo + 1, 0)
        f = np.repeat(np.arange(soup.tri.shape[0]), cnt)
        k = np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
        z = z0 + k * h
        touch = (soup.zmin[f] <= z) & (z <= soup.zmax[f])
        f, k, z = f[touch], k[touch], z[touch]
        tri = soup.tri[f]
        on_plane = np.any(tri[:, :, 2] == z[:, None], axis=1)
        degenerate_layers = np.unique(k[on_plane])
        cuts = []
        for up in (False, True):
            if up:
                sel = np.isin(k, degenerate_layers)
                if not sel.any():
                    break
                t, zz, kk = tri[sel], z[sel], k[sel]
            else:
                t, zz, kk = tri, z, k
            keep, p, q = _segments(t, zz, up)
            cuts.append((p, q, kk[keep] - b0))
        keys, xa, xb = [], [], []
        for p, q, lay in cuts:
            for down in (False, True):
                rows = None
                if down:
                    rows = _rows_through_ends(p, q, lay, y0, py, H)
                    if rows.size == 0:
                        continue
                ck, cx, cs = _row_crossings(p, q, lay, y0, py, H, down, rows)
                fk, fa, fb = _filled_intervals(ck, cx, cs)
                keys.append(fk)
                xa.append(fa)
                xb.append(fb)
        key = np.concatenate(keys)
        ia, ib = _columns(np.concatenate(xa), np.concatenate(xb), x0, px, W)
        if on_plane.any():          # vertices and edges in the plane (cuts that shrink to them)
            pk, pa, pb = _in_plane(tri[on_plane], z[on_plane], k[on_plane] - b0, grid)
            key, ia, ib = np.concatenate([key, pk]), np.concatenate([ia, pa]), np.concatenate([ib, pb])
        ok = ib >= ia
        key, ia, ib = key[ok], ia[ok], ib[ok]
        lay, row = np.divmod(key, H)
        order = np.argsort(lay, kind="stable")
        lay, row, ia, ib = lay[order], row[order], ia[order], ib[order]
        bounds = np.searchsorted(lay, np.arange(b1 - b0 + 1))
        for q in range(b1 - b0):
            s, e = bounds[q], bounds[q + 1]
            diff = np.zeros((H, W + 1), np.int32)
            if e > s:
                np.add.at(diff, (row[s:e], ia[s:e]), 1)
                np.add.at(diff, (row[s:e], ib[s:e] + 1), -1)
            yield b0 + q, np.cumsum(diff[:, :W], axis=1) > 0


# ----------------------------------------------------------------------------- runs
def runs_from_masks(masks: Iterator[tuple[int, np.ndarray]], n_pixels: int, k_start: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-column runs ``[k0, k1)`` of consecutive inside layers, from layer masks in order.

    Parameters
    ----------
    masks : iterator of (k, (height, width) bool)
        Consecutive layers from ``k_start``.
    n_pixels : int

    Returns
    -------
    pix, k0, k1 : (r,) int64
        Sorted by pixel, then layer (the layout of :class:`slicer.tracer.slicing.SliceResult`).
    """
    prev = np.zeros(n_pixels, bool)
    start = np.zeros(n_pixels, np.int64)
    out_p, out_a, out_b = [], [], []
    k = k_start
    for k, m in masks:
        cur = m.reshape(-1)
        ch = np.flatnonzero(cur != prev)
        if ch.size:
            ends = ch[prev[ch]]
            if ends.size:
                out_p.append(ends)
                out_a.append(start[ends])
                out_b.append(np.full(ends.size, k, np.int64))
            begins = ch[cur[ch]]
            start[begins] = k
            prev[ch] = cur[ch]
        k += 1
    last = np.flatnonzero(prev)
    if last.size:
        out_p.append(last)
        out_a.append(start[last])
        out_b.append(np.full(last.size, k, np.int64))
    if not out_p:
        z = np.zeros(0, np.int64)
        return z, z.copy(), z.copy()
    pix, k0, k1 = (np.concatenate(x).astype(np.int64) for x in (out_p, out_a, out_b))
    order = lexsort2(k0, pix)
    return pix[order], k0[order], k1[order]


def combine_intervals(groups, op) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boolean combination of interval sets per pixel column.

    Parameters
    ----------
    groups : list of (pix, lo, hi)
        Each a set of disjoint intervals ``[lo, hi)`` per pixel (integer layer
        runs or real spans).
    op : callable
        ``op(states) -> bool array``: ``states`` is a (len(groups), e) bool
        array, whether each group is inside just after each event position.

    Returns
    -------
    pix, lo, hi : arrays
        The intervals where ``op`` holds, sorted by pixel then start.
    """
    ev_pix, ev_t, ev_g, ev_d = [], [], [], []
    for g, (p, a, b) in enumerate(groups):
        ev_pix += [p, p]
        ev_t += [a, b]
        ev_g.append(np.full(2 * len(p), g, np.int64))
        ev_d += [np.ones(len(p), np.int64), -np.ones(len(p), np.int64)]
    pix = np.concatenate(ev_pix).astype(np.int64)
    dtype = np.result_type(*[np.asarray(t).dtype for t in ev_t]) if ev_t else np.int64
    t = np.concatenate(ev_t).astype(dtype)
    g = np.concatenate(ev_g)
    d = np.concatenate(ev_d)
    if pix.size == 0:
        return pix, t, t.copy()
    order = np.lexsort((t, pix))
    pix, t, g, d = pix[order], t[order], g[order], d[order]
    n = len(groups)
    state = np.zeros((n, pix.size), np.int64)
    for q in range(n):
        state[q] = np.cumsum(np.where(g == q, d, 0))
    # the state after the last event of each (pix, t) position
    last = np.r_[(pix[1:] != pix[:-1]) | (t[1:] != t[:-1]), True]
    pos = np.flatnonzero(last)
    ppix, pt = pix[pos], t[pos]
    val = op(state[:, pos] > 0)
    newpix = np.r_[True, ppix[1:] != ppix[:-1]]
    prev = np.r_[False, val[:-1]] & ~newpix
    rise = np.flatnonzero(val & ~prev)
    fall = np.flatnonzero(~val & prev)
    return ppix[rise], pt[rise], pt[fall]


def part_op(has_clip_inside: bool):
    """The part's combination of (lattice, clip-inside, clip-outside, solid) states:
    ``(lattice and clip-inside and not clip-outside) or solid``."""
    def op(s):
        lat = s[0] & ~s[2]
        if has_clip_inside:
            lat &= s[1]
        return lat | s[3]
    return op


# ----------------------------------------------------------------------------- vertical spans
def _edge_function(ax, ay, bx, by, px, py):
    """``(b - a) x (p - a)``, evaluated from the edge's ends in canonical order so the two
    faces of an edge get opposite values exactly."""
    swap = (ax > bx) | ((ax == bx) & (ay > by))
    sx, sy = np.where(swap, bx, ax), np.where(swap, by, ay)
    ex, ey = np.where(swap, ax, bx), np.where(swap, ay, by)
    v = (ex - sx) * (py - sy) - (ey - sy) * (px - sx)
    return np.where(swap, -v, v)


def column_hits(xy: np.ndarray, x0: float, y0: float, px: float, py: float, width: int, height: int,
                chunk: int = 1 << 21) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Which pixel centres ``(x0 + i px, y0 - j py)`` each projected triangle covers.

    A centre strictly inside a projection is covered; one on an edge is covered
    when that edge is a "left" edge of the projection (oriented
    counter-clockwise): running downward, or horizontal and running toward -x.
    The edge function is evaluated from the edge's two ends in a fixed order,
    so the two triangles of an edge that lie on either side of it get exactly
    opposite values: a centre on a shared edge (or vertex) of a surface seen
    from one side is covered once. Triangles of zero projected area cover
    nothing.

    Parameters
    ----------
    xy : (m, 3, 2) float64
        Projected corners.
    chunk : int
        Candidate (triangle, centre) pairs handled at once.

    Yields
    ------
    pix : (c,) int64
        ``j * width + i``.
    face : (c,) int64
        Index of the covering triangle in ``xy``.
    """
    a, b, c = xy[:, 0], xy[:, 1], xy[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    faces = np.flatnonzero(area != 0)
    # counter-clockwise projections: swap two corners of clockwise ones
    t = np.where((area[faces] > 0)[:, None, None], xy[faces], xy[faces][:, [0, 2, 1]])
    lo, hi = t.min(axis=1), t.max(axis=1)
    i0 = np.clip(np.ceil((lo[:, 0] - x0) / px).astype(np.int64) - 1, 0, width)
    i1 = np.clip(np.floor((hi[:, 0] - x0) / px).astype(np.int64) + 1, -1, width - 1)
    j0 = np.clip(np.ceil((y0 - hi[:, 1]) / py).astype(np.int64) - 1, 0, height)
    j1 = np.clip(np.floor((y0 - lo[:, 1]) / py).astype(np.int64) + 1, -1, height - 1)
    nw, nh = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
    cnt = nw * nh
    csum = np.cumsum(cnt)
    start = 0
    while start < faces.size:
        stop = max(int(np.searchsorted(csum, (csum[start - 1] if start else 0) + chunk, side="right")), start + 1)
        fs = np.arange(start, stop)
        cn = cnt[fs]
        f = np.repeat(fs, cn)
        loc = np.arange(int(cn.sum())) - np.repeat(np.cumsum(cn) - cn, cn)
        i = i0[f] + loc % nw[f]
        j = j0[f] + loc // nw[f]
        X = x0 + i * px
        Y = y0 - j * py
        inside = np.ones(f.size, bool)
        for u, v in ((0, 1), (1, 2), (2, 0)):
            ax, ay, bx, by = t[f, u, 0], t[f, u, 1], t[f, v, 0], t[f, v, 1]
            E = _edge_function(ax, ay, bx, by, X, Y)
            left = (by < ay) | ((by == ay) & (bx < ax))
            inside &= (E > 0) | ((E == 0) & left)
        yield j[inside] * width + i[inside], faces[f[inside]]
        start = stop


def fill_spans(pix: np.ndarray, t: np.ndarray, sign: np.ndarray):
    """Inside spans along columns (or rays) from signed surface crossings, positive fill rule.

    Parameters
    ----------
    pix : (c,) int64
    t : (c,) float64
        Crossing positions along the column.
    sign : (c,) int8
        +1 entering the solid (going toward +t), -1 leaving.

    Returns
    -------
    pix, t0, t1 : arrays
        Maximal spans where the winding number is >= 1, sorted by pixel then
        ``t0``; crossings at equal ``t`` count entries first (closed spans).
    """
    order = np.lexsort((-sign, t, pix))
    pix, t, sign = pix[order], t[order], sign[order]
    w = _per_group_cumsum(pix, sign.astype(np.int64))
    q = np.flatnonzero((w >= 1) & np.r_[pix[1:] == pix[:-1], False])
    sp, a0, a1 = pix[q], t[q], t[q + 1]
    if sp.size:         # merge spans that touch
        starts = np.flatnonzero(np.r_[True, (sp[1:] != sp[:-1]) | (a0[1:] > a1[:-1])])
        sp, a0, a1 = sp[starts], a0[starts], np.maximum.reduceat(a1, starts)
    return sp, a0, a1


def column_spans(soup: Soup, grid: SliceGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inside spans of every pixel column, clipped to the grid's z range.

    Each column is a vertical ray through its centre; a face counted by
    :func:`column_hits` gives a crossing at the height of its plane there
    (a face seen from above leaves the solid going up).

    Returns
    -------
    pix : (s,) int64
    t0, t1 : (s,) float64, mm
        Inside spans ``[t0, t1]`` (positive fill rule), sorted by pixel then height,
        within ``[z0 - h/2, z0 + (layers - 1/2) h]``.
    """
    H, W = grid.height, grid.width
    x0, y0, z0 = grid.origin
    px, py = grid.pixel_size
    zlo = z0 - 0.5 * grid.layer_height
    zhi = z0 + (grid.layers - 0.5) * grid.layer_height
    if soup.empty or H == 0 or W == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    tri = soup.tri
    out_pix, out_z, out_s = [], [], []
    for pix, f in column_hits(tri[:, :, :2], x0, y0, px, py, W, H):
        j, i = np.divmod(pix, W)
        X, Y = x0 + i * px, y0 - j * py
        A, B, C = tri[f, 0], tri[f, 1], tri[f, 2]
        den = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])
        wb = ((X - A[:, 0]) * (C[:, 1] - A[:, 1]) - (Y - A[:, 1]) * (C[:, 0] - A[:, 0])) / den
        wc = ((B[:, 0] - A[:, 0]) * (Y - A[:, 1]) - (B[:, 1] - A[:, 1]) * (X - A[:, 0])) / den
        out_pix.append(pix)
        out_z.append(A[:, 2] + wb * (B[:, 2] - A[:, 2]) + wc * (C[:, 2] - A[:, 2]))
        out_s.append(np.where(den > 0, -1, 1).astype(np.int8))     # seen from above: an exit going up
    pix, z, s = (np.concatenate(x) for x in (out_pix, out_z, out_s))
    if pix.size == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    sp, a0, a1 = fill_spans(pix, z, s)
    a0, a1 = np.maximum(a0, zlo), np.minimum(a1, zhi)
    ok = a1 > a0
    return sp[ok], a0[ok], a1[ok]


# ----------------------------------------------------------------------------- polygons
class Sections:
    """Exact cross-sections of meshes as polygons (for contours), by manifold3d.

    ``Manifold.slice`` cuts at a height as if the plane were moved up an
    infinitesimal amount (a bottom face is in, a top face out); where a vertex
    lies on the plane, the cut just below is joined to it, so the polygons
    follow the same closed convention as :func:`layer_masks`. Overlapping
    meshes are joined by the positive fill rule (manifold3d's CrossSection).
    """

    def __init__(self, meshes):
        import manifold3d

        self._m = manifold3d
        self.manifold = manifold3d.Manifold.compose([
            manifold3d.Manifold(manifold3d.Mesh64(np.array(m.vertices, dtype=np.float64),    # writable copies
                                                  np.array(m.faces, dtype=np.uint64)))
            for m in meshes])
        self._vz = np.unique(np.concatenate([m.vertices[:, 2] for m in meshes])) if meshes else np.zeros(0)

    def section(self, z: float):
        """The cross-section at ``z`` as a manifold3d CrossSection (closed convention)."""
        cs = self.manifold.slice(float(z))
        i = np.searchsorted(self._vz, z)
        if i < self._vz.size and self._vz[i] == z:
            below = self.manifold.slice(float(np.nextafter(z, -np.inf)))
            cs = self._m.CrossSection.batch_boolean([cs, below], self._m.OpType.Add)
        return cs

    def rings(self, z: float) -> list[np.ndarray]:
        """Rings at ``z``: (n, 2) float64 mm each, outer counter-clockwise, holes clockwise."""
        return [np.asarray(r, dtype=np.float64) for r in self.section(z).to_polygons()]


__all__ = ["Soup", "Sections", "layer_masks", "runs_from_masks", "combine_intervals", "part_op", "column_spans",
           "column_hits", "fill_spans",
           "LAYER_BATCH"]
