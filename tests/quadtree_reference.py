"""The guaranteed contours' quadtree, leaf walks and crossing pairs as they were
written before they became compiled kernels: whole-array numpy steps (per
level, over the cell-state passes). Naive references for
:func:`slicer._kernels.contours.quadtree.quadtree`, :func:`slicer._kernels.contours.chain.leaf_walks`
and :func:`slicer._kernels.contours.chain.pair_crossings` (bit for bit;
tests/test_quadtree.py)."""
from __future__ import annotations

import math

import numpy as np

from slicer._kernels.contours.cellbounds import PIECES, SLACK, disc_bounds, disc_bounds_binned
from slicer._kernels.contours.cellstate import (IN, ONEDIR, OUT, SMALL, THIN, clear_cells, corner_candidates, crest_candidates,
                                       judge_cells, settle_from_parent)
from slicer._kernels.contours.ridgebounds import ridge_bounds, ridge_bounds_binned
from slicer.contours.cells import COARSE_PIECES, _bin_segments, inherit_side
from slicer.contours.roots import FIELD_SLACK, _field
from slicer.model.field import point_grid
from slicer.raster.ordering import stable_argsort
from slicer.model.skeleton import Skeleton


class _Bounds:
    """Field, gradient and the disc bounds at cell centres of one plane."""

    def __init__(self, skel: Skeleton, z: float, ids: np.ndarray, tol: float, root=None, thin: float | None = None):
        self.skel, self.z, self.ids, self.tol = skel, float(z), ids, float(tol)
        #: widest section a THIN cell may hold, mm
        self.thin = float(tol if thin is None else thin)
        self.table = point_grid(skel)[0]
        self.evaluations = 0
        self.bins = None if root is None else _bin_segments(skel, self.z, *root)

    def _binned(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray):
        """The bins' arguments when every disc fits them, else None."""
        if self.bins is None:
            return None
        x0, y0, side, nx, ny, rmax, offsets, lists = self.bins
        inside = ((cx >= x0) & (cx < x0 + nx * side) & (cy >= y0) & (cy < y0 + ny * side)).all()
        if inside and (r.size == 0 or r.max() <= rmax):
            return offsets, lists, x0, y0, side, nx, ny
        return None

    def disc_bounds(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray, pieces: int = PIECES):
        """G, H, U of :func:`slicer._kernels.contours.cellbounds.disc_bounds` over the discs,
        from the segments binned near each centre when the discs fit the bins."""
        sk = self.skel
        binned = self._binned(cx, cy, r)
        if binned is not None:
            return disc_bounds_binned(self.table, binned, cx, cy, self.z, r, sk.degree, sk.sigma, sk.normalisation,
                                      pieces)
        return disc_bounds(self.table, self.ids, cx, cy, self.z, r, sk.degree, sk.sigma, sk.normalisation, pieces)

    def ridge_bounds(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray):
        """Frame and signed bounds of :func:`slicer._kernels.contours.ridgebounds.ridge_bounds`
        over the discs, binned like :meth:`disc_bounds`."""
        sk = self.skel
        binned = self._binned(cx, cy, r)
        if binned is not None:
            return ridge_bounds_binned(self.table, binned, cx, cy, self.z, r, sk.degree, sk.sigma, sk.normalisation)
        return ridge_bounds(self.table, self.ids, cx, cy, self.z, r, sk.degree, sk.sigma, sk.normalisation)

    def ridge(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray, taylor) -> np.ndarray:
        """OUT, THIN or -1 of :meth:`slicer.contours.cells._Bounds.ridge`, in numpy."""
        f0, g0, G = taylor[0], taylor[1], taylor[2]
        ux, uy, vv, uu, uv = self.ridge_bounds(cx, cy, r)
        state = np.full(cx.size, -1, np.int8)
        if self.skel.degree < 4:          # no second-derivative bound: no crest cell
            return state
        convex = self.convex_across(cx, cy, r, ux, uy, g0, G)
        with np.errstate(invalid="ignore"):
            ok = np.flatnonzero(~convex & (-vv > 0.0))
        if ok.size == 0:
            return state
        cx, cy, r, f0, g0, G = cx[ok], cy[ok], r[ok], f0[ok], g0[ok], G[ok]
        ux, uy, curv, uu, uv = ux[ok], uy[ok], -vv[ok], uu[ok], uv[ok]
        fixed = 0.5 * np.maximum(uu, 0.0) * r * r

        def crest_bound(f, g):
            gn = np.hypot(g[:, 0], g[:, 1])
            eg = FIELD_SLACK * (gn + G)
            gu = np.abs(g[:, 0] * ux + g[:, 1] * uy) + eg
            gv = np.abs(g[:, 1] * ux - g[:, 0] * uy) + eg
            return f + FIELD_SLACK * (1.0 + np.abs(f)) + r * gu + fixed + (gv + r * uv) ** 2 / (2.0 * curv)

        best = crest_bound(f0, g0)
        # towards the crest along v: a Newton step with the bound c, then a secant step
        gv0 = g0[:, 1] * ux - g0[:, 0] * uy
        lim = 0.999 * r
        t1 = np.clip(gv0 / curv, -lim, lim)
        f1, g1 = self._at(cx - t1 * uy, cy + t1 * ux)
        gv1 = g1[:, 1] * ux - g1[:, 0] * uy
        best = np.minimum(best, crest_bound(f1, g1))
        with np.errstate(invalid="ignore", divide="ignore"):
            k = (gv0 - gv1) / t1
        k = np.where(np.isfinite(k) & (k > 0.0), k, curv)
        t2 = np.clip(t1 + gv1 / k, -lim, lim)
        f2, g2 = self._at(cx - t2 * uy, cy + t2 * ux)
        best = np.minimum(best, crest_bound(f2, g2))
        with np.errstate(invalid="ignore"):
            verdict = np.where(best < 1.0, OUT, np.where(8.0 * (best - 1.0) <= curv * self.thin ** 2, THIN, -1))
        state[ok] = verdict
        return state

    def convex_across(self, cx, cy, r, ux, uy, g0, G) -> np.ndarray:
        """Discs where the gradient at ``c + h v`` (``|h| = 0.999 r``, first on the
        side where F falls along v, then on the other) proves ``F_vv > 0``
        somewhere: ``(∇F(c + h v) − ∇F(c))·v`` (h signed) is the integral of
        ``F_vv`` from c to ``c + h v``."""
        vx, vy = -uy, ux
        gv0 = g0[:, 0] * vx + g0[:, 1] * vy
        n0 = np.hypot(g0[:, 0], g0[:, 1])
        h = np.where(gv0 >= 0.0, -0.999 * r, 0.999 * r)
        convex = np.zeros(cx.size, bool)
        todo = np.arange(cx.size)
        for _ in range(2):
            _, g = self._at(cx[todo] + h[todo] * vx[todo], cy[todo] + h[todo] * vy[todo])
            rise = (g[:, 0] * vx[todo] + g[:, 1] * vy[todo] - gv0[todo]) * np.sign(h[todo])
            hit = rise > FIELD_SLACK * (np.hypot(g[:, 0], g[:, 1]) + n0[todo] + 2.0 * G[todo])
            convex[todo[hit]] = True
            todo = todo[~hit]
            h = -h
        return convex

    def _at(self, x: np.ndarray, y: np.ndarray):
        """Field and in-plane gradient at points of the plane, (k,) and (k, 2)."""
        if x.size == 0:
            return np.zeros(0), np.zeros((0, 2))
        f, g = _field(self.skel, np.column_stack([x, y, np.full(x.size, self.z)]), gradient=True)
        self.evaluations += x.size
        return f, g[:, :2]

    def classify(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray, inherited=None, values=None):
        """The states and Taylor data of :meth:`slicer.contours.cells._Bounds.classify`
        (with ``inherited`` bounds or known ``values``: as the levels below the root take them)."""
        if inherited is not None or values is not None:
            return self._judge(cx, cy, r, inherited if inherited is not None else self.disc_bounds(cx, cy, r), values)
        state, kappa, slope, taylor = self._judge(cx, cy, r, self.disc_bounds(cx, cy, r, COARSE_PIECES), values)
        again = np.flatnonzero((state != IN) & (state != OUT))
        if again.size:
            st2, kap2, slo2, tay2 = self._judge(cx[again], cy[again], r[again],
                                                self.disc_bounds(cx[again], cy[again], r[again]),
                                                values=(taylor[0][again], taylor[1][again]))
            state[again], kappa[again], slope[again] = st2, kap2, slo2
            taylor = tuple(_put(a, again, b) for a, b in zip(taylor, tay2))
        return state, kappa, slope, taylor

    def _judge(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray, bounds, values=None):
        """:meth:`classify` with the bounds ``(G, H, U)`` of the discs given."""
        G, H, U = bounds
        # the bound of F over the disc stays below 1 (or no support reaches it): outside, no evaluation
        far = U * (1.0 + FIELD_SLACK) < 1.0
        reach = np.flatnonzero(~far)
        f = np.zeros(cx.size)
        g = np.zeros((cx.size, 3))
        if values is not None:
            f[:] = values[0]
            g[:, :2] = values[1]
        elif reach.size:
            p = np.column_stack([cx[reach], cy[reach], np.full(reach.size, self.z)])
            f[reach], g[reach] = _field(self.skel, p, gradient=True)
            self.evaluations += reach.size
        # the states, the contour's curvature bound |F_tt| / |grad F| <= H / (least
        # |grad_xy F|) and the slope bounds, in one compiled pass (docs/contours.md, step 1)
        g2 = np.ascontiguousarray(g[:, :2])
        state, kappa, slope = judge_cells(f, g2, G, H, far, r, self.tol, FIELD_SLACK)
        return state, kappa, slope, (f, g2, G, H, U)

    @staticmethod
    def settle_children(taylor, r: float, cx: np.ndarray, cy: np.ndarray, centres) -> np.ndarray:
        """IN or OUT (else -1) of child cells from their parent's Taylor data, with no
        evaluation: over the child's disc (radius ``r``, inside the parent's disc of
        radius ``2 r``), ``F(p)`` lies within ``r ‖∇F(c)‖ + H (2 r)² / 2`` of the
        parent's linear model at the child's centre.

        Parameters
        ----------
        taylor : tuple
            The parents' ``(f, grad, G, H, U)`` (:meth:`classify`), one row per parent.
        r : float, mm
            Half diagonal of the children (with its slack).
        cx, cy : (4 p,) float64, mm
            Child centres, four per parent in parent order.
        centres : ((p,) float64, (p,) float64), mm
            The parents' centres.
        """
        f, g, G, H = taylor[:4]
        return settle_from_parent(f, np.ascontiguousarray(g), G, H, float(r), cx, cy, centres, FIELD_SLACK)


