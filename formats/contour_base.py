"""Contour writer protocol, polygon normalisation and atomic single-file output.

A contour writer receives, layer by layer, the cross-section of the solid as
a :class:`shapely.MultiPolygon` (mm, scene coordinates) and streams it to one
output file. Like :class:`formats.base.StackWriter` it never holds the whole
stack, and publishes its output atomically: everything goes to a hidden
temporary file beside the target (``.NAME.tmp-XXXX``), which replaces the
target with :func:`os.replace` only when the last layer is written. An
interrupted run leaves at most that temporary file, never a half-written
output at the target.

Layer heights
-------------
Layer ``k`` is the section of the solid at the voxel-centre height
``z_k = grid.origin[2] + k * grid.layer_height`` (the mid-plane of the layer,
as the PNG stack classifies it). The layer occupies
``[z_k - h/2, z_k + h/2]``; formats that store the layer's *upper* surface
(CLI ``$$LAYER``, 3MF ``ztop``) write ``z_k + h/2``.

Orientation
-----------
Every writer re-orients its input: outer rings counter-clockwise seen from
+z (looking down), holes clockwise (:func:`oriented_polygons`), whatever the
caller passed.
"""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from slicer.atomic import AtomicFile
from slicer.errors import OutputError

from formats.base import StackWriter


