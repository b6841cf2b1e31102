"""Guaranteed contours of a layer plane: an adaptive quadtree settled by bounds.

The plane ``z`` is covered by square root cells, which are split (quadtree)
until each leaf is *settled* -- proven all inside or all outside -- or
*simple* -- the field is proven strictly monotone in x and in y over it, so
the section's boundary crosses it as at most one arc, whose ends the corner
signs give -- or *thin* -- on a crest of the field, its section provably
narrower than a quarter of the finest leaves (:meth:`_Bounds.ridge`,
docs/math.md §10.1) -- or the leaf's diagonal is at most the tolerance. The proofs use
the field and its gradient at the cell's centre ``c`` and sound bounds over
the disc of radius ``r`` (half the diagonal) around it
(:mod:`slicer._kernels.contours.cellbounds`, docs/math.md §10): with ``G`` a bound of
the in-plane slope ``‖∇_xy F‖`` and ``H`` of the in-plane Hessian's norm over
the disc,

* ``|F(p) − F(c)| <= min(r G, h (|∂F/∂x(c)| + |∂F/∂y(c)|) + r² H / 2)`` over the
  cell's square (half side ``h = r/√2``; settled when this keeps ``F`` on one side
  of 1; a child is first tried with its parent's ``F(c) + ∇F(c)·d ± H |d|²/2`` at
  its four corners);
* ``|∂F/∂x(p) − ∂F/∂x(c)| <= r H`` (simple when neither partial can vanish).

Every leaf boundary is walked counter-clockwise through all leaf corners on
it (neighbouring leaves may be smaller), each sign change is an *elementary
edge* shared by exactly two leaves, and each exit from the inside is joined to
the next entry, as in marching squares; elementary edges get their vertex by
the bracketed root solve (:func:`slicer.contours.roots.solve_crossings`).
No part of the section wider than the tolerance can hide inside a leaf:
settled leaves hold none of the boundary, simple leaves hold one arc, thin
leaves nothing wider than a quarter of the finest leaves, and the others are
smaller than the tolerance.

Everything is a function of the skeleton, ``z``, the domain and ``tol``: the
result does not depend on pixel size or thread count.
"""
from __future__ import annotations

import math

import numpy as np

from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.contours.cellbounds import PIECES, SLACK
from slicer._kernels.contours.cellstate import IN, ONEDIR, OUT, SIMPLE, SMALL, THIN  # noqa: F401 (the leaf states, re-exported)
from slicer._kernels.contours.chain import chain_rings, known_values, leaf_walks, next_in_group, pair_crossings
from slicer._kernels.raster.counting_sort import DIGIT_BITS
from slicer.compiling import ABOUT, compiling
from slicer._kernels.contours.quadtree import classify_cells, plane_data, quadtree, ridge_cells
from slicer.errors import OptionError
from slicer.model.field import plane_footprints, plane_grid, point_grid, support_boxes
from slicer.model.skeleton import Skeleton
from slicer.contours.roots import FIELD_SLACK, _field, solve_crossings
from slicer.contours.simplify import CHORD_FRACTION
from slicer.constants import TOL_ULPS

#: pieces per segment of the cheap disc bounds tried before the full ones
#: (:meth:`_Bounds.classify`)
COARSE_PIECES = 4

#: cells whose side is at most this many tolerances, or at most
#: ``INHERIT_ROOT_FRACTION`` of a root cell's, take their parent's disc
#: bounds instead of computing their own (:func:`inherit_side`)
INHERIT_BELOW = 16
INHERIT_ROOT_FRACTION = 1.0 / 16.0

#: root cells have this many times the median radius of the plane's struts
ROOT_CELL_RADII = 0.5

#: sagitta of a chord of length l across an arc of curvature <= kappa, l kappa <= 1:
#: at most SAGITTA * l**2 * kappa (1/8 for small angles, 0.134 at l kappa = 1)
SAGITTA = 0.145

