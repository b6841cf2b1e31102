"""Plans for tiled slicing: the memory model, budgets, and tile/slab sizes.

A plan cuts the job grid into XY tiles (aligned to the bucket size) and Z
slabs so that the estimated peak memory fits a budget (``--max-memory``).
The estimate counts the process as it is, the scene, one layer image, the
runs of one slab while its layers are produced (of two when the next slab is
traced while this one is written: ``prefetch``), and the tiles in flight;
runs per pixel column come from tracing a small deterministic sample of
columns when the worst case (``ceil(layers / 2)`` runs a column) does not
fit. Plans depend on the grid, the options and the budget only (never on
timing), so a job is reproducible. See :mod:`slicer.scale.tiles`.
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass

import numpy as np

from slicer._kernels.runtime.launch import cores
from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.model.field import support_boxes
from slicer.errors import GridError, OptionError
from slicer.tracer.grid import SliceGrid, make_grid
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import trace
from slicer.scale.tiletask import TraceOptions, cull, trace_tile

# ---------------------------------------------------------------- memory model (bytes)
#: held per inside run of a slab while its layers are produced: the merged
#: int64 pix/k0/k1 (24) plus the event arrays and sort of ``iter_layers`` (84)
BYTES_PER_RUN = 112
#: extra per run when spans are kept (3 arrays + ``iter_coverage`` temporaries)
BYTES_PER_SPAN = 176
#: per run of a tile in flight (the tracer's parts, concatenation and sort)
BYTES_PER_TILE_RUN = 80
#: per pixel of a tile in flight (the tracer's per-ray buffers: nrun, k0/k1 room)
BYTES_PER_TILE_PIXEL = 48
#: per pixel of the plate: the layer image, its copy and the writer's encoding
BYTES_PER_LAYER_PIXEL = 6
#: the same with spans: float64 coverage layers and their anti-aliasing
BYTES_PER_COVERAGE_PIXEL = 40
#: per segment of the scene: arrays, segment table, support boxes, culling masks
BYTES_PER_SEGMENT = 320
#: a worker process of a local pool (interpreter, NumPy, Numba, kernels)
WORKER_PROCESS_BYTES = 300 * 2**20
#: largest tile edge in pixels
MAX_TILE = 1024
#: sample used to estimate runs per column: windows x (edge x edge) columns
SAMPLE_WINDOWS = 32
SAMPLE_EDGE = 4
#: the estimated run count is multiplied by this before planning
SAFETY = 1.5

_UNITS = {"": 1, "b": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40,
          "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def parse_size(text) -> int | None:
    """A memory size in bytes: ``"2GB"`` (10^9), ``"2GiB"`` or ``"2G"`` (2^30),
    ``"512MB"``, ``"1.5e9"``; ``None``, ``"none"`` or ``"0"``: no limit.

    Examples
    --------
    >>> parse_size("2GB"), parse_size("1.5 GiB"), parse_size("512m"), parse_size("none")
    (2000000000, 1610612736, 536870912, None)
    """
    if text is None:
        return None
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value, unit = float(text), ""
    else:
        s = str(text).strip().lower()
        if s in ("none", "unlimited", "0"):
            return None
        m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:e[+-]?[0-9]+)?)\s*([a-z]*)", s)
        if not m or m.group(2) not in _UNITS:
            raise OptionError(f"--max-memory: cannot read {text!r}; use e.g. 2GB, 1.5GiB, 800MB or none")
        value, unit = float(m.group(1)), m.group(2)
    n = value * _UNITS[unit]
    if not math.isfinite(n) or n <= 0:
        if n == 0:
            return None
        raise OptionError(f"--max-memory must be a positive size, got {text!r}")
    return int(n)


def format_size(n: float) -> str:
    """Bytes as a short human string (binary units): ``1.5 GiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"  # pragma: no cover


def auto_budget() -> int | None:
    """Half of the machine's physical memory, bytes (None where unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2)
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return None


def current_rss() -> int:
    """Resident memory of this process now, bytes (0 where unknown)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):  # pragma: no cover - not Linux
        return 0


