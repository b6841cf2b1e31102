"""The compiled cell-state passes against whole-array numpy references.

``slicer._kernels.contours.cellstate`` replaced a few dozen numpy steps each: the
states, curvature and slope bounds must be the same floats, including where
bounds are infinite or NaN (no support, degree 2) and gradients vanish.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slicer._kernels.contours.cellstate import (HALF_SIDE, IN, ONEDIR, OUT, SIMPLE, clear_cells, corner_candidates,
                                       corners_clear, crest_candidates, edge_clear, judge_cells, settle_from_parent)

SLACK = 1e-9


def judge_reference(f, g, G, H, far, r, tol, slack):
    gx, gy = g[:, 0], g[:, 1]
    gn = np.sqrt(gx * gx + gy * gy)      # as grad_norm
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        h = HALF_SIDE * r                               # half the side of the square in the disc
        spread = np.minimum(r * G, h * (np.abs(gx) + np.abs(gy)) + 0.5 * r * r * H)
        spread = np.where(np.isnan(spread), np.inf, spread)
        fs = slack * (1.0 + np.abs(f))
        gs = slack * (gn + G) + r * H
        gs = np.where(np.isnan(gs), np.inf, gs)
        state = np.full(f.size, -1, np.int8)
        state[(f + spread + fs < 1.0) | far] = OUT
        state[f - spread - fs > 1.0] = IN
        mx = np.abs(gx) > gs
        my = np.abs(gy) > gs
        state[(state < 0) & mx & my] = SIMPLE
        gmin = np.maximum(np.abs(gx), np.abs(gy)) - gs
        cap = H * r * r / (4.0 * gmin)
        state[(state < 0) & (mx | my) & (gmin > 0) & (cap <= 0.5 * tol)] = ONEDIR
        glo = gn - gs
        kappa = np.where(glo > 0, H / np.where(glo > 0, glo, 1.0), np.inf)
        slope = np.maximum(np.column_stack([np.abs(gx), np.abs(gy)]) - gs[:, None], 0.0)
    slope[~np.isfinite(slope)] = 0.0
    return state, kappa, slope


def random_cells(seed, k=4000):
    """Cells near the contour (f close to 1, partials of either size) with a
    share of infinite and NaN bounds and zero gradients."""
    rng = np.random.default_rng(seed)
    f = 1.0 + rng.normal(0, 0.05, k) * rng.choice([0.01, 1.0, 10.0], k)
    g = rng.normal(0, 5.0, (k, 2)) * rng.choice([0.0, 0.01, 1.0], (k, 2))
    G = np.abs(rng.normal(0, 10.0, k)) + np.hypot(g[:, 0], g[:, 1])
    H = np.abs(rng.normal(0, 200.0, k))
    r = rng.choice([1e-4, 1e-3, 1e-2, 0.05], k)
    G[rng.random(k) < 0.05] = np.inf
    H[rng.random(k) < 0.05] = np.inf
    H[rng.random(k) < 0.02] = np.nan
    far = rng.random(k) < 0.1
    return f, np.ascontiguousarray(g), G, H, far, r


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_judge_cells_matches_the_numpy_steps(seed):
    f, g, G, H, far, r = random_cells(seed)
    got = judge_cells(f, g, G, H, far, r, 1e-3, SLACK)
    want = judge_reference(f, g, G, H, far, r, 1e-3, SLACK)
    for a, b in zip(got, want):
        assert np.array_equal(a, b)
    # every state occurs, so each branch was compared
    assert set(np.unique(got[0]).tolist()) == {-1, OUT, IN, SIMPLE, ONEDIR}


@pytest.mark.parametrize("seed", [0, 1])
def test_settle_from_parent_matches_the_numpy_steps(seed):
    f, g, G, H, _, _ = random_cells(seed, 1000)
    rng = np.random.default_rng(seed + 10)
    r = 0.01
    pcx, pcy = rng.uniform(-5, 5, f.size), rng.uniform(-5, 5, f.size)
    # four children per parent, in parent order, each within the parent's cell
    cx = np.repeat(pcx, 4) + np.tile([-0.5, 0.5, -0.5, 0.5], f.size) * r
    cy = np.repeat(pcy, 4) + np.tile([-0.5, -0.5, 0.5, 0.5], f.size) * r
    F, Gr, GG, HH = (np.repeat(a, 4, axis=0) for a in (f, g, G, H))
    offset = np.column_stack([cx - np.repeat(pcx, 4), cy - np.repeat(pcy, 4)])
    gn = np.sqrt(Gr[:, 0] * Gr[:, 0] + Gr[:, 1] * Gr[:, 1])
    h = HALF_SIDE * r
    with np.errstate(invalid="ignore", over="ignore"):
        # the parent's quadratic bounds at the child's four corners
        hi = np.full(F.size, -np.inf)
        lo = np.full(F.size, np.inf)
        for sx, sy in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
            ex, ey = offset[:, 0] + sx * h, offset[:, 1] + sy * h
            lin = Gr[:, 0] * ex + Gr[:, 1] * ey
            q = 0.5 * HH * (ex * ex + ey * ey)
            hi = np.maximum(hi, lin + q)
            lo = np.minimum(lo, lin - q)
        slack = SLACK * (1.0 + np.abs(F) + 2.0 * r * (gn + GG))
    want = np.full(F.size, -1, np.int8)
    finite = HH < np.inf
    want[finite & (F + hi + slack < 1.0)] = OUT
    want[finite & (F + lo - slack > 1.0)] = IN
    got = settle_from_parent(f, g, G, H, r, cx, cy, (pcx, pcy), SLACK)
    assert np.array_equal(got, want)
    assert set(np.unique(got).tolist()) == {-1, OUT, IN}


@pytest.mark.parametrize("seed", [0, 1])
def test_crest_candidates_match_the_numpy_steps(seed):
    f, g, G, H, far, r = random_cells(seed)
    state = judge_cells(f, g, G, H, far, r, 1e-3, SLACK)[0]
    rr, thin = 0.01, 2.5e-4
    gn = np.sqrt(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        t = np.minimum(gn / H, rr)
        low = f + gn * t - 0.5 * H * t * t - SLACK * (1.0 + np.abs(f) + rr * (gn + G))
        want = (state < 0) & (gn <= rr * H * (1.0 + 1e-9) + SLACK * (gn + G)) & ~(low > 1.0 + 0.125 * H * thin ** 2)
    got = crest_candidates(state, f, g, G, H, rr, thin, SLACK, 1e-9)
    assert np.array_equal(got, want)
    assert got.any() and not got.all()


# --------------------------------------------------------------------------- IN and OUT over the square
# F(c + d) = f + g.d + d.A.d / 2 with A of norm H: its extremes over a square
# cell are the bounds the cell tests use, so these fields are the hardest ones.
def _square_samples(cx, cy, h, k=41):
    t = np.linspace(-h, h, k)
    return (cx + t[:, None] + 0.0 * t[None, :]).ravel(), (cy + 0.0 * t[:, None] + t[None, :]).ravel()


def _quadratic(f, g, theta, lam, H):
    """``F(d) = f + g.d + d.A.d/2``, A's eigenvalues ``lam H`` (lam in [-1, 1]
    each) along the directions ``theta`` and ``theta + 90°``."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[c, -s], [s, c]])
    A = R @ np.diag(np.asarray(lam) * H) @ R.T

    def F(dx, dy):
        return f + g[0] * dx + g[1] * dy + 0.5 * (A[0, 0] * dx * dx + 2 * A[0, 1] * dx * dy + A[1, 1] * dy * dy)
    return F


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(0.0, 3.2), st.sampled_from([-1.0, -0.3, 0.5, 1.0]),
       st.sampled_from([-1.0, 0.0, 1.0]), st.floats(0.1, 40.0), st.sampled_from([1e-3, 0.05]),
       st.floats(-0.02, 0.02))
