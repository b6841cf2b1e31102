"""Slicing API: a skeleton and a grid in, inside runs per pixel column out.

The tracer returns, for every pixel column, the runs ``[k0, k1)`` of layer
indices whose voxel centres are inside the solid. Layers are produced from the
runs one at a time (:meth:`SliceResult.iter_layers`), by joint iteration of
the runs' ends and the layer index, so memory is O(runs) + one layer.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from .buckets import Buckets, build_buckets
from .errors import GridError
from .grid import SliceGrid, make_grid
from .skeleton import Skeleton

#: tracing methods and their kernel codes
METHODS = {"interval": 0, "sampling": 1, "segment": 2}


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
        ``trace_seconds``, ``threads``.
    """

    grid: SliceGrid
    pix: np.ndarray
    k0: np.ndarray
    k1: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def n_runs(self) -> int:
        return int(self.pix.shape[0])

    def iter_layers(self, value: int = 255) -> Iterator[np.ndarray]:
        """Yield each layer as a (height, width) uint8 image, bottom layer first.

        Pixels inside are ``value``, outside 0. Only one layer is held at a
        time; each run contributes one "set" event at k0 and one "clear" event
        at k1.
        """
        g = self.grid
        K = g.layers
        ev_k = np.concatenate([self.k0, self.k1])
        ev_pix = np.concatenate([self.pix, self.pix])
        ev_val = np.concatenate([np.full(self.n_runs, value, np.uint8), np.zeros(self.n_runs, np.uint8)])
        order = np.argsort(ev_k, kind="stable")
        ev_k, ev_pix, ev_val = ev_k[order], ev_pix[order], ev_val[order]
        bounds = np.searchsorted(ev_k, np.arange(K + 1))
        img = np.zeros(g.width * g.height, np.uint8)
        for k in range(K):
            s, e = bounds[k], bounds[k + 1]
            if e > s:
                img[ev_pix[s:e]] = ev_val[s:e]
            yield img.reshape(g.height, g.width).copy()

    def volume(self) -> np.ndarray:
        """The whole voxel volume, (layers, height, width) bool. For tests and
        small grids only."""
        g = self.grid
        vol = np.zeros((g.layers, g.height * g.width), bool)
        for p, a, b in zip(self.pix, self.k0, self.k1):
            vol[a:b, p] = True
        return vol.reshape(g.layers, g.height, g.width)


@contextlib.contextmanager
def numba_threads(n: int | None):
    """Temporarily limit Numba's thread count (``None``: leave it)."""
    import numba

    if n is None:
        yield numba.get_num_threads()
        return
    n = int(n)
    if n < 1:
        raise GridError(f"threads must be >= 1, got {n}")
    old = numba.get_num_threads()
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(old)