#: widest section a THIN cell may hold, as a fraction of the finest leaves' side
#: (the corners of those see most of what is wider than a quarter of their side)
THIN_FRACTION = 0.25



def check_resolvable(skel: Skeleton, tol: float, name: str = "--contour-tol") -> float:
    """Refuse a tolerance that float64 cannot resolve at the scene's coordinates.

    Raises
    ------
    OptionError
        When ``tol`` is below ``TOL_ULPS`` float64 spacings of the largest
        coordinate of the scene's support.
    """
    if skel.n_segments == 0:
        return tol
    lo, hi = support_boxes(skel)
    big = float(max(np.abs(lo).max(), np.abs(hi).max(), 1.0))
    least = TOL_ULPS * float(np.spacing(big))
    if not tol >= least:
        raise OptionError(f"{name} {tol!r} mm is below what float64 resolves at the scene's coordinates "
                          f"(|x| up to {big:.6g} mm): use at least {least:.3g} mm")
    return tol


def plane_segments(skel: Skeleton, z: float) -> np.ndarray:
    """Indices of the segments whose support box meets the plane ``z``, (q,) int64."""
    lo, hi = support_boxes(skel)
    return np.flatnonzero((lo[:, 2] <= z) & (z <= hi[:, 2])).astype(np.int64)


def _bin_segments(skel: Skeleton, z: float, x0: float, y0: float, side: float, nx: int, ny: int):
    """The segments of the plane ``z`` binned on the root grid (``nx x ny`` squares of
    ``side`` from ``(x0, y0)``), each by its support's footprint in the plane grown by
    the largest disc a root cell needs (:func:`slicer.model.field.plane_footprints`), so a
    square's list holds every segment that can reach a disc of radius ``<= rmax``
    centred in it.

    Returns
    -------
    (x0, y0, side, nx, ny, rmax, offsets, lists)
    """
    rmax = 0.5 * math.sqrt(2.0) * side * (1.0 + SLACK)
    # generous: a segment binned where it cannot reach is rejected exactly as
    # without bins, so the bounds are the unbinned ones to the bit
    grow = 1.01 * rmax + 1e-6 * (1.0 + abs(x0) + abs(y0) + side * max(nx, ny))
    ids, flo, fhi = plane_footprints(skel, z, reach=grow)
    blo = np.column_stack([flo, np.zeros(ids.size)])
    bhi = np.column_stack([fhi, np.zeros(ids.size)])
    order = np.arange(ids.size, dtype=np.int64)
    offsets, local = bin_boxes(blo, bhi, order, np.array([x0, y0, -1.0]), np.array([side, side, 2.0]),
                               np.array([nx, ny, 1], np.int64))
    return x0, y0, side, nx, ny, rmax, offsets, ids[local]


