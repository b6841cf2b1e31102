"""Memory-bounded slicing: XY tiles x Z slabs, traced anywhere, merged in order.

Pixel columns are independent, so the job grid is cut into XY tiles (aligned
to the bucket size) and, when the inside runs of the whole plate would not
fit the memory budget, into Z slabs of layers. A tile of a slab is
``trace(sub_skeleton, grid.sub(...))``: only the segments whose support
reaches the tile are sent to the task (:func:`trace_tile`, a top-level
function of plain arrays, so it runs in-process, in a pool or on Dask).
The tiles of a slab are merged in tile order (never completion order) into
one :class:`~slicer.tracer.slicing.SliceResult`; its layers are written before the
next slab is traced or, when the plan holds two slabs in memory
(``prefetch``), while the next slab is traced on a background thread.

With default bounds the output is trimmed to the model (plus one voxel of
margin), which needs the model's extent before the first layer is written:
when the plan has several slabs, a first pass traces every tile and keeps
only its bounding box, then the trimmed grid is streamed (so such jobs trace
about twice; give ``--bounds`` to avoid it). With one slab the merged result
is trimmed in memory, exactly as :func:`~slicer.tracer.slicing.slice_skeleton`.
Plans are made by :mod:`slicer.scale.tileplan`; the task and the merge live in
:mod:`slicer.scale.tiletask`; executors in :mod:`slicer.scale.executors`.

Every voxel centre is classified exactly whatever the plan; tile origins are
computed from the job grid (``grid.sub``), so plans with different tile or
slab boundaries can only disagree on centres whose field is 1 to within
floating-point rounding. The same plan gives byte-identical output for any
executor and thread count.
"""
from __future__ import annotations

import contextlib
import dataclasses
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from typing import Iterator

import numpy as np

from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.errors import GridError
from slicer.scale.executors import SerialExecutor, map_ordered, open_executor
from slicer.scale.executors import executor_info as describe
from slicer.model.field import support_boxes
from slicer.tracer.grid import SliceGrid, make_grid
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult, trace, trim
from slicer.scale.tileplan import (TilePlan, auto_budget, current_rss, format_size, parse_size, plan_job, plan_slice,
                       sample_runs)
from slicer.scale.tiletask import TraceOptions, cull, merge_tiles, trace_tile


class _Runner:
    """Traces (slab, tile) pieces of a plan through an executor, in order."""

    def __init__(self, skel, plan: TilePlan, opts: TraceOptions, executor, task_threads, progress):
        self.skel = skel
        self.plan = plan
        self.opts = dataclasses.replace(opts, threads=task_threads if task_threads else opts.threads)
        self.executor = executor
        self.boxes = support_boxes(skel)
        self.progress = progress
        self.evaluations = 0
        self.seconds = 0.0
        self.threads = None

    def _bar(self, total: int, desc: str):
        from tqdm import tqdm

        return tqdm(total=total, unit="tile", desc=desc, leave=False,
                    disable=(None if self.progress is None else not self.progress))

    def run(self, pieces, extent: bool, desc: str) -> Iterator:
        """Yield ``(piece, result or None)`` in ``pieces`` order; a piece is
        ``(i0, j0, k0, w, h, layers)`` in job-grid indices."""
        g = self.plan.grid
        pieces = list(pieces)

        def tasks():   # culled lazily: only the tiles in flight hold their segments
            for i0, j0, k0, w, h, nl in pieces:
                sub = g.sub(i0, j0, k0, w, h, nl)
                arrays = cull(self.skel, *self.boxes, sub)
                yield None if arrays is None else (*arrays, self.skel.degree, self.skel.sigma, sub,
                                                   self.opts, extent)

        results = map_ordered(self.executor, trace_tile, tasks(), self.plan.window)
        with self._bar(len(pieces), desc) as bar:
            for piece, r in zip(pieces, results):
                if r is not None:
                    self.evaluations += r["evaluations"]
                    self.seconds += r["seconds"]
                    self.threads = r["threads"]
                bar.update(1)
                yield piece, r


