"""Chord refinement of contour rings: chords that stray from the surface are
split, their new vertices put on the surface, rings kept simple."""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from ..skeleton import Skeleton
from .roots import plane_distance, project_to_contour


#: chords are split until their midpoint is within this fraction of ``tol``
#: of the contour (first-order estimate); the largest deviation along a chord
#: can exceed the midpoint's when the curvature varies, so keep a margin
CHORD_FRACTION = 0.5


def refine_rings(skel: Skeleton, rings: list[np.ndarray], z: float, tol: float,
                 stats: dict | None = None, max_rounds: int = 8,
                 certified: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """Subdivide chords that stray more than ``tol / 2`` from the surface.

    The distance of a chord's quarter points and midpoint to the contour is
    estimated in the layer plane (:func:`plane_distance`). A chord above ``tol`` is split
    into about ``sqrt(dist / tol)`` pieces whose new vertices are put on the
    contour (:func:`project_to_contour`, at most a quarter of the chord away,
    so rings stay simple); a point whose root cannot be bracketed is dropped.

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
    sizes = np.array([r.shape[0] for r in rings])
    xy = np.concatenate(rings)
    ring_of = np.repeat(np.arange(len(rings)), sizes)
    done = np.concatenate(certified) if certified is not None else np.zeros(xy.shape[0], bool)
    added = 0
    evals = 0
    checks = 0
    for _ in range(max_rounds):
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        nxt = np.arange(xy.shape[0]) + 1
        nxt[starts + sizes - 1] = starts
        p, q = xy, xy[nxt]
        chord = np.hypot(*(q - p).T)
        todo = np.flatnonzero(~done & (chord > 2 * tol))
        if todo.size == 0:
            break
        # quarter points too: on a chord across varying curvature the largest
        # deviation need not be at the midpoint
        fr = np.array([0.25, 0.5, 0.75])[None, :, None]
        pt, qt = p[todo], q[todo]
        m3 = (pt[:, None, :] + fr * (qt - pt)[:, None, :]).reshape(-1, 2)
        dist = np.full(xy.shape[0], 0.0)
        dist[todo] = plane_distance(skel, m3, z)[0].reshape(-1, 3).max(axis=1)
        evals += m3.shape[0]
        checks += m3.shape[0]
        bad = todo[~(dist[todo] <= CHORD_FRACTION * tol)]
        done[todo] = True                    # checked: fine, or split below
        done[bad] = False
        if bad.size == 0:
            break
        # a chord's sagitta shrinks as its length squared: split it into
        # about sqrt(dist / tol) pieces at once (fewer rounds, fewer launches)
        with np.errstate(invalid="ignore"):
            goal = CHORD_FRACTION * tol
            nsub = np.clip(np.ceil(1.2 * np.sqrt(np.where(np.isfinite(dist[bad]), dist[bad], 4 * goal) / goal)),
                           2, 64).astype(np.int64)
        owner = np.repeat(bad, nsub - 1)
        j = np.arange(owner.size) - np.repeat(np.cumsum(nsub - 1) - (nsub - 1), nsub - 1) + 1
        frac = j / np.repeat(nsub, nsub - 1)
        cand = p[owner] + frac[:, None] * (q[owner] - p[owner])
        roots, ok, _, ne = project_to_contour(skel, cand, z, tol, reach=0.25 * chord[owner])
        evals += ne
        if not ok.any():
            break
        ins = owner[ok]
        # insert the new vertices after vertex ``ins``, in order along the chord
        pos = np.concatenate([np.arange(xy.shape[0]), ins])
        sub = np.concatenate([np.zeros(xy.shape[0], np.int64), j[ok]])
        order = np.lexsort((sub, pos))
        xy = np.concatenate([xy, roots[ok]])[order]
        ring_of = np.concatenate([ring_of, ring_of[ins]])[order]
        done = np.concatenate([done, np.zeros(ins.size, bool)])[order]
        sizes = np.bincount(ring_of, minlength=len(rings))
        added += ins.size
    if stats is not None:
        stats["refined"] = stats.get("refined", 0) + added
        stats["evaluations"] = stats.get("evaluations", 0) + evals
        stats["check_evaluations"] = stats.get("check_evaluations", 0) + checks
        stats["projection_evaluations"] = stats.get("projection_evaluations", 0) + evals - checks
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
    lr = np.array([shapely.LinearRing(r) for r in refined], dtype=object)
    bad = ~shapely.is_simple(lr)
    tree = shapely.STRtree(lr)
    i, j = tree.query(lr, predicate="intersects")
    cross = i != j
    bad[i[cross]] = True
    bad[j[cross]] = True
    stats["unrefined_rings"] = stats.get("unrefined_rings", 0) + int(bad.sum())
    return [raw[q] if bad[q] else refined[q] for q in range(len(refined))]


__all__ = ["refine_rings", "simplify", "CHORD_FRACTION", "SIMPLIFY_FRACTION"]