class _Bounds:
    """One plane's data for the quadtree kernels (:mod:`slicer._kernels.contours.quadtree`):
    the segment table, the plane's segments binned on the root grid, its point
    grid, and the settings of the cell tests."""

    def __init__(self, skel: Skeleton, z: float, ids: np.ndarray, tol: float, root=None, thin: float | None = None):
        self.skel, self.z, self.ids, self.tol = skel, float(z), ids, float(tol)
        #: widest section a THIN cell may hold, mm
        self.thin = float(tol if thin is None else thin)
        self.table = point_grid(skel)[0]
        self.evaluations = 0
        if root is None:    # one square holding every segment of the plane
            ids64 = np.ascontiguousarray(ids, np.int64)
            bins = (0.0, 0.0, np.inf, 1, 1, np.inf, np.array([0, ids64.size], np.int64), ids64)
        else:
            bins = _bin_segments(skel, self.z, *root)
        self.plane = plane_data(self.table, bins, ids, _grid_tuple(plane_grid(skel, self.z)), self.z,
                                skel.degree, skel.sigma, skel.normalisation)
        self.settings = (self.tol, self.thin, PIECES, COARSE_PIECES, FIELD_SLACK, SLACK)

    def classify(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray):
        """State of each square cell, given by its centre and the radius ``r`` of
        the disc around it (OUT, IN, SIMPLE, ONEDIR or -1: unresolved; IN and
        OUT hold over the square of half side ``r/√2``), (c,) int8,
        a bound of the contour's curvature in it, (c,) float64, 1/mm (inf: none),
        lower bounds of ``|∂F/∂x|`` and ``|∂F/∂y|`` over it, (c, 2) float64,
        1/mm (0: none), and the Taylor data of its centre: the field, (c,)
        float64 (0 where the bound ``U`` already puts the cell outside: not
        evaluated), the in-plane gradient, (c, 2) float64, 1/mm, and the bounds
        ``G``, ``H`` and ``U`` over the disc.

        The discs first get cheap bounds (``COARSE_PIECES`` pieces per
        segment); only those these leave neither IN nor OUT get the full ones.
        The full bounds are at least as tight, so the cells the cheap ones
        settle are those the full ones would settle, in the same state; the
        others get the full bounds' state and data
        (:func:`slicer._kernels.contours.quadtree.classify_at`)."""
        f64 = np.ascontiguousarray
        state, out, ev = classify_cells(self.plane, f64(cx, np.float64), f64(cy, np.float64), f64(r, np.float64),
                                        self.settings)
        self.evaluations += int(ev)
        kappa, sx, sy, f, gx, gy, G, H, U = out
        return state, kappa, np.column_stack([sx, sy]), (f, np.column_stack([gx, gy]), G, H, U)

    def ridge(self, cx: np.ndarray, cy: np.ndarray, r: np.ndarray, taylor) -> np.ndarray:
        """OUT, THIN or -1 (unresolved) of cells on a crest of the field (docs/math.md §10.1).

        With ``u``, ``v`` the frame of :func:`slicer._kernels.contours.ridgebounds.ridge_bounds` and, over the disc,
        ``F_vv <= −c < 0``, ``F_uu <= B_uu``, ``|F_uv| <= B_uv``: from any point
        ``p*`` of the disc, ``F <= M = F(p*) + r |F_u(p*)| + r² max(B_uu, 0)/2 +
        (|F_v(p*)| + r B_uv)²/(2c)`` over the disc (Taylor's remainder along
        ``p − p*``, maximised over the offset along v). ``p*`` is the centre and
        two steps towards the crest along v (Newton with ``c``, then secant), the
        least M kept. ``M < 1``: outside. Otherwise F is strictly concave along
        every line parallel to v, so each meets the section in one interval, no
        longer than ``sqrt(8 (M − 1)/c)`` (its crest is at least ``c l²/8`` above
        its ends): at most ``self.thin`` (``THIN_FRACTION`` of the finest leaves'
        side) makes the cell THIN, a leaf walked like the finest ones: what it
        holds is narrower than what their corners reliably see
        (:func:`slicer._kernels.contours.quadtree.ridge_at`). Before the bounds, the
        gradient at ``c ± 0.999 r v`` may prove ``F_vv > 0`` somewhere in the
        disc (:func:`slicer._kernels.contours.quadtree.convex_across`): no bound could
        then settle the cell, and none is computed.

        Parameters
        ----------
        cx, cy, r : (c,) float64, mm
        taylor : tuple
            ``(f, grad, G, H, U)`` at the centres (:meth:`classify`).
        """
        f64 = np.ascontiguousarray
        state, ev = ridge_cells(self.plane, f64(cx, np.float64), f64(cy, np.float64), f64(r, np.float64),
                                f64(taylor[0]), f64(taylor[1]), f64(taylor[2]), self.thin, FIELD_SLACK)
        self.evaluations += int(ev)
        return state


