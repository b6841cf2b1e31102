"""Slicing API: a skeleton and a grid in, inside runs per pixel column out.

The tracer returns, for every pixel column, the runs ``[k0, k1)`` of layer
indices whose voxel centres are inside the solid. Layers are produced from the
runs one at a time (:meth:`SliceResult.iter_layers`), by joint iteration of
the runs' ends and the layer index, so memory is O(runs) + one layer.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from slicer._kernels.runtime.launch import launch_until_fits, numba_threads, one_item_per_thread
from slicer._kernels.rays.support import kprime_max
from slicer._kernels.trace.summed import RUNS_FULL, trace_buckets
from slicer.compiling import ABOUT, compiling
from slicer._kernels.trace.union import trace_union_buckets
from slicer.model.blend import require_traceable
from slicer.tracer.buckets import DEFAULT_BUCKET, Buckets, build_buckets, thread_order
from slicer.errors import GridError
from slicer.tracer.grid import SliceGrid, make_grid
from slicer.raster.ordering import layer_events, rect_parts, stable_argsort
from slicer.model.skeleton import Skeleton
from slicer.supports.groups import is_grouped, trace_groups

#: tracing methods and their kernel codes
METHODS = {"interval": 0, "sampling": 1, "segment": 2}
#: room for runs in a bucket's first launch, per ray; a bucket that needs
#: more resumes at its first unfinished ray with four times the room
RUNS_PER_RAY = 4


@dataclass
class SliceResult:
    """Inside runs of every pixel column of a grid.

    Attributes
    ----------
    grid : SliceGrid
        Grid of the output (trimmed to the model plus one voxel of margin
        unless explicit bounds were given).
    pix : (r,) int64
        Flat pixel index ``j * width + i`` of each run.
    k0, k1 : (r,) int64
        Each run covers layers ``k0 <= k < k1``. Runs of one pixel are sorted
        and disjoint; runs are sorted by pixel.
    stats : dict
        ``method``, ``bucket``, ``evaluations`` (primitive evaluations),
        ``trace_seconds``, ``threads`` (and ``span_tol`` with spans).
    span_pix : (s,) int64 or None
        With ``spans=True``: flat pixel index of each inside span.
    span_t0, span_t1 : (s,) float64 or None, mm
        Each span is the real interval ``[t0, t1]`` of heights along the
        pixel column where F >= 1, clipped to the grid's z range
        ``[z0 - h/2, z0 + (layers - 1/2) h]``; each end lies within
        ``span_tol`` of a true crossing (ends at the clip planes are exact).
        Sorted by pixel, then height; spans of a pixel are disjoint. Voxel
        centre k is inside exactly when it lies in a span. Spans thinner
        than ``span_tol`` may be missed.
    """

    grid: SliceGrid
    pix: np.ndarray
    k0: np.ndarray
    k1: np.ndarray
    stats: dict = field(default_factory=dict)
    span_pix: np.ndarray | None = None
    span_t0: np.ndarray | None = None
    span_t1: np.ndarray | None = None

    @property
    def has_spans(self) -> bool:
        return self.span_pix is not None

    @property
    def n_runs(self) -> int:
        return int(self.pix.shape[0])

    def inside_box(self) -> tuple[int, int, int, int, int, int] | None:
        """Index box ``(i0, i1, j0, j1, k0, k1)`` (inclusive) of the inside
        voxels on :attr:`grid`, or None when nothing is inside."""
        if self.n_runs == 0:
            return None
        j, i = np.divmod(self.pix, self.grid.width)
        return (int(i.min()), int(i.max()), int(j.min()), int(j.max()), int(self.k0.min()),
                int(self.k1.max()) - 1)

    def iter_layers(self, value: int = 255) -> Iterator[np.ndarray]:
        """Yield each layer as a (height, width) uint8 image, bottom layer first.

        Pixels inside are ``value``, outside 0. Only one layer is held at a
        time; each run contributes one "set" event at k0 and one "clear" event
        at k1.
        """
        g = self.grid
        K = g.layers
        bounds, ev_pix, ev_val = layer_events(self.pix, self.k0, self.k1, K, value)
        img = np.zeros(g.width * g.height, np.uint8)
        for k in range(K):
            s, e = bounds[k], bounds[k + 1]
            if e > s:
                img[ev_pix[s:e]] = ev_val[s:e]
            yield img.reshape(g.height, g.width).copy()

    def iter_coverage(self) -> Iterator[np.ndarray]:
        """Yield, per layer, the inside fraction of each voxel's z extent.

        Voxel (i, j, k) spans heights ``[z_k - h/2, z_k + h/2]``; its coverage
        is the total length of the pixel's inside spans within that range,
        divided by h: a (height, width) float64 array in [0, 1]. Needs a
        result traced with ``spans=True``. Memory: O(spans) + one layer.
        """
        if not self.has_spans:
            raise GridError("coverage needs spans: trace with spans=True (interval method)")
        g = self.grid
        K, h = g.layers, g.layer_height
        if K == 0:
            return
        # layer-relative coordinates: voxel k covers [k, k + 1)
        u0 = (self.span_t0 - g.origin[2]) / h + 0.5
        u1 = (self.span_t1 - g.origin[2]) / h + 0.5
        yield from coverage_layers(self.span_pix, u0, u1, K, g.height, g.width)

    def volume(self) -> np.ndarray:
        """The whole voxel volume, (layers, height, width) bool. For tests and
        small grids only."""
        g = self.grid
        vol = np.zeros((g.layers, g.height * g.width), bool)
        for p, a, b in zip(self.pix, self.k0, self.k1):
            vol[a:b, p] = True
        return vol.reshape(g.layers, g.height, g.width)


def coverage_layers(span_pix: np.ndarray, u0: np.ndarray, u1: np.ndarray, layers: int, height: int,
                    width: int) -> Iterator[np.ndarray]:
    """Per layer, the covered fraction of each voxel, from spans in layer units.

    Parameters
    ----------
    span_pix : (s,) int64
    u0, u1 : (s,) float64
        Span ends in layer units: voxel k covers ``[k, k + 1)``.
    layers, height, width : int

    Yields
    ------
    (height, width) float64 in [0, 1], one layer at a time (memory O(spans) + one layer).
    """
    K, npx = layers, width * height
    ka = np.clip(np.floor(u0).astype(np.int64), 0, K - 1)
    kb = np.clip(np.floor(u1).astype(np.int64), 0, K - 1)
    # partial contributions: the first and last layer of each span
    same = ka == kb
    part_k = np.concatenate([ka, kb[~same]])
    part_pix = np.concatenate([span_pix, span_pix[~same]])
    part_v = np.concatenate([np.where(same, u1 - u0, (ka + 1) - u0), (u1 - kb)[~same]])
    order = stable_argsort(part_k)
    part_k, part_pix, part_v = part_k[order], part_pix[order], part_v[order]
    pb = np.searchsorted(part_k, np.arange(K + 1))
    # fully covered layers ka < k < kb: +1 from ka + 1, -1 from kb
    full = ~same & (kb > ka + 1)
    ev_k = np.concatenate([ka[full] + 1, kb[full]])
    ev_pix = np.concatenate([span_pix[full], span_pix[full]])
    ev_d = np.concatenate([np.ones(int(full.sum()), np.int32), -np.ones(int(full.sum()), np.int32)])
    order = stable_argsort(ev_k)
    ev_k, ev_pix, ev_d = ev_k[order], ev_pix[order], ev_d[order]
    eb = np.searchsorted(ev_k, np.arange(K + 1))
    count = np.zeros(npx, np.int32)
    for k in range(K):
        s, e = eb[k], eb[k + 1]
        if e > s:
            np.add.at(count, ev_pix[s:e], ev_d[s:e])
        cov = count.astype(np.float64)
        s, e = pb[k], pb[k + 1]
        if e > s:
            np.add.at(cov, part_pix[s:e], part_v[s:e])
        np.clip(cov, 0.0, 1.0, out=cov)
        yield cov.reshape(height, width)


def trace(skel: Skeleton, grid: SliceGrid, method: str = "interval", bucket: int = DEFAULT_BUCKET,
          threads: int | None = None, strict: bool = False, cut_support: bool = True,
          batch: int = 256, spans: bool = False, span_tol: float | None = None,
          blend: str = "sum", lazy: bool = False) -> SliceResult:
    """Classify every voxel centre of ``grid`` (no trimming).

    Parameters
    ----------
    skel : Skeleton
    grid : SliceGrid
    method : {"interval", "sampling", "segment"}
    bucket : int
        Bucket edge in pixels (0: one bucket for the whole image).
    threads : int, optional
        Numba threads (default: all).
    strict : bool
        Interval method only: do not rely on the unimodality of each
        primitive's field along a ray; bound every piece with the directional
        Lipschitz bound (slower, needs no unproven property).
    cut_support : bool
        Interval method: cut rays at every support entry and exit as well as at
        each primitive's t* (tighter pieces, more breakpoints); False cuts at
        t* only, as EG22 does.
    batch : int
        Buckets per kernel launch (bounds the run buffers' memory).
    spans : bool
        Interval method only: also return the real-valued inside spans of
        every pixel column (see :class:`SliceResult`).
    span_tol : float, optional, mm
        Position tolerance of the span ends (default ``layer_height / 64``;
        at least ``layer_height / 65536``).
    blend : {"sum", "union"}
        ``union`` (``F = max_i f_i``) is traced strut by strut
        (:mod:`slicer._kernels.trace.union`), with the interval or sampling
        method; ``cut_support`` has no effect there.
    lazy : bool
        Interval method, sum blend: the lazy walk (docs/math.md §5.5): the
        same voxels with about half the primitive evaluations, but more
        bookkeeping per piece (slower today on the samples; see
        docs/benchmarks.md).
    """
    if method not in METHODS:
        raise GridError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")
    if is_grouped(skel):            # support groups: each traced alone, united (docs/supports.md)
        return trace_groups(trace, skel, grid, method=method, bucket=bucket, threads=threads, strict=strict,
                            cut_support=cut_support, batch=batch, spans=spans, span_tol=span_tol, blend=blend,
                            lazy=lazy)
    union = require_traceable(blend, method=method) == "union"
    span_tol = _check_spans(method, spans, span_tol, grid.layer_height)
    bk = build_buckets(skel, grid, bucket)
    B = bk.size
    n, sigma, norm = skel.degree, skel.sigma, skel.normalisation
    kmax = kprime_max(n, sigma, norm)
    todo = bk.nonempty()
    # biggest buckets first; within a launch, thread_order balances static schedules too
    todo = todo[np.argsort(-np.diff(bk.offsets)[todo], kind="stable")]
    ly, lx = np.divmod(np.arange(B * B), B)   # local row/column of each ray in a bucket
    rays = np.arange(B * B, dtype=np.int64)
    pix_parts, k0_parts, k1_parts = [], [], []
    xpix_parts, xz_parts = [], []
    nevals = 0
    t0 = time.perf_counter()
    kern = trace_union_buckets if union else trace_buckets
    with compiling("the tracer", [kern], ABOUT["tracer"]), numba_threads(threads) as nthreads:
        sizes = np.diff(bk.offsets)
        for s in range(0, len(todo), batch):
            chunk = thread_order(todo[s:s + batch], sizes[todo[s:s + batch]], nthreads)
            cap = B * B * RUNS_PER_RAY
            results = _run_batch(kern, METHODS[method], chunk, bk, grid, n, sigma, norm,
                                 kmax, strict, cut_support, cap, RUNS_FULL, spans, span_tol,
                                 None if union else lazy)
            for bidx, nrun, rk0, rk1, ne, nx, xz in results:
                nevals += ne
                by, bx = divmod(int(bidx), bk.nbx)
                pix_parts.append((bx * B, by * B, B, B, np.repeat(rays, nrun)))
                k0_parts.append(rk0)
                k1_parts.append(rk1)
                if spans:
                    ray_pix = (by * B + ly) * grid.width + (bx * B + lx)
                    xpix_parts.append(np.repeat(ray_pix, nx))
                    xz_parts.append(xz)
    elapsed = time.perf_counter() - t0
    if pix_parts:
        k0 = np.concatenate(k0_parts).astype(np.int64)
        k1 = np.concatenate(k1_parts).astype(np.int64)
        # by pixel, then k0: the buckets' runs, each bucket in ray order, merged row by row
        pix, order = rect_parts(pix_parts, grid.width, minor=k0)
        pix, k0, k1 = pix[order], k0[order], k1[order]
    else:
        pix = np.zeros(0, np.int64)
        k0 = np.zeros(0, np.int64)
        k1 = np.zeros(0, np.int64)
    stats = {"method": method, "bucket": B, "evaluations": int(nevals),
             "trace_seconds": elapsed, "threads": int(nthreads)}
    if union:
        stats["blend"] = "union"
    res = SliceResult(grid, pix, k0, k1, stats)
    if spans:
        stats["span_tol"] = span_tol
        res.span_pix, res.span_t0, res.span_t1 = _pair_crossings(grid, xpix_parts, xz_parts)
    return res


def _check_spans(method: str, spans: bool, span_tol, layer_height: float):
    """Validate the span options; returns the tolerance in mm (None without spans)."""
    if not spans:
        return None
    if method != "interval":
        raise GridError(f"spans (sub-layer crossings) need method 'interval', not {method!r}")
    if span_tol is None:
        return layer_height / 64.0
    span_tol = float(span_tol)
    if not (span_tol >= layer_height / 65536.0 and span_tol <= layer_height):
        raise GridError(f"span tolerance must lie in [layer_height/65536, layer_height] = "
                        f"[{layer_height / 65536.0:g}, {layer_height:g}] mm, got {span_tol!r}")
    return span_tol


def _pair_crossings(grid: SliceGrid, xpix_parts, xz_parts):
    """Inside spans from each ray's sorted crossings (entry, exit, entry, ...),
    clipped to the grid's z range; sorted by pixel then height."""
    if not xpix_parts:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e.copy()
    xpix = np.concatenate(xpix_parts).astype(np.int64)
    xz = np.concatenate(xz_parts)
    order = np.argsort(xpix, kind="stable")    # each ray's crossings are already in order
    xpix, xz = xpix[order], xz[order]
    if len(xpix) % 2:
        raise RuntimeError("internal error: odd number of crossings")   # pragma: no cover
    pix, t0, t1 = xpix[0::2], xz[0::2], xz[1::2]
    if np.any(pix != xpix[1::2]):
        raise RuntimeError("internal error: a ray has an odd number of crossings")  # pragma: no cover
    h = grid.layer_height
    zlo = grid.origin[2] - 0.5 * h
    zhi = grid.origin[2] + (grid.layers - 0.5) * h
    t0 = np.maximum(t0, zlo)
    t1 = np.minimum(t1, zhi)
    keep = t1 > t0
    return pix[keep], t0[keep], t1[keep]


def _run_batch(kern, code, chunk, bk: Buckets, grid: SliceGrid, n, sigma, norm, kmax, strict,
               cut_support, cap, RUNS_FULL, spans=False, span_tol=None, lazy=None):
    """Run the kernel on a batch of buckets; a bucket that fills its buffers
    keeps the rays it finished and resumes at the next one with more room.

    Returns, per bucket, ``(bucket, runs per ray, k0, k1, evaluations,
    crossings per ray, crossing heights)``. ``lazy`` (None: a kernel
    without the lazy walk, the union tracer) is the interval walk's option.
    """
    B = bk.size
    out = []
    done = {}   # bucket -> the parts of its rays finished so far, in ray order
    resume = {}   # bucket -> its first ray not yet traced
    cap0, xcap0 = cap, (cap if spans else 1)
    # the launchers' argument bundles (slicer._kernels.trace.summed.trace_buckets), one type each
    buckets = (int(bk.nbx), int(B), bk.offsets, bk.ids, bk.table, bk.boxes)
    layout = (int(grid.width), int(grid.height), float(grid.origin[0]), float(grid.origin[1]),
              float(grid.pixel_size[0]), float(grid.pixel_size[1]), float(grid.origin[2]),
              float(grid.layer_height), int(grid.layers))
    prim = (int(n), float(sigma), float(norm), float(kmax))
    opt = (bool(strict), bool(cut_support), bool(lazy), bool(spans), float(span_tol) if spans else 0.0)

    def launch(pending, scale):
        cap, xcap = cap0 * scale, xcap0 * (scale if spans else 1)
        nb = len(pending)
        ray_nrun = np.zeros((nb, B * B), np.int64)
        run_k0 = np.zeros((nb, cap), np.int32)
        run_k1 = np.zeros((nb, cap), np.int32)
        stats = np.zeros((nb, 3), np.int64)
        ray_nx = np.zeros((nb, B * B), np.int64)
        cross_z = np.zeros((nb, xcap))
        first = np.array([resume.get(int(b), 0) for b in pending], np.int64)
        with one_item_per_thread():
            kern(code, pending, first, buckets, layout, prim, opt, (ray_nrun, run_k0, run_k1, stats, ray_nx, cross_z))
        full = stats[:, 0] == RUNS_FULL
        for q in range(nb):
            used = int(ray_nrun[q].sum())
            xused = int(ray_nx[q].sum())
            b = int(pending[q])
            done.setdefault(b, []).append((ray_nrun[q], run_k0[q, :used], run_k1[q, :used], int(stats[q, 1]),
                                           ray_nx[q], cross_z[q, :xused].copy()))
            if full[q]:
                resume[b] = int(stats[q, 2])
            else:
                out.append((pending[q], *_join_parts(done.pop(b))))
        if full.any() and cap > B * B * (grid.layers + 2) and (not spans or xcap > B * B * (128 * grid.layers + 64)):
            # more runs than a bucket can hold: the kernel's stack, not the buffer, overflowed
            raise RuntimeError("internal error: the tracer's stack overflowed")  # pragma: no cover
        return full

    launch_until_fits(launch, chunk, "tracer")
    return out


def _join_parts(parts):
    """One bucket's result from the parts of its rays traced by successive
    launches (each part covers later rays than the one before):
    ``(runs per ray, k0, k1, evaluations, crossings per ray, crossing heights)``."""
    if len(parts) == 1:
        return parts[0]
    nrun, k0, k1, ne, nx, xz = zip(*parts)
    return (np.sum(nrun, axis=0), np.concatenate(k0), np.concatenate(k1), sum(ne), np.sum(nx, axis=0),
            np.concatenate(xz))


def trim(result: SliceResult, margin: int = 1) -> SliceResult:
    """Crop a result to its inside voxels (and spans) plus ``margin`` empty
    voxels per side (clipped to the traced grid). An empty result keeps its
    XY size and gets zero layers."""
    g = result.grid
    sp = result.has_spans and len(result.span_pix) > 0
    if result.n_runs == 0 and not sp:
        out = SliceResult(g.sub(0, 0, 0, g.width, g.height, 0), result.pix, result.k0, result.k1,
                          dict(result.stats))
        if result.has_spans:
            out.span_pix, out.span_t0, out.span_t1 = result.span_pix, result.span_t0, result.span_t1
        return out
    pix_all = result.pix
    klo, khi = [], []
    if result.n_runs:
        klo.append(int(result.k0.min()))
        khi.append(int(result.k1.max()) - 1)
    if sp:
        pix_all = np.concatenate([pix_all, result.span_pix])
        u = (np.array([result.span_t0.min(), result.span_t1.max()]) - g.origin[2]) / g.layer_height + 0.5
        klo.append(int(np.floor(u[0])))
        khi.append(min(int(np.floor(u[1])), g.layers - 1))
    j, i = np.divmod(pix_all, g.width)
    i0 = max(int(i.min()) - margin, 0)
    i1 = min(int(i.max()) + margin, g.width - 1)
    j0 = max(int(j.min()) - margin, 0)
    j1 = min(int(j.max()) + margin, g.height - 1)
    k0 = max(min(klo) - margin, 0)
    k1 = min(max(khi) + margin, g.layers - 1)
    sub = g.sub(i0, j0, k0, i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1)
    j, i = np.divmod(result.pix, g.width)
    pix = (j - j0) * sub.width + (i - i0)
    out = SliceResult(sub, pix, result.k0 - k0, result.k1 - k0, dict(result.stats))
    if result.has_spans:
        j, i = np.divmod(result.span_pix, g.width)
        out.span_pix = (j - j0) * sub.width + (i - i0)
        out.span_t0, out.span_t1 = result.span_t0, result.span_t1
    return out


def slice_skeleton(skel: Skeleton, pixel_size: float, pixel_size_y: float | None = None,
                   layer_height: float | None = None, bounds=None, method: str = "interval",
                   bucket: int = DEFAULT_BUCKET, threads: int | None = None, strict: bool = False,
                   spans: bool = False, span_tol: float | None = None, blend: str = "sum") -> SliceResult:
    """Slice a skeleton into voxel layers, every voxel centre classified exactly.

    Parameters
    ----------
    skel : Skeleton
    pixel_size : float, mm
        Pixel pitch along x (and y unless ``pixel_size_y``).
    pixel_size_y : float, optional, mm
    layer_height : float, optional, mm
        Defaults to ``pixel_size``.
    bounds : (6,) float, optional, mm
        ``X0 Y0 Z0 X1 Y1 Z1``. Default: the whole surface plus one empty voxel
        of margin on every side (the grid is traced over the supports and
        trimmed to the model: no layer outside it).
    method : {"interval", "sampling", "segment"}
    bucket : int
        Bucket edge in pixels (0: a single global list).
    threads : int, optional
    strict : bool
        See :func:`trace`.
    spans, span_tol
        Real-valued inside spans per pixel column, ends to ``span_tol`` mm
        (default layer height / 64); interval method only. See :func:`trace`.
    blend : {"sum", "union"}
        How segment fields combine (:mod:`slicer.model.blend`): ``"union"`` classifies
        every centre as ``max_i f_i >= 1`` (interval or sampling method).

    Returns
    -------
    SliceResult

    Examples
    --------
    >>> s = Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 1.0]])
    >>> r = slice_skeleton(s, 0.25)
    >>> r.grid.width, r.grid.layers
    (9, 21)
    """
    require_traceable(blend, method=method)
    if skel.n_segments == 0:
        raise GridError("the scene has no segments: nothing to slice")
    grid = make_grid(skel.support_bounds(), pixel_size, pixel_size_y, layer_height, bounds)
    res = trace(skel, grid, method=method, bucket=bucket, threads=threads, strict=strict,
                spans=spans, span_tol=span_tol, blend=blend)
    return res if bounds is not None else trim(res)


__all__ = ["SliceResult", "slice_skeleton", "trace", "trim", "coverage_layers", "METHODS"]
