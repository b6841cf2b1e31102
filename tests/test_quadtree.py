"""The guaranteed contours' quadtree as one compiled call
(slicer._kernels.contours.quadtree) against the whole-array numpy steps it replaced
(tests/quadtree_reference.py): the same leaves, states, bounds, known values
and counts, bit for bit, on planes with and without crest cells, whatever the
thread count."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import quadtree_reference as ref
from sample_lattices import load_sample
from slicer import Skeleton
from slicer._kernels.contours.cellbounds import SLACK
from slicer._kernels.runtime.launch import numba_threads, serial
from slicer.contours import cells
from slicer.contours.cells import THIN_FRACTION, _quadtree, _root_grid, plane_segments
from slicer.model.field import evaluate

#: four struts lying in the plane z = 0 meet a vertical one: planes z = ±0.3 touch them along crests
CROSS = Skeleton([[0, 0, 0], [2, 0, 0], [-2, 0, 0], [0, 2, 0], [0, -2, 0], [0, 0, 1.5]],
                 [[0, 1], [0, 2], [0, 3], [0, 4], [0, 5]], [[0.3, 0.3]] * 4 + [[0.2, 0.2]])

#: the cross with the degree-2 kernel: no second-derivative bound, no crest cell
CROSS2 = Skeleton(CROSS.nodes, CROSS.segments, CROSS.radii, 2)

PLANES = [("octet_2x2x2", 1.03, 1e-3), ("octet_2x2x2", 2.9, 1e-3), ("jellyfish", 12.0, 1e-3),
          ("microstructure", 2.0, 2e-3), ("cross", 0.3, 1e-3), ("cross", 0.1, 1e-2), ("cross2", 0.3, 2e-2),
          ("octet_2x2x2", 1.03, 1e-2)]


def _skel(name):
    return {"cross": CROSS, "cross2": CROSS2}.get(name) or load_sample(name)


def _setup(skel, z, tol, module):
    ids = plane_segments(skel, z)
    x0, y0, s0, nx, ny, levels = _root_grid(skel, ids, tol, None)
    b = module._Bounds(skel, z, ids, tol, (x0, y0, s0, nx, ny), thin=THIN_FRACTION * s0 / 2.0 ** levels)
    return b, (x0, y0, s0, nx, ny, levels)


def _compiled(skel, z, tol):
    b, root = _setup(skel, z, tol, cells)
    out = _quadtree(b, *root)
    return out, b.evaluations


@pytest.mark.parametrize("name, z, tol", PLANES)
def test_the_compiled_quadtree_is_the_numpy_one_bit_for_bit(name, z, tol):
    skel = _skel(name)
    b, root = _setup(skel, z, tol, ref)
    want = ref._quadtree(b, *root)
    got, evaluations = _compiled(skel, z, tol)
    for a, w in zip(got[:7], want[:7]):
        assert a.dtype == w.dtype and np.array_equal(a, w, equal_nan=True)
    assert got[7] == want[7]                                    # cells examined
    for a, w in zip(got[8], want[8]):                           # known centre values
        assert np.array_equal(a, w, equal_nan=True)
    assert evaluations == b.evaluations
    state = got[4]
    if name == "cross" and z == 0.3:
        assert (state == cells.THIN).any()                      # crest cells were tried and settled
    if name == "cross2":                                        # degree 2: no curvature bound at all
        assert not (state == cells.THIN).any() and not (state == cells.SIMPLE).any()
        assert (state == cells.SMALL).any() and (state == cells.OUT).any()
        return
    assert (state == cells.SIMPLE).any() and (state == cells.OUT).any()


@pytest.mark.parametrize("name, z, tol", PLANES[:2] + PLANES[4:5])
def test_the_compiled_quadtree_does_not_depend_on_the_thread_count(name, z, tol):
    skel = _skel(name)
    with serial():
        one, e1 = _compiled(skel, z, tol)
    with numba_threads(2):
        two, e2 = _compiled(skel, z, tol)
    assert e1 == e2 and one[7] == two[7]
    for a, w in zip(one[:7] + tuple(one[8]), two[:7] + tuple(two[8])):
        assert np.array_equal(a, w, equal_nan=True)


def test_classify_and_ridge_of_arbitrary_discs_match_the_numpy_steps():
    """``_Bounds.classify`` and ``_Bounds.ridge`` (the kernels' per-cell
    functions on given discs) against the numpy steps, on the cross's crest plane."""
    skel, z, tol = CROSS, 0.3, 1e-3
    new, _ = _setup(skel, z, tol, cells)
    old, _ = _setup(skel, z, tol, ref)
    rng = np.random.default_rng(5)
    cx = rng.uniform(-2.5, 2.5, 4000)
    cy = np.where(rng.random(4000) < 0.5, rng.uniform(-0.05, 0.05, 4000), rng.uniform(-2.5, 2.5, 4000))
    r = 0.5 * math.sqrt(2.0) * rng.choice([0.004, 0.02, 0.1], 4000) * (1.0 + SLACK)
    a, b = new.classify(cx, cy, r), old.classify(cx, cy, r)
    for x, y in zip(a[:3] + a[3], b[:3] + b[3]):
        assert np.array_equal(x, y, equal_nan=True)
    assert new.evaluations == old.evaluations > 0
    ra, rb = new.ridge(cx, cy, r, a[3]), old.ridge(cx, cy, r, b[3])
    assert np.array_equal(ra, rb)
    assert (ra == cells.THIN).any() and (ra == cells.OUT).any()
    assert new.evaluations == old.evaluations