def _quadtree(bounds: _Bounds, x0: float, y0: float, s0: float, nx: int, ny: int, levels: int):
    """The leaves of :func:`slicer.contours.cells._quadtree`, level by level in numpy."""
    iy, ix = np.divmod(np.arange(nx * ny, dtype=np.int64), nx)
    out = []
    known = []
    cells = 0
    parent = None
    for lev in range(levels + 1):
        if ix.size == 0:
            break
        s = s0 / 2.0 ** lev
        rr = 0.5 * math.sqrt(2.0) * s * (1.0 + SLACK)
        cx, cy = x0 + (ix + 0.5) * s, y0 + (iy + 0.5) * s
        state = np.full(ix.size, -1, np.int8)
        kappa = np.full(ix.size, np.inf)
        slope = np.zeros((ix.size, 2))
        f = np.full(ix.size, np.nan)
        if parent is not None:            # children proven IN or OUT by their parent's data
            pc, taylor = parent
            state = bounds.settle_children(taylor, rr, cx, cy, pc)
        rest = np.flatnonzero(state < 0)
        # the parent of child j is j // 4 (four children per split cell, in order)
        up = None if parent is None else rest // 4
        # (ix + 0.5) s is (ix unit + unit/2) h exactly (s = unit h, a power of two):
        # a split cell's centre is bit for bit its children's common corner
        inherited = None
        if parent is not None and s <= inherit_side(bounds.tol, s0):
            # small cells: the parent's bounds hold over the child's disc and are
            # nearly as tight there; new ones would cost more than they save
            inherited = tuple(a[up] for a in parent[1][2:])
        # larger cells: first with the parent's bounds; those left unresolved get their own
        # (the centre's value and gradient already known), so split cells carry their own
        if parent is None:                # root cells: the cheap bounds only
            inherited = bounds.disc_bounds(cx, cy, np.full(ix.size, rr), COARSE_PIECES)
        st_r, kap_r, slo_r, taylor = bounds.classify(cx[rest], cy[rest], np.full(rest.size, rr),
                                                     inherited if inherited is not None
                                                     else tuple(a[up] for a in parent[1][2:]))
        if inherited is None and parent is not None:
            again = np.flatnonzero(st_r < 0)
            if again.size:
                st2, kap2, slo2, tay2 = bounds.classify(cx[rest[again]], cy[rest[again]], np.full(again.size, rr),
                                                        None, values=(taylor[0][again], taylor[1][again]))
                st_r[again], kap_r[again], slo_r[again] = st2, kap2, slo2
                taylor = tuple(_put(a, again, b) for a, b in zip(taylor, tay2))
        st_r, corners = _corner_test(bounds, ix[rest], iy[rest], x0, y0, s, rr, st_r, taylor)
        if lev < levels:
            st_r = _crests(bounds, cx[rest], cy[rest], rr, st_r, taylor)
        kappa[rest], slope[rest] = kap_r, slo_r
        state[rest] = st_r
        f[rest] = taylor[0]
        cells += ix.size
        if lev == levels:
            state[state < 0] = SMALL
        done = state >= 0
        unit = 1 << (levels - lev)
        out.append((ix[done] * unit, iy[done] * unit, unit, state[done], kappa[done], slope[done]))
        split = ~done
        if unit >= 2:
            known.append((ix[split] * unit + unit // 2, iy[split] * unit + unit // 2, f[split]))
        # then the corners of the cells that had the corner test, counter-clockwise from (ix, iy)
        tested = np.flatnonzero(~np.isnan(corners[0]))
        cxi, cyi = ix[rest[tested]], iy[rest[tested]]
        kxc = ((cxi[:, None] + np.array([0, 1, 1, 0])) * unit).ravel()
        kyc = ((cyi[:, None] + np.array([0, 0, 1, 1])) * unit).ravel()
        known.append((kxc, kyc, corners[:, tested].T.ravel()))
        # split cells were all classified (settled children are leaves): their Taylor data
        ks = np.flatnonzero(~done[rest])
        parent = ((cx[rest[ks]], cy[rest[ks]]), tuple(a[ks] for a in taylor))
        ix = (2 * ix[split][:, None] + np.array([0, 1, 0, 1])).ravel()
        iy = (2 * iy[split][:, None] + np.array([0, 0, 1, 1])).ravel()
    X0 = np.concatenate([o[0] for o in out])
    Y0 = np.concatenate([o[1] for o in out])
    size = np.concatenate([np.full(o[0].size, o[2], np.int64) for o in out])
    state = np.concatenate([o[3] for o in out])
    kappa = np.concatenate([o[4] for o in out])
    slope = np.concatenate([o[5] for o in out])
    kx = np.concatenate([k[0] for k in known] + [np.zeros(0, np.int64)])
    ky = np.concatenate([k[1] for k in known] + [np.zeros(0, np.int64)])
    kf = np.concatenate([k[2] for k in known] + [np.zeros(0)])
    return X0, Y0, X0 + size, Y0 + size, state, kappa, slope, cells, (kx, ky, kf)


def _corner_test(bounds: _Bounds, ix: np.ndarray, iy: np.ndarray, x0: float, y0: float, s: float, rr: float,
                 state: np.ndarray, taylor):
    """``state`` with the unresolved cells that have one partial derivative
    proven nonzero (and whose centre's linear model forecasts a pass) made ONEDIR where the field at their four corners proves
    no cap hides along their edges (:func:`slicer._kernels.contours.cellstate.clear_cells`),
    and the corner values, (4, c) (NaN where not tested)."""
    f, g, G, H = taylor[:4]
    corners = np.full((4, state.size), np.nan)
    g = np.ascontiguousarray(g)
    try_ = np.flatnonzero((state < 0) & corner_candidates(f, g, G, H, float(rr), float(s), FIELD_SLACK))
    if try_.size == 0:
        return state, corners
    xa, ya = x0 + ix[try_] * s, y0 + iy[try_] * s
    xb, yb = x0 + (ix[try_] + 1) * s, y0 + (iy[try_] + 1) * s
    pts = np.concatenate([np.column_stack([xa, ya]), np.column_stack([xb, ya]), np.column_stack([xb, yb]),
                          np.column_stack([xa, yb])])
    vals = _field(bounds.skel, np.column_stack([pts, np.full(pts.shape[0], bounds.z)]))[0].reshape(4, -1)
    bounds.evaluations += pts.shape[0]
    corners[:, try_] = vals
    out = state.copy()
    ok = clear_cells(np.ascontiguousarray(vals), g[try_], G[try_], H[try_], float(rr), float(s), FIELD_SLACK)
    out[try_[ok]] = ONEDIR
    return out, corners


def _crests(bounds: _Bounds, cx: np.ndarray, cy: np.ndarray, rr: float, state: np.ndarray, taylor) -> np.ndarray:
    """``state`` with the unresolved cells that may hold a critical point of the
    field in the plane (``‖∇_xy F(c)‖ <= r H``: the gradient may vanish in them)
    tried as crest cells (:meth:`_Bounds.ridge`), unless F is proven to exceed
    there what a crest cell allows, ``1 + c thin²/8`` with ``c <= H``: F is at
    least ``F(c) + g t − H t²/2`` a step ``t = min(g/H, r)`` up the gradient."""
    f, g, G, H = taylor[:4]
    try_ = np.flatnonzero(crest_candidates(state, f, np.ascontiguousarray(g), G, H, float(rr), bounds.thin,
                                           FIELD_SLACK, SLACK))
    if try_.size == 0:
        return state
    out = state.copy()
    out[try_] = bounds.ridge(cx[try_], cy[try_], np.full(try_.size, rr), tuple(a[try_] for a in taylor))
    return out


def _put(a: np.ndarray, rows: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A copy of ``a`` with ``a[rows] = b``."""
    out = a.copy()
    out[rows] = b
    return out


def boundary_walks(X0, Y0, X1, Y1):
    """Counter-clockwise walks over the boundaries of leaves, through every
    leaf corner lying on them.

    Returns
    -------
    px, py : (v,) int64
        Unique lattice points (corners of the given leaves).
    leaf : (w,) int64
        Leaf of each walk step (steps grouped by leaf, in walk order).
    point : (w,) int64
        Point index of each step.
    """
    cx = np.concatenate([X0, X1, X1, X0])
    cy = np.concatenate([Y0, Y0, Y1, Y1])
    big = int(max(cx.max(), cy.max())) + 2
    n = X0.size
    # the corners as unique points in (y, x) order, and each corner's point
    keys = cy * big + cx
    order = stable_argsort(keys)
    sk = keys[order]
    first = np.empty(sk.size, bool)
    first[0] = True
    np.not_equal(sk[1:], sk[:-1], out=first[1:])
    uniq = sk[first]
    point_of = np.empty(keys.size, np.int64)
    point_of[order] = np.cumsum(first) - 1
    c_bl, c_br, c_tr, c_tl = (point_of[i * n:(i + 1) * n] for i in range(4))
    py, px = np.divmod(uniq, big)
    # the same points in (x, y) order, and each point's rank there
    ocol = stable_argsort(px * big + py)
    col_rank = np.empty(ocol.size, np.int64)
    col_rank[ocol] = np.arange(ocol.size)
    # the four sides, each a run of interior points in walk order
    # bottom: y = Y0, x from X0 to X1 (increasing); right: x = X1, y increasing;
    # top: y = Y1, x decreasing; left: x = X0, y decreasing. The points strictly
    # inside a side lie between its two corners in row (column) order.
    bs, be = c_bl + 1, c_br
    rs, re = col_rank[c_br] + 1, col_rank[c_tr]
    ts, te = c_tl + 1, c_tr
    ls, le = col_rank[c_bl] + 1, col_rank[c_tl]
    counts = 4 + (be - bs) + (re - rs) + (te - ts) + (le - ls)
    leaf = np.repeat(np.arange(n, dtype=np.int64), counts)
    off = np.concatenate([[0], np.cumsum(counts)[:-1]])
    point = np.empty(leaf.size, np.int64)
    # positions of each piece inside the leaf's run
    pos_bl = off
    pos_b = pos_bl + 1
    pos_br = pos_b + (be - bs)
    pos_r = pos_br + 1
    pos_tr = pos_r + (re - rs)
    pos_t = pos_tr + 1
    pos_tl = pos_t + (te - ts)
    pos_l = pos_tl + 1
    point[pos_bl] = c_bl
    point[pos_br] = c_br
    point[pos_tr] = c_tr
    point[pos_tl] = c_tl

    def fill(pos, s, e, src, reverse):
        m = e - s
        tot = int(m.sum())
        if tot == 0:
            return
        j = np.arange(tot) - np.repeat(np.cumsum(m) - m, m)
        k = np.where(reverse, np.repeat(e, m) - 1 - j, np.repeat(s, m) + j)
        point[np.repeat(pos, m) + j] = src[k]

    row_idx = np.arange(uniq.size)             # rows: sorted order is the point order
    fill(pos_b, bs, be, row_idx, False)
    fill(pos_r, rs, re, ocol, False)
    fill(pos_t, ts, te, row_idx, True)
    fill(pos_l, ls, le, ocol, True)
    return px, py, leaf, point


def pair_crossings(leaf, point, inside, npts: int):
    """Sign changes along the leaves' walks, paired exit -> next entry in each leaf.

    Returns
    -------
    ukey : (e,) int64
        Elementary edges with a crossing, ``inside point * npts + outside point``.
    succ : (e,) int64
        The edge each one's segment leads to.
    exit_leaf : (e,) int64
        Walk-leaf index of the segment leaving each edge.
    """
    a_pt, b_pt = point, point[_next_in_group(leaf)]
    cx_i = np.flatnonzero(inside[a_pt] != inside[b_pt])
    if cx_i.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    exit_ = inside[a_pt[cx_i]]                     # inside -> outside going counter-clockwise
    lf = leaf[cx_i]
    nxt_c = _next_in_group(lf)                     # the partner of an exit: the next crossing
    e_in = np.where(exit_, a_pt[cx_i], b_pt[cx_i])
    e_out = np.where(exit_, b_pt[cx_i], a_pt[cx_i])
    ukey, eid = np.unique(e_in * npts + e_out, return_inverse=True)
    ex = np.flatnonzero(exit_)
    succ = np.full(ukey.size, -1, np.int64)
    succ[eid[ex]] = eid[nxt_c[ex]]
    exit_leaf = np.full(ukey.size, -1, np.int64)
    exit_leaf[eid[ex]] = lf[ex]
    return ukey, succ, exit_leaf


def _next_in_group(group: np.ndarray) -> np.ndarray:
    """Index of the next element of the same (contiguous) group, cyclically."""
    nxt = np.arange(group.size) + 1
    last = np.flatnonzero(np.r_[group[1:] != group[:-1], True])
    nxt[last] = np.r_[0, last[:-1] + 1]
    return nxt
