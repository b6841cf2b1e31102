"""Slicing parts: the lattice traced, the meshes cut at the same voxel centres, combined.

A part (:class:`slicer.parts.part.Part`) is sliced on one grid: the part's box
(the lattice's support box joined with the solids' bounds) plus one voxel of
margin, or ``bounds``. The lattice is traced on it by the ordinary tracer --
in memory, or in tiles and slabs on any executor
(:func:`slicer.scale.tiles.slice_planned`) -- and each mesh role is classified at
the very same voxel centres (:mod:`slicer.parts.mesh_slicing`). The runs are then
combined per pixel column, ``((lattice ∩ CI) − CO) ∪ S``, and the result is
trimmed to the part plus one voxel, as a lattice alone is.

The mesh classification uses the job grid's own centres and never depends on
tiles, slabs or executors, so every plan gives the bytes of the in-memory job
(to the same degree as for a lattice alone). With ``--aa-z`` the inside spans
are combined the same way: the lattice's from the tracer, the meshes' from
vertical rays (:func:`slicer.parts.mesh_slicing.column_spans`).

The result is a :class:`PartResult` -- a :class:`~slicer.tracer.slicing.SliceResult`
of the combined solid, which every writer, the anti-aliasing and the printer
placement read unchanged -- that also keeps the lattice's own runs for the
contours (:func:`slicer.contours.iter_contours` combines the lattice's contours
with the meshes' exact cross-sections by polygon booleans).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from slicer.model.blend import require_traceable
from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.errors import GridError
from slicer.scale.executors import executor_info as describe
from slicer.tracer.grid import SliceGrid, make_grid
from slicer.parts.mesh_slicing import Soup, column_spans, combine_intervals, layer_masks, part_op, runs_from_masks
from slicer.parts.part import Part, as_part
from slicer.tracer.slicing import SliceResult, coverage_layers, slice_skeleton, trace, trim
from slicer.scale.tileplan import TilePlan, plan_slice
from slicer.scale.tiles import slice_planned

#: the mesh roles, in the order of the combination's states (lattice first)
_ROLES = ("clip-inside", "clip-outside", "solid")


def part_grid(part: Part, pixel_size: float, pixel_size_y: float | None = None, layer_height: float | None = None,
              bounds=None) -> SliceGrid:
    """The grid a part is sliced on.

    With ``bounds``: :func:`slicer.tracer.grid.make_grid`'s (the voxels cover the box
    exactly). Default: the part's support box (the lattice's support box and
    the solids' bounds) plus one voxel of margin, on a lattice whose voxel
    *faces* lie at multiples of the pixel size and layer height, so the
    centres sit half a voxel off them: a mesh face at a round coordinate
    (a 20 mm cube from z = 0) falls between centres, never on one, and
    prints the layers and pixels its size says (400 layers of 0.05 mm).
    """
    g = make_grid(part.support_bounds(), pixel_size, pixel_size_y, layer_height, bounds)
    if bounds is not None:
        return g
    px, py = g.pixel_size
    h = g.layer_height
    i0, j1, k0 = (int(round(v)) for v in (g.origin[0] / px, g.origin[1] / py, g.origin[2] / h))
    return SliceGrid(((i0 + 0.5) * px, (j1 - 0.5) * py, (k0 + 0.5) * h), (px, py), h, g.width, g.height, g.layers)


@dataclass
class PartResult(SliceResult):
    """A sliced part: the combined solid's runs (and spans), plus the lattice's own.

    Attributes
    ----------
    part : Part
    lattice : SliceResult or None
        The lattice alone (None for a mesh-only part), on a grid of which
        ``grid`` is the window starting at column, row and layer
        ``lattice_offset``: the lattice is not cut where the part's box is
        trimmed, so its contours never follow a cut.
    lattice_offset : (3,) int
    """

    part: Part | None = None
    lattice: SliceResult | None = None
    lattice_offset: tuple[int, int, int] = (0, 0, 0)
    z_origin: float | None = None
    k_base: int = 0

    def iter_coverage(self) -> Iterator[np.ndarray]:
        """Each layer's z coverage (see :meth:`SliceResult.iter_coverage`), computed in the
        job grid's layer units (``z_origin``, the layer of ``grid``'s first layer ``k_base``)
        so that every plan -- one slab or many -- gives bit-equal coverage."""
        if self.z_origin is None or not self.has_spans:
            yield from super().iter_coverage()
            return
        g = self.grid
        K = g.layers
        if K == 0:
            return
        lo, hi = self.k_base, self.k_base + K
        u0 = self._layer_units(self.span_t0, lo, hi)
        u1 = self._layer_units(self.span_t1, lo, hi)
        yield from coverage_layers(self.span_pix, u0, u1, K, g.height, g.width)

    def _layer_units(self, t: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """Heights in layer units of this grid: clipped to whole layers ``[lo, hi]`` of the
        job grid, then shifted by the whole number ``lo`` (both exact). Ends within 1e-9 of a
        layer range's end are that end: the tracer clips its spans there in float."""
        u = (t - self.z_origin) / self.grid.layer_height + 0.5
        u = np.where(np.abs(u - lo) < 1e-9, lo, np.where(np.abs(u - hi) < 1e-9, hi, u))
        return np.clip(u, lo, hi) - lo