def test_in_and_out_hold_over_the_whole_square_cell(gx, gy, theta, l1, l2, H, side, eps):
    """A cell judged OUT (IN) from its centre's Taylor data has F < 1 (> 1) at
    every point of its square, corners included, for every field within the
    curvature bound; and where the field is the bound itself (A = ±H I) and
    clears 1 by more than the evaluation slack, the cell is settled: the
    test is tight at the square's corners, not only sound."""
    h = 0.5 * side
    r = h * np.sqrt(2.0) * (1.0 + 1e-9)
    dx, dy = _square_samples(0.0, 0.0, h)
    for sign in (1.0, -1.0):                 # OUT near the top of F, IN near its bottom
        shape = _quadratic(0.0, (gx, gy), theta, (l1, l2), H)(dx, dy)
        extreme = shape.max() if sign > 0 else shape.min()
        scale = np.abs(shape).max() + 1e-12
        f = 1.0 - extreme + eps * scale
        vals = f + shape
        st_, _, _ = judge_cells(np.array([f]), np.array([[gx, gy]]), np.array([np.inf]), np.array([H]),
                                np.zeros(1, np.bool_), np.array([r]), 1e-3, SLACK)
        if st_[0] == OUT:
            assert vals.max() < 1.0
        if st_[0] == IN:
            assert vals.min() > 1.0
        tight = l1 == l2 == sign and abs(eps) * scale > 1e-6 * (1.0 + abs(f))
        if tight and (vals.max() < 1.0 if sign > 0 else vals.min() > 1.0):
            assert st_[0] == (OUT if sign > 0 else IN)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(0.0, 3.2), st.sampled_from([-1.0, -0.3, 0.5, 1.0]),
       st.sampled_from([-1.0, 0.0, 1.0]), st.floats(0.1, 40.0), st.sampled_from([1e-3, 0.05]),
       st.floats(-0.02, 0.02), st.integers(0, 3))
