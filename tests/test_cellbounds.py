"""Bounds of the field over discs of a layer plane (slicer._kernels.contours.cellbounds
and slicer._kernels.contours.ridgebounds, docs/math.md §10).

Property: on random segments (tapered or not, short or long, any direction,
alone or meeting others at a node) and random discs of a layer plane near
them, the field sampled on the disc satisfies ``|∇_xy F| <= G``,
``‖∇²_xy F‖ <= H`` (the in-plane Hessian, by central differences of the
closed-form gradient) and ``F <= U``, the in-plane Hessian's eigenvalues lie
in the split Hessian's range ``[−lo, hi]`` (each side checked on its own),
and in the frame ``(u, v)`` of the ridge bounds ``F_vv <= FVV``,
``F_uu <= FUU`` and ``|F_uv| <= FUV``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sample_lattices import load_sample
from slicer import Skeleton
from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.contours.cellbounds import MIN_PIECES, PIECES, curvature_range, disc_bounds, disc_bounds_binned, piece_count
from slicer._kernels.contours import cellbounds as cb
from slicer._kernels.field.points import field_at_points
from slicer._kernels.rays.support import kprime_max
from slicer._kernels.contours.ridgebounds import ridge_bounds, ridge_bounds_binned
from slicer.contours.cells import THIN, _bin_segments, _root_grid, plane_segments
from slicer.model.field import evaluate, point_grid, segment_table, support_boxes

#: step of the central differences, mm; their error (h² times the third
#: derivative, and rounding over h) is far below FD_MARGIN
FD_STEP = 1e-6
FD_MARGIN = 1e-5


def _in_plane(skel: Skeleton, pts: np.ndarray):
    """In-plane gradient norm, in-plane Hessian norm and field at points, (k,) each,
    and the in-plane Hessians, (k, 2, 2)."""
    f, g = evaluate(skel, pts, gradient=True)
    hess = np.zeros((pts.shape[0], 2, 2))
    for j in range(2):
        step = np.zeros(3)
        step[j] = FD_STEP
        gp = evaluate(skel, pts + step, gradient=True)[1]
        gm = evaluate(skel, pts - step, gradient=True)[1]
        hess[:, :, j] = (gp[:, :2] - gm[:, :2]) / (2 * FD_STEP)
    hess = 0.5 * (hess + hess.transpose(0, 2, 1))
    eig = np.linalg.eigvalsh(hess)
    return np.hypot(g[:, 0], g[:, 1]), np.abs(eig).max(axis=1), f, hess


def _disc_points(c: np.ndarray, r: float, rng: np.random.Generator, k: int = 48) -> np.ndarray:
    """Centre, boundary and random points of the disc of centre c and radius r in c's plane."""
    ang = rng.uniform(0, 2 * math.pi, k)
    rad = r * np.sqrt(rng.uniform(0, 1, k))
    rad[: k // 4] = r * (1 - 1e-9)
    pts = np.column_stack([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang), np.full(k, c[2])])
    return np.vstack([c, pts])


def _check(skel: Skeleton, c: np.ndarray, r: float, seed: int):
    table = point_grid(skel)[0]
    ids = np.arange(skel.n_segments, dtype=np.int64)
    G, H, U = disc_bounds(table, ids, np.array([c[0]]), np.array([c[1]]), float(c[2]), np.array([r]),
                          skel.degree, skel.sigma, skel.normalisation)
    pts = _disc_points(c, r, np.random.default_rng(seed))
    gn, hn, f, hess = _in_plane(skel, pts)
    assert gn.max() <= G[0] * (1 + 1e-9) + FD_MARGIN, (gn.max(), G[0])
    assert hn.max() <= H[0] + FD_MARGIN * (1.0 + H[0]), (hn.max(), H[0])
    assert f.max() <= U[0] * (1 + 1e-9), (f.max(), U[0])
    _check_range(skel, table, ids, c, r, hess)
    _check_frame(skel, table, ids, c, r, hess)
    return G[0], H[0], gn.max(), hn.max()


