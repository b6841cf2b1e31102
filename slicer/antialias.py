"""Anti-aliased layers: XY supersampling, sub-layer z coverage, grey with gamma.

Coverage
--------
``--aa N`` traces the model at pixel/N: the N x N sub-pixel centres sit
symmetrically inside each output pixel (at ``(s + 1/2) / N`` of the pixel,
``s = 0 .. N-1``), and the output pixel's XY coverage is the fraction of its
sub-pixel centres that are inside (a box filter). ``--aa-z`` replaces each
inside/outside sample by the exact fraction of the voxel's z-extent
``[z_k - h/2, z_k + h/2]`` that lies inside the solid, from the real-valued
inside spans along the ray (:meth:`SliceResult.iter_coverage`); with both,
the output coverage is the mean of the N x N sub-pixel z coverages.

Grey mapping
------------
Coverage ``c`` in [0, 1] becomes the 8-bit grey ``floor(255 s(c) + 1/2)``
with ``s(c) = c^g / (c^g + (1 - c)^g)``, ``g = --gamma``:

* ``s(0) = 0``, ``s(1) = 1``, and ``s(1/2) = 1/2`` for every ``g``, so 50 %
  coverage is grey 128: a reader that thresholds at 128 (PrusaSlicer's
  importer, the Prusa firmware's area count) puts the boundary exactly at
  50 % coverage, i.e. on the true surface; ``grey >= 128`` if and only if
  ``c >= 1/2``.
* ``g = 1`` is linear (grey proportional to coverage, PrusaSlicer's
  ``gamma_correction = 1``); ``g > 1`` sharpens edges toward a threshold,
  ``g < 1`` softens them.

Without anti-aliasing the layers stay exactly 0/255.
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from formats.printers import place

from .checks import integer, positive_number
from .errors import GridError
from .grid import SliceGrid


def grey_from_coverage(cov: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """8-bit grey of a coverage array (see the module docstring).

    Parameters
    ----------
    cov : (h, w) float64 in [0, 1]
    gamma : float > 0

    Returns
    -------
    (h, w) uint8
    """
    c = np.clip(np.asarray(cov, dtype=np.float64), 0.0, 1.0)
    if gamma == 1.0:
        s = c
    else:
        a = c ** gamma
        b = (1.0 - c) ** gamma
        s = a / (a + b)          # a + b > 0: one of c, 1 - c is >= 1/2
    return np.floor(255.0 * s + 0.5).astype(np.uint8)


def box_filter(sub: np.ndarray, n: int, offset: tuple[int, int] = (0, 0)):
    """Mean over n x n blocks of a sub-pixel image placed at ``offset``.

    Parameters
    ----------
    sub : (H, W) float64 or bool
        Sub-pixel coverage; its pixel (0, 0) is sub-pixel ``offset`` =
        ``(row, column)`` of a lattice whose output pixel (r, c) holds
        sub-pixels ``[r n, (r + 1) n) x [c n, (c + 1) n)``.
    n : int
    offset : (2,) int

    Returns
    -------
    cov : (h, w) float64
        Output-pixel coverage (sub-pixels outside ``sub`` count as empty).
    origin : (2,) int
        Output pixel (row, column) of ``cov[0, 0]``.
    """
    H, W = sub.shape
    top, left = offset[0] // n, offset[1] // n
    pt, pl = offset[0] - top * n, offset[1] - left * n
    h = -(-(H + pt) // n)
    w = -(-(W + pl) // n)
    buf = np.zeros((h * n, w * n), np.float64)
    buf[pt:pt + H, pl:pl + W] = sub
    cov = np.zeros((h, w), np.float64)
    for a in range(n):                 # strided adds: ~8x faster than a mean over a 4-d view
        for b in range(n):
            cov += buf[a::n, b::n]
    cov /= n * n
    return cov, (top, left)


def output_grid(grid: SliceGrid, n: int) -> SliceGrid:
    """The output grid of a grid traced at pixel/n (blocks from sub-pixel 0)."""
    if n == 1:
        return grid
    spx, spy = grid.pixel_size
    ox, oy, oz = grid.origin
    origin = (ox + 0.5 * (n - 1) * spx, oy - 0.5 * (n - 1) * spy, oz)
    return SliceGrid(origin, (n * spx, n * spy), grid.layer_height, -(-grid.width // n),
                     -(-grid.height // n), grid.layers)


def iter_sub_coverage(result, aa_z: bool) -> Iterator[np.ndarray]:
    """Per traced layer, (H, W) float64 coverage of each (sub-)pixel: 0/1
    from the voxel centres, or the exact z coverage with ``aa_z``."""
    if aa_z:
        if not hasattr(result, "iter_coverage"):
            raise GridError("--aa-z needs the tracer's inside spans, which this version does not provide")
        for cov in result.iter_coverage():
            yield np.asarray(cov, dtype=np.float64)
    else:
        for img in result.iter_layers(1):
            yield img.astype(np.float64)


def check_aa(aa, gamma) -> tuple[int, float]:
    """Validate ``--aa`` (integer 1..16) and ``--gamma`` (> 0)."""
    return integer(aa, "--aa", lo=1, hi=16), positive_number(gamma, "--gamma")


def paste(canvas: np.ndarray, win: np.ndarray, top: int, left: int) -> None:
    """Copy ``win`` into ``canvas`` at (top, left), clipped to the canvas."""
    H, W = canvas.shape
    h, w = win.shape
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + h, H), min(left + w, W)
    if r1 > r0 and c1 > c0:
        canvas[r0:r1, c0:c1] = win[r0 - top:r1 - top, c0 - left:c1 - left]


def output_layers(result, settings) -> tuple[SliceGrid, Iterator[np.ndarray]]:
    """The output grid and the layer images of a traced result.

    Parameters
    ----------
    result : SliceResult
        Traced at the output pitch / ``settings.aa``.
    settings : formats.printers.PrintSettings
        Printer (None: the traced grid itself), anti-aliasing, gamma, ``at``.

    Returns
    -------
    grid : SliceGrid
        Output grid (the full plate with a printer).
    layers : iterator of (grid.height, grid.width) uint8
        One layer at a time, bottom first.
    """
    n, aa = settings.aa, settings.antialiased
    if settings.printer is None:
        if not aa:
            return result.grid, result.iter_layers()
        layers = (grey_from_coverage(box_filter(c, n)[0], settings.gamma)
                  for c in iter_sub_coverage(result, settings.aa_z))
        return output_grid(result.grid, n), layers
    pl = place(result, settings.printer, n, settings.at)
    return pl.grid, _plate_layers(result, pl, settings)


def _plate_layers(result, pl, settings) -> Iterator[np.ndarray]:
    shape = pl.printer.plate_shape
    src = iter_sub_coverage(result, settings.aa_z) if settings.antialiased else result.iter_layers()
    for k, img in enumerate(src):
        if k < pl.k_first:
            continue
        if k >= pl.k_first + pl.layers:
            break
        canvas = np.zeros(shape, np.uint8)
        if settings.antialiased:
            cov, (top, left) = box_filter(img, pl.aa, (pl.dj, pl.di))
            paste(canvas, grey_from_coverage(cov, settings.gamma), top, left)
        else:
            paste(canvas, img, pl.dj, pl.di)
        yield canvas


__all__ = ["grey_from_coverage", "box_filter", "output_grid", "iter_sub_coverage", "check_aa", "paste",
           "output_layers"]
