"""The field on one layer plane (slicer.model.field.plane_footprints, plane_grid,
evaluate_plane) and the cheap-first disc bounds of the contour quadtree.

The plane's support grid lists, per square, only the segments whose support
section can reach it: a point must get the value of :func:`slicer.model.field.evaluate`
to the bit, which holds only if no segment that reaches it is left out.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import quadtree_reference
from sample_lattices import load_sample
from slicer import Skeleton
from slicer._kernels.contours.cellbounds import PIECES, SLACK, disc_bounds
from slicer.contours.cells import COARSE_PIECES, IN, OUT, SIMPLE, _Bounds, _root_grid, plane_segments
from slicer.errors import SceneError
from slicer.model.field import evaluate, evaluate_plane, plane_footprints, plane_grid, segment_table, support_boxes


def _skeleton(rng: np.random.Generator, k: int, flat: bool, degree: int) -> Skeleton:
    """k struts from random nodes, radii 0.05-0.6 mm, tapered or not; with
    ``flat``, the first one lies in a horizontal plane."""
    a = rng.uniform(-2.0, 2.0, (k, 3))
    b = a + rng.normal(size=(k, 3)) * rng.choice([0.05, 1.0, 4.0], size=(k, 1))
    if flat:
        b[0, 2] = a[0, 2]
    r = rng.uniform(0.05, 0.6, (k, 2))
    untapered = rng.random(k) < 0.5
    r[untapered, 1] = r[untapered, 0]
    return Skeleton(np.vstack([a, b]), [[j, k + j] for j in range(k)], r.tolist(), degree=degree)


def _plane_points(skel: Skeleton, z: float, rng: np.random.Generator, k: int) -> np.ndarray:
    lo, hi = support_boxes(skel)
    pad = 0.2 * (hi.max(0) - lo.min(0))
    xy = rng.uniform(lo.min(0)[:2] - pad[:2], hi.max(0)[:2] + pad[:2], (k, 2))
    return np.column_stack([xy, np.full(k, z)])


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.integers(1, 6), st.booleans(), st.sampled_from([4, 6, 8]), st.floats(0.0, 1.0), st.integers(0, 2 ** 16))
def test_a_plane_point_gets_the_field_of_evaluate_to_the_bit(k, flat, degree, where, seed):
    rng = np.random.default_rng(seed)
    skel = _skeleton(rng, k, flat, degree)
    # the plane through a point of the first strut's axis (the plane of that strut
    # when it lies flat), points all over it and around that axis point
    a, b = skel.endpoints()
    q = a[0] + where * (b[0] - a[0])
    z = float(q[2])
    p = _plane_points(skel, z, rng, 3000)
    reach = skel.sigma * skel.radii[0].max()
    p[:500, :2] = q[:2] + rng.uniform(-reach, reach, (500, 2))
    f, g = evaluate(skel, p, gradient=True)
    f2, g2 = evaluate_plane(skel, p, gradient=True)
    assert (f > 0).any()
    assert np.array_equal(f, f2) and np.array_equal(g, g2)
    f3, g3 = evaluate_plane(skel, p)
    assert np.array_equal(f, f3) and g3 is None


@pytest.mark.parametrize("model", ["octet_2x2x2", "microstructure", "jellyfish"])
def test_sample_planes_get_the_field_of_evaluate_and_short_lists(model):
    skel = load_sample(model)
    lo, hi = support_boxes(skel)
    rng = np.random.default_rng(5)
    visited = []
    for z in np.linspace(lo[:, 2].min(), hi[:, 2].max(), 9)[1:-1]:
        p = _plane_points(skel, z, rng, 4000)
        f, g = evaluate(skel, p, gradient=True)
        f2, g2 = evaluate_plane(skel, p, gradient=True)
        assert np.array_equal(f, f2) and np.array_equal(g, g2)
        grid = plane_grid(skel, z)
        near = p[(f > 0.5) & (f < 2.0), :2]
        ix = np.floor((near - grid.origin[:2]) / grid.cell[:2]).astype(np.int64)
        c = ix[:, 1] * grid.dims[0] + ix[:, 0]
        visited.append(grid.offsets[c + 1] - grid.offsets[c])
    # near the surface a point visits a handful of segments, not the plane's hundreds
    assert np.concatenate(visited).mean() < 12


def test_plane_evaluation_refuses_points_off_one_plane():
    skel = Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[0.3, 0.3]])
    with pytest.raises(SceneError, match="one z"):
        evaluate_plane(skel, [[0, 0, 1.0], [0, 0, 1.5]])


@settings(max_examples=55, deadline=None, derandomize=True)
@given(st.integers(1, 4), st.booleans(), st.floats(0.0, 1.0), st.sampled_from([0.0, 1e-3, 0.05, 0.3]),
       st.integers(0, 2 ** 16))
def test_footprints_hold_every_point_a_support_reaches(k, flat, where, reach, seed):
    """Every point of the plane inside a segment's support, or within ``reach`` of
    it (as the disc bounds see it), lies in that segment's footprint. The
    reference samples the axis densely: a point it finds within reach of a
    support ball ``B(q(t), σ τ(t))`` is."""
    rng = np.random.default_rng(seed)
    skel = _skeleton(rng, k, flat, 6)
    lo, hi = support_boxes(skel)
    z = lo[:, 2].min() + where * (hi[:, 2].max() - lo[:, 2].min())
    ids, flo, fhi = plane_footprints(skel, z, reach=1.01 * reach + 1e-6)
    assert np.array_equal(ids, plane_segments(skel, z))
    p = _plane_points(skel, z, rng, 1500)
    a, b = skel.endpoints()
    t = np.linspace(0.0, 1.0, 4001)
    for q, i in enumerate(ids):
        axis = a[i] + t[:, None] * (b[i] - a[i])
        tau = skel.radii[i, 0] + t * (skel.radii[i, 1] - skel.radii[i, 0])
        gap = (np.linalg.norm(p[:, None, :] - axis[None], axis=2) - skel.sigma * tau).min(axis=1)
        near = p[gap < reach]
        inside = ((flo[q, 0] <= near[:, 0]) & (near[:, 0] <= fhi[q, 0])
                  & (flo[q, 1] <= near[:, 1]) & (near[:, 1] <= fhi[q, 1]))
        assert inside.all(), (i, near[~inside][:3])


def test_a_slanted_struts_footprint_is_its_section_not_its_box():
    """A strut rising 45 degrees over 10 mm, radius 0.2 (support radius 0.4):
    cut at mid height, its footprint is about 4 support radii wide in x,
    where its support box is 10.8 mm wide."""
    skel = Skeleton([[0, 0, 0], [10, 0, 10]], [[0, 1]], [[0.2, 0.2]], sigma=2.0)
    ids, lo, hi = plane_footprints(skel, 5.0)
    assert ids.tolist() == [0]
    assert 1.6 <= hi[0, 0] - lo[0, 0] <= 1.6 * (1 + 1e-6)        # 2 R (axis part) + 2 R
    assert hi[0, 1] - lo[0, 1] == pytest.approx(0.8, rel=1e-6)


@pytest.mark.parametrize("z", [2.3, 1.23])
def test_fewer_pieces_give_looser_disc_bounds(z):
    """Near the octet's nodes (z = 2.3, 0.2 mm below a layer of them) the discs'
    support balls reach strut ends and the pieces bound the field: fewer pieces,
    looser bounds. Half-way between the layers of nodes (z = 1.23) every disc is far
    from the ends of the struts the plane cuts, and its bounds are the lines' closed
    form (docs/math.md §10, "Away from the ends") whatever the pieces."""
    skel = load_sample("octet_2x2x2")
    table = segment_table(skel)
    rng = np.random.default_rng(2)
    ids = plane_segments(skel, z)
    lo, hi = support_boxes(skel)
    k = 4000
    cx = rng.uniform(lo[:, 0].min(), hi[:, 0].max(), k)
    cy = rng.uniform(lo[:, 1].min(), hi[:, 1].max(), k)
    r = rng.choice([0.01, 0.1, 0.3], k)
    args = (table, ids, cx, cy, z, r, skel.degree, skel.sigma, skel.normalisation)
    fine = disc_bounds(*args)
    coarse = disc_bounds(*args, COARSE_PIECES)
    assert all(np.array_equal(a, b) for a, b in zip(fine, disc_bounds(*args, PIECES)))
    for f, c in zip(fine, coarse):
        assert (f <= c * (1 + 1e-12)).all()
        if z > 2.0:
            assert (f < 0.9 * c).any()
        else:
            assert np.array_equal(f, c) and (f > 0).sum() > 500


@pytest.mark.parametrize("model, z, div", [("octet_2x2x2", 1.05, 1), ("octet_2x2x2", 0.6, 4), ("octet_2x2x2", 2.9, 1),
                                           ("octet_2x2x2", 2.9, 4), ("jellyfish", None, 1)])
def test_cheap_bounds_first_settle_cells_as_the_full_ones(model, z, div):
    """Cells classified with the cheap bounds first (root cells, ``div = 1``, and
    cells of a quarter of their side, where the cheap bounds would call some
    SIMPLE with a looser curvature) get the states and, where not IN or OUT,
    the curvature, slopes and bounds that the full bounds give them."""
    skel = load_sample(model)
    if z is None:
        lo, hi = support_boxes(skel)
        z = 0.5 * (lo[:, 2].min() + hi[:, 2].max())
    ids = plane_segments(skel, z)
    x0, y0, s0, nx, ny, _ = _root_grid(skel, ids, 1e-3, None)
    bounds = _Bounds(skel, z, ids, 1e-3, (x0, y0, s0, nx, ny))
    ref = quadtree_reference._Bounds(skel, z, ids, 1e-3, (x0, y0, s0, nx, ny))   # whole-array numpy steps
    s = s0 / div
    iy, ix = np.divmod(np.arange(nx * ny * div * div), nx * div)
    cx, cy = x0 + (ix + 0.5) * s, y0 + (iy + 0.5) * s
    r = np.full(cx.size, 0.5 * math.sqrt(2.0) * s * (1.0 + SLACK))
    state, kappa, slope, taylor = bounds.classify(cx, cy, r)
    state2, kappa2, slope2, taylor2 = ref._judge(cx, cy, r, ref.disc_bounds(cx, cy, r))
    assert np.array_equal(state, state2)
    open_ = (state != IN) & (state != OUT)
    assert open_.any() and (state == OUT).any()
    assert np.array_equal(kappa[open_], kappa2[open_]) and np.array_equal(slope[open_], slope2[open_])
    for a, b in zip(taylor, taylor2):
        assert np.array_equal(a[open_], b[open_])
    # the cheap bounds settle cells on their own, and leave some they would call SIMPLE
    cheap = ref._judge(cx, cy, r, ref.disc_bounds(cx, cy, r, COARSE_PIECES))
    assert ((cheap[0] == IN) | (cheap[0] == OUT)).sum() > 0.3 * cx.size
    if div > 1:
        assert ((cheap[0] == SIMPLE) & ~np.isclose(cheap[1], kappa2, rtol=1e-3)).any()


def test_support_boxes_are_computed_once_per_skeleton_and_read_only():
    skel = load_sample("octet_2x2x2")
    lo, hi = support_boxes(skel)
    again = support_boxes(skel)
    assert again[0] is lo and again[1] is hi
    with pytest.raises(ValueError):
        lo[0, 0] = 0.0
    other = Skeleton(skel.nodes.copy(), skel.segments.copy(), skel.radii * 2.0)
    assert (support_boxes(other)[1] - support_boxes(other)[0] > hi - lo).all()
