"""A scene's solid as a union of summed lattices, for the mesher (docs/mesh.md, "Unions").

The mesher certifies the surface of a summed field ``F = Σ f_i`` (:mod:`slicer.meshing.surface`).
Two kinds of scene unite solids instead:

* a supported scene (:class:`~slicer.supports.groups.GroupedSkeleton`): the model's
  struts sum, and its solid unites with every support and pad strut's own solid
  (those groups blend by ``union``);
* the ``union`` blend (:mod:`slicer.model.blend`): every strut's own solid unites.

Each strut's field ``f_i`` is zero off its *support*, the points within ``σ r`` of the
segment (``r`` the larger end radius). Where the supports of a set of struts do not
overlap, at most one ``f_i`` is nonzero at any point, so their sum is their largest:
the sum's solid is the union of their solids. :func:`united_lattices` therefore splits
the struts that unite into *classes* of struts with pairwise disjoint supports (a
greedy colouring of the overlap graph, in segment order), and the scene's solid is the
union of the classes' summed solids (and the model's).
"""
from __future__ import annotations

import numpy as np

from slicer.model.blend import check_blend
from slicer.model.skeleton import Skeleton

#: rows of the pairwise overlap test at a time
_ROWS = 512


def _overlaps(a: np.ndarray, b: np.ndarray, reach: np.ndarray) -> list:
    """Per segment, the segments whose supports may overlap its own: boxes of the supports'
    capsules (segment ``a``–``b``, radius ``reach``) that meet, closed.

    Parameters
    ----------
    a, b : (m, 3) float64, mm
    reach : (m,) float64, mm

    Returns
    -------
    list of (k,) int64 arrays, one per segment (itself left out)
    """
    lo = np.minimum(a, b) - reach[:, None]
    hi = np.maximum(a, b) + reach[:, None]
    out = []
    for s in range(0, len(a), _ROWS):
        meet = ((lo[s:s + _ROWS, None, :] <= hi[None]) & (lo[None] <= hi[s:s + _ROWS, None, :])).all(axis=2)
        for i, row in enumerate(meet, start=s):
            row[i] = False
            out.append(np.flatnonzero(row))
    return out


def disjoint_classes(skel: Skeleton, which: np.ndarray) -> list:
    """The segments ``which`` split into classes whose supports do not overlap within each.

    Parameters
    ----------
    skel : Skeleton
    which : (k,) int64
        Segment indices, in the order the colouring visits them.

    Returns
    -------
    list of (k_c,) int64 arrays
        Segment indices per class, ascending, classes in the order they are first used.

    Examples
    --------
    >>> s = Skeleton([[0, 0, 0], [5, 0, 0], [10, 0, 0], [30, 0, 0], [35, 0, 0]],
    ...              [[0, 1], [1, 2], [3, 4]], [[1, 1], [1, 1], [1, 1]])
    >>> [c.tolist() for c in disjoint_classes(s, np.arange(3))]
    [[0, 2], [1]]
    """
    which = np.asarray(which, np.int64)
    a, b = skel.endpoints()
    reach = skel.sigma * skel.radii.max(axis=1)
    near = _overlaps(a[which], b[which], reach[which])
    colour = np.full(len(which), -1, np.int64)
    for i, js in enumerate(near):
        used = set(colour[js].tolist())
        c = 0
        while c in used:
            c += 1
        colour[i] = c
    return [np.sort(which[colour == c]) for c in range(int(colour.max()) + 1)] if len(which) else []


def _sub_skeleton(skel: Skeleton, segments: np.ndarray) -> Skeleton:
    return Skeleton(skel.nodes, skel.segments[segments], skel.radii[segments], skel.degree, skel.sigma,
                    source=skel.source)


def united_lattices(skel: Skeleton, blend: str = "sum") -> list:
    """Summed skeletons whose solids unite to the scene's solid.

    Parameters
    ----------
    skel : Skeleton or GroupedSkeleton
    blend : {"sum", "union"}
        The model's blend (a supported scene's support and pad groups always unite).

    Returns
    -------
    list of Skeleton
        The model's struts when they sum (one skeleton), then the classes of the struts that
        unite (:func:`disjoint_classes`). A scene of one summed lattice gives itself.

    Examples
    --------
    >>> s = Skeleton([[0, 0, 0], [0, 0, 4], [4, 0, 4]], [[0, 1], [1, 2]], [[1, 1], [1, 1]])
    >>> [k.n_segments for k in united_lattices(s)], [k.n_segments for k in united_lattices(s, "union")]
    ([2], [1, 1])
    """
    blend = check_blend(blend, "blend")
    groups = getattr(skel, "groups", ()) or (("model", 0, skel.n_segments),)
    summed, united = [], []
    for role, start, stop in groups:
        seg = np.arange(start, stop, dtype=np.int64)
        (summed if role == "model" and blend == "sum" else united).append(seg)
    if len(summed) == 1 and not united and not getattr(skel, "groups", ()):
        return [skel]
    out = [_sub_skeleton(skel, seg) for seg in summed]
    if united:
        out += [_sub_skeleton(skel, c) for c in disjoint_classes(skel, np.concatenate(united))]
    return out


__all__ = ["united_lattices", "disjoint_classes"]
