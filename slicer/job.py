"""A whole slicing job: scene in, printer output written atomically."""
from __future__ import annotations

import time
from pathlib import Path

from . import __version__
from .errors import GridError
from .skeleton import Skeleton
from .slicing import SliceResult, slice_skeleton


def write_stack(result: SliceResult, out, fmt: str | None = None, meta: dict | None = None,
                force: bool = False, progress: bool | None = None, skel: Skeleton | None = None,
                contour_tol: float = 1e-3, settings=None, info: dict | None = None) -> float:
    """Stream the layers of a result to an output, atomically.

    Parameters
    ----------
    result : SliceResult
    out : path-like
        Destination (a folder for ``png``).
    fmt : str, optional
        Format name (see :data:`formats.WRITERS`); inferred from ``out`` if None.
    meta : dict, optional
        Provenance written into the format's metadata.
    force : bool
        Replace an existing output.
    progress : bool or None
        tqdm progress bar; None shows it only on a terminal.
    skel : Skeleton, optional
        The sliced skeleton; required by contour formats (``cli``, ``3mf``,
        ``svg``...), which stream :func:`slicer.contours.iter_contours`.
    contour_tol : float, mm
        Contour accuracy for contour formats.
    settings : formats.printers.PrintSettings, optional
        Printer placement, anti-aliasing and exposure for image formats (see
        :func:`slicer.antialias.render`); None writes ``result``'s own layers.
        With a printer, contour formats are placed on the plate too (the same
        layers and position as the images, coordinates in plate mm).
    info : dict, optional
        Receives ``estimate``: the writer's print time and resin volume
        (:class:`formats.estimate.PrintEstimate`), None if it has none.

    Returns
    -------
    float
        Seconds spent producing and writing layers.
    """
    from tqdm import tqdm

    from formats import writer_for

    t0 = time.perf_counter()
    writer_cls = writer_for(fmt, out)
    contours = getattr(writer_cls, "kind", "image") == "contours"
    if contours and skel is None:
        raise ValueError(f"the {writer_cls.name} format writes contours: pass the skeleton (skel=...)")
    placement = plate_placement(result, settings)
    if settings is not None and not contours:
        from .antialias import render

        grid, layers = render(result, settings)        # places on the plate, anti-aliases
        writer = writer_cls(out, grid, meta, force=force, settings=settings)
    elif placement is not None:                        # contours on the printer's plate
        grid = placement.grid
        writer = writer_cls(out, grid, meta, force=force)
    else:
        grid, layers = result.grid, result.iter_layers()
        writer = writer_cls(out, result.grid, meta, force=force)
    if contours:
        from .contours import iter_contours

        with writer:
            bar = tqdm(iter_contours(skel, result, contour_tol, placement=placement), total=grid.layers,
                       unit="layer",
                       disable=(None if progress is None else not progress), leave=False, desc="contours")
            for k, z, polys in bar:
                writer.write_layer(k, z, polys)
        return time.perf_counter() - t0
    with writer:
        bar = tqdm(layers, total=grid.layers, unit="layer", disable=(None if progress is None else not progress),
                   leave=False, desc="writing")
        for k, img in enumerate(bar):
            writer.write_layer(k, img)
    if info is not None:
        info["estimate"] = writer.estimate
    return time.perf_counter() - t0


def plate_placement(result: SliceResult, settings):
    """Where ``result`` lands on the plate of ``settings.printer``
    (:func:`formats.printers.place`), or None without a printer."""
    if settings is None or settings.printer is None:
        return None
    from formats.printers import place

    return place(result, settings.printer, settings.aa, settings.at)