@pytest.mark.parametrize("name, z", [("cross", 0.3), ("octet_2x2x2", 2.9), ("octet_2x2x2", 1.03)])
def test_the_convexity_pretest_refuses_only_what_the_crest_bound_would(name, z):
    """A crest cell needs ``F_vv`` bounded below 0 over its disc; the gradient at
    ``c ± h v`` proving ``F_vv > 0`` somewhere in it skips the frame bound. Where
    it does, that bound is indeed not negative, so the tree is the one without
    the pre-test; and it leaves the cells whose bound is negative to the test."""
    skel, tol = _skel(name), 1e-3
    b, _ = _setup(skel, z, tol, ref)
    rng = np.random.default_rng(11)
    lo, hi = skel.support_bounds()
    cx = rng.uniform(lo[0], hi[0], 6000)
    cy = rng.uniform(lo[1], hi[1], 6000)
    r = 0.5 * math.sqrt(2.0) * rng.choice([0.004, 0.02, 0.1, 0.2], 6000) * (1.0 + SLACK)
    taylor = b.classify(cx, cy, r)[3]
    near = taylor[4] >= 1.0                     # the field was evaluated at the centre
    cx, cy, r, taylor = cx[near], cy[near], r[near], [a[near] for a in taylor]
    ux, uy, vv = b.ridge_bounds(cx, cy, r)[:3]
    convex = b.convex_across(cx, cy, r, ux, uy, taylor[1], taylor[2])
    assert convex.sum() > 100
    assert np.all(vv[convex] >= 0.0)
    if name == "cross":
        assert (~convex & (vv < 0.0)).sum() > 100


@pytest.mark.parametrize("name, z, tol", PLANES[:3] + PLANES[4:5])
def test_compiled_leaf_walks_are_the_numpy_ones(name, z, tol):
    """The walks over the walked leaves' boundaries (slicer._kernels.contours.chain.leaf_walks)
    against the numpy steps: the same points, in the same order, and the same steps."""
    (X0, Y0, X1, Y1, state, *_), _ = _compiled(_skel(name), z, tol)
    act = np.flatnonzero(state >= cells.SIMPLE)
    got = cells._boundary_walks(X0[act], Y0[act], X1[act], Y1[act])
    want = ref.boundary_walks(X0[act], Y0[act], X1[act], Y1[act])
    for a, w in zip(got, want):
        assert a.dtype == w.dtype and np.array_equal(a, w)
    assert got[2].size > 4 * act.size > 0          # some walks pass corners of smaller neighbours


@pytest.mark.parametrize("name, z, tol", PLANES[:3] + PLANES[4:5])
def test_compiled_crossing_pairs_are_the_numpy_ones(name, z, tol):
    """Crossings along the walks, paired exit -> next crossing
    (slicer._kernels.contours.chain.pair_crossings), against the numpy steps, with
    the field's signs at the walks' points."""
    skel = _skel(name)
    b, (x0, y0, s0, nx, ny, levels) = _setup(skel, z, tol, cells)
    X0, Y0, X1, Y1, state, *_ = _quadtree(b, x0, y0, s0, nx, ny, levels)
    act = np.flatnonzero(state >= cells.SIMPLE)
    px, py, leaf, point = cells._boundary_walks(X0[act], Y0[act], X1[act], Y1[act])
    h = s0 / 2.0 ** levels
    inside = evaluate(skel, np.column_stack([x0 + px * h, y0 + py * h, np.full(px.size, z)]))[0] >= 1.0
    got = cells._pair_crossings(leaf, point, inside, px.size)
    want = ref.pair_crossings(leaf, point, inside, px.size)
    for a, w in zip(got, want):
        assert np.array_equal(a, w)
    assert got[0].size > 0 and (got[1] >= 0).all()
    assert np.array_equal(cells.next_in_group(leaf), ref._next_in_group(leaf))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40), st.floats(-2.0, 3.0)), max_size=60),
       st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40)), min_size=1, max_size=60))
def test_known_values_take_the_first_entry_of_each_point(known, points):
    """The walks' lattice points get the value of the first known entry at
    the same point (repeated points included), NaN where none is known."""
    first: dict = {}
    for x, y, f in known:
        first.setdefault((x, y), f)
    kx, ky, kf = (np.array([k[c] for k in known], dtype) for c, dtype in ((0, np.int64), (1, np.int64), (2, float)))
    px = np.array([p[0] for p in points], np.int64)
    py = np.array([p[1] for p in points], np.int64)
    got = cells._known_values(px, py, kx.reshape(-1), ky.reshape(-1), kf.reshape(-1))
    want = np.array([first.get(p, np.nan) for p in points])
    assert np.array_equal(got, want, equal_nan=True)
