"""Tiled, memory-bounded slicing (slicer.scale.tiles): plans, merging, streaming.

The reference is the untiled path, ``slice_skeleton``: every plan (tile
sizes, Z slabs, first pass for the model's extent) must give the same grid
and byte-identical layers.
"""
from __future__ import annotations

import dataclasses
import threading
import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formats.printer_profiles import get_printer, place
from slicer import GridError, OptionError, Skeleton
from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.model.field import support_boxes
from slicer.tracer.grid import make_grid
from slicer.scene.lattice import generate_lattice
from slicer.tracer.slicing import SliceResult, slice_skeleton, trace
from slicer.scale.tiles import (StreamedResult, TraceOptions, cull, merge_tiles, parse_size, plan_job,
                          plan_slice, slice_planned, trace_tile)

PX = 0.05


@pytest.fixture(scope="module")
def lattice():
    # graded bcc: tapered struts, nodes where 8 struts blend
    return generate_lattice("bcc", cells=(3, 2, 2), cell_size=2.0, radius=0.15, radius_top=0.3)


@pytest.fixture(scope="module")
def reference(lattice):
    res = slice_skeleton(lattice, PX)
    return res, np.stack(list(res.iter_layers()))


def layers(res) -> np.ndarray:
    return np.stack(list(res.iter_layers()))


# ----------------------------------------------------------------------------- sizes
@pytest.mark.parametrize("text, expected", [
    ("2GB", 2 * 10**9), ("2gb", 2 * 10**9), ("2G", 2 * 2**30), ("2GiB", 2 * 2**30),
    ("512MB", 512 * 10**6), ("1.5 GiB", int(1.5 * 2**30)), ("800k", 800 * 1024), ("1e9", 10**9),
    (4096, 4096), ("none", None), (None, None), ("0", None),
])
def test_parse_size(text, expected):
    assert parse_size(text) == expected


@pytest.mark.parametrize("text", ["2XB", "GB", "-1GB", "lots", "1..5GB", "inf"])
def test_parse_size_refuses_garbage(text):
    with pytest.raises(OptionError, match="max-memory"):
        parse_size(text)


# ----------------------------------------------------------------------------- merge
def _fake_tile(rng, tw, th, layers, spans):
    """Sorted runs (and spans) of a tw x th tile, as trace_tile returns them."""
    pix, k0, k1, sp, s0, s1 = [], [], [], [], [], []
    for p in range(tw * th):
        edges = np.sort(rng.choice(layers + 1, size=2 * rng.integers(0, 3), replace=False))
        for a, b in edges.reshape(-1, 2):
            pix.append(p), k0.append(a), k1.append(b)
            if spans:
                sp.append(p), s0.append(a - 0.3), s1.append(b - 0.6)
    arrays = {"pix": np.array(pix, np.int32), "k0": np.array(k0, np.int32), "k1": np.array(k1, np.int32)}
    names = [f.name for f in dataclasses.fields(SliceResult) if f.name not in ("grid", "stats")]
    for n in names:
        if n.startswith("span_"):
            arrays[n] = {"span_pix": np.array(sp, np.int32), "span_t0": np.array(s0),
                         "span_t1": np.array(s1)}[n] if spans else None
    return arrays


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 9), st.integers(1, 7), st.integers(1, 5), st.integers(0, 2**31 - 1), st.booleans())
def test_merge_tiles_matches_a_slow_reference(width, height, tile, seed, spans):
    """Random runs on a random tiling: the merged arrays are the runs of every
    pixel in image order, each pixel's own order kept, span arrays too."""
    rng = np.random.default_rng(seed)
    K = 6
    grid = make_grid(np.array([[0, 0, 0], [1, 1, 1.0]]), 1.0,
                                                   bounds=(0, 0, 0, width, height, K))
    parts, expected = [], {}
    for j0 in range(0, height, tile):
        for i0 in range(0, width, tile):
            tw, th = min(tile, width - i0), min(tile, height - j0)
            a = _fake_tile(rng, tw, th, K, spans)
            parts.append((i0, j0, tw, a))
            for q in range(len(a["pix"])):
                jl, il = divmod(int(a["pix"][q]), tw)
                expected.setdefault((j0 + jl) * width + i0 + il, []).append((int(a["k0"][q]), int(a["k1"][q])))
    res = merge_tiles(grid, parts)
    assert res.pix.dtype == np.int64 and res.k0.dtype == np.int64
    assert np.all(np.diff(res.pix) >= 0)
    got = {}
    for p, a, b in zip(res.pix, res.k0, res.k1):
        got.setdefault(int(p), []).append((int(a), int(b)))
    assert got == expected
    if spans:
        assert np.array_equal(res.span_pix, res.pix)        # by construction one span per run
        assert np.array_equal(res.span_t0, res.k0 - 0.3) and np.array_equal(res.span_t1, res.k1 - 0.6)
    else:
        assert getattr(res, "span_pix", None) is None


