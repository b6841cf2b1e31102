"""The layer stream the printability check and the preview consume.

A :class:`LayerStack` is a window of output layers (8-bit images, bottom
first) with the grid that places its pixels. It comes from a traced result
(:func:`model_layers`: the images the writers would write, cropped to the
model's window) or from an output read back (:mod:`formats.readback`).
Solid means grey >= 128: with anti-aliasing that is coverage >= 1/2
(:mod:`slicer.raster.antialias`), without it every inside pixel (255).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from formats.printer_profiles import Printer, PrintSettings, place
from formats.readback import open_stack

from slicer.raster.antialias import box_filter, grey_from_coverage, iter_sub_coverage, output_layers, paste
from slicer.tracer.grid import SliceGrid

#: grey level from which a pixel counts as solid (50 % coverage, see slicer.raster.antialias)
SOLID = 128
#: outputs with larger images are cut to the box of their solid pixels (one extra pass)
CROP_PIXELS = 4_000_000


def rounded(v: float) -> float:
    """A length, area or volume for reports: rounded to 1e-9 (far below a voxel), no -0."""
    return round(float(v), 9) + 0.0


@dataclass
class LayerStack:
    """Output layers of a job, one (grid.height, grid.width) uint8 image at a time.

    Attributes
    ----------
    grid : SliceGrid
        Where the pixels are: centre of pixel (row j, column i) of layer k at
        ``(x0 + i px, y0 - j py, z0 + k h)``, in scene mm (``frame ==
        "scene"``) or plate mm (``frame == "plate"``, build plate at Z = 0).
    layers : iterable of (grid.height, grid.width) uint8
        Bottom layer first; iterate once.
    frame : {"scene", "plate"}
    printer : formats.printer_profiles.Printer or None
    settings : formats.printer_profiles.PrintSettings or None
        Exposure settings when known (printer jobs, printer archives).
    offset : (3,) float, mm
        Translation from scene to this stack's coordinates (zero in the
        scene frame).
    window : (2,) int
        (row, column) of this window's pixel (0, 0) in the full output image
        (the plate image with a printer).
    full_shape : (2,) int
        (rows, columns) of the full output image.
    source : str
        What the layers came from (a scene or output path), for reports.
    """

    grid: SliceGrid
    layers: Iterable[np.ndarray]
    frame: str = "scene"
    printer: Printer | None = None
    settings: PrintSettings | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    window: tuple[int, int] = (0, 0)
    full_shape: tuple[int, int] | None = None
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.full_shape is None:
            self.full_shape = (self.grid.height, self.grid.width)

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter(self.layers)

    def layer_of(self, z: float) -> int:
        """Index of the layer whose centre is nearest the height ``z`` (this stack's mm)."""
        g = self.grid
        return int(np.rint((z - g.origin[2]) / g.layer_height))

    def pixel_of(self, x: float, y: float) -> tuple[float, float]:
        """(column, row) of a point (this stack's mm), as floats."""
        g = self.grid
        return (x - g.origin[0]) / g.pixel_size[0], (g.origin[1] - y) / g.pixel_size[1]


def model_layers(result, settings: PrintSettings | None, source: str = "") -> LayerStack:
    """The output layers of a traced result, cropped to the model's window.

    The images are those the writers write (:func:`slicer.raster.antialias.output_layers`):
    the traced grid's own layers without a printer (anti-aliased when asked),
    the printer's plate images with one, but only the window of the plate
    the model covers, so memory is O(model footprint) whatever the plate.

    Parameters
    ----------
    result : SliceResult or slicer.scale.tiles.StreamedResult
    settings : PrintSettings or None
        As resolved for the job (``ResolvedJob.settings``).
    source : str

    Returns
    -------
    LayerStack
    """
    if settings is None or settings.printer is None:
        grid, layers = (result.grid, result.iter_layers()) if settings is None else output_layers(result, settings)
        return LayerStack(grid, layers, "scene", None, settings, source=source)
    pl = place(result, settings.printer, settings.aa, settings.at)
    g, n = result.grid, pl.aa
    rows, cols = settings.printer.plate_shape
    top, left = pl.dj // n, pl.di // n                       # as box_filter places the traced window
    bottom = -(-(g.height + pl.dj) // n)
    right = -(-(g.width + pl.di) // n)
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(bottom, rows), min(right, cols)
    grid = pl.grid.sub(c0, r0, 0, c1 - c0, r1 - r0, pl.layers)
    return LayerStack(grid, _window_layers(result, pl, settings, (r0, c0, r1, c1)), "plate", settings.printer,
                      settings, offset=pl.offset(g), window=(r0, c0), full_shape=(rows, cols), source=source)


def read_layers(path, crop: bool | None = None) -> LayerStack:
    """The layers of an output skelslice wrote (:func:`formats.readback.open_stack`).

    Parameters
    ----------
    path : path-like
        A PNG folder, ``.zip``, ``.sl1``, ``.sl1s``, ``.goo`` or ``.nanodlp``.
    crop : bool, optional
        Cut the layers to the box of their solid pixels (plus one pixel):
        the file is read once when the layers' own boxes fit
        :data:`formats.readback.KEEP_BYTES`, else twice; default: for images
        above :data:`CROP_PIXELS` (printer plates).

    Raises
    ------
    ReadError
    """
    rs = open_stack(path)
    g = rs.grid
    if crop is None:
        crop = g.width * g.height > CROP_PIXELS
    window, layers = rs.cropped() if crop else ((0, 0, g.height, g.width), rs.layers())
    r0, c0, r1, c1 = window
    grid = g.sub(c0, r0, 0, c1 - c0, r1 - r0, g.layers)
    return LayerStack(grid, layers, rs.frame, rs.printer, rs.settings,
                      window=(r0, c0), full_shape=(g.height, g.width), source=str(path),
                      meta={"format": rs.format, **rs.meta})


def _window_layers(result, pl, settings: PrintSettings, box) -> Iterator[np.ndarray]:
    """The plate layers of a placed result, cut to ``box`` = (r0, c0, r1, c1)."""
    r0, c0, r1, c1 = box
    aa = settings.antialiased
    src = iter_sub_coverage(result, settings.aa_z) if aa else result.iter_layers()
    for k, img in enumerate(src):
        if k < pl.k_first:
            continue
        if k >= pl.k_first + pl.layers:
            break
        out = np.zeros((r1 - r0, c1 - c0), np.uint8)
        if aa:
            cov, (top, left) = box_filter(img, pl.aa, (pl.dj, pl.di))
            paste(out, grey_from_coverage(cov, settings.gamma), top - r0, left - c0)
        else:
            paste(out, img, pl.dj - r0, pl.di - c0)
        yield out


__all__ = ["LayerStack", "model_layers", "read_layers", "rounded", "SOLID", "CROP_PIXELS"]
