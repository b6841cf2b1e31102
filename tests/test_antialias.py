"""Anti-aliasing: grey mapping, box filter, supersampled and z-coverage layers.

References: per-pixel loops for the box filter; the strut's known radius
(a long strut of radius r has its surface at distance r) for the 50 %
contour; exact chord lengths for the z coverage; a fake SliceResult for the
averaging of sub-pixel z coverages.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formats.printer_profiles import PrintSettings
from slicer import Skeleton
from slicer.raster.antialias import box_filter, grey_from_coverage, output_grid
from slicer.raster.antialias import output_layers as render
from slicer.errors import GridError
from slicer.tracer.grid import SliceGrid
from slicer.tracer.slicing import slice_skeleton


# ---------------------------------------------------------------- grey mapping
@pytest.mark.parametrize("gamma", [0.3, 0.5, 1.0, 1.7, 2.2, 4.0])
def test_grey_fixed_points(gamma):
    g = grey_from_coverage(np.array([0.0, 0.5, 1.0]), gamma)
    assert g.dtype == np.uint8
    assert g.tolist() == [0, 128, 255]


def test_grey_linear_at_gamma_1():
    c = np.linspace(0, 1, 1001)
    assert np.array_equal(grey_from_coverage(c, 1.0), np.floor(255 * c + 0.5).astype(np.uint8))


@settings(max_examples=300, deadline=None)
@given(st.floats(0, 1), st.floats(0.2, 5.0))
def test_threshold_128_is_half_coverage(c, gamma):
    """A reader thresholding at 128 sees inside exactly where coverage >= 1/2."""
    g = int(grey_from_coverage(np.array([c]), gamma)[0])
    assert (g >= 128) == (c >= 0.5)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0, 1), min_size=2, max_size=30), st.floats(0.2, 5.0))
def test_grey_monotone(cs, gamma):
    c = np.sort(np.array(cs))
    assert np.all(np.diff(grey_from_coverage(c, gamma).astype(int)) >= 0)


def test_gamma_sharpens_edges():
    c = np.array([0.25, 0.75])
    lo, hi = grey_from_coverage(c, 3.0)
    assert lo < 64 and hi > 191            # steeper than linear, symmetric about 128
    assert int(lo) + int(hi) == 255


# ---------------------------------------------------------------- box filter
def _box_reference(sub, n, offset):
    """Slow reference: visit every sub-pixel, add it to its output pixel."""
    H, W = sub.shape
    rows = [(r + offset[0]) // n for r in range(H)]
    cols = [(c + offset[1]) // n for c in range(W)]
    r0, c0 = min(rows), min(cols)
    out = np.zeros((max(rows) - r0 + 1, max(cols) - c0 + 1))
    for r in range(H):
        for c in range(W):
            out[rows[r] - r0, cols[c] - c0] += sub[r, c]
    return out / (n * n), (r0, c0)


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 5), st.integers(1, 12), st.integers(1, 12), st.integers(-20, 20), st.integers(-20, 20),
       st.integers(0, 2**32 - 1))
def test_box_filter_matches_reference(n, H, W, oy, ox, seed):
    sub = np.random.default_rng(seed).random((H, W))
    cov, origin = box_filter(sub, n, (oy, ox))
    ref, ref_origin = _box_reference(sub, n, (oy, ox))
    assert origin == ref_origin
    np.testing.assert_allclose(cov, ref, rtol=0, atol=1e-12)


def test_output_grid_centres_sub_pixels_symmetrically():
    sub = SliceGrid((1.0, 5.0, 0.25), (0.1, 0.05), 0.5, 9, 7, 3)
    out = output_grid(sub, 3)
    assert (out.width, out.height, out.layers) == (3, 3, 3)
    assert out.pixel_size == pytest.approx((0.3, 0.15))
    # output pixel (0, 0) centre = mean of its 3 x 3 sub-pixel centres
    assert out.origin[0] == pytest.approx(np.mean(sub.centres_x()[:3]))
    assert out.origin[1] == pytest.approx(np.mean(sub.centres_y()[:3]))
    assert out.origin[2] == sub.origin[2]


# ---------------------------------------------------------------- real slices
def _strut(r, vertical=True):
    if vertical:
        return Skeleton([[0.013, -0.021, -6.0], [0.013, -0.021, 6.0]], [[0, 1]], [[r, r]])
    return Skeleton([[-6.0, 0.013, 0.007], [6.0, 0.013, 0.007]], [[0, 1]], [[r, r]])


def _middle_layer(res, st_):
    grid, layers = render(res, st_)
    mid = grid.layers // 2
    for k, img in enumerate(layers):
        if k == mid:
            return grid, img
    raise AssertionError("no middle layer")


@pytest.mark.parametrize("n", [4, 8])
def test_vertical_strut_50pct_contour_is_true_radius(n):
    """--aa N: the coverage area and the 50 % crossing give the radius within
    a small fraction of a pixel (measured: 0.004 px at N = 4, 0.0004 px at N = 8)."""
    r, px = 0.5, 0.05
    res = slice_skeleton(_strut(r), px / n, layer_height=0.5, bounds=(-0.8, -0.8, -1, 0.8, 0.8, 1))
    grid, img = _middle_layer(res, PrintSettings(None, 0.5, aa=n))
    assert grid.pixel_size == pytest.approx((px, px))
    cov = img.astype(float) / 255.0
    r_area = math.sqrt(cov.sum() * px * px / math.pi)
    assert abs(r_area - r) < 0.015 * px, (r_area, r)
    # 50 % crossing along the row through the axis, linear interpolation between pixel centres
    xs = grid.centres_x()
    ys = grid.centres_y()
    j = int(np.argmin(abs(ys - (-0.021))))
    row = cov[j]
    i = int(np.argmax(row))
    right = next(t for t in range(i, len(row) - 1) if row[t] >= 0.5 > row[t + 1])
    x_cross = xs[right] + (row[right] - 0.5) / (row[right] - row[right + 1]) * px
    chord = math.sqrt(r * r - (ys[j] + 0.021) ** 2)
    assert abs((x_cross - 0.013) - chord) < 0.15 * px, (x_cross - 0.013, chord)


def test_without_aa_layers_stay_binary():
    res = slice_skeleton(_strut(0.4), 0.05, layer_height=0.5, bounds=(-0.6, -0.6, -1, 0.6, 0.6, 1))
    for st_ in (None, PrintSettings(None, 0.5, exposure=3.0)):
        grid, layers = (res.grid, res.iter_layers()) if st_ is None else render(res, st_)
        vals = set()
        for img in layers:
            vals |= set(np.unique(img).tolist())
        assert vals == {0, 255}


def test_aa_z_sums_to_exact_chord_of_horizontal_strut():
    """Σ_k coverage_k h over a column = inside length of the ray = 2 sqrt(r² - y²)."""
    r, px, h = 0.5, 0.05, 0.1
    res = slice_skeleton(_strut(r, vertical=False), px, layer_height=h, bounds=(-1, -0.7, -0.7, 1, 0.7, 0.7),
                         spans=True)
    grid, layers = render(res, PrintSettings(None, h, aa_z=True))
    total = sum(img.astype(float) / 255.0 for img in layers) * h
    ys = grid.centres_y()
    col = total[:, grid.width // 2]
    chord = 2 * np.sqrt(np.clip(r * r - (ys - 0.013) ** 2, 0, None))
    inner = np.abs(ys - 0.013) < r - 2 * px        # away from the tangent rows
    # each layer's grey is quantised to 1/255 (±0.5/255 per layer)
    np.testing.assert_allclose(col[inner], chord[inner], atol=grid.layers * 0.5 / 255 * h + 1e-3)


# ---------------------------------------------------------------- fake spans
@dataclass
class FakeResult:
    """SliceResult stand-in: fixed per-layer sub-pixel coverages."""

    grid: SliceGrid
    cover: np.ndarray                     # (layers, H, W) float
    pix: np.ndarray = field(default=None)
    k0: np.ndarray = field(default=None)
    k1: np.ndarray = field(default=None)

    def __post_init__(self):
        L, H, W = self.cover.shape
        inside = self.cover >= 0.5
        pix, k0, k1 = [], [], []
        for p in range(H * W):
            col = inside[:, p // W, p % W]
            for k in range(L):
                if col[k] and (k == 0 or not col[k - 1]):
                    e = k
                    while e < L and col[e]:
                        e += 1
                    pix.append(p), k0.append(k), k1.append(e)
        self.pix, self.k0, self.k1 = (np.array(a, np.int64) for a in (pix, k0, k1))

    @property
    def n_runs(self):
        return len(self.pix)

    def iter_layers(self, value=255):
        for c in self.cover:
            yield np.where(c >= 0.5, value, 0).astype(np.uint8)

    def iter_coverage(self):
        yield from self.cover


def test_aa_and_aa_z_average_sub_pixel_z_coverages():
    rng = np.random.default_rng(7)
    n = 2
    cover = rng.random((3, 6, 4))
    fake = FakeResult(SliceGrid((0.0, 0.0, 0.05), (0.025, 0.025), 0.1, 4, 6, 3), cover)
    grid, layers = render(fake, PrintSettings(None, 0.1, aa=n, aa_z=True))
    assert (grid.width, grid.height, grid.layers) == (2, 3, 3)
    for k, img in enumerate(layers):
        expect = cover[k].reshape(3, n, 2, n).mean(axis=(1, 3))
        assert np.array_equal(img, grey_from_coverage(expect))


def test_aa_z_alone_maps_half_coverage_to_128():
    cover = np.array([[[0.0, 0.5, 1.0, 0.25]]])
    fake = FakeResult(SliceGrid((0.0, 0.0, 0.05), (0.05, 0.05), 0.1, 4, 1, 1), cover)
    grid, layers = render(fake, PrintSettings(None, 0.1, aa_z=True, gamma=2.0))
    assert next(iter(layers)).tolist() == [[0, 128, 255, int(grey_from_coverage(np.array([0.25]), 2.0)[0])]]


def test_aa_z_without_spans_is_a_clear_error():
    res = slice_skeleton(_strut(0.4), 0.1, layer_height=0.5, bounds=(-0.6, -0.6, -1, 0.6, 0.6, 1))
    grid, layers = render(res, PrintSettings(None, 0.5, aa_z=True))
    with pytest.raises(GridError, match="spans"):
        next(iter(layers))


# ----------------------------------------------------------------------------- plate images
@settings(deadline=None, max_examples=60)
@given(st.integers(1, 30), st.integers(1, 30), st.data())
def test_a_plate_image_is_scanned_inside_its_window_only_with_the_same_box(H, W, data):
    from formats.rle import occupied
    from slicer.raster.antialias import PlateImage

    r0 = data.draw(st.integers(0, H))
    r1 = data.draw(st.integers(r0, H))
    c0 = data.draw(st.integers(0, W))
    c1 = data.draw(st.integers(c0, W))
    img = PlateImage.blank((H, W))
    if r1 > r0 and c1 > c0:
        rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
        img[r0:r1, c0:c1] = np.where(rng.random((r1 - r0, c1 - c0)) < data.draw(st.floats(0, 1)), 200, 0)
    img.window = (r0, r1, c0, c1)
    assert occupied(img) == occupied(np.asarray(img))
    # what is derived from it knows nothing of the window
    assert img[1:].window is None and img.T.window is None and img.copy().window is None
    assert (img >= 128).window is None


@pytest.mark.parametrize("aa", [1, 2])
def test_plate_layers_know_where_the_model_is(aa):
    from formats.printer_profiles import get_printer
    from formats.rle import occupied

    s = Skeleton([[0, 0, 0], [3, 1, 2]], [[0, 1]], [[0.4, 0.6]])
    prn = get_printer("prusa-sl1s")
    res = slice_skeleton(s, prn.pixel_size[0] / aa, layer_height=0.05)
    grid, layers = render(res, PrintSettings(prn, 0.05, aa=aa))
    seen = 0
    for img in layers:
        r0, r1, c0, c1 = img.window
        plain = np.asarray(img)
        outside = plain.copy()
        outside[r0:r1, c0:c1] = 0
        assert not outside.any()                 # nothing outside the window
        assert occupied(img) == occupied(plain)
        seen += plain.any()
    assert seen > 5


def test_plate_pool_reuses_only_plates_nobody_holds():
    from slicer.raster.antialias import PlatePool, paste

    pool = PlatePool((6, 8), size=2)
    a = pool.take()
    a.window = paste(a, np.full((2, 3), 9, np.uint8), 1, 2)
    view = a[1:3]                                  # a view keeps its plate busy
    b = pool.take()
    assert b is not a and not b.any()
    del view
    kept = a                                       # so does any other reference
    c = pool.take()
    assert c is not a and c is not b
    del kept, a, b
    d = pool.take()                                # released: cleared and handed out again
    assert d.window == (0, 0, 0, 0) and not np.asarray(d).any()
    e = pool.take()
    assert e is not d and not e.any()


def test_plate_layers_held_by_the_caller_stay_intact():
    """A caller that keeps every layer gets distinct plates; one that streams gets
    the same pixels from reused plates."""
    from formats.printer_profiles import get_printer

    s = Skeleton([[0, 0, 0], [3, 1, 2]], [[0, 1]], [[0.4, 0.6]])
    prn = get_printer("prusa-sl1s")
    res = slice_skeleton(s, prn.pixel_size[0], layer_height=0.05)
    kept = list(render(res, PrintSettings(prn, 0.05))[1])
    assert len({id(x) for x in kept}) == len(kept)
    streamed = [np.asarray(x).copy() for x in render(res, PrintSettings(prn, 0.05))[1]]
    assert all(np.array_equal(np.asarray(a), b) for a, b in zip(kept, streamed))
    assert sum(b.any() for b in streamed) > 5