# ---------------------------------------------------------------- planning
@dataclass(frozen=True)
class TilePlan:
    """How a job is cut: XY tiles of ``tile`` px, slabs of ``slab`` layers.

    Attributes
    ----------
    grid : SliceGrid
        The traced grid (with default bounds the output is its trim).
    tile, slab : int
        Tile edge in pixels, layers per slab.
    budget : int or None
        Memory budget, bytes (None: unlimited).
    runs_per_column : float
        Inside runs per pixel column over all layers, estimated (or an
        upper bound when not sampled).
    sampled : bool
    estimate : dict
        Peak memory estimate by part, bytes (``total`` included).
    seconds : float or None
        Rough trace time from the sample (None if not sampled).
    window : int
        Tiles in flight at once.
    trim : bool
        Default bounds: the output is trimmed to the model.
    prefetch : bool
        The next slab is traced while this one's layers are written (the
        estimate then holds the runs of two slabs).
    """

    grid: SliceGrid
    tile: int
    slab: int
    budget: int | None
    runs_per_column: float
    sampled: bool
    estimate: dict
    seconds: float | None
    window: int
    trim: bool
    prefetch: bool = False

    def tiles(self, i0: int = 0, j0: int = 0, i1: int | None = None, j1: int | None = None):
        """XY tiles ``(i0, j0, w, h)`` covering columns [i0, i1) and rows [j0, j1),
        on the tile lattice of the job grid, row-major."""
        g, T = self.grid, self.tile
        i1 = g.width if i1 is None else i1
        j1 = g.height if j1 is None else j1
        out = []
        for tj in range((j0 // T) * T, j1, T):
            for ti in range((i0 // T) * T, i1, T):
                a, b = max(ti, i0), max(tj, j0)
                out.append((a, b, min(ti + T, i1) - a, min(tj + T, j1) - b))
        return out

    def slabs(self, k0: int = 0, k1: int | None = None):
        """Layer ranges ``(ka, kb)`` covering [k0, k1)."""
        k1 = self.grid.layers if k1 is None else k1
        return [(a, min(a + self.slab, k1)) for a in range(k0, k1, self.slab)] if k1 > k0 else []

    @property
    def n_tiles(self) -> int:
        return len(self.tiles())

    @property
    def n_slabs(self) -> int:
        return max(1, len(self.slabs()))

    @property
    def passes(self) -> int:
        return 2 if (self.trim and self.n_slabs > 1) else 1

    def to_dict(self) -> dict:
        return {"grid": self.grid.to_dict(), "tile": self.tile, "tiles": self.n_tiles, "slab": self.slab,
                "slabs": self.n_slabs, "passes": self.passes, "budget": self.budget,
                "runs_per_column": self.runs_per_column, "sampled": self.sampled,
                "estimate": dict(self.estimate), "seconds": self.seconds, "window": self.window,
                "trim": self.trim, "prefetch": self.prefetch}

    def describe(self) -> str:
        g = self.grid
        e = self.estimate
        lines = [
            f"grid:      {g.width} x {g.height} px x {g.layers} layers = {g.n_voxels:.3g} voxels"
            + (" (trimmed to the model after tracing)" if self.trim else ""),
            f"           pixel {g.pixel_size[0]:g} x {g.pixel_size[1]:g} mm, layer {g.layer_height:g} mm, "
            f"origin ({', '.join(f'{v:g}' for v in g.origin)}) mm",
            f"tiles:     {self.n_tiles} of up to {self.tile} x {self.tile} px, {self.window} in flight",
            f"slabs:     {self.n_slabs} of up to {self.slab} layers"
            + (" (2 passes: the first finds the model's extent; give --bounds to avoid it)"
               if self.passes == 2 else "")
            + ("; the next is traced while one is written" if self.prefetch else ""),
            f"runs:      {self.runs_per_column:.3g} per column "
            + ("(estimated from a sample)" if self.sampled else "(upper bound, not sampled)"),
            f"memory:    ~{format_size(e['total'])} peak estimated"
            + (f" (budget {format_size(self.budget)})" if self.budget else " (no budget)")
            + f": process {format_size(e['process'])}, scene {format_size(e['scene'])}, "
              f"runs {format_size(e['runs'])}, tiles {format_size(e['tiles'])}, "
              f"layer {format_size(e['layer'])}",
        ]
        if self.seconds is not None:
            lines.append(f"time:      ~{_duration(self.seconds * self.passes)} to trace (rough, from the sample)")
        return "\n".join(lines)


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.1f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


def _r2(n: int) -> np.ndarray:
    """First n points of the R2 low-discrepancy sequence in [0, 1)^2."""
    phi = 1.324717957244746
    a = np.array([1 / phi, 1 / phi**2])
    return (0.5 + np.arange(1, n + 1)[:, None] * a[None, :]) % 1.0


def sample_runs(skel: Skeleton, grid: SliceGrid, opts: TraceOptions, boxes=None,
                windows: int = SAMPLE_WINDOWS, edge: int = SAMPLE_EDGE) -> tuple[float, float, float]:
    """Estimate inside runs per column (all layers), trace seconds per column
    and the inside fraction of the voxels.

    Traces ``windows`` small windows of ``edge x edge`` columns placed on a
    low-discrepancy sequence over the plate (deterministic).

    Returns
    -------
    runs_per_column, seconds_per_column, fill : float
    """
    lo, hi = boxes if boxes is not None else support_boxes(skel)
    e = max(1, min(edge, grid.width, grid.height))
    runs = cols = inside = 0
    seconds = 0.0
    one = dataclasses.replace(opts, threads=1, spans=False)
    for u, v in _r2(windows):
        i0 = int(u * (grid.width - e + 1))
        j0 = int(v * (grid.height - e + 1))
        sub = grid.sub(i0, j0, 0, e, e, grid.layers)
        arrays = cull(skel, lo, hi, sub)
        cols += e * e
        if arrays is None:
            continue
        r = trace_tile(*arrays, skel.degree, skel.sigma, sub, one, extent=True)
        seconds += r["seconds"]     # the tracer's own time, without per-window set-up
        runs += r["runs"]
        inside += r["inside"]
    n = max(cols, 1)
    return runs / n, seconds / n, inside / (n * max(grid.layers, 1))


def plan_job(skel: Skeleton, grid: SliceGrid, opts: TraceOptions, budget: int | None = None,
             workers: int = 1, pool_processes: int = 0, trim_output: bool = False,
             sample: bool | None = None, tile: int | None = None, boxes=None,
             layer_bytes_per_pixel: float = BYTES_PER_LAYER_PIXEL,
             process_bytes: int | None = None, slab: int | None = None,
             prefetch: bool | None = None) -> TilePlan:
    """Choose tile and slab sizes so the estimated peak memory fits ``budget``.

    Parameters
    ----------
    skel : Skeleton
    grid : SliceGrid
        The job grid (the support grid with default bounds).
    opts : TraceOptions
    budget : int, optional
        Bytes for the whole job (this process, plus local worker processes);
        None: no limit (one slab).
    workers : int
        Tasks run at once (tiles in flight = workers + 1, or 1 when serial).
    pool_processes : int
        Local worker processes whose memory counts against the budget.
    trim_output : bool
        Default bounds (the output is trimmed to the model).
    sample : bool, optional
        Trace a small sample to estimate the runs per column and the time.
        Default: only when the upper bound ``ceil(layers / 2)`` runs per
        column does not fit the budget.
    tile : int, optional
        Tile edge in pixels (rounded up to the bucket size). Default: the
        whole plate for one worker up to 1024 px, else small enough for
        4 tiles per worker.
    layer_bytes_per_pixel : float
        Memory per plate pixel of the layer being written (more with
        anti-aliasing).
    process_bytes : int, optional
        Memory the process uses before the job (default: measured now).
    slab : int, optional
        Layers per slab, instead of the largest that fits the budget.
    prefetch : bool or None
        With several slabs, trace the next slab while one is written
        (:attr:`TilePlan.prefetch`). True: the slabs are sized so that two
        fit the budget (GridError if two slabs of ``slab`` layers do not).
        None (default): only when two slabs of the size chosen without
        prefetching fit anyway (never more slabs for it). False: never. A
        one-slab plan never prefetches.

    Raises
    ------
    GridError
        Even one layer per slab does not fit the budget.
    """
    W, H, K = grid.width, grid.height, grid.layers
    B = opts.bucket if opts.bucket and opts.bucket > 0 else DEFAULT_BUCKET
    serial = workers <= 1
    window = 1 if serial else workers + 1
    if tile is None:
        if serial:
            T = min(max(W, H), MAX_TILE)
        else:
            T = int(math.ceil(math.sqrt(W * H / (4.0 * workers))))
        T = max(B, min(MAX_TILE, -(-T // B) * B))
    else:
        T = int(tile)
        if T < 1:
            raise OptionError(f"--tile must be >= 1 px, got {tile}")
        T = -(-T // B) * B if opts.bucket and T > B else T
    upper = float(math.ceil(K / 2))
    seconds = None
    warm_up(opts)          # the kernels' memory counts too; warms the cache before workers start
    process = (current_rss() if process_bytes is None else int(process_bytes)) \
        + pool_processes * WORKER_PROCESS_BYTES
    scene = skel.n_segments * BYTES_PER_SEGMENT
    layer = W * H * layer_bytes_per_pixel
    per_run = BYTES_PER_RUN + (BYTES_PER_SPAN if opts.spans else 0)

    def estimate(rpc: float, L: int, two: bool = False) -> dict:
        # a run crossing a slab boundary counts once per slab: one more run in the
        # columns that are inside at the boundary (the inside fraction of the voxels)
        split = min(1.0, fill * SAFETY) if L < K else 0.0
        rpc_slab = min(rpc * SAFETY * L / max(K, 1) + split, math.ceil(L / 2))
        tpx = min(T, W) * min(T, H)
        tiles = window * tpx * (BYTES_PER_TILE_PIXEL + rpc_slab * BYTES_PER_TILE_RUN)
        # prefetching (``two``): the slab being written and the next one, merged
        runs = W * H * rpc_slab * per_run * (2 if two and L < K else 1)
        total = process + scene + layer + runs + tiles
        return {"process": process, "scene": scene, "layer": layer, "runs": runs, "tiles": tiles,
                "total": total}

    def fits(L: int, two: bool) -> bool:
        return budget is None or estimate(rpc, L, two)["total"] <= budget

    rpc, fill, sampled = upper, 1.0, False
    if sample is None:
        sample = budget is not None and estimate(upper, K)["total"] > budget
    if sample:
        if boxes is None:
            boxes = support_boxes(skel)
        rpc, spc, fill = sample_runs(skel, grid, opts, boxes)
        sampled = True
        par = workers if not serial else max(1, opts.threads or cores())
        seconds = spc * W * H / par
    if slab is not None:
        if int(slab) < 1:
            raise OptionError(f"--slab must be >= 1 layer, got {slab}")
        L = min(int(slab), max(K, 1))
        if not fits(L, False):
            raise GridError(f"--max-memory {format_size(budget)} is too small for slabs of {L} layers: "
                            f"they need ~{format_size(estimate(rpc, L)['total'])}")
    elif not fits(max(K, 1), False):
        if K <= 1:
            raise GridError(f"--max-memory {format_size(budget)} is too small for this job: it needs "
                            f"~{format_size(estimate(rpc, max(K, 1))['total'])}")
        if not fits(1, False):
            e = estimate(rpc, 1)
            raise GridError(
                f"--max-memory {format_size(budget)} is too small for this job: even one layer per slab "
                f"needs ~{format_size(e['total'])} (process {format_size(e['process'])}, scene "
                f"{format_size(e['scene'])}, layer image {format_size(e['layer'])}, runs "
                f"{format_size(e['runs'] + e['tiles'])})")
        L = _largest(lambda n: fits(n, prefetch is True), K - 1)   # one slab has no split runs
        if L == 0:
            e = estimate(rpc, 1, True)
            raise GridError(f"--max-memory {format_size(budget)} is too small to trace a slab while another is "
                            f"written (--prefetch): two one-layer slabs need ~{format_size(e['total'])}; "
                            f"give --no-prefetch")
    else:
        L = max(K, 1)
    L = max(1, min(L, max(K, 1)))
    # balance the slabs: same count, equal sizes
    n = -(-max(K, 1) // L)
    L = -(-max(K, 1) // n)
    # prefetch: asked for (the slabs above were sized for two), or by default when two slabs of
    # this size fit anyway -- never more slabs for it (each re-culls and re-walks every tile)
    two = L < max(K, 1) and prefetch is not False and fits(L, True)
    if prefetch is True and L < max(K, 1) and not two:
        e = estimate(rpc, L, True)
        raise GridError(f"--max-memory {format_size(budget)} is too small for two slabs of {L} layers "
                        f"(--prefetch): they need ~{format_size(e['total'])}; give --no-prefetch or a smaller "
                        f"--slab")
    return TilePlan(grid, T, L, budget, float(rpc), sampled, estimate(rpc, L, two), seconds, window, trim_output,
                    two)


def _largest(ok, hi: int) -> int:
    """The largest n in [1, hi] with ``ok(n)`` (``ok`` monotone: true up to some n), or 0."""
    if hi < 1 or not ok(1):
        return 0
    lo = 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if ok(mid):
            lo = mid
        else:
            hi = mid - 1
    return lo


def warm_up(opts: TraceOptions) -> None:
    """Load (or compile) the tracing kernels: one column of a one-segment scene."""
    s = Skeleton([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [[0, 1]], [[0.5, 0.5]])
    g = SliceGrid((0.25, 0.05, -1.0), (0.1, 0.1), 0.25, 1, 1, 13)
    trace(s, g, **dataclasses.replace(opts, threads=1).trace_kwargs())


def plan_slice(skel: Skeleton, pixel_size: float, pixel_size_y: float | None = None,
               layer_height: float | None = None, bounds=None, method: str = "interval",
               bucket: int = DEFAULT_BUCKET, threads: int | None = None, strict: bool = False,
               spans: bool = False, span_tol: float | None = None, *, max_memory=None,
               executor_info=None, tile: int | None = None, sample: bool | None = None,
               layer_bytes_per_pixel: float | None = None,
               process_bytes: int | None = None, slab: int | None = None,
               grid: SliceGrid | None = None, blend: str = "sum", prefetch: bool | None = None) -> TilePlan:
    """The plan :func:`slice_planned` would follow (grid checks included),
    without tracing more than the sample. Used by ``--dry-run``.

    ``blend``: as :func:`slicer.tracer.slicing.slice_skeleton` (the sample is traced with it).
    ``prefetch``: as :func:`plan_job`.

    ``layer_bytes_per_pixel`` defaults to :data:`BYTES_PER_LAYER_PIXEL`, or
    :data:`BYTES_PER_COVERAGE_PIXEL` with spans (float coverage layers).
    ``grid``: trace this grid as it is (never trimmed by the tiles), instead
    of the one made from the skeleton's supports and ``bounds``."""
    if layer_bytes_per_pixel is None:
        layer_bytes_per_pixel = BYTES_PER_COVERAGE_PIXEL if spans else BYTES_PER_LAYER_PIXEL
    if skel.n_segments == 0:
        raise GridError("the scene has no segments: nothing to slice")
    trim_output = bounds is None and grid is None
    if grid is None:
        grid = make_grid(skel.support_bounds(), pixel_size, pixel_size_y, layer_height, bounds)
    opts = TraceOptions(method, bucket, threads, strict, spans, span_tol, blend)
    workers = executor_info.workers if executor_info is not None and executor_info.kind != "serial" else 1
    procs = workers if executor_info is not None and executor_info.kind == "processes" else 0
    if executor_info is not None and executor_info.kind == "dask" and executor_info.address \
            and executor_info.address.startswith(("tcp://127.", "inproc://")):
        procs = workers
    return plan_job(skel, grid, opts, parse_size(max_memory), workers=workers, pool_processes=procs,
                    trim_output=trim_output, sample=sample, tile=tile,
                    layer_bytes_per_pixel=layer_bytes_per_pixel, process_bytes=process_bytes, slab=slab,
                    prefetch=prefetch)



__all__ = ["TilePlan", "plan_job", "plan_slice", "sample_runs", "parse_size", "format_size", "current_rss",
           "auto_budget", "warm_up", "BYTES_PER_RUN", "BYTES_PER_SPAN", "BYTES_PER_TILE_RUN",
           "BYTES_PER_TILE_PIXEL", "BYTES_PER_LAYER_PIXEL", "BYTES_PER_COVERAGE_PIXEL", "BYTES_PER_SEGMENT",
           "WORKER_PROCESS_BYTES", "MAX_TILE", "SAFETY"]
