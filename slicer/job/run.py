"""A whole slicing job: scene in, printer output written atomically.

:func:`run_slice` takes a :class:`~slicer.job.spec.SliceJob` (or the same
settings as keyword options), refuses what it can before any tracing
(destinations, options, grid size, plate fit from a guaranteed lower bound of
the footprint), traces — in memory or in tiles and slabs — and streams the
layers to a writer of :mod:`formats` (:func:`slicer.raster.placed_layers.write_stack`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from formats import WRITERS
from formats.estimate import print_estimate

from slicer._version import __version__
from slicer._kernels.contours.quadtree import quadtree
from slicer._kernels.trace.summed import trace_buckets
from slicer._kernels.trace.union import trace_union_buckets
from slicer.compiling import ABOUT, compiling
from slicer.raster.antialias import output_layers
from slicer.atomic import check_destination
from slicer.arguments import resolvable, scene_reach
from slicer.contours import check_resolvable, write_contours
from slicer.errors import GridError, OutputError
from slicer.scale.executors import executor_info as describe_executor
from slicer.model.field import evaluate
from slicer.tracer.grid import SliceGrid, make_grid
from slicer.job.spec import ResolvedJob, SliceJob
from slicer.raster.placed_layers import plate_placement, write_stack
from slicer.parts.slicing import part_grid, plan_part, slice_part, slice_part_planned
from slicer.parts.part import Part
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult, slice_skeleton
from slicer.supports.groups import refuse_pieces
from slicer.supports.show import refuse_grouped
from slicer.scale.tiles import plan_slice, slice_planned


def run_slice(skel: Skeleton, out, job: SliceJob | None = None, *, progress: bool | None = None,
              dry_run: bool = False, report=None, executor_info=None, **options) -> dict:
    """Slice ``skel`` and write the layers to ``out``; returns a summary dict.

    Parameters
    ----------
    skel : Skeleton
    out : path-like
        The output (a folder for PNG stacks, else a file).
    job : SliceJob, optional
        Every setting of the job. Instead, the same settings may be given as
        keyword ``options`` with the ``slice`` command's option names
        (``pixel_size=0.05, printer="prusa-sl1s", aa=2, max_memory="4GB", ...``,
        see :data:`slicer.job.spec.OPTIONS`); not both.
    progress : bool or None
        tqdm bars; None shows them only on a terminal.
    dry_run : bool
        Plan (after a quick sample) and return the plan, writing nothing.
    report : callable, optional
        Called with the tile plan's description before tracing.
    executor_info : slicer.scale.executors.ExecutorInfo, optional
        With an open executor passed as ``executor``.

    Returns
    -------
    dict
        The output grid (``width``, ``height``, ``layers``, ``pixel_size``,
        ``layer_height``, ``origin``), the tracer's stats (``evaluations``,
        ``trace_seconds``, ...), ``write_seconds``, ``runs``, ``output``,
        ``format`` and ``contours``; with ``dry_run``: ``plan``,
        ``plan_text`` and ``dry_run``.

    Raises
    ------
    OutputError
        ``out`` exists (without ``force``) or cannot be written; checked before
        any work. Nothing is left at ``out`` on any failure.
    OptionError, FormatError
        Invalid or conflicting options, or what the format cannot hold.
    GridError
        A grid beyond the voxel limit, a model that cannot fit the printer's
        plate (all refused before any tracing), or, with default bounds, a
        scene with no surface at all.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> s = Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 1.0]])
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "strut_stack"
    >>> summary = run_slice(s, out, pixel_size=0.25, progress=False)
    >>> summary["width"], summary["layers"], summary["format"]
    (9, 21, 'png')
    """
    if job is None:
        job = SliceJob.from_options(**options)
    elif options:
        raise TypeError(f"run_slice takes a SliceJob or keyword options, not both (got {sorted(options)})")
    out_opts = job.output
    check_destination(Path(out), out_opts.force)          # fail before any work
    if out_opts.contours is not None:                      # ``--contours FILE`` beside the images
        check_destination(Path(out_opts.contours), out_opts.force)
    resolved = job.resolve(out)
    contours = out_opts.contours is not None or getattr(WRITERS[resolved.fmt], "kind", "image") == "contours"
    with _first_compile(job.trace_options(resolved).blend, contours):
        return _run_resolved(skel, out, job, resolved, contours, progress=progress, dry_run=dry_run, report=report,
                             executor_info=executor_info)


def _first_compile(blend: str, contours: bool):
    """Announce, at the job's start, the compilation of the kernels it will use if they are not compiled yet
    (:func:`slicer.compiling.compiling`): the tracer of ``blend``, and the guaranteed contours."""
    what, entries, seconds = "the tracer", [trace_union_buckets if blend == "union" else trace_buckets], ABOUT["tracer"]
    if contours:
        what, seconds = what + " and the guaranteed contours", seconds + ABOUT["contours"]
        entries.append(quadtree)
    return compiling(what, entries, seconds)


def _run_resolved(skel, out, job: SliceJob, resolved: ResolvedJob, contours: bool, *, progress, dry_run, report,
                  executor_info) -> dict:
    """:func:`run_slice` once the job is resolved."""
    out_opts = job.output
    if contours:
        refuse_grouped(skel, "the contours")                  # supports: docs/supports.md
        resolvable(out_opts.contour_tol, "--contour-tol", scene_reach(skel))
    if isinstance(skel, Part) and not skel.has_meshes:     # a lattice alone: the lattice's own path
        skel = skel.skeleton
    # a contour tolerance float64 cannot resolve at the scene's coordinates: refused before any work
    lattice = skel.skeleton if isinstance(skel, Part) else skel
    if lattice is not None:                                # (a part may hold meshes only)
        check_resolvable(lattice, out_opts.contour_tol)
    traced = _trace(skel, job, resolved, progress=progress, dry_run=dry_run, report=report,
                    executor_info=executor_info)
    if dry_run:
        plan = traced if isinstance(traced, dict) else {
            **traced.grid.to_dict(), "plan": traced.to_dict(), "plan_text": traced.describe(), "dry_run": True}
        est = print_estimate(resolved.settings, plan["layers"]) if resolved.printer else None
        return {**plan, "output": str(out), "format": resolved.fmt, "estimate": est and est.to_dict()}
    res = traced
    opts = job.trace_options(resolved)
    meta = {"generator": f"skelslice {__version__}", "method": opts.method, "bucket": res.stats["bucket"]}
    if opts.blend != "sum":
        meta["blend"] = opts.blend
    if out_opts.scene_name:
        meta["scene"] = out_opts.scene_name
    written: dict = {}
    write_s = write_stack(res, out, resolved.fmt, meta, out_opts.force, progress, skel=skel,
                          contour_tol=out_opts.contour_tol, settings=resolved.settings, info=written)
    contour_info = None
    placement = plate_placement(res, resolved.settings)
    if out_opts.contours is not None:
        contour_info = write_contours(skel, res, out_opts.contours, out_opts.contour_tol, out_opts.force, meta,
                                      placement=placement)
    images = getattr(WRITERS[resolved.fmt], "kind", "image") != "contours"
    if resolved.settings is not None and images:
        grid = output_layers(res, resolved.settings)[0]
    else:
        grid = res.grid if placement is None else placement.grid
    return {**grid.to_dict(), **res.stats, "write_seconds": write_s, "runs": res.n_runs,
            "output": str(out), "format": resolved.fmt, "contours": contour_info,
            "estimate": written.get("estimate") and written["estimate"].to_dict()}


def slice_job(skel: Skeleton, job: SliceJob, *, progress: bool | None = None, report=None,
              executor_info=None) -> tuple[SliceResult, ResolvedJob]:
    """Slice ``skel`` in memory as ``run_slice`` would, writing nothing.

    For consumers of the layer stream (``skelslice check``, ``skelslice
    preview``): the same checks, plate refusal and tracing as
    :func:`run_slice`, the output format being the printer's (or a PNG
    stack), whose limits apply.

    Returns
    -------
    result : SliceResult or slicer.scale.tiles.StreamedResult
        The traced runs (a streamed result, to be iterated once, when the job
        asks for tiles, slabs or an executor).
    resolved : slicer.job.spec.ResolvedJob
        The checked settings; ``resolved.settings`` gives the output layers
        (:func:`slicer.raster.antialias.output_layers`).

    Raises
    ------
    OptionError, FormatError, GridError
        As :func:`run_slice`.
    """
    resolved = job.resolve("")
    return _trace(skel, job, resolved, progress=progress, report=report, executor_info=executor_info), resolved


def _trace(skel: Skeleton, job: SliceJob, resolved: ResolvedJob, *, progress=None, dry_run: bool = False,
           report=None, executor_info=None):
    """Trace a resolved job (planned in tiles and slabs when asked); with
    ``dry_run`` return the tile plan instead (a part's: its summary dict)."""
    scale = job.scale
    opts = job.trace_options(resolved)
    g = job.grid
    part = skel if isinstance(skel, Part) else None
    if part is not None and not part.has_meshes:           # a lattice alone: the lattice's own path
        skel, part = part.skeleton, None
    grid_args = (skel, resolved.pitch[0], resolved.pitch[1], resolved.layer_height, g.bounds)
    if part is None:
        refuse_off_plate(skel, resolved, g.bounds)
    elif not part.has_clips and part.skeleton is not None:    # solids only add to the lattice's footprint
        refuse_off_plate(part.skeleton, resolved, g.bounds)
    if part is not None:
        res = _slice_part_job(part, grid_args, opts, scale, dry_run, report, executor_info, progress)
        if dry_run:
            return res                                     # the plan's summary (a dict)
    elif dry_run or report is not None or scale.planned or executor_info is not None:
        executor = scale.executor
        if executor is None or isinstance(executor, str):
            executor_info = describe_executor(executor or "serial", scale.workers, scale.scheduler)
        args = (*grid_args, opts.method, opts.bucket, opts.threads, opts.strict, opts.spans)
        plan = plan_slice(*args, max_memory=scale.max_memory, executor_info=executor_info, tile=scale.tile,
                          slab=scale.slab, sample=True if dry_run else None, blend=opts.blend,
                          prefetch=scale.prefetch)
        if report is not None:
            report(plan.describe())
        if dry_run:
            return plan
        refuse_pieces(skel, plan.n_tiles, plan.n_slabs, executor)     # support groups: one piece
        res = slice_planned(*args, plan=plan, executor=executor, executor_info=executor_info,
                            workers=scale.workers, scheduler=scale.scheduler, progress=progress, blend=opts.blend)
    else:
        res = slice_skeleton(*grid_args, **opts.trace_kwargs())
    if res.n_runs == 0 and g.bounds is None:
        raise GridError(
            "the surface is empty: no voxel centre is inside the solid (F >= 1). Struts shorter than "
            "about 0.688 x their radius, or thinner than the pixel, have no printable surface; "
            "see `skelslice info SCENE --pixel-size MM`")
    return res


def _slice_part_job(part: Part, grid_args: tuple, opts, scale, dry_run: bool, report, executor_info, progress):
    """The slicing step of :func:`run_slice` for a part with meshes (:mod:`slicer.parts.slicing`):
    returns the result, or with ``dry_run`` the plan's summary."""
    args = (part, *grid_args[1:], opts.method, opts.bucket, opts.threads, opts.strict, opts.spans, opts.span_tol)
    planned = dry_run or report is not None or scale.planned or executor_info is not None
    if not planned:
        return slice_part(*args, blend=opts.blend)
    executor = scale.executor
    if executor is None or isinstance(executor, str):
        executor_info = describe_executor(executor or "serial", scale.workers, scale.scheduler)
    if part.skeleton is None:            # meshes only: nothing to tile
        grid = part_grid(part, *grid_args[1:])
        text = (f"grid:      {grid.width} x {grid.height} px x {grid.layers} layers = {grid.n_voxels:.3g} voxels "
                f"(trimmed to the part after slicing)\nmeshes:    {part.describe()} (cut layer by layer, in memory)")
        if report is not None:
            report(text)
        if dry_run:
            return {**grid.to_dict(), "plan": {"grid": grid.to_dict()}, "plan_text": text, "dry_run": True}
        return slice_part(*args, blend=opts.blend)
    plan = plan_part(*args, max_memory=scale.max_memory, executor_info=executor_info, tile=scale.tile,
                     slab=scale.slab, sample=True if dry_run else None, blend=opts.blend,
                     prefetch=scale.prefetch)
    if report is not None:
        report(plan.describe())
    if dry_run:
        return {**plan.grid.to_dict(), "plan": plan.to_dict(), "plan_text": plan.describe(), "dry_run": True}
    return slice_part_planned(*args, plan=plan, executor=executor, executor_info=executor_info,
                              workers=scale.workers, scheduler=scale.scheduler, progress=progress, blend=opts.blend)


def footprint_lower_bound(skel: Skeleton, grid: SliceGrid, probes: int = 256) -> np.ndarray | None:
    """A box of voxel centres known to be inside, found without tracing.

    For each of the six axis directions, the voxel centres nearest the
    skeleton's most extreme nodes along it are classified with the exact
    field (``F >= 1`` with a margin of 1e-9 for rounding) until one is
    inside; from there, the centres further out along the same direction,
    up to the support's reach, are classified too and the farthest inside
    one is kept. The inside voxels of a traced result include every centre
    found here, so the box they span is a lower bound of the model's
    footprint (and height) on this grid.

    Parameters
    ----------
    skel : Skeleton
    grid : SliceGrid
        The grid the job will trace (any origin; centres outside it are ignored).
    probes : int
        Nodes tried per direction, at most.

    Returns
    -------
    (2, 3) int64 or None
        ``[[i0, j0, k0], [i1, j1, k1]]``: the lowest and highest column, row
        and layer of inside centres found; None if none was found.
    """
    steps = np.array([grid.pixel_size[0], grid.pixel_size[1], grid.layer_height])
    shape = np.array([grid.width, grid.height, grid.layers])
    ijk = np.rint(_to_index(grid, skel.nodes))
    ijk = ijk[np.all((ijk >= 0) & (ijk < shape), axis=1)].astype(np.int64)
    if not len(ijk):
        return None
    reach = skel.sigma * float(skel.radii.max())
    found = []
    for axis in range(3):
        # index direction that moves outward: +i is +x, +j is -y, +k is +z
        for outward in (-1, 1):
            order = np.argsort(-outward * ijk[:, axis], kind="stable")[:probes]
            cand = ijk[order]
            inside = _inside(skel, grid, cand)
            if not inside.any():
                continue
            start = cand[int(np.argmax(inside))]
            n = int(min(np.ceil(reach / steps[axis]) + 1, 4096))
            ray = np.repeat(start[None, :], n, axis=0)
            ray[:, axis] += outward * np.arange(1, n + 1)
            ray = ray[(ray[:, axis] >= 0) & (ray[:, axis] < shape[axis])]
            hit = _inside(skel, grid, ray) if len(ray) else np.zeros(0, bool)
            found.append(ray[np.nonzero(hit)[0][-1]] if hit.any() else start)
    if not found:
        return None
    found = np.array(found)
    return np.stack([found.min(axis=0), found.max(axis=0)])


def _to_index(grid: SliceGrid, points: np.ndarray) -> np.ndarray:
    """(column, row, layer) coordinates of points, as floats."""
    px, py = grid.pixel_size
    x0, y0, z0 = grid.origin
    return np.stack([(points[:, 0] - x0) / px, (y0 - points[:, 1]) / py, (points[:, 2] - z0) / grid.layer_height],
                    axis=1)


def _inside(skel: Skeleton, grid: SliceGrid, ijk: np.ndarray) -> np.ndarray:
    """Whether voxel centres (column, row, layer) are certainly inside (F >= 1 + 1e-9)."""
    px, py = grid.pixel_size
    x0, y0, z0 = grid.origin
    centres = np.stack([x0 + ijk[:, 0] * px, y0 - ijk[:, 1] * py, z0 + ijk[:, 2] * grid.layer_height], axis=1)
    return evaluate(skel, centres)[0] >= 1.0 + 1e-9


def refuse_off_plate(skel: Skeleton, resolved: ResolvedJob, bounds) -> None:
    """Refuse, before tracing, a model that cannot fit the printer's plate.

    Uses :func:`footprint_lower_bound` on the grid the job will trace, so a
    refusal is certain: the traced footprint can only be larger. The exact
    check (:func:`formats.printer_profiles.place`) still runs after tracing.

    Raises
    ------
    GridError
        The footprint's lower bound is wider or deeper than the plate, or
        taller than the printer, naming both sizes.
    """
    prn = resolved.printer
    if prn is None or skel.n_segments == 0:
        return
    grid = make_grid(skel.support_bounds(), resolved.pitch[0], resolved.pitch[1], resolved.layer_height, bounds)
    box = footprint_lower_bound(skel, grid)
    if box is None:
        return
    px, py = grid.pixel_size
    size_x = (box[1, 0] - box[0, 0] + 1) * px
    size_y = (box[1, 1] - box[0, 1] + 1) * py
    height = (box[1, 2] - box[0, 2] + 1) * grid.layer_height
    W, H = prn.display
    if size_x > W + 1e-9 or size_y > H + 1e-9:
        raise GridError(f"the model (at least {size_x:.2f} x {size_y:.2f} mm) does not fit on the {prn.label} "
                        f"plate ({W:g} x {H:g} mm); refused before slicing")
    if height > prn.max_height + 1e-9:
        raise GridError(f"the model is at least {height:.2f} mm tall; the {prn.label} prints at most "
                        f"{prn.max_height:g} mm; refused before slicing")


def check_not_input(out, *inputs) -> None:
    """Refuse an output that is one of the inputs or a folder holding one
    (``--force`` would destroy it).

    Raises
    ------
    OutputError
    """
    o = Path(out).resolve()
    for src in inputs:
        if src is None:
            continue
        s = Path(src).resolve()
        if o == s or o in s.parents:
            what = "is the input" if o == s else "holds the input"
            raise OutputError(f"{out}: the output {what} {src}; choose another output")


__all__ = ["run_slice", "slice_job", "footprint_lower_bound", "refuse_off_plate", "check_not_input"]