def test_children_settled_by_their_parent_hold_over_their_squares(gx, gy, theta, l1, l2, H, side, eps, child):
    """:func:`settle_from_parent`: a child (side ``side``, one quarter of its
    parent) settled OUT or IN from the parent's centre data is so at every
    point of its square, for every field within the parent's curvature bound;
    and it is settled where the field is the bound itself and clears 1."""
    h = 0.5 * side
    r = h * np.sqrt(2.0) * (1.0 + 1e-9)
    ox, oy = (h if child & 1 else -h), (h if child & 2 else -h)
    dx, dy = _square_samples(ox, oy, h)
    cx = np.array([-h, h, -h, h])
    cy = np.array([-h, -h, h, h])
    for sign in (1.0, -1.0):
        shape = _quadratic(0.0, (gx, gy), theta, (l1, l2), H)(dx, dy)
        extreme = shape.max() if sign > 0 else shape.min()
        scale = np.abs(shape).max() + 1e-12
        f = 1.0 - extreme + eps * scale
        vals = f + shape
        G = np.hypot(gx, gy) + 2.0 * r * H          # the slope's bound over the parent's disc
        got = settle_from_parent(np.array([f]), np.array([[gx, gy]]), np.array([G]), np.array([H]), r, cx, cy,
                                 (np.zeros(1), np.zeros(1)), SLACK)[child]
        if got == OUT:
            assert vals.max() < 1.0
        if got == IN:
            assert vals.min() > 1.0
        tight = l1 == l2 == sign and abs(eps) * scale > 1e3 * SLACK * (1.0 + abs(f) + 2.0 * r * (np.hypot(gx, gy) + G))
        if tight and (vals.max() < 1.0 if sign > 0 else vals.min() > 1.0):
            assert got == (OUT if sign > 0 else IN)


# --------------------------------------------------------------------------- the corner test
# F along an edge of length s with |F''| <= H: a parabola of curvature alpha H plus a sine of
# curvature at most (1 - |alpha|) H, so every such draw honours the bound the test assumes.
def _edge_function(p, q, alpha, m, amp, w, phase, H, s):
    def phi(x):
        return (p + q * x + 0.5 * alpha * H * (x - m * s) ** 2
                + amp * (1.0 - abs(alpha)) * H / w ** 2 * np.sin(w * x + phase))
    return phi


def _crossings(values):
    """Sign changes of ``values >= 1`` along a dense sampling."""
    inside = values >= 1.0
    return int(np.count_nonzero(inside[1:] != inside[:-1]))


@settings(max_examples=400, deadline=None, derandomize=True)
@given(st.floats(0.9, 1.1), st.floats(-2.0, 2.0), st.floats(-1.0, 1.0), st.floats(-0.5, 1.5), st.floats(0.0, 1.0),
       st.floats(5.0, 400.0), st.floats(0.0, 2 * np.pi), st.floats(1.0, 400.0), st.floats(1e-3, 0.1))
def test_edge_clear_is_sound_on_every_function_within_the_curvature_bound(p, q, alpha, m, amp, w, phase, H, s):
    phi = _edge_function(p, q, alpha, m, amp, w, phase, H, s)
    a, b = phi(0.0), phi(s)
    if edge_clear(a, b, H, s, SLACK):
        # what the edge's ends say is what happens along it: no crossing, or exactly one
        assert _crossings(phi(np.linspace(0.0, s, 4001))) == int((a >= 1.0) != (b >= 1.0))


