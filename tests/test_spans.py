"""Real-valued inside spans along each pixel column (interval tracer, ``spans=True``).

References: a dense march of the field along the same rays (step a quarter
of the span tolerance), and the field on both sides of every span end.
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers import CASES, _node26
from slicer import Skeleton
from slicer.errors import GridError
from slicer.tracer.grid import make_grid
from slicer.tracer.slicing import slice_skeleton, trace, trim

SPAN_CASES = ["vertical_on_column", "horizontal_on_layer", "near_constant_taper", "cone_ratio_100",
              "thinner_than_pixel", "offset_5000mm", "node_26_struts"]


def _column(grid, pix, zs):
    j, i = divmod(int(pix), grid.width)
    x = grid.origin[0] + i * grid.pixel_size[0]
    y = grid.origin[1] - j * grid.pixel_size[1]
    return np.stack([np.full_like(zs, x), np.full_like(zs, y), zs], 1)


def _ray_spans(res, pix):
    m = res.span_pix == pix
    return res.span_t0[m], res.span_t1[m]


def _dense_spans(skel, grid, pix, step):
    """Inside intervals of a column by marching at ``step``: (starts, ends, step)."""
    h = grid.layer_height
    zlo = grid.origin[2] - 0.5 * h
    zhi = grid.origin[2] + (grid.layers - 0.5) * h
    zs = np.arange(zlo, zhi + step, step)
    zs[-1] = min(zs[-1], zhi)
    ins = skel.field(_column(grid, pix, zs)) >= 1.0
    d = np.diff(np.concatenate([[False], ins, [False]]).astype(np.int8))
    a = np.nonzero(d == 1)[0]
    b = np.nonzero(d == -1)[0] - 1
    return zs[a], zs[b]


@pytest.mark.parametrize("case", SPAN_CASES)
def test_spans_match_a_dense_march_and_the_voxel_classes(case):
    skel, px, h = CASES[case]
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    tol = h / 16
    res = trace(skel, grid, bucket=16, spans=True, span_tol=tol)
    # spans do not change the voxel classification
    plain = trace(skel, grid, bucket=16)
    assert np.array_equal(res.pix, plain.pix) and np.array_equal(res.k0, plain.k0)
    assert np.array_equal(res.k1, plain.k1)
    if case != "thinner_than_pixel":
        assert len(res.span_pix) > 0
    # a voxel centre is inside iff it lies in a span of its pixel
    vol = res.volume().reshape(grid.layers, -1)
    zc = grid.centres_z()
    for p in np.unique(np.concatenate([res.pix, res.span_pix])):
        t0, t1 = _ray_spans(res, p)
        assert np.all(t1 > t0) and np.all(t0[1:] > t1[:-1])       # sorted, disjoint
        inside = ((zc[:, None] >= t0[None]) & (zc[:, None] <= t1[None])).any(1)
        assert np.array_equal(inside, vol[:, p]), p
    # each end is within tol of a crossing: the class changes across [t - tol, t + tol]
    zlo = grid.origin[2] - 0.5 * h
    zhi = grid.origin[2] + (grid.layers - 0.5) * h
    for ends, sign in ((res.span_t0, 1), (res.span_t1, -1)):
        free = (ends > zlo) & (ends < zhi)
        P_lo = np.concatenate([_column(grid, p, np.array([t - sign * tol])) for p, t in
                               zip(res.span_pix[free], ends[free])] or [np.zeros((0, 3))])
        P_hi = np.concatenate([_column(grid, p, np.array([t + sign * tol])) for p, t in
                               zip(res.span_pix[free], ends[free])] or [np.zeros((0, 3))])
        f_out, f_in = skel.field(P_lo), skel.field(P_hi)
        assert np.all(f_out < 1 + 1e-9) and np.all(f_in >= 1 - 1e-9)
    # against a dense march on sampled columns: no span wider than 2 tol is missed
    rng = np.random.default_rng(3)
    cols = np.unique(np.concatenate([rng.choice(np.unique(res.span_pix), min(25, len(np.unique(res.span_pix))),
                                                replace=False) if len(res.span_pix) else [],
                                     rng.integers(0, grid.width * grid.height, 10)])).astype(int)
    step = tol / 4
    for p in cols:
        r0, r1 = _dense_spans(skel, grid, p, step)
        t0, t1 = _ray_spans(res, p)
        for a, b in zip(r0, r1):
            if b - a <= 2 * tol:
                continue
            hit = (np.abs(t0 - a) <= tol + step) & (np.abs(t1 - b) <= tol + step)
            assert hit.any(), (case, p, a, b, t0, t1)
        for a, b in zip(t0, t1):
            assert np.any((r0 <= b + tol + step) & (r1 >= a - tol - step)), (case, p, a, b, r0, r1)


def test_thin_feature_between_layer_centres_is_kept_as_a_span():
    """A horizontal strut thinner than a layer, lying between two layer centres:
    no centre is inside (the voxel classes say empty), but its span is found."""
    r = 0.04
    skel = Skeleton([[-1, 0, 0.4], [1, 0, 0.4]], [[0, 1]], [[r, r]])
    res = slice_skeleton(skel, 0.05, layer_height=0.2, bounds=(-1.5, -0.5, 0.0, 1.5, 0.5, 1.0), spans=True)
    zc = res.grid.centres_z()
    assert np.min(np.abs(zc - 0.4)) >= 0.09 and res.n_runs == 0
    assert len(res.span_pix) > 0
    thick = res.span_t1 - res.span_t0
    # the column nearest the axis passes at distance d: chord 2 sqrt(r^2 - d^2) (long strut: the
    # surface is at distance r from the axis, to ~1e-3 r away from the ends)
    d = np.min(np.abs(res.grid.centres_y()))
    assert thick.max() == pytest.approx(2 * np.sqrt(r * r - d * d), abs=2 * 0.2 / 64 + 1e-3)
    cov = np.stack(list(res.iter_coverage()))
    assert cov.max() > 0.1 and cov.sum() * 0.2 == pytest.approx(thick.sum(), rel=1e-12)


def test_coverage_integrates_the_spans_and_is_exact_for_a_vertical_strut():
    """Coverage of a layer = inside length / h; a long vertical strut's column
    through the axis is covered 0 < c < 1 only in its end layers."""
    skel = CASES["vertical_on_column"][0]
    res = slice_skeleton(skel, 0.1, layer_height=0.1, spans=True)
    g = res.grid
    cov = np.stack(list(res.iter_coverage()))
    assert cov.shape == (g.layers, g.height, g.width)
    assert cov.min() >= 0 and cov.max() <= 1
    per_pix = np.bincount(res.span_pix, res.span_t1 - res.span_t0, minlength=g.width * g.height)
    assert np.allclose(cov.sum(0).ravel() * g.layer_height, per_pix, rtol=0, atol=1e-12)
    # voxels whose centre is inside have coverage >= 1/2 when a single crossing cuts them,
    # and full layers are exactly 1
    vol = res.volume()
    assert np.all(cov[vol & (cov < 1)] >= 0.5 - 1e-9)
    j, i = np.argwhere(vol.any(0))[len(np.argwhere(vol.any(0))) // 2]
    col = cov[:, j, i]
    partial = np.nonzero((col > 0) & (col < 1))[0]
    assert len(partial) <= 2 and np.all(col[partial[0] + 1:partial[-1]] == 1.0)


def test_spans_are_identical_for_one_and_two_threads():
    skel = _node26()
    grid = make_grid(skel.support_bounds(), 0.09, layer_height=0.08)
    a = trace(skel, grid, bucket=8, threads=1, spans=True)
    b = trace(skel, grid, bucket=8, threads=2, spans=True)
    for name in ("span_pix", "span_t0", "span_t1", "pix", "k0", "k1"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def test_trim_keeps_spans_and_their_pixels():
    skel = CASES["cone_ratio_100"][0]
    grid = make_grid(skel.support_bounds(), 0.1, layer_height=0.1)
    full = trace(skel, grid, spans=True)
    cut = trim(full)
    assert len(cut.span_pix) == len(full.span_pix)
    assert np.array_equal(cut.span_t0, full.span_t0)
    # same columns in space
    jf, i_f = np.divmod(full.span_pix, grid.width)
    jc, ic = np.divmod(cut.span_pix, cut.grid.width)
    assert np.allclose(grid.origin[0] + i_f * grid.pixel_size[0], cut.grid.origin[0] + ic * grid.pixel_size[0])
    assert np.allclose(grid.origin[1] - jf * grid.pixel_size[1], cut.grid.origin[1] - jc * grid.pixel_size[1])


@pytest.mark.parametrize("kw, msg", [
    ({"method": "sampling", "spans": True}, "need method 'interval'"),
    ({"spans": True, "span_tol": 0.0}, "span tolerance"),
    ({"spans": True, "span_tol": 1.0}, "span tolerance"),
])
def test_bad_span_options_are_refused(kw, msg):
    skel = CASES["vertical_on_column"][0]
    with pytest.raises(GridError, match=msg):
        slice_skeleton(skel, 0.1, **kw)


def test_coverage_without_spans_is_refused():
    res = slice_skeleton(CASES["vertical_on_column"][0], 0.2)
    with pytest.raises(GridError, match="spans=True"):
        next(res.iter_coverage())


def test_a_column_lying_in_the_surface_does_not_explode_into_noise_spans():
    """A pixel column exactly on a constant-radius strut's surface sees F = 1 up
    to rounding along the whole strut: spans must not be refined down to the
    noise (it used to give millions of spans at a small tolerance)."""
    s = Skeleton([[0, 0, 0], [0, 0, 3], [0, 0, 3], [0, 0, 5]], [[0, 1], [2, 3]], [[0.5, 0.5], [0.5, 0.5]])
    g = make_grid(s.support_bounds(), 0.1)
    r = trace(s, g, spans=True, span_tol=g.layer_height / 65536)
    per_pix = np.bincount(r.span_pix)
    assert per_pix.max() <= g.layers + 2
    assert r.stats["evaluations"] < 2_000_000