def _grid_tuple(grid):
    """A point grid as the kernels take it: ``(offsets, ids, origin, cell, dims)``."""
    return grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims


def inherit_side(tol: float, s0: float) -> float:
    """Side (mm) at and below which a cell takes its parent's disc bounds: the
    smaller of ``INHERIT_BELOW`` tolerances and ``INHERIT_ROOT_FRACTION`` of the
    root cells' side ``s0``. Own bounds are tighter the larger the cell is
    against the struts, whatever the tolerance: with the tolerance alone, a
    coarse one (10 um) made every cell below the root take the root's bounds
    (octet at 0.1 mm, 10 um: 2.60 M cells instead of 1.66 M)."""
    return min(INHERIT_BELOW * tol, INHERIT_ROOT_FRACTION * s0)


def _quadtree(bounds: _Bounds, x0: float, y0: float, s0: float, nx: int, ny: int, levels: int):
    """Leaves of the quadtree over ``nx x ny`` root cells of side ``s0``
    (:func:`slicer._kernels.contours.quadtree.quadtree`, one compiled call).

    Root cells get the cheap disc bounds only. Cells no larger than
    :func:`inherit_side` take their parent's disc bounds; larger ones first
    try their parent's, and those left unresolved get their own; split cells
    carry their own Taylor data to their children, which it may settle with
    no evaluation.

    Returns
    -------
    X0, Y0, X1, Y1 : (l,) int64
        Leaf corners on the finest lattice (spacing ``s0 / 2**levels``).
    state : (l,) int8
    kappa : (l,) float64
        Bound of the contour's curvature in each leaf, 1/mm.
    slope : (l, 2) float64
        Lower bounds of ``|∂F/∂x|`` and ``|∂F/∂y|`` over each leaf, 1/mm.
    cells : int
        Cells examined.
    known : ((k,) int64, (k,) int64, (k,) float64)
        Lattice points ``(x, y)`` where the field is known: the centres of
        the split cells (corners of their children), and its values there.
    """
    X0, Y0, size, state, kappa, slope, cells, ev, kx, ky, kf = quadtree(
        bounds.plane, (float(x0), float(y0), float(s0), int(nx), int(ny)), int(levels),
        inherit_side(bounds.tol, s0), bounds.settings)
    bounds.evaluations += int(ev)
    return X0, Y0, X0 + size, Y0 + size, state, kappa, slope, int(cells), (kx, ky, kf)


def _known_values(px, py, kx, ky, kf) -> np.ndarray:
    """Field at lattice points ``(px, py)`` where ``(kx, ky)`` holds it (``kf``), NaN elsewhere
    (:func:`slicer._kernels.contours.chain.known_values`)."""
    f = np.ascontiguousarray
    return known_values(f(px, np.int64), f(py, np.int64), f(kx, np.int64), f(ky, np.int64), f(kf, np.float64))