def trace(skel: Skeleton, grid: SliceGrid, method: str = "interval", bucket: int = 64,
          threads: int | None = None, strict: bool = False, cut_support: bool = True,
          batch: int = 256) -> SliceResult:
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
    """
    from ._kernels.raysupport import kprime_max
    from ._kernels.trace import RUNS_FULL, trace_buckets

    if method not in METHODS:
        raise GridError(f"unknown method {method!r}; choose one of {sorted(METHODS)}")
    bk = build_buckets(skel, grid, bucket)
    B = bk.size
    n, sigma, norm = skel.degree, skel.sigma, skel.normalisation
    kmax = kprime_max(n, sigma, norm)
    todo = bk.nonempty()
    # biggest buckets first: with chunk size 1 the threads share the load evenly
    todo = todo[np.argsort(-np.diff(bk.offsets)[todo], kind="stable")]
    ly, lx = np.divmod(np.arange(B * B), B)   # local row/column of each ray in a bucket
    pix_parts, k0_parts, k1_parts = [], [], []
    nevals = 0
    t0 = time.perf_counter()
    with numba_threads(threads) as nthreads:
        import numba

        for s in range(0, len(todo), batch):
            chunk = todo[s:s + batch]
            cap = B * B * 4
            results = _run_batch(trace_buckets, METHODS[method], chunk, bk, grid, n, sigma, norm,
                                 kmax, strict, cut_support, cap, numba, RUNS_FULL)
            for bidx, nrun, rk0, rk1, ne in results:
                nevals += ne
                by, bx = divmod(int(bidx), bk.nbx)
                i = bx * B + lx
                j = by * B + ly
                has = nrun > 0
                p = (j * grid.width + i)[has]
                pix_parts.append(np.repeat(p, nrun[has]))
                k0_parts.append(rk0)
                k1_parts.append(rk1)
    elapsed = time.perf_counter() - t0
    if pix_parts:
        pix = np.concatenate(pix_parts).astype(np.int64)
        k0 = np.concatenate(k0_parts).astype(np.int64)
        k1 = np.concatenate(k1_parts).astype(np.int64)
        order = np.lexsort((k0, pix))
        pix, k0, k1 = pix[order], k0[order], k1[order]
    else:
        pix = np.zeros(0, np.int64)
        k0 = np.zeros(0, np.int64)
        k1 = np.zeros(0, np.int64)
    stats = {"method": method, "bucket": B, "evaluations": int(nevals),
             "trace_seconds": elapsed, "threads": int(nthreads)}
    return SliceResult(grid, pix, k0, k1, stats)


def _run_batch(kern, code, chunk, bk: Buckets, grid: SliceGrid, n, sigma, norm, kmax, strict,
               cut_support, cap, numba, RUNS_FULL):
    """Run the kernel on a batch of buckets, retrying overflowing ones with more room."""
    B = bk.size
    out = []
    pending = chunk
    while len(pending):
        nb = len(pending)
        ray_nrun = np.zeros((nb, B * B), np.int64)
        run_k0 = np.zeros((nb, cap), np.int32)
        run_k1 = np.zeros((nb, cap), np.int32)
        stats = np.zeros((nb, 2), np.int64)
        with numba.parallel_chunksize(1):
            kern(code, pending, bk.nbx, B, grid.width, grid.height, bk.offsets, bk.ids, bk.table,
                 bk.boxes, grid.origin[0], grid.origin[1], grid.pixel_size[0],
                 grid.pixel_size[1], grid.origin[2], grid.layer_height, grid.layers, n, sigma, norm,
                 kmax, strict, cut_support, bk.longest(), cap, ray_nrun, run_k0, run_k1, stats)
        retry = []
        for q in range(nb):
            if stats[q, 0] == RUNS_FULL:
                retry.append(pending[q])
                continue
            used = int(ray_nrun[q].sum())
            out.append((pending[q], ray_nrun[q], run_k0[q, :used], run_k1[q, :used], int(stats[q, 1])))
        pending = np.array(retry, dtype=np.int64)
        cap *= 4
    return out


def trim(result: SliceResult, margin: int = 1) -> SliceResult:
    """Crop a result to its inside voxels plus ``margin`` empty voxels per side
    (clipped to the traced grid). An empty result keeps its XY size and gets
    zero layers."""
    g = result.grid
    if result.n_runs == 0:
        return SliceResult(g.sub(0, 0, 0, g.width, g.height, 0), result.pix, result.k0, result.k1,
                           dict(result.stats))
    j, i = np.divmod(result.pix, g.width)
    i0 = max(int(i.min()) - margin, 0)
    i1 = min(int(i.max()) + margin, g.width - 1)
    j0 = max(int(j.min()) - margin, 0)
    j1 = min(int(j.max()) + margin, g.height - 1)
    k0 = max(int(result.k0.min()) - margin, 0)
    k1 = min(int(result.k1.max()) - 1 + margin, g.layers - 1)
    sub = g.sub(i0, j0, k0, i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1)
    pix = (j - j0) * sub.width + (i - i0)
    return SliceResult(sub, pix, result.k0 - k0, result.k1 - k0, dict(result.stats))


def slice_skeleton(skel: Skeleton, pixel_size: float, pixel_size_y: float | None = None,
                   layer_height: float | None = None, bounds=None, method: str = "interval",
                   bucket: int = 64, threads: int | None = None, strict: bool = False) -> SliceResult:
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
    if skel.n_segments == 0:
        raise GridError("the scene has no segments: nothing to slice")
    grid = make_grid(skel.support_bounds(), pixel_size, pixel_size_y, layer_height, bounds)
    res = trace(skel, grid, method=method, bucket=bucket, threads=threads, strict=strict)
    return res if bounds is not None else trim(res)


__all__ = ["SliceResult", "slice_skeleton", "trace", "trim", "METHODS", "numba_threads"]
