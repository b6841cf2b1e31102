"""The compiled root solver, projections and chord refinement against the
whole-array numpy passes they replaced (tests/refine_reference.py): the same
points, flags, rings and evaluation counts, bit for bit."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import refine_reference as ref
from sample_lattices import load_sample
from slicer import Skeleton
from slicer._kernels.contours.refine import insert_after, ring_next
from slicer.contours import guaranteed_rings, layer_mask, mask_rings, refine_rings, solve_crossings
from slicer.contours.roots import plane_distance, project_to_contour
from slicer.model.field import evaluate
from slicer.tracer.slicing import slice_skeleton

TRIPOD = Skeleton([[0, 0, 0], [3, 1, 2], [5, -1, 2], [1, 3, 1]], [[0, 1], [1, 2], [1, 3]],
                  [[0.4, 0.9], [0.9, 0.3], [0.9, 0.5]])


def _segments(skel, n, seed, one_plane):
    """Segments from near the axis outwards in random directions (some
    start outside or end inside: not bracketed)."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.05, 0.95, n)
    a = np.array([0, 0, 0]) + t[:, None] * np.array([3, 1, 2]) + rng.normal(scale=0.3, size=(n, 3))
    d = rng.normal(size=(n, 3))
    if one_plane:
        a[:, 2] = 1.0
        d[:, 2] = 0.0
    d /= np.linalg.norm(d, axis=1)[:, None]
    return a, a + rng.uniform(0.5, 3.0, n)[:, None] * d


@pytest.mark.parametrize("one_plane", [True, False])
@pytest.mark.parametrize("tol", [1e-3, 1e-6])
def test_root_solve_matches_the_batch_solver(one_plane, tol):
    a, b = _segments(TRIPOD, 300, 11, one_plane)
    fa, fb = evaluate(TRIPOD, a)[0], evaluate(TRIPOD, b)[0]
    assert ((fa >= 1) & (fb < 1)).sum() > 50 and ((fa < 1) | (fb >= 1)).sum() > 20
    slope = np.random.default_rng(2).uniform(0, 0.5, a.shape[0])
    for kw in ({}, {"fa": fa}, {"fa": fa, "fb": fb}, {"fa": fa, "fb": fb, "slope": slope}):
        got = solve_crossings(TRIPOD, a, b, tol, **kw)
        want = ref.solve_crossings(TRIPOD, a, b, tol, **kw)
        for g, w in zip(got, want):
            assert np.array_equal(g, w), kw


def test_projection_and_distance_match_the_batch_passes():
    z = 1.0
    rng = np.random.default_rng(4)
    xy = np.column_stack([rng.uniform(0.0, 3.0, 400), rng.uniform(-1.0, 2.0, 400)])
    reach = rng.uniform(0.0, 0.5, 400)
    for r in (None, reach):
        got = project_to_contour(TRIPOD, xy, z, 1e-3, reach=r)
        want = ref.project_to_contour(TRIPOD, xy, z, 1e-3, reach=r)
        assert want[1].sum() > 50 and (~want[1]).sum() > 50
        for g, w in zip(got, want):
            assert np.array_equal(g, w)
    for g, w in zip(plane_distance(TRIPOD, xy, z), ref.plane_distance(TRIPOD, xy, z)):
        assert np.array_equal(g, w)


def _raster_rings(skel, px, k):
    res = slice_skeleton(skel, px)
    g = res.grid
    z = float(g.origin[2] + k * g.layer_height)
    return mask_rings(skel, layer_mask(res, k), g.origin[:2], g.pixel_size, z, refine=False), z


@pytest.mark.parametrize("tol", [1e-2, 1e-3])
def test_refinement_matches_the_batch_rounds(tol):
    """Raster rings (coarse: every round splits) and guaranteed rings with
    their certified chords: the same rings, vertex for vertex, and the same
    counts; the refinement did work."""
    octet = load_sample("octet_2x2x2")
    cases = [(TRIPOD, *_raster_rings(TRIPOD, 0.2, 6), None)]
    cert: list = []
    z = 2.05
    cases.append((octet, guaranteed_rings(octet, z, tol, certified=cert), z, cert))
    for skel, rings, z, certified in cases:
        assert rings
        s_got: dict = {}
        s_want: dict = {}
        got = refine_rings(skel, rings, z, tol, s_got, certified=certified)
        want = ref.refine_rings(skel, rings, z, tol, s_want, certified=certified)
        assert len(got) == len(want)
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
        assert s_got == s_want and s_got["refined"] > 0


def test_refinement_stops_after_max_rounds():
    rings, z = _raster_rings(TRIPOD, 0.2, 6)
    counts = []
    for rounds in (0, 1, 2):
        s_got: dict = {}
        s_want: dict = {}
        got = refine_rings(TRIPOD, rings, z, 1e-4, s_got, max_rounds=rounds)
        want = ref.refine_rings(TRIPOD, rings, z, 1e-4, s_want, max_rounds=rounds)
        assert all(np.array_equal(g, w) for g, w in zip(got, want)) and s_got == s_want
        counts.append(sum(r.shape[0] for r in got))
    assert counts[0] == sum(r.shape[0] for r in rings) < counts[1] < counts[2]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 6), min_size=1, max_size=6), st.data())
def test_ring_successors_and_insertion(sizes, data):
    """``ring_next`` closes every ring on itself; ``insert_after`` puts each new
    vertex right after its owner, in order, in the owner's ring, not done."""
    ring = np.repeat(np.arange(len(sizes), dtype=np.int64), sizes)
    n = ring.size
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    want = np.arange(1, n + 1)
    want[starts + np.array(sizes) - 1] = starts
    assert np.array_equal(ring_next(ring), want)
    owner = np.array(sorted(data.draw(st.lists(st.integers(0, n - 1), max_size=8))), np.int64)
    new = np.column_stack([np.arange(owner.size) + 100.0, -np.arange(owner.size) - 100.0])
    xy = np.column_stack([np.arange(n, dtype=float), np.arange(n, dtype=float)])
    done = np.ones(n, bool)
    oxy, oring, odone = insert_after(xy, ring, done, new, owner)
    expect = []
    for i in range(n):
        expect.append((tuple(xy[i]), ring[i], True))
        expect += [(tuple(new[q]), ring[i], False) for q in np.flatnonzero(owner == i)]
    assert [(tuple(p), r, d) for p, r, d in zip(oxy, oring, odone)] == expect