def _empty(grid: SliceGrid, spans: bool, method: str) -> SliceResult:
    """The lattice result of a mesh-only part: no runs."""
    z = np.zeros(0, np.int64)
    r = SliceResult(grid, z, z.copy(), z.copy(), {"method": method, "bucket": 0, "evaluations": 0,
                                                   "trace_seconds": 0.0, "threads": 1})
    if spans:
        r.span_pix, r.span_t0, r.span_t1 = z.copy(), np.zeros(0), np.zeros(0)
    return r


def _soups(part: Part) -> dict[str, Soup]:
    return {role: Soup.of(part.of_role(role)) for role in _ROLES if part.of_role(role)}


def _role_runs(soups: dict, grid: SliceGrid, k_start: int, k_stop: int) -> dict:
    """Runs of each role's classification over layers [k_start, k_stop), slab-local k."""
    out = {}
    for role, soup in soups.items():
        pix, k0, k1 = runs_from_masks(layer_masks(soup, grid, k_start, k_stop), grid.width * grid.height, k_start)
        out[role] = (pix, k0 - k_start, k1 - k_start)
    return out


def _role_spans(soups: dict, grid: SliceGrid) -> dict:
    return {role: column_spans(soup, grid) for role, soup in soups.items()}


def _overlapping(spans, zlo: float, zhi: float):
    """The spans that reach into ``[zlo, zhi]``, ends kept as they are (the coverage of a
    :class:`PartResult` clips them to whole layers exactly)."""
    pix, t0, t1 = spans
    keep = (t1 > zlo) & (t0 < zhi)
    return pix[keep], t0[keep], t1[keep]


def combine(part: Part, lattice: SliceResult, roles: dict, role_spans: dict | None = None) -> PartResult:
    """The part's result on ``lattice.grid``: runs (and spans) combined per pixel column.

    Parameters
    ----------
    part : Part
    lattice : SliceResult
        The lattice's runs (empty for a mesh-only part) on the grid.
    roles : dict role -> (pix, k0, k1)
        Each mesh role's runs on the same grid and layers.
    role_spans : dict role -> (pix, t0, t1), optional
        Each role's inside spans, when the lattice has spans.
    """
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    op = part_op("clip-inside" in roles)
    groups = [(lattice.pix, lattice.k0, lattice.k1)] + [roles.get(r, empty) for r in _ROLES]
    pix, k0, k1 = combine_intervals(groups, op)
    res = PartResult(lattice.grid, pix, k0, k1, dict(lattice.stats), part=part, lattice=lattice)
    if lattice.has_spans:
        g = lattice.grid
        zlo = g.origin[2] - 0.5 * g.layer_height
        zhi = g.origin[2] + (g.layers - 0.5) * g.layer_height
        fe = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        sg = [(lattice.span_pix, lattice.span_t0, lattice.span_t1)] + \
             [_overlapping(role_spans[r], zlo, zhi) if r in role_spans else fe for r in _ROLES]
        res.span_pix, res.span_t0, res.span_t1 = combine_intervals(sg, op)
        res.span_t0 = res.span_t0.astype(np.float64)
        res.span_t1 = res.span_t1.astype(np.float64)
    return res


def crop(result: SliceResult, i0: int, j0: int, k0: int, width: int, height: int, layers: int) -> SliceResult:
    """The part of ``result`` inside a window of its grid (runs and spans clipped to it)."""
    g = result.grid
    sub = g.sub(i0, j0, k0, width, height, layers)
    j, i = np.divmod(result.pix, g.width)
    a, b = np.maximum(result.k0 - k0, 0), np.minimum(result.k1 - k0, layers)
    keep = (i >= i0) & (i < i0 + width) & (j >= j0) & (j < j0 + height) & (b > a)
    out = SliceResult(sub, (j[keep] - j0) * width + (i[keep] - i0), a[keep], b[keep], dict(result.stats))
    if result.has_spans:
        j, i = np.divmod(result.span_pix, g.width)
        zlo = sub.origin[2] - 0.5 * sub.layer_height
        zhi = sub.origin[2] + (layers - 0.5) * sub.layer_height
        t0, t1 = result.span_t0, result.span_t1          # ends kept (see _overlapping)
        keep = (i >= i0) & (i < i0 + width) & (j >= j0) & (j < j0 + height) & (t1 > zlo) & (t0 < zhi)
        out.span_pix = (j[keep] - j0) * width + (i[keep] - i0)
        out.span_t0, out.span_t1 = t0[keep], t1[keep]
    return out


