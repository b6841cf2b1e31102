"""The tile task and the merge of tile results.

:func:`trace_tile` is a top-level function of plain arrays (the segments
:func:`cull` keeps for the tile, the kernel, the tile's grid and the tracer
options), so it runs in-process, in a process pool or on Dask workers, and
returns compact runs. :func:`merge_tiles` puts tile results together into
one :class:`~slicer.tracer.slicing.SliceResult`, deterministically.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.tracer.grid import SliceGrid
from slicer.raster.ordering import rect_parts
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult, trace


@dataclass(frozen=True)
class TraceOptions:
    """Tracer settings shared by every tile (see :func:`slicer.tracer.slicing.trace`).

    ``blend`` (:mod:`slicer.model.blend`) is checked by the job and passed to the tracer.
    """

    method: str = "interval"
    bucket: int = DEFAULT_BUCKET
    threads: int | None = None
    strict: bool = False
    spans: bool = False
    span_tol: float | None = None
    blend: str = "sum"

    def trace_kwargs(self) -> dict:
        kw = dict(method=self.method, bucket=self.bucket, threads=self.threads, strict=self.strict)
        if self.spans:
            kw.update(spans=True, span_tol=self.span_tol)
        if self.blend != "sum":
            kw.update(blend=self.blend)
        return kw


def _array_fields() -> list[str]:
    """Names of SliceResult's per-run / per-span array fields (all but grid, stats)."""
    return [f.name for f in dataclasses.fields(SliceResult) if f.name not in ("grid", "stats")]


def _compact(a: np.ndarray) -> np.ndarray:
    """int64 arrays that fit become int32 (halves what a task sends back)."""
    if a.dtype == np.int64 and (a.size == 0 or (a.max() < 2**31 and a.min() >= -2**31)):
        return a.astype(np.int32)
    return a


def trace_tile(nodes: np.ndarray, segments: np.ndarray, radii: np.ndarray, degree: int, sigma: float,
               grid: SliceGrid, opts: TraceOptions, extent: bool = False) -> dict:
    """Trace one tile; a top-level function of plain arrays (picklable for pools and Dask).

    Parameters
    ----------
    nodes : (n, 3) float64, mm
    segments : (m, 2) int64
    radii : (m, 2) float64, mm
        The segments whose support reaches the tile (see :func:`cull`).
    degree, sigma
        Kernel of the scene.
    grid : SliceGrid
        The tile: a sub-grid of the job grid.
    opts : TraceOptions
    extent : bool
        Return only the bounding box of the inside voxels (first pass of a
        trimmed, streamed job).

    Returns
    -------
    dict
        ``arrays``: SliceResult array fields in tile coordinates (int32
        where they fit), or with ``extent`` ``bbox``: ``(i0, i1, j0, j1, k0,
        k1)`` inclusive tile indices or None; plus ``runs``, ``inside``
        (voxels), ``evaluations``, ``seconds`` and ``threads``.
    """
    skel = Skeleton(nodes, segments, radii, degree, sigma)
    res = trace(skel, grid, **opts.trace_kwargs())
    out = {"runs": res.n_runs, "inside": int((res.k1 - res.k0).sum()),
           "evaluations": int(res.stats.get("evaluations", 0)),
           "seconds": float(res.stats.get("trace_seconds", 0.0)), "threads": res.stats.get("threads")}
    if extent:
        out["bbox"] = _bbox(res)
        return out
    out["arrays"] = {name: (None if getattr(res, name) is None else _compact(getattr(res, name)))
                     for name in _array_fields()}
    return out


def _bbox(res: SliceResult):
    if res.n_runs == 0:
        return None
    j, i = np.divmod(res.pix, res.grid.width)
    return (int(i.min()), int(i.max()), int(j.min()), int(j.max()), int(res.k0.min()), int(res.k1.max()) - 1)