def _check_range(skel, table, ids, c, r, hess):
    """Both sides of the split Hessian against the sampled Hessians' eigenvalues."""
    lo, hi = (a[0] for a in curvature_range(table, ids, np.array([c[0]]), np.array([c[1]]), float(c[2]),
                                            np.array([r]), skel.degree, skel.sigma, skel.normalisation))
    eig = np.linalg.eigvalsh(hess)
    assert eig[:, 0].min() >= -lo - FD_MARGIN * (1.0 + lo), (eig[:, 0].min(), -lo)
    assert eig[:, 1].max() <= hi + FD_MARGIN * (1.0 + abs(hi)), (eig[:, 1].max(), hi)


def _check_frame(skel, table, ids, c, r, hess):
    """The ridge bounds over the disc against the sampled Hessians, in their frame."""
    ux, uy, fvv, fuu, fuv = (a[0] for a in ridge_bounds(table, ids, np.array([c[0]]), np.array([c[1]]), float(c[2]),
                                                         np.array([r]), skel.degree, skel.sigma, skel.normalisation))
    assert abs(math.hypot(ux, uy) - 1.0) < 1e-12
    u, v = np.array([ux, uy]), np.array([-uy, ux])
    dvv = np.einsum("i,kij,j->k", v, hess, v).max()
    duu = np.einsum("i,kij,j->k", u, hess, u).max()
    duv = np.abs(np.einsum("i,kij,j->k", u, hess, v)).max()
    assert dvv <= fvv + FD_MARGIN * (1.0 + abs(fvv)), (dvv, fvv)
    assert duu <= fuu + FD_MARGIN * (1.0 + abs(fuu)), (duu, fuu)
    assert duv <= fuv + FD_MARGIN * (1.0 + fuv), (duv, fuv)


unit = st.floats(-1.0, 1.0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.tuples(unit, unit, unit).filter(lambda v: sum(x * x for x in v) > 0.01),
       st.sampled_from([0.02, 0.3, 1.0, 3.0, 20.0]),          # strut length, mm
       st.floats(0.05, 1.0), st.floats(0.05, 1.0), st.booleans(),  # end radii; tapered or not
       st.floats(0.0, 1.0), st.floats(0.0, 2.5), st.floats(0.0, 2 * math.pi),
       st.sampled_from([1e-4, 0.003, 0.03, 0.3]),              # disc radius, mm
       st.sampled_from([4, 6, 8]), st.integers(0, 2 ** 16))
