"""Islands: regions of a layer that start in mid-air.

On a resin printer every layer is cured against the one before it, so a
connected region of layer k is held only if it overlaps the solid of layer
k - 1. Definitions used here:

* a *region* is an 8-connected set of solid pixels of one layer (pixels that
  touch at a corner cure together, as UVtools and the NanoDLP statistics
  count islands);
* a region is *held* when one of its pixels is solid in the layer below at
  the same pixel (face overlap between consecutive layers; a diagonal step
  between layers does not hold it);
* the lowest layer with a solid pixel sits on the build plate: its regions
  are held.

A region that is not held is an *island*: reported once, at the layer where
it starts, with its centroid and area. The layers above it are cured onto
it, so a part that hangs in mid-air shows as one island at its lowest layer
(a branch hanging down to a free end shows at the free end's bottom).

Memory is one label image and the previous layer's solid mask.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer._kernels.raster.labels import held_regions, label_layer, region_stats
from slicer.tracer.grid import SliceGrid
from slicer.printability.stream import rounded


@dataclass(frozen=True)
class Island:
    """A region of one layer held by nothing below.

    Attributes
    ----------
    layer : int
        Layer index in the stack (0 = its bottom layer).
    z : float, mm
        Height of the layer's centres.
    x, y : float, mm
        Centroid of the region's pixel centres.
    area : float, mm²
    pixels : int
    bbox : (4,) int
        Columns and rows ``[i0, j0, i1, j1]`` (inclusive) in the stack's window.
    """

    layer: int
    z: float
    x: float
    y: float
    area: float
    pixels: int
    bbox: tuple[int, int, int, int]

    def to_dict(self) -> dict:
        return {"layer": self.layer, "z": rounded(self.z), "x": rounded(self.x), "y": rounded(self.y),
                "area": rounded(self.area),
                "pixels": self.pixels, "bbox": list(self.bbox)}


class IslandFinder:
    """Finds islands in a stream of solid masks (call :meth:`add` per layer, bottom first).

    Parameters
    ----------
    grid : SliceGrid
        Grid of the masks.
    """

    def __init__(self, grid: SliceGrid):
        self.grid = grid
        self.islands: list[Island] = []
        self._below: np.ndarray | None = None        # solid mask of the previous layer; None: no solid yet
        self._labels = np.empty((grid.height, grid.width), np.int32)

    def add(self, k: int, solid: np.ndarray) -> None:
        """Layer ``k``'s solid mask, (height, width) bool."""
        if self._below is None:
            if solid.any():
                self._below = solid.copy()           # on the plate
            return
        n = label_layer(solid.view(np.uint8), True, self._labels)
        if n:
            lab = self._labels
            held = held_regions(lab, n, self._below)
            if not held.all():
                self._record(k, region_stats(lab, n), held)
        self._below = solid.copy()

    def _record(self, k: int, st: np.ndarray, held: np.ndarray) -> None:
        g = self.grid
        px, py = g.pixel_size
        z = g.origin[2] + k * g.layer_height
        for r in np.nonzero(~held)[0]:
            n, si, sj, i0, j0, i1, j1 = (int(v) for v in st[r])
            self.islands.append(Island(int(k), float(z), float(g.origin[0] + si / n * px),
                                       float(g.origin[1] - sj / n * py), float(n * px * py), n, (i0, j0, i1, j1)))

__all__ = ["Island", "IslandFinder"]
