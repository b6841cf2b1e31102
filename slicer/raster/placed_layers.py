"""Layers on their way out: a traced result streamed to a writer, placed and anti-aliased.

:func:`write_stack` pulls one layer at a time from a
:class:`~slicer.tracer.slicing.SliceResult` (or the contours of each layer), places
it on a printer's plate and anti-aliases it (:mod:`slicer.raster.antialias`), and
hands it to a writer of :mod:`formats`, which publishes the output atomically.
"""
from __future__ import annotations

import time

from tqdm import tqdm

from formats import writer_for
from formats.base import write_ordered
from formats.printer_profiles import place

from slicer.raster.antialias import output_layers
from slicer.contours import iter_contours
from slicer.errors import OutputError
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult


def write_stack(result: SliceResult, out, fmt: str | None = None, meta: dict | None = None,
                force: bool = False, progress: bool | None = None, skel: Skeleton | None = None,
                contour_tol: float = 1e-3, settings=None, info: dict | None = None,
                workers: int | None = None) -> float:
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
    settings : formats.printer_profiles.PrintSettings, optional
        Printer placement, anti-aliasing and exposure for image formats (see
        :func:`slicer.raster.antialias.output_layers`); None writes ``result``'s own layers.
        With a printer, contour formats are placed on the plate too (the same
        layers and position as the images, coordinates in plate mm).
    info : dict, optional
        Receives ``estimate``: the writer's print time and resin volume
        (:class:`formats.estimate.PrintEstimate`), None if it has none.
    workers : int, optional
        Threads encoding image layers (:func:`formats.base.write_ordered`;
        default: the cores). The output does not depend on it.

    Returns
    -------
    float
        Seconds spent producing and writing layers.
    """
    t0 = time.perf_counter()
    writer_cls = writer_for(fmt, out)
    contours = getattr(writer_cls, "kind", "image") == "contours"
    if contours and skel is None:
        raise OutputError(f"{out}: the {writer_cls.name} format writes contours: pass the skeleton (skel=...)")
    placement = plate_placement(result, settings)
    if settings is not None and not contours:
        grid, layers = output_layers(result, settings, skel, contour_tol)   # places on the plate, anti-aliases
        writer = writer_cls(out, grid, meta, force=force, settings=settings)
    elif placement is not None:                                # contours on the printer's plate
        grid = placement.grid
        writer = writer_cls(out, grid, meta, force=force)
    else:
        grid, layers = result.grid, result.iter_layers()
        writer = writer_cls(out, result.grid, meta, force=force)
    hide = None if progress is None else not progress
    with writer:
        if contours:
            items = iter_contours(skel, result, contour_tol, placement=placement)
            for k, z, polys in tqdm(items, total=grid.layers, unit="layer", disable=hide, leave=False,
                                    desc="contours"):
                writer.write_layer(k, z, polys)
        else:
            # encoded on a thread pool, stored in order (byte-identical to a serial run)
            write_ordered(writer, tqdm(layers, total=grid.layers, unit="layer", disable=hide, leave=False,
                                       desc="writing"), workers)
    if info is not None:
        info["estimate"] = getattr(writer, "estimate", None)
    return time.perf_counter() - t0


def plate_placement(result: SliceResult, settings):
    """Where ``result`` lands on the plate of ``settings.printer``
    (:func:`formats.printer_profiles.place`), or None without a printer."""
    if settings is None or settings.printer is None:
        return None
    return place(result, settings.printer, settings.aa, settings.at)


__all__ = ["write_stack", "plate_placement"]