def _until(pieces_results, stop: threading.Event) -> Iterator:
    """``pieces_results`` until ``stop`` is set (then the rest are cancelled)."""
    try:
        for item in pieces_results:
            if stop.is_set():
                return
            yield item
    finally:
        pieces_results.close()


def _in_order(make, slabs, prefetch: bool) -> Iterator[SliceResult]:
    """``make(ka, kb, stop)`` for each slab, yielded in order.

    With ``prefetch`` the next slab is made on one background thread while
    the caller holds the current one (the tracing kernels release the GIL);
    if the caller stops early or fails, the slab in progress is abandoned at
    its next tile.
    """
    stop = threading.Event()
    if not prefetch or len(slabs) < 2:
        for ka, kb in slabs:
            yield make(ka, kb, stop)
        return
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="next-slab")
    fut = pool.submit(make, *slabs[0], stop)
    try:
        for nxt in [*slabs[1:], None]:
            res = fut.result()
            fut = None if nxt is None else pool.submit(make, *nxt, stop)
            yield res
            del res
    finally:
        stop.set()
        pool.shutdown(wait=True, cancel_futures=True)


def _merge_slab(plan: TilePlan, out_grid: SliceGrid, oi: int, oj: int, pieces_results, stats) -> SliceResult:
    parts = []
    for (i0, j0, _k0, w, _h, _nl), r in pieces_results:
        if r is not None:
            parts.append((i0 - oi, j0 - oj, w, r["arrays"]))
    return merge_tiles(out_grid, parts, stats)


class StreamedResult:
    """A result produced slab by slab: layers are made as they are consumed.

    It has the reading interface of :class:`SliceResult` that writers use
    (``grid``, ``stats``, ``n_runs``, ``has_spans``, :meth:`iter_layers`,
    :meth:`iter_coverage`), but holds the runs of one slab at a time.
    Iterate it once.
    """

    def __init__(self, runner: _Runner, grid: SliceGrid, origin_ij: tuple[int, int, int], stats: dict,
                 n_runs: int | None, box: tuple[int, ...] | None = None):
        self._runner = runner
        self.grid = grid
        self._o = origin_ij
        self.stats = stats
        self._n_runs = n_runs
        self._box = box
        self.has_spans = runner.opts.spans
        self._close = None

    def _own(self, stack: contextlib.ExitStack) -> None:
        """Close ``stack`` (the executor) when the slabs are done or the result is dropped."""
        self._close = weakref.finalize(self, stack.close)

    def close(self) -> None:
        """Shut the executor down (done by itself after the last slab)."""
        if self._close is not None:
            self._close()

    @property
    def n_runs(self) -> int:
        """Inside runs (known before streaming when the job was trimmed; else
        counted as slabs are produced)."""
        return int(self._n_runs or 0)

    def inside_box(self) -> tuple[int, int, int, int, int, int] | None:
        """Index box ``(i0, i1, j0, j1, k0, k1)`` (inclusive) of the inside
        voxels on :attr:`grid` (see :meth:`SliceResult.inside_box`), known
        from the extent pass of a trimmed job; None when nothing is inside.

        Raises
        ------
        GridError
            The job was not trimmed (explicit bounds), so the box is unknown
            before the slabs are traced.
        """
        if self._box is None:
            raise GridError("the inside voxels' extent is known before streaming only for jobs without --bounds")
        return self._box

    def iter_slabs(self) -> Iterator[SliceResult]:
        """Each slab as a SliceResult on its sub-grid of :attr:`grid`, bottom first.

        With a prefetching plan (:attr:`TilePlan.prefetch`) the next slab is
        traced on a background thread while the caller uses this one, so at
        most two slabs are held at once; the slabs themselves are the same.
        """
        plan, g = self._runner.plan, self.grid
        oi, oj, ok = self._o
        tiles = plan.tiles(oi, oj, oi + g.width, oj + g.height)

        def traced(ka: int, kb: int, stop: threading.Event) -> SliceResult | None:
            pieces = [(i0, j0, ka, w, h, kb - ka) for i0, j0, w, h in tiles]
            slab_grid = g.sub(0, 0, ka - ok, g.width, g.height, kb - ka)
            return _merge_slab(plan, slab_grid, oi, oj,
                               _until(self._runner.run(pieces, False, "tracing"), stop), self.stats)

        counted = 0
        try:
            for res in _in_order(traced, plan.slabs(ok, ok + g.layers), plan.prefetch):
                counted += res.n_runs
                yield res
                del res     # before the slab after the next is traced
        finally:
            self.close()
        self.stats.update(evaluations=self._runner.evaluations, trace_seconds=self._runner.seconds)
        self._n_runs = counted   # runs crossing slab boundaries count once per slab

    def _chain(self, name: str, *args) -> Iterator[np.ndarray]:
        for slab in self.iter_slabs():
            layers = getattr(slab, name)(*args)
            del slab    # only the layer generator keeps the slab, until it is done
            yield from layers
            del layers

    def iter_layers(self, value: int = 255) -> Iterator[np.ndarray]:
        """Each layer as a (height, width) uint8 image, bottom first (see
        :meth:`SliceResult.iter_layers`)."""
        return self._chain("iter_layers", value)

    def iter_coverage(self) -> Iterator[np.ndarray]:
        """Each layer's z coverage (see :meth:`SliceResult.iter_coverage`)."""
        return self._chain("iter_coverage")