def run_slice(skel: Skeleton, out, *, pixel_size: float | None = None, pixel_size_y: float | None = None,
              layer_height: float | None = None, bounds=None, method: str = "interval",
              bucket: int = 64, threads: int | None = None, strict: bool = False,
              fmt: str | None = None, force: bool = False, scene_name: str | None = None,
              progress: bool | None = None, contour_tol: float = 1e-3, printer: str | None = None,
              at=None, aa: int = 1, aa_z: bool = False, gamma: float = 1.0, exposure: float | None = None,
              bottom_exposure: float | None = None, bottom_layers: int | None = None,
              max_memory=None, executor=None, executor_info=None, workers: int | None = None,
              scheduler: str | None = None, tile: int | None = None, slab: int | None = None,
              dry_run: bool = False, report=None, contours=None) -> dict:
    """Slice ``skel`` and write the layers to ``out``; returns a summary dict.

    ``printer`` (a :data:`formats.printers.PRINTERS` name) sets the pixel
    pitch and places the model on the plate (centred, or its footprint
    centre ``at`` = (X, Y) plate mm, bottom on the plate); ``aa``, ``aa_z``
    and ``gamma`` anti-alias (:mod:`slicer.antialias`); ``exposure``,
    ``bottom_exposure`` (s) and ``bottom_layers`` go into printer formats.
    :func:`formats.printers.resolve_job` checks how the options combine.

    ``max_memory`` (bytes or ``"4GB"``), ``executor`` (a kind, opened
    after the request is checked, with ``workers`` and ``scheduler``; or an
    open executor with its ``executor_info``, see
    :func:`slicer.executors.open_executor`), ``tile`` (px) and ``slab``
    (layers) slice in tiles and slabs that fit the budget
    (:mod:`slicer.tiles`); ``report`` is called with the plan's description
    before tracing; ``dry_run`` returns the plan (``plan`` in the summary)
    after a quick sample, writing nothing.

    Raises
    ------
    OutputError
        ``out`` exists (without ``force``) or cannot be written; checked before
        any work. Nothing is left at ``out`` on any failure.
    GridError
        Invalid sizes or bounds, a grid beyond the voxel limit (refused before
        any work), or, with default bounds, a scene with no surface at all.
    """
    import inspect

    from formats import WRITERS
    from formats.base import check_destination
    from formats.printers import resolve_job

    from .antialias import render

    check_destination(Path(out), force)   # fail before any work
    if contours is not None:              # ``--contours FILE``: GeoJSON / JSON beside the images
        check_destination(Path(contours), force)
    job = resolve_job(fmt, out, printer, pixel_size, pixel_size_y, layer_height, bounds, aa, aa_z, gamma, at,
                      exposure, bottom_exposure, bottom_layers)
    if job.spans and "spans" not in inspect.signature(slice_skeleton).parameters:
        raise GridError("--aa-z needs the tracer's inside spans (slice_skeleton(..., spans=True)), "
                        "which this version does not provide")
    if dry_run or report is not None or any(v is not None for v in (max_memory, executor, executor_info, tile, slab)):
        from .executors import executor_info as describe
        from .tiles import plan_slice, slice_planned

        args = (skel, job.pitch[0], job.pitch[1], job.layer_height, bounds, method, bucket, threads, strict,
                job.spans)
        if executor is None or isinstance(executor, str):
            executor_info = describe(executor or "serial", workers, scheduler)
        plan = plan_slice(*args, max_memory=max_memory, executor_info=executor_info, tile=tile, slab=slab,
                          sample=True if dry_run else None)
        if report is not None:
            report(plan.describe())
        if dry_run:
            from formats.estimate import print_estimate

            est = print_estimate(job.settings, plan.grid.layers) if job.settings and job.settings.printer else None
            return {**plan.grid.to_dict(), "plan": plan.to_dict(), "plan_text": plan.describe(), "dry_run": True,
                    "output": str(out), "format": job.fmt, "estimate": est and est.to_dict()}
        res = slice_planned(*args, plan=plan, executor=executor, executor_info=executor_info, workers=workers,
                            scheduler=scheduler, progress=progress)
    else:
        res = slice_skeleton(skel, job.pitch[0], job.pitch[1], job.layer_height, bounds, method, bucket, threads,
                             strict, **({"spans": True} if job.spans else {}))
    if res.n_runs == 0 and bounds is None:
        raise GridError(
            "the surface is empty: no voxel centre is inside the solid (F >= 1). Struts shorter than "
            "about 0.688 x their radius, or thinner than the pixel, have no printable surface; "
            "see `skelslice info SCENE --pixel-size MM`")
    meta = {"generator": f"skelslice {__version__}", "method": method, "bucket": res.stats["bucket"]}
    if scene_name:
        meta["scene"] = scene_name
    written: dict = {}
    write_s = write_stack(res, out, job.fmt, meta, force, progress, skel=skel, contour_tol=contour_tol,
                          settings=job.settings, info=written)
    contour_info = None
    if contours is not None:
        from .contours import write_contours

        contour_info = write_contours(skel, res, contours, contour_tol, force, meta,
                                      placement=plate_placement(res, job.settings))
    images = getattr(WRITERS[job.fmt], "kind", "image") != "contours"
    if job.settings is not None and images:
        grid = render(res, job.settings)[0]
    else:
        placement = plate_placement(res, job.settings)
        grid = res.grid if placement is None else placement.grid
    return {**grid.to_dict(), **res.stats, "write_seconds": write_s, "runs": res.n_runs,
            "output": str(out), "format": job.fmt, "contours": contour_info,
            "estimate": written.get("estimate") and written["estimate"].to_dict()}


def check_not_input(out, *inputs) -> None:
    """Refuse an output that is one of the inputs or a folder holding one
    (``--force`` would destroy it).

    Raises
    ------
    OutputError
    """
    from .errors import OutputError

    o = Path(out).resolve()
    for src in inputs:
        if src is None:
            continue
        s = Path(src).resolve()
        if o == s or o in s.parents:
            what = "is the input" if o == s else "holds the input"
            raise OutputError(f"{out}: the output {what} {src}; choose another output")