def _window(full: SliceGrid, sub: SliceGrid) -> tuple[int, int, int]:
    """Column, row and layer of ``sub``'s first voxel in ``full`` (a sub-grid of it)."""
    px, py = full.pixel_size
    return (int(round((sub.origin[0] - full.origin[0]) / px)), int(round((full.origin[1] - sub.origin[1]) / py)),
            int(round((sub.origin[2] - full.origin[2]) / full.layer_height)))


def _finish(part: Part, res: PartResult, trimmed: bool) -> PartResult:
    """Trim to the model plus one voxel (as :func:`slicer.tracer.slicing.trim`), the lattice with it."""
    if not trimmed:
        return res
    t = trim(res)
    window = _window(res.grid, t.grid)
    return PartResult(t.grid, t.pix, t.k0, t.k1, t.stats, t.span_pix, t.span_t0, t.span_t1, part=part,
                      lattice=res.lattice, lattice_offset=window, z_origin=res.z_origin,
                      k_base=res.k_base + window[2])


def _slice_meshes(part: Part, lattice: SliceResult, spans: bool) -> PartResult:
    """The meshes classified on the lattice result's grid and combined with it.

    ``stats`` gets ``mesh_seconds`` (wall) and ``mesh_cpu_seconds`` (this thread's CPU
    time: the mesh work runs here) and ``mesh_faces``."""
    t0, c0 = time.perf_counter(), time.thread_time()
    g = lattice.grid
    soups = _soups(part)
    roles = _role_runs(soups, g, 0, g.layers)
    rspans = _role_spans(soups, g) if spans else None
    res = combine(part, lattice, roles, rspans)
    res.z_origin = g.origin[2]
    res.stats["mesh_seconds"] = time.perf_counter() - t0
    res.stats["mesh_cpu_seconds"] = time.thread_time() - c0
    res.stats["mesh_faces"] = int(sum(s.tri.shape[0] for s in soups.values()))
    return res


def slice_part(part, pixel_size: float, pixel_size_y: float | None = None, layer_height: float | None = None,
               bounds=None, method: str = "interval", bucket: int = DEFAULT_BUCKET, threads: int | None = None,
               strict: bool = False, spans: bool = False, span_tol: float | None = None,
               blend: str = "sum") -> SliceResult:
    """:func:`slicer.tracer.slicing.slice_skeleton` for a part (a lattice and meshes), in memory.

    A part without meshes (or a Skeleton) is sliced by
    :func:`~slicer.tracer.slicing.slice_skeleton` itself. Otherwise the result is a
    :class:`PartResult` on the part's grid (:func:`part_grid`), trimmed to the
    part plus one voxel with default bounds.

    Parameters
    ----------
    part : Part or Skeleton
    pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict, spans, span_tol, blend
        As :func:`slicer.tracer.slicing.slice_skeleton`.

    Examples
    --------
    >>> import trimesh
    >>> from slicer.parts.meshes import make_mesh
    >>> from slicer.parts.part import Part, PartMesh
    >>> box = trimesh.creation.box(extents=(2, 2, 2))
    >>> p = Part(None, [PartMesh(make_mesh(box.vertices, box.faces, "box"), "solid")])
    >>> r = slice_part(p, 0.5)
    >>> r.grid.width, int((r.k1 - r.k0).sum())          # 4 x 4 x 4 centres, half a voxel off the faces
    (6, 64)
    """
    part = as_part(part)
    if not part.has_meshes:
        return slice_skeleton(part.skeleton, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads,
                              strict, spans, span_tol, blend=blend)
    require_traceable(blend, method=method)
    grid = part_grid(part, pixel_size, pixel_size_y, layer_height, bounds)
    if part.skeleton is not None:
        lat = trace(part.skeleton, grid, method=method, bucket=bucket, threads=threads, strict=strict,
                    spans=spans, span_tol=span_tol, blend=blend)
    else:
        lat = _empty(grid, spans, method)
    return _finish(part, _slice_meshes(part, lat, spans), bounds is None)


