"""The voxel grid of a slicing job: pixel sizes, layer height, placement."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from slicer.arguments import MAX_CELLS, RESOLUTION_RATIO, fmt_num, positive_number
from slicer.errors import GridError

#: refuse jobs larger than this many voxels before any work starts
MAX_VOXELS = MAX_CELLS


@dataclass(frozen=True)
class SliceGrid:
    """Voxel grid with centres ``(x0 + i px, y0 - j py, z0 + k h)``.

    Columns ``i`` run toward +x, rows ``j`` toward -y (row 0 is the top of an
    image seen from above), layers ``k`` toward +z.

    Parameters
    ----------
    origin : (3,) float64, mm
        Centre of voxel (0, 0, 0).
    pixel_size : (2,) float64, mm
        Pixel pitch along x and y.
    layer_height : float, mm
    width, height, layers : int
        Columns, rows and layers.
    """

    origin: tuple[float, float, float]
    pixel_size: tuple[float, float]
    layer_height: float
    width: int
    height: int
    layers: int

    @property
    def shape(self) -> tuple[int, int, int]:
        """(layers, height, width)."""
        return (self.layers, self.height, self.width)

    @property
    def n_voxels(self) -> int:
        return self.width * self.height * self.layers

    def centres_x(self) -> np.ndarray:
        """(width,) float64: x of each column's centres."""
        return self.origin[0] + np.arange(self.width) * self.pixel_size[0]

    def centres_y(self) -> np.ndarray:
        """(height,) float64: y of each row's centres."""
        return self.origin[1] - np.arange(self.height) * self.pixel_size[1]

    def centres_z(self) -> np.ndarray:
        """(layers,) float64: z of each layer's centres."""
        return self.origin[2] + np.arange(self.layers) * self.layer_height

    def sub(self, i0: int, j0: int, k0: int, width: int, height: int, layers: int) -> "SliceGrid":
        """The sub-grid starting at column i0, row j0, layer k0 (same spacing)."""
        px, py = self.pixel_size
        o = (self.origin[0] + i0 * px, self.origin[1] - j0 * py, self.origin[2] + k0 * self.layer_height)
        return replace(self, origin=o, width=width, height=height, layers=layers)

    def to_dict(self) -> dict:
        return {
            "width": self.width, "height": self.height, "layers": self.layers,
            "pixel_size": list(self.pixel_size), "layer_height": self.layer_height,
            "origin": list(self.origin),
        }


def _positive(name: str, value) -> float:
    return positive_number(value, name, GridError)


#: coordinates may be at most this many times the smallest grid step
#: (:data:`slicer.arguments.RESOLUTION_RATIO`, docs/scene-format.md "Limits")
MAX_RESOLUTION_RATIO = RESOLUTION_RATIO


def _check_resolution(lo, hi, steps, what: str) -> None:
    """Refuse boxes whose coordinates or extent float64 cannot resolve at the grid steps."""
    step = min(steps)
    reach = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
    extent = float(np.max(np.asarray(hi) - np.asarray(lo)))
    if not (math.isfinite(reach) and math.isfinite(extent)) or max(reach, extent) > MAX_RESOLUTION_RATIO * step:
        raise GridError(
            f"{what} reaches {fmt_num(reach)} mm from the origin and spans {fmt_num(extent)} mm, more than "
            f"{MAX_RESOLUTION_RATIO:.0e} grid steps of {fmt_num(step)} mm: float64 cannot place the voxel "
            f"centres exactly; move the model near the origin or use a larger pixel size or layer height")


def make_grid(support_box: np.ndarray, pixel_size: float, pixel_size_y: float | None = None,
              layer_height: float | None = None, bounds=None) -> SliceGrid:
    """Build the grid of a job.

    Parameters
    ----------
    support_box : (2, 3) float64, mm
        Box that contains the whole surface (:meth:`Skeleton.support_bounds`).
    pixel_size : float, mm
        Pixel pitch along x (and y unless ``pixel_size_y``).
    pixel_size_y : float, optional, mm
    layer_height : float, optional, mm
        Defaults to ``pixel_size``.
    bounds : (6,) float, optional, mm
        ``X0 Y0 Z0 X1 Y1 Z1``: the voxels cover exactly this box (voxel
        centres at half a pixel inside its faces). Default: the support box
        plus one voxel of margin, on a lattice aligned to multiples of the
        pixel size and layer height.

    Raises
    ------
    GridError
        Non-positive or non-finite sizes, an empty box, more than
        ``MAX_VOXELS`` voxels, or coordinates beyond ``MAX_RESOLUTION_RATIO``
        grid steps.
    """
    px = _positive("pixel size", pixel_size)
    py = _positive("pixel size y", pixel_size_y) if pixel_size_y is not None else px
    h = _positive("layer height", layer_height) if layer_height is not None else px
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64).reshape(-1)
        if b.shape != (6,) or not np.all(np.isfinite(b)):
            raise GridError(f"bounds must be 6 finite numbers X0 Y0 Z0 X1 Y1 Z1, got {list(bounds)}")
        lo, hi = b[:3], b[3:]
        if np.any(hi <= lo):
            raise GridError(f"bounds must have X1 > X0, Y1 > Y0, Z1 > Z0, got {b.tolist()}")
        _check_resolution(lo, hi, (px, py, h), "the --bounds box")
        counts = [math.ceil((hi[a] - lo[a]) / d - 1e-9) for a, d in enumerate((px, py, h))]
        origin = (lo[0] + 0.5 * px, hi[1] - 0.5 * py, lo[2] + 0.5 * h)
    else:
        lo, hi = support_box
        _check_resolution(lo, hi, (px, py, h), "the model")
        i0, i1 = math.floor(lo[0] / px) - 1, math.ceil(hi[0] / px) + 1
        j0, j1 = math.floor(lo[1] / py) - 1, math.ceil(hi[1] / py) + 1
        k0, k1 = math.floor(lo[2] / h) - 1, math.ceil(hi[2] / h) + 1
        counts = [i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1]
        origin = (i0 * px, j1 * py, k0 * h)
    w, hh, k = (int(c) for c in counts)
    n = float(w) * float(hh) * float(k)
    if n > MAX_VOXELS:
        raise GridError(
            f"the grid would have {fmt_num(w)} x {fmt_num(hh)} x {fmt_num(k)} = {n:.3g} voxels "
            f"(limit {MAX_VOXELS:.0e}); use a larger pixel size or layer height")
    return SliceGrid(tuple(float(v) for v in origin), (px, py), h, w, hh, k)


__all__ = ["SliceGrid", "make_grid", "MAX_VOXELS", "MAX_RESOLUTION_RATIO"]