def test_merge_refuses_fields_present_in_some_tiles_only():
    g = make_grid(np.zeros((2, 3)), 1.0, bounds=(0, 0, 0, 2, 1, 2))
    a = {"pix": np.zeros(0, np.int32), "k0": np.zeros(0, np.int32), "k1": np.zeros(0, np.int32)}
    b = dict(a, span_pix=np.zeros(0, np.int32), span_t0=np.zeros(0), span_t1=np.zeros(0))
    a.update(span_pix=None, span_t0=None, span_t1=None)
    with pytest.raises(ValueError, match="span_pix"):
        merge_tiles(g, [(0, 0, 1, a), (1, 0, 1, b)])


# ----------------------------------------------------------------------------- culling
def test_cull_keeps_exactly_what_the_tile_needs(lattice):
    """A tile traced with the culled segments equals the tile traced with the
    whole scene, and culling drops most segments of a small tile."""
    grid = make_grid(lattice.support_bounds(), PX)
    lo, hi = support_boxes(lattice)
    sub = grid.sub(40, 30, 10, 24, 24, 40)
    nodes, seg, radii = cull(lattice, lo, hi, sub)
    assert 0 < len(seg) < lattice.n_segments / 2
    a = trace(lattice, sub)
    b = trace(Skeleton(nodes, seg, radii, lattice.degree, lattice.sigma), sub)
    assert a.n_runs > 0
    for f in ("pix", "k0", "k1"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert cull(lattice, lo, hi, grid.sub(0, 0, 0, 1, 1, 1)) is None   # a corner outside every support


# ----------------------------------------------------------------------------- plans
def test_plan_tiles_and_slabs_cover_the_grid_once(lattice):
    grid = make_grid(lattice.support_bounds(), PX)
    B = DEFAULT_BUCKET
    assert plan_job(lattice, grid, TraceOptions(), tile=3 * B + 4).tile == 4 * B   # a multiple of the bucket
    small = B * 5 // 8
    plan = plan_job(lattice, grid, TraceOptions(), budget=None, tile=small)
    assert plan.tile == small                   # smaller than a bucket: kept
    cover = np.zeros((grid.height, grid.width), int)
    for i0, j0, w, h in plan.tiles():
        assert i0 % small == 0 and j0 % small == 0
        cover[j0:j0 + h, i0:i0 + w] += 1
    assert np.all(cover == 1)
    # a sub-rectangle: tiles are clipped to it and stay on the same lattice
    cover[:] = 0
    for i0, j0, w, h in plan.tiles(10, 30, 100, 80):
        cover[j0:j0 + h, i0:i0 + w] += 1
    assert cover[30:80, 10:100].min() == 1 and cover.sum() == 50 * 90
    assert [s for s in plan.slabs()] == [(0, grid.layers)]


def test_smaller_budgets_give_more_slabs_and_fit(lattice):
    grid = make_grid(lattice.support_bounds(), PX)
    opts = TraceOptions()
    K = grid.layers
    slabs = []
    for n in (1, 2, 5, 12):
        need = plan_job(lattice, grid, opts, process_bytes=0, sample=True, slab=-(-K // n),
                        prefetch=False).estimate["total"]
        plan = plan_job(lattice, grid, opts, budget=need, process_bytes=0, sample=True)
        assert plan.estimate["total"] <= need and plan.n_slabs <= n
        ranges = plan.slabs()
        assert ranges[0][0] == 0 and ranges[-1][1] == grid.layers
        assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))
        slabs.append(plan.n_slabs)
    assert slabs == sorted(slabs) and slabs[0] == 1 and slabs[-1] > 6
    with pytest.raises(GridError, match="too small"):
        plan_job(lattice, grid, opts, budget=10**5, process_bytes=0)


