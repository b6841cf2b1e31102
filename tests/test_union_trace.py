"""The union blend's tracer against a dense reference: ``max_i f_i`` at every voxel centre.

Every voxel centre must be classified exactly as ``max_i f_i(centre) >= 1``
in the point evaluation of :func:`slicer.model.field.evaluate` (``blend="union"``),
with no tolerance band: both evaluate each strut's own field at the same
point. Scenes: the tracer's stiff cases, high-valence nodes, random struts
(hypothesis). With spans, centre k lies in a span exactly when it is inside,
and span ends lie within ``span_tol`` of a crossing.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import CASES
from slicer import Skeleton
from slicer.errors import OptionError
from slicer.model.field import evaluate
from slicer.tracer.grid import make_grid
from slicer.tracer.slicing import slice_skeleton, trace
from slicer.scale.tileplan import plan_slice
from slicer.scale.tiles import slice_planned
from validation.bulge import node


def dense_union(skel, grid):
    """(layers, height, width) union field at every voxel centre of ``grid``."""
    X, Y, Z = np.meshgrid(grid.centres_x(), grid.centres_y(), grid.centres_z(), indexing="xy")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return evaluate(skel, P, blend="union")[0].reshape(grid.height, grid.width, grid.layers).transpose(2, 0, 1)


def span_volume(res):
    """(layers, height, width) bool: voxel centres lying in some span."""
    g = res.grid
    zc = g.centres_z()
    vol = np.zeros((g.layers, g.height * g.width), bool)
    for p, a, b in zip(res.span_pix, res.span_t0, res.span_t1):
        vol[(zc >= a) & (zc <= b), p] = True
    return vol.reshape(g.layers, g.height, g.width)


def assert_union_exact(skel, grid, **kw):
    res = trace(skel, grid, blend="union", **kw)
    vol = res.volume()
    f = dense_union(skel, grid)
    bad = vol != (f >= 1.0)
    assert not bad.any(), (f"{int(bad.sum())} voxels misclassified, e.g. (k, j, i) = "
                           f"{tuple(int(v) for v in np.argwhere(bad)[0])}, F = {f[tuple(np.argwhere(bad)[0])]!r}")
    if kw.get("spans"):
        assert np.array_equal(span_volume(res), vol)
        _assert_span_ends(skel, res)
    return res, f


def _assert_span_ends(skel, res, most=60):
    """Each span end strictly inside the grid's z range has a sign change of
    F - 1 within span_tol of it (sampled at span_tol / 8)."""
    g = res.grid
    tol = res.stats["span_tol"]
    h = g.layer_height
    zlo, zhi = g.origin[2] - 0.5 * h, g.origin[2] + (g.layers - 0.5) * h
    pick = np.linspace(0, len(res.span_pix) - 1, min(most, len(res.span_pix))).astype(int) if len(res.span_pix) else []
    s = np.linspace(-1.0, 1.0, 17) * tol * (1 + 1e-6)
    for q in pick:
        j, i = divmod(int(res.span_pix[q]), g.width)
        x, y = g.origin[0] + i * g.pixel_size[0], g.origin[1] - j * g.pixel_size[1]
        for t in (res.span_t0[q], res.span_t1[q]):
            if t == zlo or t == zhi:
                continue
            P = np.stack([np.full(s.size, x), np.full(s.size, y), t + s], axis=1)
            inside = evaluate(skel, P, blend="union")[0] >= 1.0
            assert inside.any() and not inside.all(), (q, t, tol)


# ----------------------------------------------------------------------------- exactness
@pytest.mark.parametrize("case", sorted(CASES))
def test_every_voxel_matches_the_dense_union(case):
    skel, px, h = CASES[case]
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    res, f = assert_union_exact(skel, grid, bucket=16)
    if case not in ("lone_short_strut", "thinner_than_pixel"):
        assert res.n_runs > 0


@pytest.mark.parametrize("kw", [{"strict": True}, {"spans": True}, {"bucket": 0}, {"method": "sampling"}])
@pytest.mark.parametrize("case", ["node_26_struts", "cone_ratio_100", "horizontal_on_layer", "vertical_on_column"])
def test_union_variants_are_exact(case, kw):
    skel, px, h = CASES[case]
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    assert_union_exact(skel, grid, **{"bucket": 16, **kw})


@pytest.mark.parametrize("valence, radius", [(12, 0.5), (16, 0.35), (24, 0.25)])
def test_high_valence_node_is_the_union_of_its_struts(valence, radius):
    """Where 12+ struts meet, the sum bulges but the union keeps each strut's
    own surface: every voxel is inside exactly when some strut's field alone
    is >= 1, and the sum has voxels the union has not."""
    skel = node(valence, radius, 2.5)
    bounds = (-2.2, -2.2, -2.2, 2.2, 2.2, 2.2)
    res = slice_skeleton(skel, 0.08, bounds=bounds, blend="union", spans=True)
    g = res.grid
    X, Y, Z = np.meshgrid(g.centres_x(), g.centres_y(), g.centres_z(), indexing="xy")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    per = np.stack([evaluate(Skeleton(skel.nodes, skel.segments[i:i + 1], skel.radii[i:i + 1]), P)[0]
                    for i in range(skel.n_segments)])
    want = (per >= 1.0).any(axis=0).reshape(g.height, g.width, g.layers).transpose(2, 0, 1)
    vol = res.volume()
    assert np.array_equal(vol, want)
    assert np.array_equal(span_volume(res), vol)
    summed = slice_skeleton(skel, 0.08, bounds=bounds).volume()
    assert np.all(summed >= vol) and (summed & ~vol).sum() > 0.002 * vol.sum()


def test_union_costs_fewer_evaluations_than_the_sum_at_a_node():
    skel = node(12, 0.5, 3.0)
    bounds = (-3.5, -3.5, -3.5, 3.5, 3.5, 3.5)
    u = slice_skeleton(skel, 0.1, bounds=bounds, blend="union").stats["evaluations"]
    s = slice_skeleton(skel, 0.1, bounds=bounds).stats["evaluations"]
    assert 0 < u < s


_coord = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
_radius = st.floats(0.08, 0.7, allow_nan=False, allow_infinity=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.tuples(_coord, _coord, _coord), st.tuples(_coord, _coord, _coord), _radius, _radius),
                min_size=1, max_size=7),
       st.sampled_from([0.07, 0.1, 0.13]), st.sampled_from([0.05, 0.1]), st.booleans(), st.sampled_from([0, 4, 16]))
def test_random_scenes_match_the_dense_union(struts, px, h, spans, bucket):
    nodes = np.array([p for a, b, _, _ in struts for p in (a, b)], float)
    if any(np.linalg.norm(nodes[2 * i] - nodes[2 * i + 1]) < 0.05 for i in range(len(struts))):
        return
    segs = np.array([[2 * i, 2 * i + 1] for i in range(len(struts))])
    radii = np.array([[r0, r1] for _, _, r0, r1 in struts], float)
    skel = Skeleton(nodes, segs, radii)
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    assert_union_exact(skel, grid, bucket=bucket, spans=spans)


def test_struts_meeting_inside_leave_no_gap_between_their_spans():
    """Strut 2's field falls through 1 where strut 3's rises through it, about
    15 nm apart, with the union inside all along (found by the random scenes
    above). Each strut's crossing is located to span_tol on its own, so the
    two spans came out 1.8 nm apart and the union reported an end where
    there is no crossing at all."""
    struts = [((0.0, 0.0, 0.0), (0.0, 0.0, 1.5), 0.25, 0.5), ((0.0, 0.0, 0.0), (0.5, -1.0, 0.0), 0.5, 0.5),
              ((1.8801482075701905, 0.0, 0.0), (0.0, 0.0, -1.408322834455154), 0.6675802167766487,
               0.6568080872426902),
              ((-0.8256233981628867, -0.9007436238425501, 0.323424172851587),
               (-0.15234375, 1.8939477541342624, -0.9670933585688279), 0.7, 0.6917508839700575)]
    nodes = np.array([p for a, b, _, _ in struts for p in (a, b)], float)
    skel = Skeleton(nodes, [[2 * i, 2 * i + 1] for i in range(4)], [[r0, r1] for _, _, r0, r1 in struts])
    grid = make_grid(skel.support_bounds(), 0.1, layer_height=0.05)
    res, _ = assert_union_exact(skel, grid, bucket=0, spans=True)
    pix = 30 * grid.width + 25
    mine = [(a, b) for p, a, b in zip(res.span_pix, res.span_t0, res.span_t1) if p == pix]
    assert len(mine) == 1 and mine[0][0] < -1.48 and mine[0][1] > 0.05, mine


def test_span_merge_closes_only_centre_free_gaps_below_the_limit():
    """``merge_spans``: overlapping spans join; a gap narrower than the limit
    joins only when no voxel centre lies in it; wider gaps stay."""
    from slicer._kernels.trace.union import merge_spans
    z0, h = 0.0, 0.1
    # spans (0.02, 0.151), (0.1512, 0.3): gap 2e-4 without a centre -> joined
    xs = np.array([0.1512, 0.3, 0.02, 0.151])
    assert merge_spans(xs, 4, 1e-3, z0, h) == 2 and tuple(xs[:2]) == (0.02, 0.3)
    # the same gap around the centre 0.2 -> kept
    xs = np.array([0.2001, 0.3, 0.02, 0.1999])
    assert merge_spans(xs, 4, 1e-3, z0, h) == 4 and tuple(xs[:4]) == (0.02, 0.1999, 0.2001, 0.3)
    # a centre exactly at a span's end belongs to the span, not to the gap
    xs = np.array([0.02, 0.2, 0.2004, 0.3])
    assert merge_spans(xs, 4, 1e-3, z0, h) == 2
    # a centre-free gap as wide as the limit -> kept; overlap -> joined
    xs = np.array([0.02, 0.151, 0.152, 0.17, 0.16, 0.18])
    assert merge_spans(xs, 6, 1e-3, z0, h) == 4 and tuple(xs[:4]) == (0.02, 0.151, 0.152, 0.18)


@pytest.mark.parametrize("seed", range(4))
def test_union_of_one_strut_equals_sum(seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1, 1, 3)
    s = Skeleton([a, a + rng.uniform(-3, 3, 3)], [[0, 1]], [rng.uniform(0.1, 0.8, 2)])
    for kw in ({}, {"spans": True}):
        u = slice_skeleton(s, 0.06, blend="union", **kw)
        v = slice_skeleton(s, 0.06, **kw)
        assert u.grid == v.grid and np.array_equal(u.volume(), v.volume())


# ----------------------------------------------------------------------------- determinism
def _layers(res):
    return np.stack(list(res.iter_layers()))


def _coverage(res):
    return np.stack(list(res.iter_coverage()))


def test_threads_buckets_tiles_slabs_and_executors_agree():
    """Layers are byte-identical whatever the threads, buckets, tiles, slabs and
    executor; span ends and coverage agree to 1e-9 (tile origins are rounded
    once more than the plate's, as for the sum)."""
    rng = np.random.default_rng(3)
    nodes = rng.uniform(0, 4, (12, 3))
    segs = np.array([[i, (i + 1) % 12] for i in range(12)] + [[i, (i + 5) % 12] for i in range(0, 12, 3)])
    skel = Skeleton(nodes, segs, rng.uniform(0.15, 0.45, (len(segs), 2)))
    # explicit bounds: a trimmed job with several slabs trims on the runs only, the in-memory one on the spans too
    args = (skel, 0.08, None, 0.07, tuple(skel.support_bounds().ravel()))
    ref = slice_skeleton(*args, blend="union", spans=True, threads=1)
    lay, cov = _layers(ref), _coverage(ref)
    assert lay.any()
    for kw in ({"threads": 2}, {"bucket": 8}, {"bucket": 0}):
        res = slice_skeleton(*args, blend="union", spans=True, **kw)
        assert np.array_equal(res.span_pix, ref.span_pix) and np.array_equal(res.span_t0, ref.span_t0)
        assert np.array_equal(_layers(res), lay), kw
    for tile, slab, run in ((16, None, {}), (24, 9, {}), (32, None, {"executor": "threads", "workers": 2}),
                            (32, 20, {"executor": "processes", "workers": 2})):
        plan = plan_slice(*args, spans=True, blend="union", tile=tile, slab=slab)
        assert slab is None or plan.n_slabs > 1
        res = slice_planned(*args, spans=True, blend="union", progress=False, plan=plan, **run)
        assert np.array_equal(_layers(res), lay), (tile, slab, run)
        res = slice_planned(*args, spans=True, blend="union", progress=False, plan=plan, **run)
        assert np.allclose(_coverage(res), cov, rtol=0, atol=1e-9), (tile, slab, run)


def test_segment_method_refused_for_union():
    skel = node(12, 0.5, 3.0)
    with pytest.raises(OptionError, match="--blend union.*--method segment.*--method interval"):
        slice_skeleton(skel, 0.1, method="segment", blend="union")
