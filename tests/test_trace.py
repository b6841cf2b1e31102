"""Slicing tracer against a dense reference: the field at every voxel centre.

Every method must classify every voxel centre as ``F(centre) >= 1``; the only
tolerated disagreements are centres where ``|F - 1| <= 1e-9`` (summation
order). Scenes are the stiff cases of the tracer issue.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from PIL import Image

from helpers import CASES, Ray, _node26, _scene, check_ray
from slicer import Skeleton
from slicer.tracer.grid import make_grid
from slicer.tracer.slicing import METHODS, slice_skeleton, trace

TOL = 1e-9


def dense_field(skel, grid):
    """(layers, height, width) field at every voxel centre of ``grid``."""
    X, Y, Z = np.meshgrid(grid.centres_x(), grid.centres_y(), grid.centres_z(), indexing="xy")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return skel.field(P).reshape(grid.height, grid.width, grid.layers).transpose(2, 0, 1)


def assert_exact(skel, grid, method, bucket=16, **kw):
    res = trace(skel, grid, method=method, bucket=bucket, **kw)
    vol = res.volume()
    f = dense_field(skel, grid)
    bad = (vol != (f >= 1.0)) & (np.abs(f - 1.0) > TOL)
    assert not bad.any(), (
        f"{method}: {int(bad.sum())} voxels misclassified, e.g. at (k, j, i) = "
        f"{tuple(int(v) for v in np.argwhere(bad)[0])}, F = {f[tuple(np.argwhere(bad)[0])]!r}")
    return res, f


@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_every_voxel_matches_dense_reference(case, method):
    skel, px, h = CASES[case]
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    res, f = assert_exact(skel, grid, method)
    if case == "lone_short_strut":
        # L = 0.36 tau < 0.688 tau: no surface at all (docs/math.md §1.5)
        assert f.max() < 1.0 and res.n_runs == 0
    elif case != "thinner_than_pixel":
        assert res.n_runs > 0


@pytest.mark.parametrize("kw", [{"strict": True}, {"cut_support": False}])
@pytest.mark.parametrize("case", ["node_26_struts", "cone_ratio_100", "horizontal_on_layer"])
def test_interval_variants_are_exact_too(case, kw):
    skel, px, h = CASES[case]
    grid = make_grid(skel.support_bounds(), px, layer_height=h)
    assert_exact(skel, grid, "interval", **kw)


def test_random_lattice_all_methods_and_bucket_sizes():
    rng = np.random.default_rng(7)
    nodes = rng.uniform(0, 5, (15, 3))
    segs = np.array([[i, (i + 3) % 15] for i in range(15)] + [[i, (i + 7) % 15] for i in range(0, 15, 2)])
    radii = rng.uniform(0.15, 0.5, (len(segs), 2))
    skel = Skeleton(nodes, segs, radii)
    grid = make_grid(skel.support_bounds(), 0.09, 0.11, 0.07)
    vols = []
    for method, bucket, kw in [("interval", 8, {}), ("interval", 0, {}), ("interval", 16, {"cut_support": False}),
                               ("interval", 16, {"strict": True}), ("sampling", 5, {}), ("segment", 64, {})]:
        res, _ = assert_exact(skel, grid, method, bucket=bucket, **kw)
        vols.append(res.volume())
    for v in vols[1:]:
        assert np.array_equal(v, vols[0])


def test_interval_needs_far_fewer_evaluations_than_sampling():
    skel, px, h = CASES["node_26_struts"]
    grid = make_grid(skel.support_bounds(), px, layer_height=h / 4)
    ev = {m: trace(skel, grid, method=m).stats["evaluations"] for m in ("interval", "sampling")}
    assert ev["interval"] * 3 < ev["sampling"], ev


def test_default_bounds_cover_the_surface_with_one_empty_voxel_margin():
    skel = CASES["cone_ratio_100"][0]
    res = slice_skeleton(skel, 0.1, layer_height=0.1)
    g = res.grid
    vol = res.volume()
    assert vol.any()
    # one empty voxel on every side, and nothing outside the model
    for axis in range(3):
        occupied = np.nonzero(vol.any(axis=tuple(a for a in range(3) if a != axis)))[0]
        assert occupied[0] == 1 and occupied[-1] == vol.shape[axis] - 2
    # the untrimmed trace over the supports has no inside voxel the trimmed one lost
    full = trace(skel, make_grid(skel.support_bounds(), 0.1, layer_height=0.1))
    assert full.volume().sum() == vol.sum()


def test_explicit_bounds_layout():
    skel = CASES["vertical_on_column"][0]
    res = slice_skeleton(skel, 0.25, layer_height=0.5, bounds=(-1, -1, 0, 1, 1, 3))
    g = res.grid
    assert (g.width, g.height, g.layers) == (8, 8, 6)
    assert g.origin == (-0.875, 0.875, 0.25)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    st.lists(st.floats(-2, 2), min_size=6, max_size=6),
    st.floats(0.05, 1.0), st.floats(0.05, 1.0),
    st.floats(-1.5, 1.5), st.floats(-1.5, 1.5),
    st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(0.001, 1.0)), min_size=1, max_size=3),
)
def test_slicing_ray_bounds_are_sound(ends, r0, r1, ox, oy, pieces):
    """A random segment and a slicing ray (vertical, ``t = z``) through the
    tracer's own kernels (ray_support, eval_along, piece_bounds, lipschitz):
    a miss is a miss, nothing lies outside [t_in, t_out], the field is
    unimodal, below H_FMAX, inside both the unimodal and the strict piece
    bounds, monotone where called monotone, and its slope within the
    Lipschitz bound (test_ray_unimodal.check_ray; any direction and the
    stiff tapers are in that module)."""
    a, b = np.array(ends[:3]), np.array(ends[3:])
    if np.linalg.norm(b - a) < 1e-3:
        return
    ray = Ray(Skeleton([a, b], [[0, 1]], [[r0, r1]]), (ox, oy, 0.0), (0.0, 0.0, 1.0))
    check_ray(ray, pieces)


def test_one_and_two_threads_give_identical_bytes(tmp_path):
    """Through the real entry point, in fresh processes: same PNG bytes."""
    skel = _node26()
    scene = tmp_path / "node.json"
    skel.save(scene)
    outs = []
    for t in (1, 2):
        out = tmp_path / f"out{t}"
        r = subprocess.run([sys.executable, "-m", "slicer", "slice", str(scene), "-o", str(out),
                            "--pixel-size", "0.07", "--threads", str(t), "--bucket", "8", "-q"],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        outs.append(out)
    meta = [json.loads((o / "slices.json").read_text()) for o in outs]
    assert meta[0]["files"] == meta[1]["files"] and len(meta[0]["files"]) == meta[0]["layers"]
    for name in meta[0]["files"] + ["slices.json"]:
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name


def test_png_stack_layout_matches_field_at_voxel_centres(tmp_path):
    """slices.json's origin/pixel_size/layer_height and the row/column
    convention locate every voxel centre: pixel == 255 iff F(centre) >= 1."""
    from slicer.job.run import run_slice

    skel = _scene([[0, 0, 0], [2.0, 0.5, 1.5], [0, 0, 0], [-0.5, 1.5, 1.0]], [[0, 1], [2, 3]],
                  [[0.4, 0.2], [0.4, 0.3]])
    out = tmp_path / "stack"
    run_slice(skel, out, pixel_size=0.1, pixel_size_y=0.13, layer_height=0.11, progress=False)
    meta = json.loads((out / "slices.json").read_text())
    W, H, K = meta["width"], meta["height"], meta["layers"]
    (x0, y0, z0), (px, py), h = meta["origin"], meta["pixel_size"], meta["layer_height"]
    vol = np.stack([np.asarray(Image.open(out / f)) for f in meta["files"]])
    assert vol.shape == (K, H, W) and vol.dtype == np.uint8 and set(np.unique(vol)) <= {0, 255}
    k, j, i = np.meshgrid(np.arange(K), np.arange(H), np.arange(W), indexing="ij")
    P = np.stack([x0 + i * px, y0 - j * py, z0 + k * h], -1).reshape(-1, 3)
    f = skel.field(P).reshape(K, H, W)
    bad = ((vol == 255) != (f >= 1)) & (np.abs(f - 1) > TOL)
    assert not bad.any()
    assert (vol == 255).sum() > 100


@pytest.mark.parametrize("spans", [False, True])
def test_long_strut_with_flat_field_along_the_ray_is_exact(spans):
    """Rays parallel to a long strut's axis inside it see F nearly constant: the
    Hermite estimate of the crossing at the end cap is poor and lands near the
    far end of the piece again and again. Split placement must still terminate
    within the kernel's stack (it used to overflow and retry forever)."""
    skel = _scene([[0, 0, 0], [0, 0, 40]], [[0, 1]], [[0.5, 0.5]])
    grid = make_grid(skel.support_bounds(), 0.05, layer_height=0.05)
    res, _ = assert_exact(skel, grid, "interval", bucket=8, spans=spans)
    assert res.n_runs > 250


