"""Layer contours: the inside region of each layer as polygons with holes.

The package is split by stage:

* :mod:`.cells` -- the guaranteed contours of a layer plane: an adaptive
  quadtree whose cells are settled by sound per-primitive bounds of the field
  over each cell (:mod:`slicer._kernels.contours.cellbounds`), so that every part of the
  section wider than the tolerance appears, whatever the pixel size;
* :mod:`.roots` -- bracketed root solving of ``F = 1`` on segments, distances
  and projections in the layer plane;
* :mod:`.marching` -- marching squares on an exactly classified raster (the
  raster's own contours, kept for comparison and for rasters without a field);
* :mod:`.simplify` -- chord refinement that keeps rings simple;
* :mod:`.rings` -- oriented rings to valid MultiPolygons;
* :mod:`.layers` -- per-layer iteration (lattices and parts) and the
  GeoJSON/JSON writer.

Conventions: coordinates in mm, seen from above (+z); outer rings are
counter-clockwise, holes clockwise. See docs/contours.md.

Examples
--------
>>> from slicer import Skeleton
>>> from slicer.tracer.slicing import slice_skeleton
>>> s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
>>> r = slice_skeleton(s, 0.1)
>>> mp = layer_contours(s, r, r.grid.layers // 2)
>>> round(mp.area, 2), mp.is_valid           # a disc of radius 1
(3.14, True)
"""
from __future__ import annotations

from slicer.contours.cells import check_resolvable, guaranteed_rings
from slicer.contours.layers import (each_plane, finish_rings, grid_box, iter_contours, iter_part_contours, layer_contours, part_layer_contours, plane_contours,
                     write_contours)
from slicer.contours.marching import layer_mask, mask_rings
from slicer.contours.rings import rings_to_multipolygon, signed_areas
from slicer.contours.roots import plane_distance, project_to_contour, solve_crossings
from slicer.contours.simplify import refine_rings

__all__ = ["plane_contours", "finish_rings", "each_plane", "guaranteed_rings", "check_resolvable", "grid_box", "layer_contours", "iter_contours", "iter_part_contours", "part_layer_contours", "layer_mask", "mask_rings",
           "refine_rings", "rings_to_multipolygon", "signed_areas", "solve_crossings", "plane_distance",
           "project_to_contour", "write_contours"]