def test_edge_clear_refuses_the_largest_cap_its_bound_allows_and_accepts_clear_edges():
    H, s = 100.0, 0.02
    bump = H * s * s / 8.0                       # the deepest excursion |F''| <= H allows between the ends
    # a parabola of curvature -H peaking mid-edge just above 1, both ends below: a hidden cap
    for top in (1.0 + 1e-6, 1.0 + 0.5 * bump):
        phi = _edge_function(top, 0.0, -1.0, 0.5, 0.0, 1.0, 0.0, H, s)
        a, b = phi(0.0), phi(s)
        assert a < 1.0 and b < 1.0 and _crossings(phi(np.linspace(0.0, s, 4001))) == 2
        assert not edge_clear(a, b, H, s, SLACK)
    # the same shape a little lower stays below 1: clear, and so are the mirrored (inside) case
    # and a steep line across 1
    assert edge_clear(1.0 - bump - 1e-6, 1.0 - bump - 1e-6, H, s, SLACK)
    assert edge_clear(1.0 + bump + 1e-6, 1.0 + bump + 1e-6, H, s, SLACK)
    assert edge_clear(1.0 - 0.6 * H * s * s, 1.0 + 0.6 * H * s * s, H, s, SLACK)
    # a crossing pair can hide next to a crossing when the ends differ by less than H s^2
    assert not edge_clear(1.0 - 0.4 * H * s * s, 1.0 + 0.4 * H * s * s, H, s, SLACK)
    for bad in (np.inf, np.nan):
        assert not edge_clear(0.5, 0.5, bad, s, SLACK)


def test_corners_clear_checks_the_edges_along_the_direction_that_may_not_be_monotone():
    """F = 1 + g (y - c) + (H/2)(x - s/2)^2 on the cell [0, s]^2: dF/dy = g everywhere
    (``my``), the left and right edges cross 1 once, and the level set is a parabola
    that dips an outside region down through the top edge between two top corners
    that are both inside."""
    H, g, s = 100.0, 5.0, 0.02
    bump = H * s * s / 8.0
    c = s + 0.25 * bump / g                      # the top edge's middle is a quarter bump below 1

    def F(x, y, lift=0.0):
        return 1.0 + g * (y - c) + 0.5 * H * (x - 0.5 * s) ** 2 + lift

    f00, f10, f11, f01 = F(0, 0), F(s, 0), F(s, s), F(0, s)
    x = np.linspace(0.0, s, 4001)
    assert f11 >= 1.0 and f01 >= 1.0 and _crossings(F(x, s)) == 2      # the dip the corners miss
    assert not corners_clear(f00, f10, f11, f01, False, True, H, s, SLACK)
    # told (wrongly) that x is the monotone direction, only the vertical edges would be
    # checked, and they are clear: the direction decides which edges are tested
    assert _crossings(F(0.0, x)) == 1 and _crossings(F(s, x)) == 1
    assert corners_clear(f00, f10, f11, f01, True, False, H, s, SLACK)
    # lifted by two bumps, the top edge lies wholly inside and the cell is clear
    vals = F(0, 0, 2 * bump), F(s, 0, 2 * bump), F(s, s, 2 * bump), F(0, s, 2 * bump)
    assert corners_clear(*vals, False, True, H, s, SLACK)
    assert _crossings(F(x, s, 2 * bump)) == 0 and _crossings(F(x, 0.0, 2 * bump)) == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_corner_candidates_and_clear_cells_are_the_per_cell_tests(seed):
    f, g, G, H, far, r = random_cells(seed, 2000)
    rng = np.random.default_rng(seed + 20)
    rr = 0.01
    s = rr * np.sqrt(2.0)
    cand = corner_candidates(f, g, G, H, rr, s, SLACK)
    corners = np.ascontiguousarray(1.0 + rng.normal(0.0, 0.02, (4, f.size)))
    clear = clear_cells(corners, g, G, H, rr, s, SLACK)
    gn = np.sqrt(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1])
    with np.errstate(invalid="ignore", over="ignore"):
        gs = SLACK * (gn + G) + rr * H
    gs = np.where(np.isnan(gs), np.inf, gs)
    mx, my = np.abs(g[:, 0]) > gs, np.abs(g[:, 1]) > gs
    h = 0.5 * s
    for j in range(f.size):
        fc = (f[j] - g[j, 0] * h - g[j, 1] * h, f[j] + g[j, 0] * h - g[j, 1] * h,
              f[j] + g[j, 0] * h + g[j, 1] * h, f[j] - g[j, 0] * h + g[j, 1] * h)
        want = bool(mx[j] or my[j]) and corners_clear(*fc, mx[j], my[j], H[j], s, 0.0)
        assert cand[j] == want
        assert clear[j] == corners_clear(*corners[:, j], mx[j], my[j], H[j], s, SLACK)
    assert cand.any() and not cand.all() and clear.any() and not clear.all()