def _bundle():
    """Seven parallel vertical chains of short struts 0.25 mm apart, radius
    0.2 mm, joints at random heights: one thick cable whose inside stretches
    hold hundreds of breakpoints (t_in, t_out, t* of every strut)."""
    rng = np.random.default_rng(1)
    nodes, segs = [], []
    for k in range(7):
        ang = 2 * np.pi * k / 7
        x, y = (0.25 * np.cos(ang), 0.25 * np.sin(ang)) if k else (0.0, 0.0)
        zs = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 0.8, 30))])
        base = len(nodes)
        nodes += [[x, y, z] for z in zs]
        segs += [[base + i, base + i + 1] for i in range(len(zs) - 1)]
    return _scene(nodes, segs, np.full((len(segs), 2), 0.2))


@pytest.mark.parametrize("spans", [False, True])
def test_inside_stretches_are_leapt_over_not_walked_breakpoint_by_breakpoint(spans):
    """Inside the cable, the unimodal lower bound ``sum min(f(ta), f(tb))``
    settles many breakpoints at a time (docs/math.md §5.6). Walking them one
    piece at a time, with every active strut evaluated at each, costs about
    3,500 evaluations per pixel column here (5,000 with spans); the leaps
    cost about 1,300 (2,200). The voxels (and spans) stay exact."""
    skel = _bundle()
    grid = make_grid(skel.support_bounds(), 0.05, layer_height=0.05)
    res, f = assert_exact(skel, grid, "interval", bucket=8, spans=spans)
    columns = np.unique(res.pix).size
    assert columns > 200 and (f >= 1).sum() > 50_000
    per_column = res.stats["evaluations"] / columns
    assert per_column < (3000 if spans else 2000), per_column


