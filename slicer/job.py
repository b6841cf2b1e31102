"""A whole slicing job: scene in, printer output written atomically."""
from __future__ import annotations

import time
from pathlib import Path

from . import __version__
from .errors import GridError
from .skeleton import Skeleton
from .slicing import SliceResult, slice_skeleton


def write_stack(result: SliceResult, out, fmt: str | None = None, meta: dict | None = None,
                force: bool = False, progress: bool | None = None) -> float:
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

    Returns
    -------
    float
        Seconds spent producing and writing layers.
    """
    from tqdm import tqdm

    from formats import writer_for

    t0 = time.perf_counter()
    writer_cls = writer_for(fmt, out)
    writer = writer_cls(out, result.grid, meta, force=force)
    with writer:
        layers = result.iter_layers()
        bar = tqdm(layers, total=result.grid.layers, unit="layer", disable=(None if progress is None else not progress),
                   leave=False, desc="writing")
        for k, img in enumerate(bar):
            writer.write_layer(k, img)
    return time.perf_counter() - t0


def run_slice(skel: Skeleton, out, *, pixel_size: float, pixel_size_y: float | None = None,
              layer_height: float | None = None, bounds=None, method: str = "interval",
              bucket: int = 64, threads: int | None = None, strict: bool = False,
              fmt: str | None = None, force: bool = False, scene_name: str | None = None,
              progress: bool | None = None) -> dict:
    """Slice ``skel`` and write the layers to ``out``; returns a summary dict.

    Raises
    ------
    OutputError
        ``out`` exists (without ``force``) or cannot be written; checked before
        any work. Nothing is left at ``out`` on any failure.
    GridError
        Invalid sizes or bounds, a grid beyond the voxel limit (refused before
        any work), or, with default bounds, a scene with no surface at all.
    """
    from formats.base import check_destination

    check_destination(Path(out), force)   # fail before any work
    res = slice_skeleton(skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict)
    if res.n_runs == 0 and bounds is None:
        raise GridError(
            "the surface is empty: no voxel centre is inside the solid (F >= 1). Struts shorter than "
            "about 0.688 x their radius, or thinner than the pixel, have no printable surface; "
            "see `skelslice info SCENE --pixel-size MM`")
    meta = {"generator": f"skelslice {__version__}", "method": method, "bucket": res.stats["bucket"]}
    if scene_name:
        meta["scene"] = scene_name
    write_s = write_stack(res, out, fmt, meta, force, progress)
    return {**res.grid.to_dict(), **res.stats, "write_seconds": write_s, "runs": res.n_runs,
            "output": str(out)}