def test_sampled_slope_curvature_and_value_stay_below_the_disc_bounds(direction, length, r0, r1, tapered, t, off,
                                                                      phi, r, degree, seed):
    if not tapered:
        r1 = r0
    u = np.array(direction) / np.linalg.norm(direction)
    a = np.array([0.1, -0.2, 0.3])
    b = a + length * u
    skel = Skeleton([a, b], [[0, 1]], [[r0, r1]], degree=degree)
    # a disc centre at distance off * tau from the axis point q(t), in the plane through it
    q = a + t * (b - a)
    tau = r0 + t * (r1 - r0)
    side = np.cross(u, [0.0, 0.0, 1.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-6 else np.array([1.0, 0.0, 0.0])
    side2 = np.cross(u, side)
    side2[2] = 0.0
    w = math.cos(phi) * side + math.sin(phi) * side2
    w[2] = 0.0
    w = w / max(np.linalg.norm(w), 1e-12)
    _check(skel, q + off * tau * w, r, seed)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(2, 5), st.floats(0.1, 0.6), st.booleans(), st.floats(0.0, 1.5), st.floats(0.0, 2 * math.pi),
       st.sampled_from([1e-3, 0.02, 0.2]), st.integers(0, 2 ** 16))
def test_bounds_hold_where_struts_meet(k, radius, tapered, off, phi, r, seed):
    rng = np.random.default_rng(seed)
    ends = rng.normal(size=(k, 3))
    ends = 2.0 * ends / np.linalg.norm(ends, axis=1)[:, None]
    nodes = np.vstack([[0.0, 0.0, 0.0], ends])
    segs = [[0, j] for j in range(1, k + 1)]
    radii = [[radius, radius * (rng.uniform(0.5, 1.5) if tapered else 1.0)] for _ in segs]
    skel = Skeleton(nodes, segs, radii)
    c = np.array([off * radius * math.cos(phi), off * radius * math.sin(phi), rng.uniform(-0.5, 0.5) * radius])
    _check(skel, c, r, seed)


def test_bounds_are_close_on_a_strut_surface():
    """A vertical strut of radius 1 cut across, a disc of radius 0.01 on its surface: the true
    in-plane slope and curvature are 7/3. Far from the ends the bounds are the whole line's
    (docs/math.md §10, "Away from the ends"): within 2 % of them. A strut lying in the plane:
    in-plane curvature 1.556 (across it; 0 along it); at 45 degrees, beside the axis, 1.556
    across it and -7/6 along the plane's other direction; in the plane z = 0.5 above a strut
    lying along it, 3/4 of 1.556 less 1/4 of 7/3, about 0.58: within 2 % again. Near the
    ends the pieces bound the field, and their bound follows the in-plane part of the
    Hessian across the axis (docs/math.md §10, "Across the axis"), not the whole of its
    tangential curvature 7/3 (the pieces alone: 2.52)."""
    s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([1.0, 0.0, 0.0]), 0.01, 0)
    assert abs(gn - 7 / 3) < 0.05 and abs(hn - 7 / 3) < 0.05
    assert G <= 1.02 * 7 / 3 and H <= 1.02 * hn
    s = Skeleton([[-5, 0, 0], [5, 0, 0]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([0.0, 1.0, 0.0]), 0.01, 0)
    assert abs(hn - 1.556) < 0.1               # it grows by ~7/mm across the disc
    assert H <= 1.02 * hn
    s = Skeleton([[-5, 0, -5], [5, 0, 5]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([0.0, 1.0, 0.0]), 0.01, 0)
    assert abs(hn - 1.556) < 0.1
    assert H <= 1.02 * hn
    s = Skeleton([[-5, 0, 0], [5, 0, 0]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([0.0, math.sqrt(0.75), 0.5]), 0.01, 0)
    assert abs(hn - 0.583) < 0.1
    assert H <= 1.03 * hn
    # shorter struts: the discs' support balls reach the ends, the pieces bound the field
    s = Skeleton([[-1.2, 0, -1.2], [1.2, 0, 1.2]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([0.0, 1.0, 0.0]), 0.01, 0)
    assert H <= 1.25 * hn
    s = Skeleton([[-1.5, 0, 0], [1.5, 0, 0]], [[0, 1]], [[1.0, 1.0]])
    G, H, gn, hn = _check(s, np.array([0.0, math.sqrt(0.75), 0.5]), 0.01, 0)
    assert H <= 2.1 * hn


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.tuples(unit, unit, unit).filter(lambda v: sum(x * x for x in v) > 0.01),
       st.floats(0.2, 1.0),                                     # radius, mm
       st.floats(0.3, 1.6), st.floats(0.0, 2 * math.pi),        # distance from the axis (radii), angle around it
       st.sampled_from([1e-4, 0.003, 0.03]),                    # disc radius, mm
       st.sampled_from([4, 6, 8]), st.integers(0, 2 ** 16))
def test_split_hessian_holds_on_each_side_beside_a_long_strut(direction, radius, off, phi, r, degree, seed):
    """Beside a long untapered strut, away from its ends, the split Hessian's two
    sides are close to the true extremes (small discs) and must still hold: the
    sampled in-plane Hessians' least and largest eigenvalues lie in ``[−lo, hi]``
    (:func:`_check`)."""
    u = np.array(direction) / np.linalg.norm(direction)
    a = -10.0 * u
    skel = Skeleton([a, -a], [[0, 1]], [[radius, radius]], degree=degree)
    _check(skel, _beside(u, off * radius, phi), r, seed)


def _line_field(skel: Skeleton, rho: float) -> float:
    """The field of a whole line of radius ``skel.radii[0, 0]`` at distance ``rho``
    (docs/math.md §1.3): ``N σ B_m (1 − ρ²/(στ)²)^(m + 1/2)``, B_m by its product."""
    m = skel.degree // 2
    bm = 2.0 * math.prod(2 * k / (2 * k + 1) for k in range(1, m + 1))
    a = max(1.0 - (rho / (skel.sigma * skel.radii[0, 0])) ** 2, 0.0)
    return skel.normalisation * skel.sigma * bm * a ** (m + 0.5)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.tuples(unit, unit, unit).filter(lambda v: sum(x * x for x in v) > 0.01),
       st.floats(0.2, 1.0),                                     # radius, mm
       st.floats(0.0, 1.9), st.floats(0.0, 2 * math.pi),        # distance from the axis (radii), angle around it
       st.sampled_from([1e-4, 0.01, 0.1, 0.4]),                 # disc radius, mm
       st.sampled_from([4, 6, 8]), st.integers(0, 2 ** 16))
def test_line_bounds_hold_and_are_the_lines_away_from_the_ends(direction, radius, off, phi, r, degree, seed):
    """Away from an untapered strut's ends, where no support ball of the disc reaches
    them, the bounds are those of the whole line in closed form (docs/math.md §10,
    "Away from the ends"): they hold at the sampled points (:func:`_check`, discs up
    to 0.4 mm, which hold the turn of the curvature across the axis), and the value
    bound is the line's field at the disc's nearest distance to the axis, to the
    bounds' slack. (The discs stay clear of the support's edge, ``στ`` from the
    axis: for degree 4 the curvature across the axis rises as ``√A`` there, beyond
    what the central differences resolve.)"""
    u = np.array(direction) / np.linalg.norm(direction)
    a = -10.0 * u
    skel = Skeleton([a, -a], [[0, 1]], [[radius, radius]], degree=degree)
    c = _beside(u, off * radius, phi)
    _check(skel, c, r, seed)
    table = point_grid(skel)[0]
    U = disc_bounds(table, np.array([0]), c[:1], c[1:2], float(c[2]), np.array([r]), degree, skel.sigma,
                    skel.normalisation)[2][0]
    near = max(np.linalg.norm(c - np.dot(c, u) * u) - r, 0.0)
    assert U == pytest.approx(_line_field(skel, near), rel=1e-7, abs=1e-8)


def _beside(u: np.ndarray, dist: float, phi: float) -> np.ndarray:
    """The offset ``dist`` from an axis along ``u``, at angle ``phi`` around it."""
    n1 = np.cross(u, [0.0, 0.0, 1.0]) if abs(u[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    n1 = n1 / np.linalg.norm(n1)
    n2 = np.cross(u, n1)
    return dist * (math.cos(phi) * n1 + math.sin(phi) * n2)


@given(st.floats(0.0, 5.0), st.floats(1e-6, 2.0), st.sampled_from([1, 2, 4, 8, 10, 32]))
@settings(max_examples=300, deadline=None)
def test_piece_count_refines_the_cheap_pieces(length, r, pieces):
    """About one piece per disc radius of reach, a multiple of the cheap bounds'
    piece count (so the full pieces refine theirs), never more than asked."""
    k = piece_count(0.25, 0.25 + length, r, pieces)
    if pieces <= MIN_PIECES:
        assert k == pieces
        return
    assert MIN_PIECES <= k <= pieces and (k % MIN_PIECES == 0 or k == pieces)
    assert k * r >= length * (1 - 1e-12) or k == pieces      # pieces no longer than r unless capped
    assert k == MIN_PIECES or (k - MIN_PIECES) * r < length    # and not needlessly many


def test_full_bounds_are_never_looser_than_the_cheap_ones():
    """Over discs of every size on a graded lattice plane, the bounds from the
    adaptive piece count are at most the 4-piece ones (up to their rounding slack)
    and the sampled field stays below them (:func:`_check` covers the latter for
    single discs)."""
    skel = load_sample("bcc_3x3x3_graded")
    table = point_grid(skel)[0]
    lo, hi = skel.support_bounds()
    z = 0.5 * (lo[2] + hi[2]) + 0.013
    ids = plane_segments(skel, z)
    rng = np.random.default_rng(3)
    k = 4000
    cx = lo[0] + rng.random(k) * (hi[0] - lo[0])
    cy = lo[1] + rng.random(k) * (hi[1] - lo[1])
    r = 10.0 ** rng.uniform(-4, 0, k)
    args = (table, ids, cx, cy, z, r, skel.degree, skel.sigma, skel.normalisation)
    full = disc_bounds(*args, PIECES)
    cheap = disc_bounds(*args, MIN_PIECES)
    for f, c in zip(full, cheap):
        assert np.all(f <= c * (1 + 1e-8) + 1e-12)
    # and on large discs the extra pieces do tighten them
    assert np.any((full[0] < cheap[0] * (1 - 1e-6)) & (r > 0.05))


def test_ridge_bounds_see_the_crest_of_a_strut_lying_in_the_plane():
    """The plane through the top of a horizontal strut (radius 0.4): across the strut
    the field is concave (F_vv = −14.58 on the crest), along it constant away from
    its ends. The frame follows the strut, the bound of F_vv stays negative over
    discs up to 0.1 mm and those of F_uu and |F_uv| are rounding-sized (the
    derivatives along an untapered axis are end terms, zero out of their reach);
    near an end they are not."""
    s = Skeleton([[-3, 0, 0], [3, 0, 0]], [[0, 1]], [[0.4, 0.4]])
    table = point_grid(s)[0]
    ids = np.array([0])
    for r, most in ((0.001, -13.0), (0.01, -12.5), (0.1, -3.0)):
        ux, uy, fvv, fuu, fuv = (a[0] for a in ridge_bounds(table, ids, np.array([0.3]), np.array([0.01]), 0.4,
                                                             np.array([r]), s.degree, s.sigma, s.normalisation))
        assert abs(ux) == 1.0 and uy == 0.0
        assert -14.6 < fvv < most, (r, fvv)
        assert 0.0 <= fuu < 1e-6 and 0.0 <= fuv < 1e-6, (r, fuu, fuv)
    _, _, fvv, fuu, fuv = ridge_bounds(table, ids, np.array([2.9]), np.array([0.0]), 0.4, np.array([0.01]),
                                       s.degree, s.sigma, s.normalisation)
    assert fuu[0] > 0.1 and fuv[0] > 0.1


def test_binned_bounds_are_the_bounds_over_every_segment_of_the_plane():
    """Each disc looks only at the segments binned near its centre, and gets the
    bounds of all the plane's segments to the bit (a segment left out could only
    be one whose support cannot reach the disc)."""

    skel = load_sample("bcc_3x3x3_graded")
    table = point_grid(skel)[0]
    lo, hi = skel.support_bounds()
    rng = np.random.default_rng(7)
    for z in np.linspace(lo[2], hi[2], 7)[1:-1]:
        ids = plane_segments(skel, z)
        x0, y0, s0, nx, ny, _ = _root_grid(skel, ids, 1e-3, None)
        bx0, by0, side, bnx, bny, rmax, offsets, lists = _bin_segments(skel, z, x0, y0, s0, nx, ny)
        assert lists.size < ids.size * nx * ny            # the bins do leave segments out
        k = 3000
        cx = x0 + rng.random(k) * nx * s0
        cy = y0 + rng.random(k) * ny * s0
        r = rmax * rng.random(k) ** 3
        args = (z, r, skel.degree, skel.sigma, skel.normalisation)
        want = disc_bounds(table, ids, cx, cy, *args)
        got = disc_bounds_binned(table, (offsets, lists, bx0, by0, side, bnx, bny), cx, cy, *args)
        for a, b in zip(want, got):
            assert np.array_equal(a, b)
        assert (want[0] > 0).any() and (want[0] == 0).any()   # discs both near and far from the struts
        want = ridge_bounds(table, ids, cx, cy, *args)
        got = ridge_bounds_binned(table, (offsets, lists, bx0, by0, side, bnx, bny), cx, cy, *args)
        for a, b in zip(want, got):
            assert np.array_equal(a, b)
        assert len(set(zip(want[0].round(6), want[1].round(6)))) > 2        # frames of several struts


def test_the_field_does_not_depend_on_the_point_grid():
    """A point sums the segments of its cell in segment order, and a segment whose
    support misses it adds exactly 0: any grid gives the same bits."""

    skel = load_sample("octet_2x2x2")
    table = segment_table(skel)
    lo, hi = support_boxes(skel)
    blo, ext = lo.min(0), hi.max(0) - lo.min(0)
    p = blo + ext * np.random.default_rng(3).random((20000, 3))
    out = []
    for n in (1, 3, 8):
        dims = np.array([n, n, n], np.int64)
        off, ids = bin_boxes(lo, hi, np.arange(skel.n_segments, dtype=np.int64), blo, ext / dims, dims)
        out.append(field_at_points(p, table, off, ids, blo, ext / dims, dims, skel.degree // 2,
                                   1.0 / skel.sigma ** 2, skel.normalisation, True))
    assert (out[0][0] > 1.0).any()
    for f, g in out[1:]:
        assert np.array_equal(f, out[0][0]) and np.array_equal(g, out[0][1])


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.floats(0.0, math.pi), st.floats(0.1, 0.6), st.one_of(st.floats(-3e-3, 1e-3), st.floats(-2e-5, 0.0)),
       st.booleans(), st.floats(-1.0, 1.0),
       st.floats(-1.0, 1.0), st.sampled_from([0.002, 0.01, 0.05]), st.sampled_from([1e-4, 1e-3]),
       st.integers(0, 2 ** 16))
def test_crest_cells_hold_what_they_claim(phi, radius, depth, crossing, along, across, r, thin, seed):
    """Discs near the crest of a strut lying in the plane (the plane at ``depth``
    radii from its top; alone, or crossing another strut): a disc the crest test
    calls outside has F < 1 at every sampled point, and one it calls thin meets
    every sampled line across the crest in an inside stretch no longer than
    ``thin`` (plus the sampling step); planes a few 1e-6 radii below the top
    cut stretches about as wide as ``thin``."""
    from slicer.contours.cells import OUT, THIN, _Bounds

    u = np.array([math.cos(phi), math.sin(phi), 0.0])
    v = np.array([-u[1], u[0], 0.0])
    nodes = [-2.0 * u, 2.0 * u]
    segs = [[0, 1]]
    if crossing:                                  # a second strut meets the first at a node
        nodes += [1.2 * u + 1.5 * v + [0, 0, 0.3], 1.2 * u - 1.5 * v - [0, 0, 0.3]]
        segs.append([2, 3])
    skel = Skeleton(nodes, segs, [[radius, radius]] * len(segs))
    z = radius * (1.0 + depth)
    c = along * 1.5 * u + across * r * v
    cx, cy, rr = np.array([c[0]]), np.array([c[1]]), np.array([r])
    b = _Bounds(skel, z, plane_segments(skel, z), 1e-3, thin=thin)
    state, _, _, taylor = b.classify(cx, cy, rr)
    if state[0] >= 0:
        return
    verdict = b.ridge(cx, cy, rr, taylor)[0]
    if verdict < 0:
        return
    ux, uy = ridge_bounds(b.table, b.ids, cx, cy, z, rr, skel.degree, skel.sigma, skel.normalisation)[:2]
    fu, fv = np.array([ux[0], uy[0], 0.0]), np.array([-uy[0], ux[0], 0.0])
    step = thin / 8
    t = np.arange(-r, r + step, step)
    for s in np.random.default_rng(seed).uniform(-r, r, 12):
        half = math.sqrt(max(r * r - s * s, 0.0))
        tt = t[np.abs(t) <= half]
        pts = np.array([c[0], c[1], z]) + s * fu + tt[:, None] * fv
        f = evaluate(skel, pts)[0]
        inside = tt[f >= 1.0]
        if verdict == OUT:
            assert inside.size == 0, (s, f.max())
        else:
            assert verdict == THIN
            assert inside.size == 0 or inside.max() - inside.min() <= thin + 2 * step, (s, inside.min(), inside.max())


@pytest.mark.parametrize("depth, width_um, thin", [(1e-7, 0.49, True), (5e-7, 1.095, False), (1e-6, 1.549, False)])
def test_crest_test_is_sharp_at_its_width(depth, width_um, thin):
    """A strut of radius 0.3 lying in the plane, the plane ``depth`` mm below its top:
    the section is a strip ``width_um`` µm wide (sampled below). With thin = 1 µm,
    discs on the crest are thin when the strip is half of that, and neither thin
    nor outside when it is 1.1 or 1.5 times that."""
    from slicer.contours.cells import _Bounds

    s = Skeleton([[-2, 0, 0], [2, 0, 0]], [[0, 1]], [[0.3, 0.3]])
    z = 0.3 - depth
    y = np.linspace(-5e-3, 5e-3, 100001)
    inside = y[evaluate(s, np.column_stack([np.full(y.size, 0.2), y, np.full(y.size, z)]))[0] >= 1.0]
    assert inside.max() - inside.min() == pytest.approx(width_um * 1e-3, abs=5e-7)
    b = _Bounds(s, z, plane_segments(s, z), 1e-3, thin=1e-3)
    for r in (0.001, 0.01):
        cx, cy, rr = np.array([0.2]), np.array([0.3 * r]), np.array([r])
        state, _, _, taylor = b.classify(cx, cy, rr)
        assert state[0] < 0
        assert b.ridge(cx, cy, rr, taylor)[0] == (THIN if thin else -1)


def _frame_of(u: np.ndarray, a: np.ndarray, p: np.ndarray):
    """The unit vectors ``n_p`` (from the axis line through ``a`` along ``u`` to p) and ``m_p = u × n_p``."""
    w = p - a
    nvec = w - (w @ u) * u
    nvec = nvec / np.linalg.norm(nvec)
    return nvec, np.cross(u, nvec)


def _hessian_3d(skel: Skeleton, p: np.ndarray) -> np.ndarray:
    """The field's 3-D Hessian at p by central differences of the closed-form gradient."""
    hess = np.zeros((3, 3))
    for j in range(3):
        step = np.zeros(3)
        step[j] = FD_STEP
        gp = evaluate(skel, (p + step)[None], gradient=True)[1][0]
        gm = evaluate(skel, (p - step)[None], gradient=True)[1][0]
        hess[:, j] = (gp - gm) / (2 * FD_STEP)
    return 0.5 * (hess + hess.T)


@settings(max_examples=120, deadline=None, derandomize=True)
@given(st.tuples(unit, unit, unit).filter(lambda v: sum(x * x for x in v) > 0.01),
       st.sampled_from([0.3, 1.0, 20.0]),                       # strut length, mm
       st.floats(0.2, 1.0), st.floats(-0.2, 1.2),               # radius; the foot along the strut (fraction)
       st.floats(0.2, 1.6), st.floats(0.0, 2 * math.pi),        # distance from the axis (radii), angle around it
       st.sampled_from([1e-3, 0.03, 0.1]),                      # disc radius, mm
       st.sampled_from([4, 6, 8]), st.integers(0, 2 ** 16))
def test_across_axis_terms_hold_at_sampled_points(direction, length, radius, t, off, phi, r, degree, seed):
    """The terms of an untapered segment behind the bound across its axis
    (docs/math.md §10, "Across the axis"), at points of the disc: its second
    derivative across the axis ``n_pᵀ∇²f n_p`` lies in ``[rl, ru]``, the
    tangential one ``m_pᵀ∇²f m_p = −b`` in ``[−bh, −bl]``, and the plane's
    normal has ``(m_p·ẑ)² >= zm`` and ``(n_p·ẑ)² >= zn``."""
    u = np.array(direction) / np.linalg.norm(direction)
    a = np.array([0.1, -0.2, 0.3])
    skel = Skeleton([a, a + length * u], [[0, 1]], [[radius, radius]], degree=degree)
    seg = point_grid(skel)[0]
    a, u = seg[0, :3], seg[0, 3:6]         # the table orients the segment
    c = a + t * length * u + _beside(u, off * radius, phi)
    ta, tb = cb._reach_interval(seg, 0, c[0], c[1], c[2], r, skel.sigma)
    if not tb > ta:
        return
    k1 = kprime_max(skel.degree, skel.sigma, skel.normalisation)
    k2 = cb.kernel_curvature_max(skel.degree, skel.sigma, skel.normalisation)
    pieces = piece_count(ta, tb, r, PIECES)
    out = cb._piece_bounds(seg, 0, c[0], c[1], c[2], r, ta, tb, skel.degree, skel.sigma, skel.normalisation, k1, k2,
                           pieces, np.empty(cb.disc_work(pieces)))
    bh, bl, ru, rl, zm, zn = out[3], out[4], out[6], out[7], out[8], out[9]
    for p in _disc_points(c, r, np.random.default_rng(seed), k=16):
        nvec, mvec = _frame_of(u, a, p)
        assert mvec[2] ** 2 >= zm - 1e-12 and nvec[2] ** 2 >= zn - 1e-12, (mvec[2] ** 2, zm, nvec[2] ** 2, zn)
        hess = _hessian_3d(skel, p)
        radial, tangential = nvec @ hess @ nvec, mvec @ hess @ mvec
        margin = FD_MARGIN * (1.0 + abs(bh))
        assert rl - margin <= radial <= ru + margin, (rl, radial, ru)
        assert -bh - margin <= tangential <= -bl + margin, (-bh, tangential, -bl)