def _halo(offset=0.8):
    """A slanted strut ringed by sixteen short fat blobs that have no surface of
    their own (L = 0.27 tau, docs/math.md §1.5) and lift the field near the
    strut's surface by a few hundredths to a quarter: members whose bound on a
    ray is often below WEAK_CUT, with their peaks on the pieces that hold
    crossings."""
    rng = np.random.default_rng(3)
    u = np.array([3.0, 0.0, 2.4]) / np.linalg.norm([3.0, 0.0, 2.4])
    v = np.cross(u, [0.0, 1.0, 0.0])
    v /= np.linalg.norm(v)
    nodes, segs, radii = [[0, 0, 0], [3, 0, 2.4]], [[0, 1]], [[0.45, 0.3]]
    for k in range(16):
        ang = 2 * np.pi * k / 16 + 0.3
        a = u * rng.uniform(0, 1.5) + offset * (np.cos(ang) * np.array([0.0, 1.0, 0.0]) + np.sin(ang) * v)
        d = u + 0.15 * rng.normal(size=3)
        d /= np.linalg.norm(d)
        nodes += [list(a), list(a + 0.08 * d)]
        segs.append([len(nodes) - 2, len(nodes) - 1])
        radii.append([0.3, 0.3])
    return _scene(nodes, segs, radii)