# ----------------------------------------------------------------------------- planned
def plan_part(part: Part, pixel_size: float, pixel_size_y=None, layer_height=None, bounds=None,
              method: str = "interval", bucket: int = DEFAULT_BUCKET, threads=None, strict: bool = False, spans: bool = False,
              span_tol=None, **plan_kw) -> TilePlan:
    """The tile plan of a part's lattice on the part's grid (:func:`part_grid`; never
    trimmed by the tiles: the combined result is). Keywords as :func:`slicer.scale.tileplan.plan_slice`."""
    grid = part_grid(part, pixel_size, pixel_size_y, layer_height, bounds)
    return plan_slice(part.skeleton, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                      spans, span_tol, grid=grid, **plan_kw)


def _union_box(a, b):
    """The smallest inclusive index box ``(i0, i1, j0, j1, k0, k1)`` holding boxes ``a`` and ``b``."""
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]), min(a[4], b[4]),
            max(a[5], b[5]))


class PartStreamedResult:
    """A part sliced slab by slab (the reading interface of :class:`~slicer.tracer.slicing.SliceResult`
    that writers use, like :class:`slicer.scale.tiles.StreamedResult`). Iterate it once.

    With default bounds a first pass over the slabs finds the combined extent
    (the lattice is traced twice, as a trimmed lattice-only streamed job is).
    """

    def __init__(self, part: Part, make_stream, grid: SliceGrid, trimmed: bool, spans: bool, stats: dict):
        self.part = part
        self._make = make_stream          # () -> a fresh StreamedResult of the lattice on ``grid``
        self._full = grid
        self._soups = _soups(part)
        self._spans = _role_spans(self._soups, grid) if spans else None
        self.has_spans = spans
        self.stats = stats
        self._box = (0, 0, 0, grid.width, grid.height, grid.layers)
        self._n_runs = None
        self._inside = None
        if trimmed:
            self._box, self._n_runs, inside = self._extent()
            if inside is not None:
                i0, j0, k0 = self._box[:3]
                self._inside = (inside[0] - i0, inside[1] - i0, inside[2] - j0, inside[3] - j0,
                                inside[4] - k0, inside[5] - k0)
        i0, j0, k0, w, h, nl = self._box
        self.grid = grid.sub(i0, j0, k0, w, h, nl)
        self._trimmed = trimmed

    def inside_box(self) -> tuple[int, int, int, int, int, int] | None:
        """Index box ``(i0, i1, j0, j1, k0, k1)`` (inclusive) of the inside voxels on
        :attr:`grid`, from the extent pass (see :meth:`slicer.scale.tiles.StreamedResult.inside_box`).

        Raises
        ------
        GridError
            The job was not trimmed (explicit bounds).
        """
        if not self._trimmed:
            raise GridError("the inside voxels' extent is known before streaming only for jobs without --bounds")
        return self._inside

    def _combined_slabs(self, stream) -> Iterator[tuple[int, PartResult]]:
        """(first job layer, combined slab result on the full-width slab grid)."""
        g = self._full
        k = 0
        wall = cpu = 0.0
        for slab in stream.iter_slabs():
            nl = slab.grid.layers
            t0, c0 = time.perf_counter(), time.thread_time()
            roles = _role_runs(self._soups, g, k, k + nl)
            res = combine(self.part, slab, roles, self._spans)
            wall += time.perf_counter() - t0
            cpu += time.thread_time() - c0
            yield k, res
            k += nl
        self.stats.update(stream.stats)
        self.stats.update(mesh_seconds=wall, mesh_cpu_seconds=cpu)

    def _extent(self):
        box = inside = None
        runs = 0
        for k, res in self._combined_slabs(self._make()):
            if res.n_runs == 0 and not (res.has_spans and len(res.span_pix)):
                continue
            runs += res.n_runs
            r = res.inside_box()
            if r is not None:
                r = r[:4] + (r[4] + k, r[5] + k)
                inside = r if inside is None else _union_box(inside, r)
            j, i = np.divmod(np.concatenate([res.pix, res.span_pix]) if res.has_spans else res.pix, res.grid.width)
            ka = [int(res.k0.min())] if res.n_runs else []
            kb = [int(res.k1.max()) - 1] if res.n_runs else []
            if res.has_spans and len(res.span_pix):
                u = (np.array([res.span_t0.min(), res.span_t1.max()]) - res.grid.origin[2]) / res.grid.layer_height
                ka.append(int(np.floor(u[0] + 0.5)))
                kb.append(min(int(np.floor(u[1] + 0.5)), res.grid.layers - 1))
            b = (int(i.min()), int(i.max()), int(j.min()), int(j.max()), k + min(ka), k + max(kb))
            box = b if box is None else _union_box(box, b)
        g = self._full
        if box is None:
            return (0, 0, 0, g.width, g.height, 0), 0, None
        i0, j0, k0 = max(box[0] - 1, 0), max(box[2] - 1, 0), max(box[4] - 1, 0)
        i1, j1, k1 = min(box[1] + 1, g.width - 1), min(box[3] + 1, g.height - 1), min(box[5] + 1, g.layers - 1)
        return (i0, j0, k0, i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1), runs, inside

    @property
    def n_runs(self) -> int:
        return int(self._n_runs or 0)

    def iter_slabs(self) -> Iterator[PartResult]:
        """Each slab of the (trimmed) output grid, as a :class:`PartResult`, bottom first."""
        i0, j0, k0, w, h, nl = self._box
        if nl == 0:
            return
        counted = 0
        for k, res in self._combined_slabs(self._make()):
            a, b = max(k0, k), min(k0 + nl, k + res.grid.layers)
            if b <= a:
                continue
            c = crop(res, i0, j0, a - k, w, h, b - a)
            lat = crop(res.lattice, 0, 0, a - k, res.grid.width, res.grid.height, b - a)
            counted += c.n_runs
            yield PartResult(c.grid, c.pix, c.k0, c.k1, c.stats, c.span_pix, c.span_t0, c.span_t1,
                             part=self.part, lattice=lat, lattice_offset=(i0, j0, 0), z_origin=self._full.origin[2],
                             k_base=a)
        if self._n_runs is None:
            self._n_runs = counted

    def _chain(self, name: str, *args) -> Iterator:
        for slab in self.iter_slabs():
            yield from getattr(slab, name)(*args)

    def iter_layers(self, value: int = 255) -> Iterator[np.ndarray]:
        return self._chain("iter_layers", value)

    def iter_coverage(self) -> Iterator[np.ndarray]:
        return self._chain("iter_coverage")


