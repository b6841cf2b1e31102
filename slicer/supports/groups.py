"""Groups of struts: segments that blend within a group and unite between groups.

A supported scene holds the model's struts first, then the supports' and the
pad's. Each kind is a *group*: a contiguous range of segments whose fields
combine by the job's blend (``sum`` by default), while the groups combine by
union: a voxel centre is inside when it is inside some group's own solid. So
the model keeps its designed shape where a support touches it, and every
contact is the size of the support's tip (docs/supports.md).

In a scene file (format version 2)::

    "groups": [{"role": "model", "segments": [0, 154]},
               {"role": "support", "segments": [154, 300]},
               {"role": "pad", "segments": [300, 381]}]

``segments`` is the half-open range ``[start, stop)``; the ranges follow one
another from 0 to the number of segments, none empty. Roles: ``model``,
``support``, ``pad``.

The model group blends by the job's ``--blend``; the support and pad groups by
``union``, so every support strut keeps its designed radius and identical
struts (the pad's rows, the pillars' feet) reach exactly the same depth.
Slicing traces each group on the job's grid by the ordinary tracer and joins
the groups' inside runs (and spans) per pixel column (:func:`trace_groups`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer.errors import OptionError, SceneError
from slicer.model.field import evaluate
from slicer.parts.mesh_slicing import combine_intervals
from slicer.model.skeleton import Skeleton

#: group roles
ROLES = ("model", "support", "pad")
#: roles that are not the model (what the check and info count as supports)
SUPPORT_ROLES = ("support", "pad")


@dataclass(frozen=True, eq=False)
class GroupedSkeleton(Skeleton):
    """A :class:`~slicer.model.skeleton.Skeleton` whose segments fall in groups that unite.

    Parameters
    ----------
    nodes, segments, radii, degree, sigma, source
        As :class:`~slicer.model.skeleton.Skeleton`.
    groups : tuple of (role, start, stop)
        Contiguous, non-empty segment ranges covering ``0 .. m`` in order.

    Raises
    ------
    SceneError
        As :class:`Skeleton`, or for groups that are not such ranges.

    Examples
    --------
    >>> g = GroupedSkeleton([[0, 0, 0], [0, 0, 4], [3, 0, 0]], [[0, 1], [0, 2]], [[1, 1], [1, 1]],
    ...                     groups=(("model", 0, 1), ("support", 1, 2)))
    >>> g.group_skeleton(1).n_segments, g.support_segments
    (1, 1)
    """

    groups: tuple = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "groups", check_groups(self.groups, self.n_segments, self.source))

    def group_skeleton(self, g: int) -> Skeleton:
        """Group ``g`` alone, as a :class:`Skeleton` (all the nodes, the group's segments)."""
        _, a, b = self.groups[g]
        return Skeleton(self.nodes, self.segments[a:b], self.radii[a:b], self.degree, self.sigma)

    def role_mask(self, roles) -> np.ndarray:
        """(m,) bool: the segments of groups whose role is in ``roles``."""
        out = np.zeros(self.n_segments, bool)
        for role, a, b in self.groups:
            if role in roles:
                out[a:b] = True
        return out

    @property
    def support_segments(self) -> int:
        """Number of segments of the support and pad groups."""
        return int(self.role_mask(SUPPORT_ROLES).sum())

    def field(self, points, blend: str = "sum") -> np.ndarray:
        """Field value at points: the largest of the groups' own fields (the model's by
        ``blend``, the others' by union), so that ``F >= 1`` is the union of the groups'
        solids ((k,) float64)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return np.max([evaluate(self.group_skeleton(g), pts, blend=blend if role == "model" else "union")[0]
                       for g, (role, _a, _b) in enumerate(self.groups)], axis=0)

    def translated(self, offset) -> "GroupedSkeleton":
        """The same skeleton and groups moved by ``offset`` ((3,) float64, mm)."""
        off = np.asarray(offset, dtype=np.float64).reshape(3)
        return GroupedSkeleton(self.nodes + off, self.segments, self.radii, self.degree, self.sigma,
                               groups=self.groups)


def check_groups(groups, m: int, src: str | None = None) -> tuple:
    """Groups as a tuple of ``(role, start, stop)``, checked against ``m`` segments.

    Raises
    ------
    SceneError
        Naming the group entry and the value.
    """
    out = []
    expect = 0
    for i, g in enumerate(groups):
        if not isinstance(g, (tuple, list)) or len(g) != 3:
            raise SceneError(f"groups[{i}] = {g!r} must be (role, start, stop)", src)
        role, a, b = g
        if role not in ROLES:
            raise SceneError(f'groups[{i}].role = {role!r} is not a group role; use one of '
                             + ", ".join(f'"{r}"' for r in ROLES), src)
        for v in (a, b):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise SceneError(f"groups[{i}].segments = [{a!r}, {b!r}] must be two integers", src)
        if int(a) != expect:
            raise SceneError(f"groups[{i}].segments starts at {int(a)} but the groups must follow one another "
                             f"from segment 0 (expected {expect})", src)
        if not int(b) > int(a):
            raise SceneError(f"groups[{i}].segments = [{int(a)}, {int(b)}] is empty (the range is [start, stop))",
                             src)
        if int(b) > m:
            raise SceneError(f"groups[{i}].segments = [{int(a)}, {int(b)}] reaches past the last segment "
                             f"(there are {m} segments)", src)
        out.append((str(role), int(a), int(b)))
        expect = int(b)
    if not out:
        raise SceneError('"groups" is empty; leave it out for a scene of one group', src)
    if expect != m:
        raise SceneError(f"the groups end at segment {expect} but there are {m} segments; every segment "
                         f"belongs to a group", src)
    return tuple(out)


def groups_from_json(value, m: int, src: str | None) -> tuple:
    """The ``"groups"`` entry of a version 2 scene, checked (see the module docstring)."""
    if type(value) is not list:
        raise SceneError(f'"groups" must be a list of {{"role": ..., "segments": [start, stop]}} objects, '
                         f"got {type(value).__name__}", src)
    raw = []
    for i, e in enumerate(value):
        if type(e) is not dict:
            raise SceneError(f'groups[{i}] must be an object {{"role": ..., "segments": [start, stop]}}', src)
        bad = [k for k in e if k not in ("role", "segments") and k != "metadata" and not k.startswith("x-")]
        if bad:
            raise SceneError(f'groups[{i}] has the unknown key "{bad[0]}"; a group has "role" and "segments"', src)
        for k in ("role", "segments"):
            if k not in e:
                raise SceneError(f'groups[{i}] has no "{k}"', src)
        seg = e["segments"]
        if type(seg) is not list or len(seg) != 2 or any(type(v) is not int for v in seg):
            raise SceneError(f'groups[{i}].segments = {seg!r} must be [start, stop], two JSON integers', src)
        raw.append((e["role"], seg[0], seg[1]))
    return check_groups(raw, m, src)


def with_groups(skel: Skeleton, value, src: str | None) -> GroupedSkeleton:
    """``skel`` with the groups of a scene file's ``"groups"`` entry."""
    groups = groups_from_json(value, skel.n_segments, src)
    return GroupedSkeleton(skel.nodes, skel.segments, skel.radii, skel.degree, skel.sigma, source=src, groups=groups)


def groups_document(groups) -> list[dict]:
    """The ``"groups"`` entry of a scene file."""
    return [{"role": r, "segments": [a, b]} for r, a, b in groups]


def is_grouped(skel) -> bool:
    """True for a skeleton with more than one group."""
    return len(getattr(skel, "groups", ()) or ()) > 1


def group_options(role: str, kw: dict) -> dict:
    """The tracing options of a group: the job's for the model; the union blend for supports and
    the pad (every support strut keeps its designed radius), which the ``segment`` method lacks.

    Raises
    ------
    OptionError
        ``method="segment"`` for a support or pad group.
    """
    if role == "model":
        return kw
    if kw.get("method", "interval") not in ("interval", "sampling"):
        raise OptionError(f"--method {kw.get('method')}: supports are traced with the union blend, which needs "
                          f"--method interval or sampling")
    return {**kw, "blend": "union", "lazy": False}


def trace_groups(trace, skel: GroupedSkeleton, grid, **kw):
    """Trace each group of ``skel`` on ``grid`` with ``trace`` (:func:`slicer.tracer.slicing.trace`)
    and unite the inside runs (and spans) per pixel column.

    Returns
    -------
    SliceResult
        Runs of the union; ``stats`` sums the groups' ``evaluations`` and
        ``trace_seconds``.
    """
    results = [trace(skel.group_skeleton(g), grid, **group_options(role, kw))
               for g, (role, _a, _b) in enumerate(skel.groups)]

    def union(states):
        return states.any(axis=0)

    first = results[0]
    pix, k0, k1 = combine_intervals([(r.pix, r.k0, r.k1) for r in results], union)
    stats = dict(first.stats)
    stats["evaluations"] = int(sum(r.stats.get("evaluations", 0) for r in results))
    stats["trace_seconds"] = float(sum(r.stats.get("trace_seconds", 0.0) for r in results))
    model = [(r.pix, r.k0, r.k1) for r, (role, _a, _b) in zip(results, skel.groups) if role == "model"]
    _mp, mk0, mk1 = combine_intervals(model, union) if model else (None, np.zeros(0), np.zeros(0))
    stats["support_voxels"] = int((k1 - k0).sum()) - int((mk1 - mk0).sum())   # inside beyond the model's
    out = type(first)(grid, pix.astype(np.int64), k0.astype(np.int64), k1.astype(np.int64), stats)
    if first.has_spans:
        sp, t0, t1 = combine_intervals([(r.span_pix, r.span_t0, r.span_t1) for r in results], union)
        out.span_pix, out.span_t0, out.span_t1 = sp.astype(np.int64), t0.astype(np.float64), t1.astype(np.float64)
    return out


def refuse_pieces(skel, n_tiles: int, n_slabs: int, executor) -> None:
    """Supported scenes are traced group by group in one piece: refuse plans of several
    tiles or slabs, or another executor, by name (:class:`OptionError`)."""
    if not is_grouped(skel):
        return
    if n_tiles > 1 or n_slabs > 1 or executor not in (None, "serial"):
        raise OptionError(f"a scene with support groups is sliced in one piece in this process; the plan has "
                          f"{n_tiles} tiles and {n_slabs} slabs on executor {executor or 'serial'}: give a larger "
                          f"--max-memory (or none) and leave out --tile, --slab and --executor")


__all__ = ["GroupedSkeleton", "ROLES", "SUPPORT_ROLES", "check_groups", "groups_from_json", "with_groups",
           "groups_document", "is_grouped", "group_options", "trace_groups", "refuse_pieces"]
