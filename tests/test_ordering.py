"""Linear-time stable orders (slicer.raster.ordering): NumPy's stable sorts are the reference."""
from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from slicer.raster.ordering import layer_events, lexsort2, rect_parts, stable_argsort

# keys spanning one, two and three radix digits, with many ties at the low end
_KEYS = st.one_of(
    arrays(np.int64, st.integers(0, 300), elements=st.integers(0, 7)),
    arrays(np.int64, st.integers(0, 300), elements=st.integers(0, 2**16 + 5)),
    arrays(np.int64, st.integers(0, 300), elements=st.integers(0, 2**40)),
    arrays(np.int64, st.integers(0, 300), elements=st.sampled_from([0, 65535, 65536, 2**32 - 1, 2**32, 2**48 - 1])),
)


@settings(deadline=None)        # the first example may compile the kernel
@given(_KEYS)
def test_stable_argsort_is_numpys_stable_argsort(keys):
    assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))


@settings(deadline=None)
@given(_KEYS, st.data())
def test_lexsort2_is_numpys_lexsort(major, data):
    minor = data.draw(arrays(np.int64, major.shape, elements=st.integers(0, 2**20)))
    assert np.array_equal(lexsort2(minor, major), np.lexsort((minor, major)))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.uint32, np.int64, np.uint64])
def test_any_integer_dtype(dtype):
    keys = np.random.default_rng(3).integers(0, np.iinfo(dtype).max // 2 + 1, 5000, dtype=np.uint64).astype(dtype)
    keys[::7] = keys[3]                       # ties keep their input order
    assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))


def test_keys_beyond_the_radix_fall_back_to_numpy():
    rng = np.random.default_rng(4)
    negative = rng.integers(-1000, 1000, 2000)
    wide = rng.integers(0, 2**62, 2000)
    wide[::5] = wide[1]
    for keys in (negative, wide, np.array([2**64 - 1, 0, 2**64 - 1], np.uint64)):
        assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))


def test_large_arrays_of_layer_and_pixel_keys():
    rng = np.random.default_rng(5)
    layer = rng.integers(0, 1009, 300_000)
    pixel = rng.integers(0, 4000 * 2500, 300_000)
    assert np.array_equal(stable_argsort(layer), np.argsort(layer, kind="stable"))
    assert np.array_equal(lexsort2(layer, pixel), np.lexsort((layer, pixel)))


@pytest.mark.parametrize("bad", [np.zeros(4), np.zeros((2, 2), np.int64), np.array(["a", "b"])])
def test_non_integer_or_not_1d_keys_are_refused(bad):
    with pytest.raises(TypeError, match="1-D integer array"):
        stable_argsort(bad)


@settings(deadline=None)
@given(st.integers(1, 40), st.data())
def test_layer_events_are_the_events_in_stable_layer_order(layers, data):
    n = data.draw(st.integers(0, 200))
    k0 = np.array(data.draw(st.lists(st.integers(0, layers - 1), min_size=n, max_size=n)), np.int64)
    length = np.array(data.draw(st.lists(st.integers(1, layers), min_size=n, max_size=n)), np.int64)
    k1 = np.minimum(k0 + length, layers)
    pix = np.array(data.draw(st.lists(st.integers(0, 50), min_size=n, max_size=n)), np.int64)
    value = data.draw(st.integers(1, 255))
    ev_k = np.concatenate([k0, k1])
    ev_pix = np.concatenate([pix, pix])
    ev_val = np.concatenate([np.full(n, value, np.uint8), np.zeros(n, np.uint8)])
    order = np.argsort(ev_k, kind="stable")
    starts, got_pix, got_val = layer_events(pix, k0, k1, layers, value)
    assert np.array_equal(starts, np.searchsorted(ev_k[order], np.arange(layers + 1)))
    assert np.array_equal(got_pix, ev_pix[order]) and np.array_equal(got_val, ev_val[order])


@pytest.mark.parametrize("k0, k1, where", [([0, 3], [2, 6], "run 1 covers layers [3, 6)"),
                                          ([0, -1], [2, 1], "run 1"), ([2], [2], "run 0 covers layers [2, 2)")])
def test_layer_events_refuse_runs_outside_the_layers(k0, k1, where):
    with pytest.raises(ValueError, match=re.escape(where)):
        layer_events(np.zeros(len(k0), np.int64), np.array(k0), np.array(k1), 5)


@settings(deadline=None, max_examples=200)
@given(st.integers(1, 30), st.integers(1, 30), st.integers(1, 12), st.data())
def test_rect_parts_is_the_stable_order_of_plate_pixels(W, H, T, data):
    """Tiles (or buckets, whose local width stays T at the plate's edge) with sorted
    local indices, given in any order; some unsorted parts and a minor key too."""
    bucket_like = data.draw(st.booleans())
    parts = []
    for j0 in range(0, H, T):
        for i0 in range(0, W, T):
            tw, th = min(T, W - i0), min(T, H - j0)
            stride = T if bucket_like else tw
            n = data.draw(st.integers(0, 2 * tw * th))
            jl = np.array(data.draw(st.lists(st.integers(0, th - 1), min_size=n, max_size=n)), np.int64)
            il = np.array(data.draw(st.lists(st.integers(0, tw - 1), min_size=n, max_size=n)), np.int64)
            local = jl * stride + il
            parts.append((i0, j0, stride, th, local if data.draw(st.booleans()) and n > 1 else np.sort(local)))
    parts = data.draw(st.permutations(parts))
    n = sum(len(p[4]) for p in parts)
    minor = None
    if data.draw(st.booleans()):
        minor = np.array(data.draw(st.lists(st.integers(0, 3), min_size=n, max_size=n)), np.int64)
    want_pix = np.concatenate([(j0 + loc // tw) * W + i0 + loc % tw for i0, j0, tw, _, loc in parts]) \
        if parts else np.zeros(0, np.int64)
    pix, order = rect_parts(parts, W, minor)
    assert np.array_equal(pix, want_pix)
    want = np.argsort(want_pix, kind="stable") if minor is None else np.lexsort((minor, want_pix))
    assert np.array_equal(order, want)
