"""Ring assembly: oriented rings to valid MultiPolygons."""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from slicer._kernels.contours.chain import ring_areas


def signed_areas(rings: list[np.ndarray]) -> np.ndarray:
    """Shoelace area of each ring, mm^2 (positive: counter-clockwise)."""
    if not rings:
        return np.zeros(0)
    starts = np.concatenate([[0], np.cumsum([r.shape[0] for r in rings])]).astype(np.int64)
    return ring_areas(np.ascontiguousarray(np.concatenate(rings), dtype=np.float64), starts)


def rings_to_multipolygon(rings: list[np.ndarray]):
    """Assemble disjoint simple rings into a MultiPolygon.

    Counter-clockwise rings are outer boundaries, clockwise rings holes; each
    hole goes to the smallest outer ring that contains it. Orientation is kept
    as given.

    Parameters
    ----------
    rings : list of (n_q, 2) float64, mm

    Returns
    -------
    shapely.MultiPolygon
    """
    rings = [r for r in rings if r.shape[0] >= 3]
    if not rings:
        return shapely.MultiPolygon()
    area = signed_areas(rings)
    outer = np.flatnonzero(area > 0)
    holes = np.flatnonzero(area < 0)
    if outer.size == 0:                    # holes alone (or flat rings): nothing to fill
        return shapely.MultiPolygon()
    lrs = as_linearrings(rings)
    owned: list[list[int]] = [[] for _ in outer]
    if holes.size and outer.size:
        tree = shapely.STRtree(shapely.polygons(lrs[outer]))
        probe = shapely.points(np.array([rings[q][0] for q in holes]))
        hi, oi = tree.query(probe, predicate="within")
        best = np.full(holes.size, -1)
        for h, o in zip(hi, oi):
            if best[h] < 0 or area[outer[o]] < area[outer[best[h]]]:
                best[h] = o
        for h, o in enumerate(best):
            if o >= 0:
                owned[o].append(holes[h])
    # each polygon's shell, then its holes, in one call
    parts = [[q, *owned[s]] for s, q in enumerate(outer)]
    which = np.repeat(np.arange(len(parts)), [len(p) for p in parts])
    polys = shapely.polygons(lrs[np.concatenate(parts)], indices=which)
    return shapely.MultiPolygon(list(polys))


def as_linearrings(rings: list[np.ndarray]) -> np.ndarray:
    """Rings of three or more vertices as shapely LinearRings (closed), in one call, (r,) object."""
    sizes = [r.shape[0] for r in rings]
    return shapely.linearrings(np.concatenate(rings), indices=np.repeat(np.arange(len(rings)), sizes))



def _polygons_only(geom):
    """The polygons of a shapely geometry as an oriented MultiPolygon (outer rings
    counter-clockwise, holes clockwise)."""
    polys = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and not g.is_empty]
    polys += [p for g in shapely.get_parts(geom) if g.geom_type == "MultiPolygon" for p in g.geoms]
    return shapely.MultiPolygon([orient(p, 1.0) for p in polys])


__all__ = ["signed_areas", "rings_to_multipolygon", "as_linearrings"]
