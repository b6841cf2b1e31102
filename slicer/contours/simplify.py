"""Chord refinement of contour rings: chords that stray from the surface are
split, their new vertices put on the surface, rings kept simple."""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from slicer._kernels.contours.refine import refine_chords
from slicer.model.skeleton import Skeleton
from slicer.contours.rings import as_linearrings
from slicer.contours.roots import FIELD_SLACK, field_tuple


#: chords are split until their midpoint is within this fraction of ``tol``
#: of the contour (first-order estimate); the largest deviation along a chord
#: can exceed the midpoint's when the curvature varies, so keep a margin
CHORD_FRACTION = 0.5


def refine_rings(skel: Skeleton, rings: list[np.ndarray], z: float, tol: float,
                 stats: dict | None = None, max_rounds: int = 8,
                 certified: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Subdivide chords that stray more than ``tol / 2`` from the surface.

    The distance of a chord's quarter points and midpoint to the contour is
    estimated in the layer plane (:func:`slicer.contours.roots.plane_distance`).
    A chord above ``tol`` is split into about ``sqrt(dist / tol)`` pieces whose
    new vertices are put on the contour
    (:func:`slicer.contours.roots.project_to_contour`, at most a quarter of the
    chord away, so rings stay simple); a point whose root cannot be bracketed
    is dropped. One compiled call does every round
    (:func:`slicer._kernels.contours.refine.refine_chords`).

    Parameters
    ----------
    skel : Skeleton
    rings : list of (n_q, 2) float64, mm
    z : float, mm
    tol : float, mm
    stats : dict, optional
        ``refined`` and ``evaluations`` are increased, and the latter's split:
        ``check_evaluations`` (chord quarter points and midpoints) and
        ``projection_evaluations`` (new vertices put on the contour).
    max_rounds : int
        Rounds of splitting (each checks the new chords' midpoints; a chord
        found within the tolerance is not checked again).
    certified : list of (n_q,) bool, optional
        Chords (vertex i to i + 1) already proven within ``tol / 2`` of the
        contour (:func:`slicer.contours.cells.guaranteed_rings`): not checked.

    Returns
    -------
    list of (n_q', 2) float64
    """
    if not rings:
        return rings
    xy = np.ascontiguousarray(np.concatenate(rings), dtype=np.float64)
    ring_of = np.repeat(np.arange(len(rings), dtype=np.int64), [r.shape[0] for r in rings])
    done = np.concatenate(certified).astype(bool) if certified is not None else np.zeros(xy.shape[0], bool)
    xy, ring_of, (added, evals, checks) = refine_chords(field_tuple(skel, z), xy, ring_of, done, float(z),
                                                        (float(tol), CHORD_FRACTION * tol), int(max_rounds),
                                                        FIELD_SLACK)
    if stats is not None:
        stats["refined"] = stats.get("refined", 0) + int(added)
        stats["evaluations"] = stats.get("evaluations", 0) + int(evals)
        stats["check_evaluations"] = stats.get("check_evaluations", 0) + int(checks)
        stats["projection_evaluations"] = stats.get("projection_evaluations", 0) + int(evals - checks)
    sizes = np.bincount(ring_of, minlength=len(rings))
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    return [xy[bounds[q]:bounds[q + 1]] for q in range(len(rings))]


#: vertices whose removal moves the contour by at most this fraction of ``tol`` are dropped
SIMPLIFY_FRACTION = 0.25


def simplify(mp, dist: float):
    """Drop vertices of a MultiPolygon that a chord can skip within ``dist`` mm
    (Douglas-Peucker, topology preserved: rings stay simple and apart); the kept
    vertices are a subset, so still on the surface. Returns ``mp`` itself if the
    result would not be a valid MultiPolygon of the same number of parts.

    Plain Douglas-Peucker runs first: at a fraction of the tolerance it almost
    never makes rings touch, and it is several times faster than the
    topology-preserving variant, which runs only when the plain result is not
    valid or lost a ring (GEOS drops a ring it collapses); where neither has
    to keep more vertices to stay valid, the two keep the same ones."""
    holes = shapely.get_num_interior_rings(list(mp.geoms))
    for keep in (False, True):
        out = _same_parts(shapely.simplify(mp, dist, preserve_topology=keep), holes)
        if out is not None:
            return shapely.MultiPolygon([orient(p, 1.0) for p in out.geoms])
    return mp


def _same_parts(out, holes):
    """``out`` as a valid MultiPolygon whose polygons have ``holes`` holes
    each (plain Douglas-Peucker drops a ring it collapses), or None."""
    if out.geom_type == "Polygon":
        out = shapely.MultiPolygon([out])
    if out.geom_type != "MultiPolygon" or len(out.geoms) != len(holes):
        return None
    if not np.array_equal(shapely.get_num_interior_rings(list(out.geoms)), holes) or not out.is_valid:
        return None
    return out


def _keep_simple(refined: list[np.ndarray], raw: list[np.ndarray], stats: dict) -> list[np.ndarray]:
    """Undo the refinement of rings that it made self-intersecting or made
    touch another ring (a thin neck, a projection across a gap). Marching
    squares rings are simple and disjoint, so the result is too; the undone
    rings keep their vertices on the surface but not the chord tolerance
    (counted in ``stats["unrefined_rings"]``)."""
    if not refined:
        return refined
    lr = as_linearrings(refined)
    bad = ~shapely.is_simple(lr)
    tree = shapely.STRtree(lr)
    i, j = tree.query(lr, predicate="intersects")
    cross = i != j
    bad[i[cross]] = True
    bad[j[cross]] = True
    stats["unrefined_rings"] = stats.get("unrefined_rings", 0) + int(bad.sum())
    return [raw[q] if bad[q] else refined[q] for q in range(len(refined))]


__all__ = ["refine_rings", "simplify", "CHORD_FRACTION", "SIMPLIFY_FRACTION"]