def test_sample_estimates_runs_per_column(lattice, reference):
    res, _ = reference
    plan = plan_slice(lattice, PX, sample=True, process_bytes=0)
    g = plan.grid
    true_rpc = res.n_runs / (g.width * g.height)     # the same runs over the (larger) support grid
    assert plan.sampled and 0.3 * true_rpc < plan.runs_per_column < 3 * true_rpc
    assert plan.seconds is not None and plan.seconds > 0
    text = plan.describe()
    for word in ("grid:", "tiles:", "slabs:", "memory:", "time:"):
        assert word in text


# ----------------------------------------------------------------------------- tiled == untiled
def _budget(skel, slabs, **kw) -> float:
    """A budget that fits about ``slabs`` slabs written one after the other:
    the estimate of that plan (a prefetching plan then has more slabs)."""
    K = plan_slice(skel, **kw, process_bytes=0).grid.layers
    return plan_slice(skel, **kw, sample=True, process_bytes=0, slab=-(-K // slabs),
                      prefetch=False).estimate["total"]


@pytest.mark.parametrize("tile, fraction", [(16, None), (64, None), (32, 3), (64, 7)])
def test_tiled_default_bounds_equal_untiled(lattice, reference, tile, fraction):
    ref, ref_layers = reference
    budget = fraction and _budget(lattice, fraction, pixel_size=PX, tile=tile)
    plan = plan_slice(lattice, PX, tile=tile, max_memory=budget, process_bytes=0, sample=True)
    res = slice_planned(lattice, PX, plan=plan, progress=False)
    if fraction is None:
        assert plan.n_slabs == 1 and isinstance(res, SliceResult)
        assert np.array_equal(res.pix, ref.pix) and np.array_equal(res.k0, ref.k0)
    else:
        assert plan.n_slabs > 1 and plan.passes == 2 and isinstance(res, StreamedResult)
    assert res.grid == ref.grid
    assert np.array_equal(layers(res), ref_layers)


def test_streamed_explicit_bounds_equal_untiled(lattice):
    bounds = (-0.5, -0.5, 0.3, 5.5, 3.7, 3.9)
    ref = slice_skeleton(lattice, PX, layer_height=0.07, bounds=bounds)
    kw = dict(pixel_size=PX, layer_height=0.07, bounds=bounds, tile=32)
    plan = plan_slice(lattice, **kw, max_memory=_budget(lattice, 4, **kw), process_bytes=0, sample=True)
    assert plan.n_slabs > 2 and plan.passes == 1
    res = slice_planned(lattice, PX, layer_height=0.07, bounds=bounds, plan=plan, progress=False)
    assert isinstance(res, StreamedResult) and res.grid == ref.grid
    slabs = list(res.iter_slabs())
    assert sum(s.grid.layers for s in slabs) == ref.grid.layers
    assert np.array_equal(np.concatenate([layers(s) for s in slabs]), layers(ref))
    assert res.n_runs >= ref.n_runs        # runs crossing a slab boundary count once per slab


def test_spans_and_coverage_survive_tiling(lattice):
    bounds = (-0.5, -0.5, 0.3, 5.5, 3.7, 2.9)
    ref = slice_skeleton(lattice, 0.1, bounds=bounds, spans=True)
    one = slice_planned(lattice, 0.1, bounds=bounds, spans=True, tile=16, progress=False)
    assert isinstance(one, SliceResult)
    assert np.array_equal(one.span_pix, ref.span_pix)
    # tile origins are rounded once more than the plate's: span ends move by ~1e-11 mm at most
    for f in ("span_t0", "span_t1"):
        assert np.allclose(getattr(one, f), getattr(ref, f), rtol=0, atol=1e-9), f
    kw = dict(pixel_size=0.1, bounds=bounds, spans=True, tile=16)
    plan = plan_slice(lattice, **kw, max_memory=_budget(lattice, 3, **kw), process_bytes=0, sample=True)
    assert plan.n_slabs > 1
    streamed = slice_planned(lattice, 0.1, bounds=bounds, spans=True, plan=plan, progress=False)
    cov = np.stack(list(streamed.iter_coverage()))
    cov_ref = np.stack(list(ref.iter_coverage()))
    assert np.allclose(cov, cov_ref, atol=1e-9, rtol=0)


def test_empty_scene_region_gives_an_empty_trimmed_result():
    # a strut too short to have a surface
    s = Skeleton([[0, 0, 0], [0.3, 0, 0]], [[0, 1]], [[0.6, 0.6]])
    plan = plan_slice(s, 0.05, tile=16, max_memory=0.6e6, process_bytes=0, sample=False)  # upper bound
    assert plan.n_slabs > 1
    res = slice_planned(s, 0.05, plan=plan, progress=False)
    assert res.n_runs == 0 and res.grid.layers == 0


def test_trace_tile_is_compact_and_picklable(lattice):
    import pickle

    grid = make_grid(lattice.support_bounds(), PX)
    lo, hi = support_boxes(lattice)
    sub = grid.sub(64, 0, 0, 64, 64, grid.layers)
    args = (*cull(lattice, lo, hi, sub), lattice.degree, lattice.sigma, sub, TraceOptions(threads=1))
    out = pickle.loads(pickle.dumps(trace_tile))(*pickle.loads(pickle.dumps(args)))
    assert out["arrays"]["pix"].dtype == np.int32 and out["runs"] == len(out["arrays"]["k0"]) > 0
    ext = trace_tile(*args, extent=True)
    i0, i1, j0, j1, k0, k1 = ext["bbox"]
    j, i = np.divmod(out["arrays"]["pix"], 64)
    assert (i0, i1, j0, j1) == (i.min(), i.max(), j.min(), j.max())
    assert (k0, k1) == (out["arrays"]["k0"].min(), out["arrays"]["k1"].max() - 1)


# ----------------------------------------------------------------------------- memory
def _peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_streaming_bounds_the_memory_of_runs():
    """Python-side peak (NumPy reports to tracemalloc): a many-slab plan holds
    a fraction of the runs the one-slab plan holds."""
    skel = generate_lattice("cubic", cells=(4, 4, 6), cell_size=1.0, radius=0.12)
    bounds = (-0.3, -0.3, -0.3, 4.3, 4.3, 6.3)
    kw = dict(layer_height=0.01, bounds=bounds, tile=64)
    one = plan_slice(skel, 0.04, **kw, process_bytes=0, sample=True)
    many = plan_slice(skel, 0.04, **kw, max_memory=one.estimate["total"] / 6, process_bytes=0, sample=True)
    assert one.n_slabs == 1 and many.n_slabs >= 6

    def consume(plan):
        def run():
            res = slice_planned(skel, 0.04, **kw, plan=plan, progress=False)
            for _ in res.iter_layers():
                pass
        return run

    big, small = _peak(consume(one)), _peak(consume(many))
    assert small <= many.estimate["total"] and small < big / 2, (small, big, many.estimate["total"])


def test_streamed_result_is_placed_on_a_plate_like_the_untiled_one(lattice, reference):
    """A multi-slab job knows its inside box from the extent pass, so a printer
    placement needs no second trace and lands where the in-memory job's does."""
    prn = get_printer("prusa-sl1s")
    assert prn.pixel_size == (PX, PX)
    ref, _ = reference
    plan = plan_slice(lattice, PX, tile=32, max_memory=_budget(lattice, 3, pixel_size=PX, tile=32),
                      process_bytes=0, sample=True)
    res = slice_planned(lattice, PX, plan=plan, progress=False)
    assert isinstance(res, StreamedResult) and plan.n_slabs > 1
    assert res.inside_box() == ref.inside_box()
    j, i = np.divmod(ref.pix, ref.grid.width)
    assert ref.inside_box() == (i.min(), i.max(), j.min(), j.max(), ref.k0.min(), ref.k1.max() - 1)
    assert place(res, prn, at=(40.0, 30.0)) == place(ref, prn, at=(40.0, 30.0))


def test_streamed_result_without_trim_does_not_guess_its_box(lattice):
    bounds = (-0.5, -0.5, 0.3, 5.5, 3.7, 3.9)
    kw = dict(pixel_size=PX, layer_height=0.07, bounds=bounds, tile=32)
    plan = plan_slice(lattice, **kw, max_memory=_budget(lattice, 4, **kw), process_bytes=0, sample=True)
    res = slice_planned(lattice, PX, layer_height=0.07, bounds=bounds, plan=plan, progress=False)
    with pytest.raises(GridError, match="without --bounds"):
        res.inside_box()


# ----------------------------------------------------------------------------- prefetching
def _slab_plan(lattice, prefetch: bool, slabs: int = 4):
    bounds = (-0.5, -0.5, 0.3, 5.5, 3.7, 3.9)
    kw = dict(pixel_size=PX, layer_height=0.07, bounds=bounds, tile=32)
    K = plan_slice(lattice, **kw, process_bytes=0).grid.layers
    plan = plan_slice(lattice, **kw, process_bytes=0, slab=-(-K // slabs), prefetch=prefetch)
    assert plan.n_slabs == slabs and plan.prefetch == prefetch
    return plan, dict(layer_height=0.07, bounds=bounds)


def _recording_tracer(monkeypatch):
    """Replace the tile task by one that records the first layer of every tile it traces."""
    import slicer.scale.tiles as tiles

    started, lock = [], threading.Lock()

    def recording(*args):
        with lock:
            started.append(args[-3].origin[2])      # the sub-grid's z origin
        return trace_tile(*args)

    monkeypatch.setattr(tiles, "trace_tile", recording)
    return started


def test_prefetching_gives_the_same_slabs_and_traces_the_next_one_meanwhile(lattice, monkeypatch):
    plan_on, kw = _slab_plan(lattice, True)
    plan_off, _ = _slab_plan(lattice, False)
    assert (plan_on.grid, plan_on.tile, plan_on.slab) == (plan_off.grid, plan_off.tile, plan_off.slab)
    started = _recording_tracer(monkeypatch)
    slabs = plan_on.slabs()
    z_of = {ka: plan_on.grid.origin[2] + ka * plan_on.grid.layer_height for ka, _ in slabs}
    got = []
    for i, slab in enumerate(slice_planned(lattice, PX, **kw, plan=plan_on, progress=False).iter_slabs()):
        if i + 1 < len(slabs):       # while the caller holds slab i, slab i + 1 is being traced
            deadline = time.monotonic() + 60
            while not any(abs(z - z_of[slabs[i + 1][0]]) < 1e-9 for z in started):
                assert time.monotonic() < deadline, f"slab {i + 1} was not traced while slab {i} was held"
                time.sleep(0.01)
        got.append(layers(slab))
    started.clear()
    serial = []
    for i, slab in enumerate(slice_planned(lattice, PX, **kw, plan=plan_off, progress=False).iter_slabs()):
        if i + 1 < len(slabs):       # without prefetching, nothing of the next slab has started
            assert not any(abs(z - z_of[slabs[i + 1][0]]) < 1e-9 for z in started)
        serial.append(layers(slab))
    assert np.array_equal(np.concatenate(got), np.concatenate(serial))
    assert np.array_equal(np.concatenate(got), layers(slice_skeleton(lattice, PX, **kw)))


def test_a_caller_that_stops_early_stops_the_prefetch(lattice, monkeypatch):
    plan, kw = _slab_plan(lattice, True, slabs=5)
    started = _recording_tracer(monkeypatch)
    res = slice_planned(lattice, PX, **kw, plan=plan, progress=False)
    it = res.iter_slabs()
    next(it)
    it.close()                       # waits for the slab in flight, starts no other
    before = len(started)
    time.sleep(0.2)
    assert len(started) == before
    z2 = plan.grid.origin[2] + plan.slabs()[2][0] * plan.grid.layer_height
    assert not any(abs(z - z2) < 1e-9 for z in started)
    assert not any(t.name.startswith("next-slab") for t in threading.enumerate())


def test_a_failure_while_prefetching_reaches_the_caller(lattice, monkeypatch):
    import slicer.scale.tiles as tiles

    plan, kw = _slab_plan(lattice, True, slabs=3)
    z1 = plan.grid.origin[2] + plan.slabs()[1][0] * plan.grid.layer_height

    def failing(*args):
        if abs(args[-3].origin[2] - z1) < 1e-9:
            raise MemoryError("tile of slab 1")
        return trace_tile(*args)

    monkeypatch.setattr(tiles, "trace_tile", failing)
    it = slice_planned(lattice, PX, **kw, plan=plan, progress=False).iter_slabs()
    next(it)
    with pytest.raises(MemoryError, match="tile of slab 1"):
        next(it)


def test_prefetching_plans_fit_two_slabs_in_the_budget(lattice):
    kw = dict(pixel_size=PX, tile=32, process_bytes=0, sample=True)
    budget = _budget(lattice, 2, pixel_size=PX, tile=32)
    off = plan_slice(lattice, **kw, max_memory=budget, prefetch=False)
    asked = plan_slice(lattice, **kw, max_memory=budget, prefetch=True)
    assert asked.prefetch and not off.prefetch and off.n_slabs > 1
    assert off.n_slabs < asked.n_slabs and asked.estimate["total"] <= budget
    # the estimate holds the runs of two slabs: the same slabs written one by one need half
    single = plan_slice(lattice, **kw, slab=asked.slab, prefetch=False)
    assert asked.estimate["runs"] == pytest.approx(2 * single.estimate["runs"])
    assert "the next is traced while one is written" in asked.describe()
    # by default: never more slabs for it -- prefetch only when two planned slabs fit anyway
    auto = plan_slice(lattice, **kw, max_memory=budget)
    assert (auto.slab, auto.prefetch) == (off.slab, False)
    roomy = plan_slice(lattice, **kw, max_memory=budget, slab=asked.slab)
    assert roomy.prefetch and roomy.slab == asked.slab
    # one slab never prefetches
    assert not plan_slice(lattice, **kw).prefetch
    assert not plan_slice(lattice, **kw, prefetch=True).prefetch


def test_prefetch_asked_for_with_too_small_a_budget_is_refused(lattice):
    kw = dict(pixel_size=PX, tile=32, process_bytes=0, sample=True)
    K = plan_slice(lattice, **kw).grid.layers
    L = -(-K // 3)
    budget = int(plan_slice(lattice, **kw, slab=L, prefetch=False).estimate["total"]) + 1
    assert not plan_slice(lattice, **kw, max_memory=budget, slab=L).prefetch
    with pytest.raises(GridError, match=r"too small for two slabs of \d+ layers \(--prefetch\).*--no-prefetch"):
        plan_slice(lattice, **kw, max_memory=budget, slab=L, prefetch=True)