class ContourWriter(StackWriter):
    """Streams per-layer polygons to one output file, published atomically.

    Parameters
    ----------
    path : path-like
        Final output file.
    grid : slicer.tracer.grid.SliceGrid
        Grid of the layers: layer count, layer height, the box of the job.
    meta : dict, optional
        Provenance (generator, method, scene), written where the format allows.
    force : bool
        Replace an existing output.
    settings : formats.printer_profiles.PrintSettings, optional
        Accepted as for every writer; contours are in scene mm, or in plate
        mm when a printer job places them (``grid`` is then the plate's, see
        :func:`slicer.contours.iter_contours`).

    Notes
    -----
    Call :meth:`write_layer` with increasing ``k``; layers that are skipped
    (and all layers after the last one written, at :meth:`close`) are written
    empty, so the output always has ``grid.layers`` layers. Subclasses
    implement ``_begin``, ``_layer`` and ``_end`` writing bytes to
    ``self.fh``.
    """

    #: writers of this kind take polygons, not images (see slicer.job.run)
    kind = "contours"
    #: format name in the registry
    name = ""

    def __init__(self, path, grid, meta: dict | None = None, force: bool = False, settings=None):
        super().__init__(path, grid, meta, force, settings)
        self._out = AtomicFile(self.path)
        self.fh = self._out.fh
        self._next = 0
        self._began = False

    # ------------------------------------------------------------------ geometry of the job
    @property
    def layer_height(self) -> float:
        return float(self.grid.layer_height)

    def z_section(self, k: int) -> float:
        """Height (mm) at which layer ``k`` is cut: the voxel centres' z."""
        return float(self.grid.origin[2] + k * self.grid.layer_height)

    def z_top(self, k: int) -> float:
        """Upper surface (mm) of layer ``k``."""
        return float(self.grid.origin[2] + (k + 0.5) * self.grid.layer_height)

    def box(self) -> tuple[float, float, float, float, float, float]:
        """The job's box ``(x0, y0, z0, x1, y1, z1)``, mm: voxel faces, not centres."""
        g = self.grid
        px, py = g.pixel_size
        x0 = g.origin[0] - 0.5 * px
        y1 = g.origin[1] + 0.5 * py
        z0 = g.origin[2] - 0.5 * g.layer_height
        return (float(x0), float(y1 - g.height * py), float(z0),
                float(x0 + g.width * px), float(y1), float(z0 + g.layers * g.layer_height))

    # ------------------------------------------------------------------ protocol
    def write_layer(self, k: int, z: float, polygons) -> None:
        """Write layer ``k``, cut at height ``z`` (mm).

        Parameters
        ----------
        k : int
            Layer index, ``0 <= k < grid.layers``, larger than the last one written.
        z : float, mm
            Section height; must be :meth:`z_section` ``(k)`` (checked to 1e-6
            of the layer height, it guards against mixing up grids).
        polygons : shapely Polygon, MultiPolygon, GeometryCollection of polygons, or None
            The section in mm, valid polygons; orientation does not matter.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise TypeError(f"layer index must be an integer, got {k!r}")
        k = int(k)
        if not self._next <= k < self.grid.layers:
            self.abort()
            raise OutputError(f"{self.path}: layer {k} is out of order or range (next is {self._next}, "
                             f"the grid has {self.grid.layers} layers)")
        if not math.isclose(float(z), self.z_section(k), rel_tol=0.0, abs_tol=1e-6 * self.layer_height):
            self.abort()
            raise OutputError(f"{self.path}: layer {k} is cut at z = {z!r} but the grid's layer {k} is at "
                             f"z = {self.z_section(k)!r}")
        polys = oriented_polygons(polygons)
        try:
            if not self._began:
                self._begin()
                self._began = True
            while self._next < k:
                self._layer(self._next, [])
                self._next += 1
            self._layer(k, polys)
        except OutputError:
            self.abort()
            raise
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot write layer {k} ({exc.strerror or exc})") from None
        except BaseException:
            self.abort()
            raise
        self._next = k + 1

    def close(self) -> None:
        """Write the remaining (empty) layers and the trailer, then publish."""
        try:
            if not self._began:
                self._begin()
                self._began = True
            while self._next < self.grid.layers:
                self._layer(self._next, [])
                self._next += 1
            self._end()
            self._out.publish(self.force)
        except OSError as exc:
            self.abort()
            if isinstance(exc, OutputError):
                raise
            raise OutputError(f"{self.path}: cannot finish the output ({exc.strerror or exc})") from None
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Remove everything written so far; the target is untouched."""
        self._out.discard()

    # ------------------------------------------------------------------ format hooks
    def _begin(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def _layer(self, k: int, polygons: list[shapely.Polygon]) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def _end(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError


def oriented_polygons(geom) -> list[shapely.Polygon]:
    """The polygons of ``geom``, outer rings CCW and holes CW (seen from +z).

    Parameters
    ----------
    geom : Polygon, MultiPolygon, GeometryCollection, iterable of polygons, or None

    Returns
    -------
    list of shapely.Polygon
        Non-empty polygons in input order.

    Raises
    ------
    TypeError
        A non-polygonal part (point, line).

    Examples
    --------
    >>> from shapely import Polygon
    >>> p, = oriented_polygons(Polygon([(0, 0), (0, 1), (1, 1), (1, 0)]))  # given clockwise
    >>> p.exterior.is_ccw
    True
    """
    if geom is None:
        return []
    if isinstance(geom, shapely.Polygon):
        parts: Iterable = [geom]
    elif isinstance(geom, (shapely.MultiPolygon, shapely.GeometryCollection)):
        parts = geom.geoms
    elif isinstance(geom, shapely.Geometry):
        raise TypeError(f"a layer's section must be polygons, got a {geom.geom_type}")
    else:
        parts = list(geom)
    out = []
    for p in parts:
        if isinstance(p, (shapely.MultiPolygon, shapely.GeometryCollection)):
            out.extend(oriented_polygons(p))
            continue
        if not isinstance(p, shapely.Polygon):
            raise TypeError(f"a layer's section must be polygons, got a {getattr(p, 'geom_type', type(p).__name__)}")
        if not p.is_empty:
            out.append(orient(p, sign=1.0))
    return out


def rings(poly: shapely.Polygon) -> list[tuple[np.ndarray, bool]]:
    """``[(coords, is_outer), ...]``: the closed rings of an oriented polygon.

    ``coords`` is ``(n + 1, 2)`` float64 mm with the first point repeated last.
    """
    out = [(shapely.get_coordinates(poly.exterior), True)]
    out.extend((shapely.get_coordinates(r), False) for r in poly.interiors)
    return out


__all__ = ["ContourWriter", "oriented_polygons", "rings"]
