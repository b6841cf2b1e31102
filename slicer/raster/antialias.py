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

Exact area
----------
``--aa exact`` traces at the output pitch and makes each pixel's coverage
the exact area of the layer's section inside the pixel square, divided by
the pixel's area: the guaranteed contours of the layer
(:func:`slicer.contours.iter_contours`, every feature wider than
``--contour-tol``, vertices on the surface to it) are accumulated edge by
edge into the pixels they cross (:mod:`slicer._kernels.raster.coverage`, exact up
to float64 rounding for the polygons). The only error is the contours' own:
at most ``tol`` times the boundary length inside the pixel, over its area.
With ``--aa-z`` the coverage is the mean of the exact areas on
``Z_PLANES`` planes at the midpoints of equal sub-layers of the voxel
(the midpoint rule in z): where the area varies with Lipschitz constant
``L`` (fraction per mm) over the voxel the error is at most ``L h / (4 S)``
(``S = Z_PLANES``); where a horizontal face of the solid lies inside the
voxel the area jumps and the error can reach ``1 / (2 S)`` of the pixel.

Without anti-aliasing the layers stay exactly 0/255.
"""
from __future__ import annotations

import itertools
import sys
from typing import Iterator

import numpy as np

from formats.printer_profiles import place

from slicer._kernels.raster.coverage import ring_coverage
from slicer.arguments import integer, positive_number
from slicer.contours import check_resolvable, each_plane, grid_box, iter_contours
from slicer.errors import GridError, OptionError, OutputError
from slicer.tracer.grid import SliceGrid
from slicer.parts.slicing import PartResult, PartStreamedResult

#: sub-layer planes per voxel of ``--aa exact --aa-z`` (midpoint rule in z)
Z_PLANES = 4

#: the ``--aa`` value of exact-area anti-aliasing
EXACT = "exact"


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
    """Validate ``--aa`` (integer 1..16, or ``exact``: traced at the output
    pitch, 1) and ``--gamma`` (> 0)."""
    if is_exact(aa):
        return 1, positive_number(gamma, "--gamma")
    if isinstance(aa, str):
        try:
            aa = int(aa.strip())
        except ValueError:
            raise OptionError(f"--aa must be an integer from 1 to 16 or 'exact', got {aa!r}") from None
    return integer(aa, "--aa", lo=1, hi=16), positive_number(gamma, "--gamma")


def is_exact(aa) -> bool:
    """Whether an ``--aa`` value asks for exact-area coverage."""
    return isinstance(aa, str) and aa.strip().lower() == EXACT


def polygon_coverage(polys, grid: SliceGrid) -> np.ndarray:
    """Exact covered fraction of each pixel of ``grid`` by polygons of the layer plane.

    Parameters
    ----------
    polys : shapely.MultiPolygon, mm
        Valid; outer rings and holes of opposite orientations.
    grid : SliceGrid

    Returns
    -------
    (grid.height, grid.width) float64 in [0, 1]
    """
    H, W = grid.height, grid.width
    rings = [np.asarray(r.coords)[:-1, :2] for p in polys.geoms for r in (p.exterior, *p.interiors)]
    rings = [r for r in rings if r.shape[0] >= 3]
    if not rings:
        return np.zeros((H, W))
    (x0, y0), (px, py) = grid.origin[:2], grid.pixel_size
    xy = np.concatenate(rings)
    u = (xy[:, 0] - (x0 - 0.5 * px)) / px
    v = ((y0 + 0.5 * py) - xy[:, 1]) / py
    starts = np.concatenate([[0], np.cumsum([r.shape[0] for r in rings])]).astype(np.int64)
    return np.clip(np.abs(ring_coverage(u, v, starts, W, H)), 0.0, 1.0)


def iter_exact_coverage(skel, result, aa_z: bool, tol: float) -> Iterator[np.ndarray]:
    """Per layer of ``result``, the exact-area coverage of each pixel
    (module docstring), (H, W) float64.

    Raises
    ------
    OptionError
        ``aa_z`` on a part (a lattice with meshes): its contours exist on the
        layer planes only.
    """
    g = result.grid
    if not aa_z:
        for _, _, polys in iter_contours(skel, result, tol):
            yield polygon_coverage(polys, g)
        return
    if isinstance(result, (PartResult, PartStreamedResult)):
        raise OptionError("--aa exact with --aa-z is not available for lattices with meshes: use --aa N --aa-z")
    tol = check_resolvable(skel, tol)
    h = g.layer_height
    zs = [g.origin[2] + k * h - 0.5 * h + (q + 0.5) * h / Z_PLANES for k in range(g.layers) for q in range(Z_PLANES)]
    planes = each_plane(skel, zs, tol, grid_box(g))
    for _ in range(g.layers):
        cov = np.zeros((g.height, g.width))
        for _, polys in itertools.islice(planes, Z_PLANES):
            cov += polygon_coverage(polys, g)
        yield cov / Z_PLANES


def paste(canvas: np.ndarray, win: np.ndarray, top: int, left: int) -> tuple[int, int, int, int] | None:
    """Copy ``win`` into ``canvas`` at (top, left), clipped to the canvas; returns
    the rows and columns ``(r0, r1, c0, c1)`` written (half-open), None if none."""
    H, W = canvas.shape
    h, w = win.shape
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + h, H), min(left + w, W)
    if r1 > r0 and c1 > c0:
        canvas[r0:r1, c0:c1] = win[r0 - top:r1 - top, c0 - left:c1 - left]
        return r0, r1, c0, c1
    return None


class PlateImage(np.ndarray):
    """A printer plate's layer image that knows where it may be non-zero.

    ``window``: ``(r0, r1, c0, c1)`` (half-open rows and columns) outside
    which every pixel is zero, or None (unknown). Writers that look for the
    model's box (:func:`formats.rle.occupied`) then scan the window only, not
    the whole plate (59 Mpx on a large printer). Views, copies and results of
    operations are plain: their ``window`` is None.
    """

    window: tuple[int, int, int, int] | None = None

    def __array_finalize__(self, obj) -> None:
        self.window = None

    @classmethod
    def blank(cls, shape: tuple[int, int]) -> "PlateImage":
        """An all-zero plate image whose window is empty."""
        out = np.zeros(shape, np.uint8).view(cls)
        out.window = (0, 0, 0, 0)
        return out

    def clear(self) -> None:
        """Zero the window and empty it (only the window can be non-zero)."""
        r0, r1, c0, c1 = self.window if self.window is not None else (0, self.shape[0], 0, self.shape[1])
        np.asarray(self)[r0:r1, c0:c1] = 0
        self.window = (0, 0, 0, 0)


class PlatePool:
    """Plate images reused once nobody else holds them.

    A fresh plate (59 Mpx on a large printer) costs a page fault per page the
    layer is pasted into, every layer. A plate whose only reference is the
    pool's (no writer, encoder thread or view still holds it) is cleared --
    its window only -- and handed out again; otherwise a new one is made (at
    most ``size`` are kept).
    """

    def __init__(self, shape: tuple[int, int], size: int = 16):
        self.shape = shape
        self.size = size
        self._plates: list[PlateImage] = []

    def take(self) -> PlateImage:
        for plate in self._plates:
            # references: the pool's list, the loop variable and getrefcount's argument
            if sys.getrefcount(plate) <= 3:
                plate.clear()
                return plate
        plate = PlateImage.blank(self.shape)
        if len(self._plates) < self.size:
            self._plates.append(plate)
        return plate


def _coverage(result, settings, skel, tol) -> Iterator[np.ndarray]:
    if getattr(settings, "aa_exact", False):
        if skel is None:
            raise OutputError("--aa exact needs the skeleton (its contours give the exact areas)")
        tol = check_resolvable(skel, tol)
        yield from iter_exact_coverage(skel, result, settings.aa_z, tol)
    else:
        yield from iter_sub_coverage(result, settings.aa_z)


def output_layers(result, settings, skel=None, tol: float = 1e-3) -> tuple[SliceGrid, Iterator[np.ndarray]]:
    """The output grid and the layer images of a traced result.

    Parameters
    ----------
    result : SliceResult
        Traced at the output pitch / ``settings.aa``.
    settings : formats.printer_profiles.PrintSettings
        Printer (None: the traced grid itself), anti-aliasing, gamma, ``at``.
    skel : Skeleton, optional
        Needed by ``--aa exact`` (``settings.aa_exact``).
    tol : float, mm
        Contour tolerance of ``--aa exact``.

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
                  for c in _coverage(result, settings, skel, tol))
        return output_grid(result.grid, n), layers
    pl = place(result, settings.printer, n, settings.at)
    return pl.grid, _plate_layers(result, pl, settings, skel, tol)


def _plate_layers(result, pl, settings, skel=None, tol: float = 1e-3) -> Iterator[np.ndarray]:
    plates = PlatePool(pl.printer.plate_shape)
    src = _coverage(result, settings, skel, tol) if settings.antialiased else result.iter_layers()
    for k, img in enumerate(src):
        if k < pl.k_first:
            continue
        if k >= pl.k_first + pl.layers:
            break
        canvas = plates.take()
        if settings.antialiased:
            cov, (top, left) = box_filter(img, pl.aa, (pl.dj, pl.di))
            window = paste(canvas, grey_from_coverage(cov, settings.gamma), top, left)
        else:
            window = paste(canvas, img, pl.dj, pl.di)
        canvas.window = window or (0, 0, 0, 0)
        yield canvas


__all__ = ["polygon_coverage", "iter_exact_coverage", "is_exact", "Z_PLANES", "grey_from_coverage", "box_filter", "output_grid", "iter_sub_coverage", "check_aa", "paste",
           "PlateImage", "output_layers"]