def test_weak_members_add_no_cuts_to_their_cluster():
    """cluster_breakpoints skips the t*, t_in and t_out of a member whose bound
    on the ray is below ``weak``, and keeps the others' (sorted, inside the
    cluster)."""
    from slicer._kernels.rays.walk import cluster_breakpoints
    from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT

    hrec = np.zeros((3, NHIT))
    for r, (t_in, t_star, t_out, fmax) in enumerate([(0.0, 1.0, 2.0, 0.9), (0.5, 1.5, 3.0, 0.1),
                                                     (2.5, 3.5, 4.0, 0.19999)]):
        hrec[r, [H_TIN, H_TSTAR, H_TOUT, H_FMAX]] = t_in, t_star, t_out, fmax
    order = np.arange(3, dtype=np.int64)
    bps = np.empty(16)
    nb = cluster_breakpoints(hrec, order, 0, 3, 0.0, 4.0, True, 0.0, 0.0, bps)
    assert list(bps[:nb]) == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0]
    nb = cluster_breakpoints(hrec, order, 0, 3, 0.0, 4.0, True, 0.0, 0.0, bps, 0.2)
    assert list(bps[:nb]) == [0.0, 1.0, 2.0, 4.0]


@pytest.mark.parametrize("kw", [{}, {"lazy": True}, {"spans": True}, {"strict": True}])
def test_weak_members_near_the_surface_keep_every_voxel_exact(kw):
    """Without their cuts the blobs of :func:`_halo` are bounded by the ambiguous
    case of docs/math.md §5.1 on the pieces that hold their peaks (§5.7);
    every voxel centre still takes the class of its own field value."""
    skel = _halo()
    grid = make_grid(skel.support_bounds(), 0.05, layer_height=0.05)
    f = dense_field(skel, grid)
    strut = Skeleton(skel.nodes, skel.segments[:1], skel.radii[:1])
    share = (f - dense_field(strut, grid))[np.abs(f - 1.0) < 0.05]
    assert ((share > 0.01) & (share < 0.2)).sum() > 300   # the blobs matter where the surface is
    res, _ = assert_exact(skel, grid, "interval", bucket=16, **kw)
    assert res.n_runs > 900


def test_runs_stay_inside_a_grid_that_crops_the_model():
    """Explicit bounds cutting through the model: runs never reach past the
    last layer, and centres beyond the grid are not evaluated."""
    skel = _scene([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[0.5, 0.5]])
    one = make_grid(skel.support_bounds(), 0.1, layer_height=0.1, bounds=(-0.05, -0.05, 0.45, 0.05, 0.05, 0.55))
    assert (one.width, one.height, one.layers) == (1, 1, 1)
    res = trace(skel, one)
    assert res.n_runs == 1 and (res.k0[0], res.k1[0]) == (0, 1)
    grid = make_grid(skel.support_bounds(), 0.05, layer_height=0.05, bounds=(-1, -1, 0.2, 1, 1, 0.6))
    for method in sorted(METHODS):
        res, _ = assert_exact(skel, grid, method)
        assert res.k1.max() <= grid.layers and res.k0.min() >= 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 500), min_size=0, max_size=80), st.integers(1, 6))