def slice_planned(skel: Skeleton, pixel_size: float, pixel_size_y: float | None = None,
                  layer_height: float | None = None, bounds=None, method: str = "interval",
                  bucket: int = DEFAULT_BUCKET, threads: int | None = None, strict: bool = False,
                  spans: bool = False, span_tol: float | None = None, *, max_memory=None,
                  executor=None, executor_info=None, workers: int | None = None,
                  scheduler: str | None = None, tile: int | None = None,
                  progress: bool | None = None, plan: TilePlan | None = None, blend: str = "sum"):
    """:func:`slicer.tracer.slicing.slice_skeleton` within a memory budget, on any executor.

    Parameters
    ----------
    skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict, blend
        As :func:`slicer.tracer.slicing.slice_skeleton`.
    spans, span_tol
        As :func:`slicer.tracer.slicing.trace`.
    max_memory : int or str, optional
        Budget (:func:`parse_size`); None: unlimited.
    executor : str or concurrent.futures.Executor, optional
        Where tiles run: an executor kind (``"serial"``, ``"threads"``,
        ``"processes"``, ``"dask"``), opened after the plan is made and
        closed when the result has been read, or an open executor (then
        pass ``executor_info`` too; see
        :func:`slicer.scale.executors.open_executor`). Default: this process.
    executor_info : slicer.scale.executors.ExecutorInfo, optional
        Worker count and threads per task of an open ``executor``.
    workers, scheduler
        For an executor kind: pool size, Dask scheduler address.
    tile : int, optional
        Tile edge in pixels (see :func:`plan_job`).
    progress : bool or None
        tqdm bar over tiles; None: only on a terminal.
    plan : TilePlan, optional
        A plan from :func:`plan_slice` (skips planning).

    Returns
    -------
    SliceResult or StreamedResult
        A SliceResult when the plan has one slab (held in memory), else a
        StreamedResult that traces slab by slab while it is read.
    """
    stack = contextlib.ExitStack()
    if executor is None or isinstance(executor, str):
        kind = executor or "serial"
        if plan is None:    # plan (and refuse absurd requests) before any cluster starts
            plan = plan_slice(skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads,
                              strict, spans, span_tol, max_memory=max_memory,
                              executor_info=executor_info or describe(kind, workers, scheduler), tile=tile,
                              blend=blend)
        ex, info = stack.enter_context(open_executor(kind, workers, scheduler))
    else:
        ex, info = executor, executor_info
        if plan is None:
            plan = plan_slice(skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads,
                              strict, spans, span_tol, max_memory=max_memory, executor_info=info, tile=tile,
                              blend=blend)
    opts = TraceOptions(method, bucket, threads, strict, spans, span_tol, blend)
    try:
        res = _run_plan(skel, plan, opts, ex, info, progress)
    except BaseException:
        stack.close()
        raise
    if isinstance(res, StreamedResult):
        res._own(stack.pop_all())    # closed once the layers have been read
    else:
        stack.close()
    return res


