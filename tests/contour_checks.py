"""Shared test helpers for contour formats: sample sections and raster comparisons."""
from __future__ import annotations

import numpy as np
import shapely
from shapely import MultiPolygon, Polygon, box

from slicer.tracer.grid import SliceGrid

#: the sample job: x in [-1, 11], y in [-1, 7], 5 layers of 0.2 mm from z = 0
GRID = SliceGrid(origin=(-0.95, 6.95, 0.1), pixel_size=(0.1, 0.1), layer_height=0.2,
                 width=120, height=80, layers=5)


def sample_layers() -> list:
    """Sections covering the cases a writer can get wrong.

    Layer 0: a square frame (outer + hole) holding an island that has its own
    hole, plus a disc (many vertices); layer 1: empty; layer 2: one triangle
    given clockwise; layer 3: two separate regions; layer 4: None.
    """
    frame = Polygon(box(0, 0, 6, 6).exterior.coords, [box(1, 1, 5, 5).exterior.coords])
    island = Polygon(box(2, 2, 4, 4).exterior.coords, [box(2.5, 2.5, 3.5, 3.5).exterior.coords])
    disc = shapely.Point(8.5, 3.0).buffer(1.5, quad_segs=16)
    tri_cw = Polygon([(0.5, 0.5), (3.0, 5.5), (5.5, 0.5)])
    assert not tri_cw.exterior.is_ccw
    return [MultiPolygon([frame, island, disc]), MultiPolygon(), tri_cw,
            MultiPolygon([box(0, 0, 2, 2), Polygon(disc.exterior.coords, [shapely.Point(8.5, 3.0).buffer(0.5).exterior.coords])]),
            None]


def write_all(writer_cls, path, layers=None, grid=GRID, **kw):
    """Write ``layers`` (default :func:`sample_layers`) with ``writer_cls``; returns the writer."""
    layers = sample_layers() if layers is None else layers
    w = writer_cls(path, grid, {"generator": "skelslice test", "scene": "sample.json"}, **kw)
    with w:
        for k, mp in enumerate(layers):
            w.write_layer(k, grid.origin[2] + k * grid.layer_height, mp)
    return w


def as_multipolygon(geom) -> MultiPolygon:
    """``geom`` (None, Polygon, MultiPolygon or a collection) as a MultiPolygon."""
    if geom is None or geom.is_empty:
        return MultiPolygon()
    if isinstance(geom, Polygon):
        return MultiPolygon([geom])
    if isinstance(geom, MultiPolygon):
        return geom
    return MultiPolygon([g for g in geom.geoms if isinstance(g, Polygon)])


def evenodd(rings) -> MultiPolygon:
    """The region of closed rings combined by nesting (each ring toggles inside/outside)."""
    shape = Polygon()
    for p in sorted((Polygon(r) for r in rings if len(r) >= 3), key=lambda p: -p.area):
        shape = shapely.symmetric_difference(shape, p)
    return as_multipolygon(shape)


def pixel_centres(grid: SliceGrid = GRID, sub: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) arrays of x, y at the pixel centres of ``grid`` (``sub`` x finer)."""
    px, py = grid.pixel_size
    x0 = grid.origin[0] - 0.5 * px
    y1 = grid.origin[1] + 0.5 * py
    xs = x0 + (np.arange(grid.width * sub) + 0.5) * px / sub
    ys = y1 - (np.arange(grid.height * sub) + 0.5) * py / sub
    return np.meshgrid(xs, ys)


def assert_same_fill(got, want, grid: SliceGrid = GRID, eps: float = 1e-4, sub: int = 2) -> None:
    """Both regions contain the same pixel centres, except centres within ``eps`` of an edge.

    Also checks the areas agree to ``eps`` x the boundary length.
    """
    got, want = as_multipolygon(got), as_multipolygon(want)
    X, Y = pixel_centres(grid, sub)
    a = shapely.contains_xy(got, X, Y)
    b = shapely.contains_xy(want, X, Y)
    near = np.zeros(X.shape, bool)
    for g in (got, want):
        if not g.is_empty:
            near |= shapely.dwithin(g.boundary, shapely.points(X, Y), eps)
    bad = (a != b) & ~near
    assert not bad.any(), f"{bad.sum()} pixel centres differ, e.g. at {X[bad][:3]}, {Y[bad][:3]}"
    assert abs(got.area - want.area) <= eps * max(want.length, 1.0), (got.area, want.area)