def slice_part_planned(part, pixel_size: float, pixel_size_y=None, layer_height=None, bounds=None,
                       method: str = "interval", bucket: int = DEFAULT_BUCKET, threads=None, strict: bool = False,
                       spans: bool = False, span_tol=None, *, max_memory=None, executor=None, executor_info=None,
                       workers: int | None = None, scheduler: str | None = None, tile: int | None = None,
                       slab: int | None = None, progress=None, plan: TilePlan | None = None, blend: str = "sum"):
    """:func:`slicer.scale.tiles.slice_planned` for a part: tiles, slabs and executors for the
    lattice, the meshes at the same centres.

    Parameters as :func:`slicer.scale.tiles.slice_planned` (``slab``: layers per
    slab, as :func:`slicer.scale.tileplan.plan_slice`); ``plan`` from
    :func:`plan_part`. A mesh-only part is sliced in memory (there is no
    lattice to tile).

    Returns
    -------
    PartResult or PartStreamedResult (what slice_planned returns for a part without meshes)
    """
    part = as_part(part)
    run_kw = dict(max_memory=max_memory, executor=executor, executor_info=executor_info, workers=workers,
                  scheduler=scheduler, tile=tile)
    run_kw["blend"] = require_traceable(blend, method=method)
    if not part.has_meshes:
        if plan is None:
            info = executor_info if executor_info is not None or not (executor is None or isinstance(executor, str)) \
                else describe(executor or "serial", workers, scheduler)
            plan = plan_slice(part.skeleton, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads,
                              strict, spans, span_tol, max_memory=max_memory, executor_info=info, tile=tile, slab=slab,
                              blend=blend)
        return slice_planned(part.skeleton, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads,
                             strict, spans, span_tol, plan=plan, progress=progress, **run_kw)
    if part.skeleton is None:
        return slice_part(part, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                          spans, span_tol)
    if plan is None:
        info = executor_info if executor_info is not None or not (executor is None or isinstance(executor, str)) \
            else describe(executor or "serial", workers, scheduler)
        plan = plan_part(part, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                         spans, span_tol, max_memory=max_memory, executor_info=info, tile=tile, slab=slab,
                         blend=blend)
    args = (part.skeleton, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict, spans,
            span_tol)

    def stream():
        return slice_planned(*args, plan=plan, progress=progress, **run_kw)

    if plan.n_slabs == 1:
        return _finish(part, _slice_meshes(part, stream(), spans), bounds is None)
    stats = {"method": method, "bucket": bucket, "plan": plan.to_dict()}
    return PartStreamedResult(part, stream, plan.grid, bounds is None, spans, stats)


__all__ = ["PartResult", "PartStreamedResult", "slice_part", "slice_part_planned", "plan_part", "part_grid",
           "combine", "crop"]