def _boundary_walks(X0, Y0, X1, Y1):
    """Counter-clockwise walks over the boundaries of leaves, through every
    leaf corner lying on them (:func:`slicer._kernels.contours.chain.leaf_walks`).

    Returns
    -------
    px, py : (v,) int64
        Unique lattice points (corners of the given leaves), in (y, x) order.
    leaf : (w,) int64
        Leaf of each walk step (steps grouped by leaf, in walk order).
    point : (w,) int64
        Point index of each step.
    """
    big = int(max(X1.max(), Y1.max(), X0.max(), Y0.max())) + 2
    passes = max(1, -(-(big * big).bit_length() // DIGIT_BITS))
    f = np.ascontiguousarray
    return leaf_walks(f(X0, np.int64), f(Y0, np.int64), f(X1, np.int64), f(Y1, np.int64), passes)


def guaranteed_rings(skel: Skeleton, z: float, tol: float = 1e-3, stats: dict | None = None,
                     root_cell: float | None = None, certified: list | None = None) -> list[np.ndarray]:
    """Rings of the exact section ``F(x, y, z) >= 1``, every feature wider than ``tol``.

    Parameters
    ----------
    skel : Skeleton
    z : float, mm
    tol : float, mm
        Leaves are split until their diagonal is at most ``tol``; vertices are
        root-solved to ``tol`` along leaf edges.
    stats : dict, optional
        Updated with ``evaluations`` (all field evaluations, points) and
        their split by stage: ``cell_evaluations`` (cell centres, with the
        gradient), ``corner_evaluations`` (leaf corners on the walks) and
        ``root_evaluations`` (root solves of the crossings); ``cells``,
        ``leaves``, ``small_leaves`` (of the finest level), ``thin_leaves``
        (crest cells walked like those), ``vertices``, ``unbracketed``.
    root_cell : float, optional, mm
        Side of the root cells (default: ``ROOT_CELL_RADII`` times the median
        radius of the plane's struts).
    certified : list, optional
        Filled with one (n_q,) bool array per ring: chord ``i -> i + 1`` lies in
        a simple leaf whose curvature bound ``kappa`` proves its arc within
        ``CHORD_FRACTION * tol`` of it: ``SAGITTA * l**2 * kappa <= CHORD_FRACTION * tol``
        and ``l * kappa <= 1`` (an arc of curvature at most kappa, turning less than
        a half turn, is no farther from its chord than the circular arc of curvature
        kappa: ``(1 - sqrt(1 - (l kappa / 2)**2)) / kappa <= 0.134 l**2 kappa``).

    Returns
    -------
    list of (n_q, 2) float64
        Outer rings counter-clockwise, holes clockwise (not yet refined).
    """
    st = {"evaluations": 0, "cell_evaluations": 0, "corner_evaluations": 0, "root_evaluations": 0,
          "cells": 0, "leaves": 0, "small_leaves": 0, "thin_leaves": 0, "vertices": 0, "unbracketed": 0}
    rings = []
    ids = plane_segments(skel, z)
    if ids.size:
        with compiling("the guaranteed contours", [quadtree], ABOUT["contours"]):
            rings = _plane_rings(skel, float(z), tol, ids, root_cell, certified, st)
    if stats is not None:
        for key, v in st.items():
            stats[key] = stats.get(key, 0) + v
    return rings


def _root_grid(skel: Skeleton, ids: np.ndarray, tol: float, root_cell: float | None):
    """Root cells over the support of the plane's segments, one empty cell all around:
    ``(x0, y0, s0, nx, ny, levels)``."""
    lo, hi = support_boxes(skel)
    xlo, ylo = lo[ids, 0].min(), lo[ids, 1].min()
    xhi, yhi = hi[ids, 0].max(), hi[ids, 1].max()
    if root_cell is None:
        root_cell = ROOT_CELL_RADII * float(np.median(skel.radii[ids].mean(axis=1)))
    s0 = float(min(max(root_cell, 4.0 * tol), max(xhi - xlo, yhi - ylo)))
    levels = max(0, int(math.ceil(math.log2(math.sqrt(2.0) * s0 / tol))))
    nx = int(math.ceil((xhi - xlo) / s0)) + 2
    ny = int(math.ceil((yhi - ylo) / s0)) + 2
    return xlo - s0, ylo - s0, s0, nx, ny, levels


def _pair_crossings(leaf, point, inside, npts: int):
    """Sign changes along the leaves' walks, paired exit -> next entry in each leaf
    (:func:`slicer._kernels.contours.chain.pair_crossings`).

    Returns
    -------
    ukey : (e,) int64
        Elementary edges with a crossing, ``inside point * npts + outside point``, ascending.
    succ : (e,) int64
        The edge each one's segment leads to.
    exit_leaf : (e,) int64
        Walk-leaf index of the segment leaving each edge.
    """
    passes = max(1, -(-(int(npts) * int(npts)).bit_length() // DIGIT_BITS))
    return pair_crossings(leaf, point, np.ascontiguousarray(inside, np.bool_), int(npts), passes)


def _plane_rings(skel, z, tol, ids, root_cell, certified, st) -> list[np.ndarray]:
    """:func:`guaranteed_rings` for a plane that some supports meet."""
    x0, y0, s0, nx, ny, levels = _root_grid(skel, ids, tol, root_cell)
    bounds = _Bounds(skel, z, ids, tol, (x0, y0, s0, nx, ny), thin=THIN_FRACTION * s0 / 2.0 ** levels)
    X0, Y0, X1, Y1, state, kappa, slope, cells, known = _quadtree(bounds, x0, y0, s0, nx, ny, levels)
    st["cells"] += cells
    st["leaves"] += X0.size
    st["small_leaves"] += int((state == SMALL).sum())
    st["thin_leaves"] += int((state == THIN).sum())
    st["evaluations"] += bounds.evaluations
    st["cell_evaluations"] += bounds.evaluations
    act = np.flatnonzero(state >= SIMPLE)
    if act.size == 0:
        return []
    px, py, leaf, point = _boundary_walks(X0[act], Y0[act], X1[act], Y1[act])
    h = s0 / 2.0 ** levels
    wx, wy = x0 + px * h, y0 + py * h
    f = _known_values(px, py, *known)
    todo = np.flatnonzero(np.isnan(f))
    f[todo] = _field(skel, np.column_stack([wx[todo], wy[todo], np.full(todo.size, z)]))[0]
    st["evaluations"] += todo.size
    st["corner_evaluations"] += todo.size
    ukey, succ, exit_leaf = _pair_crossings(leaf, point, f >= 1.0, px.size)
    if ukey.size == 0:
        return []
    order, starts, status = chain_rings(succ)
    if status != 0:   # pragma: no cover - every elementary edge borders two walked leaves
        raise RuntimeError("guaranteed contours: crossings do not chain into closed rings")
    ui, uo = np.divmod(ukey, px.size)
    za = np.full(ui.size, z)
    A = np.column_stack([wx[ui], wy[ui], za])
    B = np.column_stack([wx[uo], wy[uo], za])
    # the leaf that walked each elementary edge holds it: its slope bound along the edge
    horizontal = py[ui] == py[uo]
    edge_slope = np.where(horizontal, slope[act[exit_leaf], 0], slope[act[exit_leaf], 1])
    _, tt, ok, ne = solve_crossings(skel, A, B, tol, fa=f[ui], fb=f[uo], slope=edge_slope)
    st["evaluations"] += ne
    st["root_evaluations"] += ne
    st["unbracketed"] += int((~ok).sum())
    tt = np.clip(tt, 1e-6, 1.0 - 1e-6)            # keep vertices off the lattice points: rings stay simple
    verts = (A + tt[:, None] * (B - A))[:, :2]
    st["vertices"] += int(ukey.size)
    rings = [verts[order[starts[q]:starts[q + 1]]] for q in range(starts.size - 1)]
    if certified is not None:
        lk = act[exit_leaf]                        # the leaf each chord crosses
        kq = np.where(state[lk] == SIMPLE, kappa[lk], np.inf)[order]
        ring = np.repeat(np.arange(starts.size - 1), np.diff(starts))
        rv = verts[order]
        step = rv[next_in_group(ring)] - rv        # chord i -> i + 1 of each ring, cyclically
        ell = np.hypot(step[:, 0], step[:, 1])
        with np.errstate(invalid="ignore", over="ignore"):
            ok = (SAGITTA * ell * ell * kq <= CHORD_FRACTION * tol) & (ell * kq <= 1.0)
        certified.extend(ok[starts[q]:starts[q + 1]] for q in range(starts.size - 1))
    return rings


__all__ = ["guaranteed_rings", "check_resolvable", "plane_segments", "FIELD_SLACK", "ROOT_CELL_RADII"]