def cull(skel: Skeleton, lo: np.ndarray, hi: np.ndarray, grid: SliceGrid):
    """The segments whose support box can reach ``grid``, as plain arrays.

    Parameters
    ----------
    skel : Skeleton
    lo, hi : (m, 3) float64, mm
        Support boxes (:func:`slicer.model.field.support_boxes`).
    grid : SliceGrid
        A tile.

    Returns
    -------
    (nodes (n', 3), segments (m', 2), radii (m', 2)) or None when no segment
    reaches the tile. Segment order is kept, so the tracer's bucket lists
    (and hence its output) are the same as with the whole scene.
    """
    px, py = grid.pixel_size
    h = grid.layer_height
    x0, y0, z0 = grid.origin
    # one pixel of slack beyond the voxels' faces: a superset of what the buckets keep
    box_lo = (x0 - 1.5 * px, y0 - (grid.height + 0.5) * py, z0 - 1.5 * h)
    box_hi = (x0 + (grid.width + 0.5) * px, y0 + 1.5 * py, z0 + (grid.layers + 0.5) * h)
    mask = (hi[:, 0] >= box_lo[0]) & (lo[:, 0] <= box_hi[0]) & (hi[:, 1] >= box_lo[1]) \
        & (lo[:, 1] <= box_hi[1]) & (hi[:, 2] >= box_lo[2]) & (lo[:, 2] <= box_hi[2])
    ids = np.nonzero(mask)[0]
    if ids.size == 0:
        return None
    seg = skel.segments[ids]
    used, inv = np.unique(seg, return_inverse=True)
    return (np.ascontiguousarray(skel.nodes[used]), inv.reshape(-1, 2).astype(np.int64),
            np.ascontiguousarray(skel.radii[ids]))


# ---------------------------------------------------------------- merging
def merge_tiles(grid: SliceGrid, parts: list, stats: dict | None = None) -> SliceResult:
    """Merge tile results into one result on ``grid``, deterministically.

    Every array field of :class:`SliceResult` is concatenated. Fields named
    ``pix`` or ``<prefix>pix`` are flat pixel indices and are remapped from
    tile to ``grid`` coordinates; the other fields starting with the same
    ``<prefix>`` (e.g. ``span_t0``) travel with them, the rest with ``pix``.
    Each group is then stably sorted by its pixel index, which keeps each
    pixel's own order (a pixel lies in one tile only).

    Parameters
    ----------
    grid : SliceGrid
        Grid of the merged result (same layers as every tile).
    parts : list of (i0, j0, tile_width, arrays)
        Tile column/row offsets in ``grid``, the tile's width and its
        ``arrays`` dict (field name -> array or None), as :func:`trace_tile`
        returns them.
    stats : dict, optional
    """
    names = _array_fields()
    keys = [n for n in names if n == "pix" or n.endswith("_pix")]
    prefixes = sorted((k[:-3] for k in keys), key=len, reverse=True)
    group = {n: next(p for p in prefixes if n.startswith(p)) for n in names}
    out: dict = {}
    for key in keys:
        prefix = key[:-3]
        members = [n for n in names if group[n] == prefix]
        present = [p[3].get(key) is not None for p in parts]
        if parts and not all(present):
            if any(present):
                raise ValueError(f"merge_tiles: field {key!r} is present in some tiles only")
            out.update({n: None for n in members})
            continue
        if not parts:
            default = {"pix": np.zeros(0, np.int64), "k0": np.zeros(0, np.int64), "k1": np.zeros(0, np.int64)}
            out.update({n: default.get(n) for n in members})
            continue
        rects = []
        for i0, j0, tw, arrays in parts:
            local = np.asarray(arrays[key])
            rows = int(local.max()) // tw + 1 if local.size else 0
            rects.append((i0, j0, tw, rows, local))
        # tiles are sorted by pixel: merged row by row of the plate (else sorted)
        pix, order = rect_parts(rects, grid.width)
        out[key] = pix[order]
        for n in members:
            if n == key:
                continue
            cat = np.concatenate([p[3][n] for p in parts])
            if cat.dtype.kind in "iu":
                cat = cat.astype(np.int64)
            out[n] = cat[order]
    return SliceResult(grid=grid, stats=dict(stats or {}), **out)



__all__ = ["TraceOptions", "trace_tile", "cull", "merge_tiles"]
