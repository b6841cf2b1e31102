"""Pillars merged into trees: neighbouring heads share one pillar.

Heads whose way down to the base is free are gathered greedily, in the order
of their points: each unassigned head takes the unassigned heads within the
tree distance (nearest first, at most :data:`TREE_SIZE` in all). The group's
pillar stands at the pixel centre nearest the heads' centroid; each head's
lower end joins it by a branch that falls at least as steeply as 45 degrees
(so every layer of a branch rests on the one below), at the highest junction
that allows it. A group whose branches or pillar would meet the model, or
whose junction would sit less than two pillar radii above the base, keeps a
pillar per head.

Tall pillars (more than :data:`BRACE_HEIGHT` above the base) are braced to
their nearest tall neighbour within :data:`BRACE_SPAN` by X braces of
45-degree struts of half the pillar radius (:func:`braces`).
"""
from __future__ import annotations

import numpy as np

from slicer.supports.points import march

#: the largest number of heads on one pillar
TREE_SIZE = 4
#: points per mm along a branch tested against the model's field
BRANCH_SAMPLES = 50


def tree_groups(xy: np.ndarray, free: np.ndarray, distance: float) -> list[list[int]]:
    """Indices of the free heads grouped for shared pillars (groups of one included).

    Parameters
    ----------
    xy : (q, 2) float64, mm
        The heads' positions.
    free : (q,) bool
        Heads whose way down is free (others are never grouped).
    distance : float, mm
        Largest distance from a group's first head to another of its heads (0: no groups).

    Returns
    -------
    list of list of int
        Every free head in exactly one group, groups in the order of their first head.
    """
    left = set(np.nonzero(free)[0].tolist())
    out = []
    for i in np.nonzero(free)[0]:
        if i not in left:
            continue
        left.discard(i)
        d = np.hypot(xy[:, 0] - xy[i, 0], xy[:, 1] - xy[i, 1])
        near = [int(j) for j in np.argsort(d, kind="stable") if j in left and d[j] <= distance]
        group = [int(i)] + near[:TREE_SIZE - 1]
        left.difference_update(group)
        out.append(group)
    return out


def junction(field, xy: np.ndarray, hz: np.ndarray, centre: np.ndarray, base: float, clearance: float,
             step: float) -> float | None:
    """The height where the heads ``xy`` (lower ends at ``hz``) can join a pillar at ``centre``,
    or None when the branches or the pillar would meet the model (``field >= 1``) or the
    junction would sit less than ``clearance`` above ``base``."""
    d = np.hypot(xy[:, 0] - centre[0], xy[:, 1] - centre[1])
    zj = float(np.min(hz - d))
    if zj < base + clearance:
        return None
    for q in range(len(xy)):
        n = max(2, int(np.hypot(d[q], hz[q] - zj) * BRANCH_SAMPLES))
        t = np.linspace(0.0, 1.0, n)
        pts = np.column_stack([xy[q, 0] + t * (centre[0] - xy[q, 0]), xy[q, 1] + t * (centre[1] - xy[q, 1]),
                               hz[q] + t * (zj - hz[q])])
        if np.any(field(pts) >= 1.0):
            return None
    hit = march(field, centre[None, :], np.array([zj]), -step, np.array([base]), True)
    return None if not np.isnan(hit[0]) else zj




#: pillars taller than this (mm above the base) are braced
BRACE_HEIGHT = 10.0
#: braces join pillars at most this far apart (mm)
BRACE_SPAN = 8.0


def brace_pairs(pillars: list) -> list[tuple[int, int]]:
    """Pairs of pillars to brace: each tall pillar with its nearest tall neighbour within
    :data:`BRACE_SPAN` (each pair once, in the order found).

    Parameters
    ----------
    pillars : list of (x, y, bottom, top)
    """
    p = np.array(pillars, dtype=np.float64).reshape(-1, 4)
    tall = np.nonzero(p[:, 3] - p[:, 2] > BRACE_HEIGHT)[0]
    pairs = []
    for i in tall:
        d = np.hypot(p[tall, 0] - p[i, 0], p[tall, 1] - p[i, 1])
        d[tall == i] = np.inf
        if not len(d) or d.min() > BRACE_SPAN:
            continue
        j = int(tall[int(np.argmin(d))])
        pair = (min(int(i), j), max(int(i), j))
        if pair not in pairs:
            pairs.append(pair)
    return pairs


def braces(field, a, b, radius: float) -> list[tuple[tuple, tuple]]:
    """X braces between two pillars ``a`` and ``b`` ((x, y, bottom, top) each): pairs of
    45-degree struts crossing between them, one above the other from two radii above the
    base to the lower top, each kept only if its axis stays out of the model (``field < 1``).

    Returns
    -------
    list of (lower end, upper end)
        Points (x, y, z), mm.
    """
    d = float(np.hypot(b[0] - a[0], b[1] - a[1]))
    out = []
    if d <= 0:
        return out
    z = max(a[2], b[2]) + 2 * radius
    top = min(a[3], b[3]) - radius
    t = np.linspace(0.0, 1.0, max(2, int(d * np.sqrt(2) * BRANCH_SAMPLES)))
    while z + d <= top:
        for p, q in ((a, b), (b, a)):
            lo, hi = (p[0], p[1], z), (q[0], q[1], z + d)
            pts = np.column_stack([lo[0] + t * (hi[0] - lo[0]), lo[1] + t * (hi[1] - lo[1]), z + t * d])
            if not np.any(field(pts) >= 1.0):
                out.append((lo, hi))
        z += d
    return out


__all__ = ["TREE_SIZE", "BRACE_HEIGHT", "BRACE_SPAN", "tree_groups", "junction", "brace_pairs", "braces"]
