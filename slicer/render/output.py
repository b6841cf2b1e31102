"""Writing renders: the image as PNG and the crossings as ``.npz``, atomically.

The job of ``skelslice render``: :func:`run_render` checks both destinations
before any work, renders (:func:`slicer.render.rendering.render`, or
:func:`slicer.render.parts.render_part` for a part) and writes the files
through :mod:`slicer.atomic`.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from formats.base import zip_entry

from slicer.atomic import AtomicFile, check_destination
from slicer.errors import OutputError
from slicer.parts.part import Part
from slicer.render.rendering import RenderResult, render
from slicer.render.parts import render_part
from slicer.model.skeleton import Skeleton
from slicer.supports.show import render_scene


def save_png(image: np.ndarray, path, force: bool = False) -> None:
    """Write an (H, W, 3) or (H, W, 4) uint8 image as PNG, atomically."""
    path = Path(path)
    check_destination(path, force)
    mode = "RGBA" if image.shape[2] == 4 else "RGB"
    with AtomicFile(path) as out:
        Image.fromarray(image, mode).save(out.fh, format="PNG", optimize=True)
        out.publish(force)


def save_roots(result: RenderResult, path, force: bool = False) -> None:
    """Write the ``--roots-out`` arrays (:meth:`RenderResult.roots_arrays`) as ``.npz``, atomically."""
    path = Path(path)
    check_destination(path, force)
    arrays = result.roots_arrays()
    with AtomicFile(path) as out:
        _write_npz(out.fh, arrays)
        out.publish(force)


def _write_npz(fh, arrays: dict) -> None:
    """``np.savez_compressed`` with the fixed zip timestamps of
    :func:`formats.base.zip_entry`, so equal arrays give equal bytes (the file
    is readable by ``np.load``)."""
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, a in arrays.items():
            with zf.open(zip_entry(f"{name}.npy", True), "w", force_zip64=True) as out:
                np.lib.format.write_array(out, np.asanyarray(a), allow_pickle=False)


def run_render(skel: Skeleton | Part, out, *, roots_out=None, force: bool = False, transparent: bool = False,
               **options) -> dict:
    """Render ``skel`` to the PNG ``out`` (and the roots to ``roots_out``).

    Both destinations are checked before any work; nothing is left at them on
    failure. ``options`` go to :func:`render`. Returns the stats dict.
    """
    out = Path(out)
    check_destination(out, force)
    if roots_out is not None:
        roots_out = Path(roots_out)
        if roots_out.resolve() == out.resolve():
            raise OutputError(f"{roots_out}: the roots file cannot be the image file")
        check_destination(roots_out, force)
    if isinstance(skel, Part) and not skel.has_meshes:
        skel = skel.skeleton                                       # a lattice alone (perhaps with supports)
    draw = render_part if isinstance(skel, Part) else render_scene   # a part: lattice and meshes
    res = draw(skel, keep_roots=roots_out is not None, **options)
    save_png(res.image(transparent), out, force)
    if roots_out is not None:
        save_roots(res, roots_out, force)
    return res.stats


__all__ = ["run_render", "save_png", "save_roots"]