def _compile_before_workers(skel: Skeleton, opts: TraceOptions) -> None:
    """Compile the tracer in this process before worker processes start (a tiny trace of one strut with the
    job's options): the workers on this machine then load it from the compiled cache, one compile per
    machine instead of one per worker (docs/scale.md, "A cold machine")."""
    one = Skeleton([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [[0, 1]], [[0.5, 0.5]], degree=skel.degree, sigma=skel.sigma)
    trace(one, make_grid(one.support_bounds(), 0.25), **{**opts.trace_kwargs(), "threads": 1})


def _run_plan(skel, plan: TilePlan, opts: TraceOptions, ex, info, progress):
    if ex is None:
        ex = SerialExecutor()
    if info is not None and info.kind in ("processes", "dask"):
        _compile_before_workers(skel, opts)
    task_threads = info.task_threads if info is not None else None
    runner = _Runner(skel, plan, opts, ex, task_threads, progress)
    g = plan.grid
    stats = {"method": opts.method, "bucket": opts.bucket if opts.bucket else max(g.width, g.height),
             "threads": task_threads if task_threads else opts.threads, "plan": plan.to_dict()}
    if plan.n_slabs == 1:
        pieces = [(i0, j0, 0, w, h, g.layers) for i0, j0, w, h in plan.tiles()]
        if len(pieces) == 1 and isinstance(ex, SerialExecutor):
            res = trace(skel, g, **opts.trace_kwargs())     # today's path, exactly
            res.stats["plan"] = plan.to_dict()
        else:
            res = _merge_slab(plan, g, 0, 0, runner.run(pieces, False, "tracing"), stats)
            res.stats.update(evaluations=runner.evaluations, trace_seconds=runner.seconds,
                             threads=runner.threads)
        return trim(res) if plan.trim else res
    if not plan.trim:
        return StreamedResult(runner, g, (0, 0, 0), stats, None)
    # first pass: the model's extent, keeping only a box per tile
    box = None
    runs = 0
    pieces = [(i0, j0, ka, w, h, kb - ka) for ka, kb in plan.slabs() for i0, j0, w, h in plan.tiles()]
    for (i0, j0, k0, _w, _h, _nl), r in runner.run(pieces, True, "extent"):
        if r is None or r["bbox"] is None:
            continue
        runs += r["runs"]
        a = r["bbox"]
        b = (a[0] + i0, a[1] + i0, a[2] + j0, a[3] + j0, a[4] + k0, a[5] + k0)
        box = b if box is None else (min(box[0], b[0]), max(box[1], b[1]), min(box[2], b[2]),
                                     max(box[3], b[3]), min(box[4], b[4]), max(box[5], b[5]))
    if box is None:
        return SliceResult(g.sub(0, 0, 0, g.width, g.height, 0), np.zeros(0, np.int64),
                           np.zeros(0, np.int64), np.zeros(0, np.int64), stats)
    i0, j0, k0 = max(box[0] - 1, 0), max(box[2] - 1, 0), max(box[4] - 1, 0)
    i1, j1, k1 = min(box[1] + 1, g.width - 1), min(box[3] + 1, g.height - 1), min(box[5] + 1, g.layers - 1)
    out = g.sub(i0, j0, k0, i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1)
    inside = (box[0] - i0, box[1] - i0, box[2] - j0, box[3] - j0, box[4] - k0, box[5] - k0)
    # runs split at slab boundaries were counted once per slab: an upper bound
    return StreamedResult(runner, out, (i0, j0, k0), stats, runs, inside)



__all__ = ["TilePlan", "TraceOptions", "StreamedResult", "plan_job", "plan_slice", "slice_planned",
           "merge_tiles", "trace_tile", "cull", "sample_runs", "parse_size", "format_size",
           "current_rss", "auto_budget"]