def test_thread_order_balances_static_blocks(costs, T):
    """Any static split into T contiguous blocks (as Numba's OpenMP layer
    schedules a prange) gets near-equal shares: no block exceeds the mean by
    more than the largest item; the order is a permutation."""
    from slicer.tracer.buckets import thread_order

    costs = np.array(costs, dtype=np.int64)
    todo = np.arange(100, 100 + len(costs), dtype=np.int64)
    out = thread_order(todo, costs, T)
    assert sorted(out.tolist()) == todo.tolist()
    if len(costs) == 0:
        return
    c = costs[out - 100]
    bounds = np.linspace(0, len(c), T + 1).round().astype(int)
    for ceil_split in (False, True):
        if ceil_split:    # blocks of ceil(n / T) items, the last one shorter
            k = -(-len(c) // T)
            bounds = np.minimum(np.arange(T + 1) * k, len(c))
        shares = [int(c[a:b].sum()) for a, b in zip(bounds[:-1], bounds[1:])]
        assert max(shares) <= c.sum() / T + 2 * c.max() + 1e-9


@settings(max_examples=300, deadline=None)
@given(st.floats(-1.0, -1e-3), st.floats(1e-3, 1.0), st.floats(0.0, 2.1), st.floats(0.0, 2.1),
       st.floats(1e-6, 0.05), st.floats(0.1, 10.0))
def test_a_coarse_hermite_estimate_stays_near_the_cubic_root(ga, gb, alpha, beta, step, w):
    """A centre split stops Newton once a step moves less than ``step`` of
    the bracket; where the Hermite cubic is monotone (one root: end slopes
    of ``alpha`` and ``beta`` times the secant's, ``alpha² + beta² <= 9``,
    Fritsch-Carlson) the estimate must still be that root to about ``step``
    (the full iteration is the reference), inside the bracket. (A cubic
    with three roots may yield another one: any centre is a correct split,
    only the count changes.)"""
    from slicer._kernels.rays.walk import hermite_point

    da, db = alpha * (gb - ga) / w, beta * (gb - ga) / w
    ta = 3.0
    exact = hermite_point(ta, ta + w, ga, gb, da, db)
    coarse = hermite_point(ta, ta + w, ga, gb, da, db, step)
    assert ta <= coarse <= ta + w
    assert abs(coarse - exact) <= 2.0 * step * w


@pytest.mark.parametrize("blend", ["sum", "union"])
@pytest.mark.parametrize("spans", [False, True])
def test_buckets_that_fill_their_buffers_resume(monkeypatch, spans, blend):
    """A ray through a stack of twelve struts has twelve runs: with room for
    one run per ray, the buckets fill their buffers, keep the rays they
    finished and resume at the next one. The runs,
    spans and evaluation count are those of a launch with room to spare."""
    import slicer.tracer.slicing as slicing

    nodes = [[x, 0.1 * (k % 3), 0.45 * k] for k in range(12) for x in (-1.0, 1.0)]
    segs = [[2 * k, 2 * k + 1] for k in range(12)]
    skel = _scene(nodes, segs, np.full((12, 2), 0.15))
    grid = make_grid(skel.support_bounds(), 0.1, layer_height=0.05)
    kw = dict(bucket=8, spans=spans, blend=blend)
    launches = []
    real = slicing.launch_until_fits

    def counting(launch, items, what, **k):
        def once(pending, scale):
            launches.append(len(pending))
            return launch(pending, scale)
        return real(once, items, what, **k)

    monkeypatch.setattr(slicing, "launch_until_fits", counting)
    monkeypatch.setattr(slicing, "RUNS_PER_RAY", 64)
    roomy = trace(skel, grid, **kw)
    assert len(launches) == 1
    launches.clear()
    monkeypatch.setattr(slicing, "RUNS_PER_RAY", 1)
    tight = trace(skel, grid, **kw)
    assert len(launches) >= 2 and launches[0] > launches[1] > 0
    assert np.array_equal(tight.pix, roomy.pix)
    assert np.array_equal(tight.k0, roomy.k0) and np.array_equal(tight.k1, roomy.k1)
    assert tight.stats["evaluations"] == roomy.stats["evaluations"]
    if spans:
        assert np.array_equal(tight.span_pix, roomy.span_pix)
        assert np.array_equal(tight.span_t0, roomy.span_t0) and np.array_equal(tight.span_t1, roomy.span_t1)
    vol = tight.volume()
    f = dense_field(skel, grid)
    assert not ((vol != (f >= 1.0)) & (np.abs(f - 1.0) > TOL)).any()
    assert (vol.reshape(grid.layers, -1).astype(bool).sum(axis=0) > 0).sum() > 100
