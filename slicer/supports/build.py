"""Supports and a pad as struts: :func:`supported_scene`.

From each support point (:mod:`.points`) a **head** -- a tapered strut whose
upper end, of radius ``tip_radius``, enters the model ``penetration`` above its
underside -- and a **pillar** straight down: to the pad, to the plate (on a
foot), or onto the model below where the straight path down meets it first.
The model is lifted by ``elevation`` (a whole number of layers); the **pad**
is a slab of parallel struts under the supports (and under the model, which
then rests on it, with ``elevation = 0``).

The support and pad struts follow the model's in the result, in groups that
unite with the model (:mod:`.groups`). Every strut of the supports and the
pad is traced with the union blend, so identical struts reach exactly the
same depth: the pad's rows and the feet rest on one layer. Heights are
chosen on the layer lattice of the grid the points were found on (default
grids are aligned to multiples of the layer height), with the lowest
surface of the pad or the feet half a layer below a layer's centres.

After building, the supported scene is sliced on the same grid and checked
for islands; any left (a minimum the model's own slices did not show) gets
supports too, for up to ``rounds`` rounds.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from slicer.atomic import write_bytes
from slicer.arguments import fmt_num, magnitude, number, scene_numbers
from slicer.errors import GridError, OptionError
from slicer.model.field import evaluate
from slicer.tracer.grid import SliceGrid
from slicer.scene.write import scene_document
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import slice_skeleton
from slicer.supports.groups import GroupedSkeleton, groups_document
from slicer.supports.points import bisect_z, march, overhang_pixels, region_points, skeleton_minima, underside, unheld_regions
from slicer.supports.trees import brace_pairs, braces, junction, tree_groups


#: the largest length a support setting may have, mm (no printer builds larger)
MAX_LENGTH = 1000.0


@dataclass(frozen=True)
class SupportSettings:
    """What the supports look like (lengths in mm, the angle in degrees).

    Attributes
    ----------
    tip_radius : float, default 0.2
        Radius of a head's upper end (PrusaSlicer's head front diameter 0.4 mm).
    penetration : float, default 0.2
        How far a head's end enters the model above its underside (at most half
        the model's thickness there).
    head_length : float, default 1.0
        Length of the tapered head, from the tip to the pillar.
    pillar_radius : float, default 0.5
    foot_radius : float, default 1.0
        Without a pad: the radius of the short strut each pillar stands on.
    elevation : float, default 3.0
        Lift of the model above the plate (or the pad); rounded to whole layers.
        0 puts the model on the pad (which it then needs).
    pad : bool, default True
    pad_thickness : float, default 1.0
    pad_margin : float, default 2.0
        The pad reaches this far beyond the pillars (and the model's footprint).
    bridge_length : float, default 2.0
        The largest span of an unheld region or an overhang left between two
        support points (or between one and what holds the overhang).
    critical_angle : float, default 45
        Overhangs flatter than this (degrees from the horizontal) are
        supported where they span more than ``bridge_length``; 0: no overhang
        supports (islands and minima only).
    tree_distance : float, default 3.0
        Heads with a free way down within this distance share a pillar (at
        most four on one; :mod:`.trees`); 0: a pillar per head.
    pixel_size, layer_height : float, default 0.05
        The grid the points are found on (the printer's, for a printer job).
    rounds : int, default 3
        Slice-and-check rounds after the first build.
    """

    tip_radius: float = 0.2
    penetration: float = 0.2
    head_length: float = 1.0
    pillar_radius: float = 0.5
    foot_radius: float = 1.0
    elevation: float = 3.0
    pad: bool = True
    pad_thickness: float = 1.0
    pad_margin: float = 2.0
    bridge_length: float = 2.0
    critical_angle: float = 45.0
    tree_distance: float = 3.0
    pixel_size: float = 0.05
    layer_height: float = 0.05
    rounds: int = 3

    def __post_init__(self):
        for name in ("tip_radius", "head_length", "pillar_radius", "foot_radius", "pad_thickness", "bridge_length",
                     "pixel_size", "layer_height"):
            object.__setattr__(self, name, magnitude(getattr(self, name), f"--{name.replace('_', '-')}",
                                                     positive=True))
        for name in ("penetration", "elevation", "pad_margin", "tree_distance"):
            v = number(getattr(self, name), f"--{name.replace('_', '-')}", lo=0.0)
            object.__setattr__(self, name, magnitude(v, f"--{name.replace('_', '-')}"))
        for name in ("tip_radius", "head_length", "pillar_radius", "foot_radius", "pad_thickness", "bridge_length",
                     "penetration", "elevation", "pad_margin", "tree_distance"):
            if getattr(self, name) > MAX_LENGTH:
                raise OptionError(f"--{name.replace('_', '-')} {fmt_num(getattr(self, name))} mm is beyond "
                                  f"{MAX_LENGTH:g} mm (a printer's build volume)")
        if self.tip_radius < self.pixel_size / 2:
            raise OptionError(f"--tip-radius {fmt_num(self.tip_radius)} mm is thinner than half the pixel "
                              f"({fmt_num(self.pixel_size)} mm): such a tip prints no pixel")
        if self.bridge_length < self.pixel_size:
            raise OptionError(f"--bridge-length {fmt_num(self.bridge_length)} mm is shorter than the pixel "
                              f"({fmt_num(self.pixel_size)} mm)")
        a = number(self.critical_angle, "--critical-angle", lo=0.0)
        if not a < 90.0:
            raise OptionError(f"--critical-angle {fmt_num(a)} must be below 90 degrees (0: no overhang supports)")
        object.__setattr__(self, "critical_angle", a)
        if self.tip_radius > self.pillar_radius:
            raise OptionError(f"--tip-radius {fmt_num(self.tip_radius)} is larger than the pillar radius "
                              f"{fmt_num(self.pillar_radius)} mm")
        if self.elevation == 0 and not self.pad:
            raise OptionError("--elevation 0 puts the model on the pad: it needs --pad (a model on the bare plate "
                              "needs no lift; give an elevation for supports without a pad)")
        if not isinstance(self.rounds, int) or isinstance(self.rounds, bool) or self.rounds < 0:
            raise OptionError(f"rounds = {self.rounds!r} must be an integer >= 0")

    @property
    def lift(self) -> float:
        """The elevation rounded to whole layers, mm."""
        return round(self.elevation / self.layer_height) * self.layer_height

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class SupportReport:
    """What :func:`supported_scene` made.

    Attributes
    ----------
    points : (q, 3) float64, mm
        Contact points on the model's underside (in the lifted frame).
    kinds : list of str
        ``island``, ``minimum``, ``overhang`` or ``recheck`` per point.
    supports : int
        Heads (one per point).
    to_model : int
        Pillars that end on the model below.
    pad_rows : int
    pillars : int
        Pillars to the pad or plate (a tree's counts once).
    trees : int
        Pillars shared by several heads.
    braces : int
        Brace struts between tall pillars.
    lift : float, mm
    islands_left : int
        Islands the last slice-and-check still found (0 when all are held).
    seconds : float
    """

    points: np.ndarray
    kinds: list
    supports: int
    to_model: int
    pad_rows: int
    lift: float
    islands_left: int
    rounds: int
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)
    pillars: int = 0
    trees: int = 0
    braces: int = 0

    def to_dict(self) -> dict:
        return {"supports": self.supports, "to_model": self.to_model, "pillars": self.pillars, "trees": self.trees,
                "braces": self.braces,
                "pad_rows": self.pad_rows,
                "lift": self.lift, "islands_left": self.islands_left, "rounds": self.rounds,
                "kinds": {k: self.kinds.count(k) for k in sorted(set(self.kinds))},
                "seconds": round(self.seconds, 3), "settings": self.settings}


class _Struts:
    """Nodes, segments and radii being collected."""

    def __init__(self):
        self.nodes: list = []
        self.segs: list = []
        self.radii: list = []

    def add(self, a, b, ra: float, rb: float) -> None:
        n = len(self.nodes)
        self.nodes += [tuple(float(v) for v in a), tuple(float(v) for v in b)]
        self.segs.append((n, n + 1))
        self.radii.append((float(ra), float(rb)))


def _free_end_reach(radius: float, length: float) -> float:
    """How far below its lower end node a lone vertical strut reaches (the union blend), mm."""
    s = Skeleton([[0.0, 0.0, 0.0], [0.0, 0.0, length]], [[0, 1]], [[radius, radius]])
    f = _field(s, "union")
    z = bisect_z(f, np.zeros((1, 2)), np.array([0.0]), np.array([-2.0 * radius]))
    return float(-z[0])


def _field(skel, blend: str):
    def f(pts):
        return evaluate(skel, np.ascontiguousarray(pts, dtype=np.float64), blend=blend)[0]
    return f


def _snap_half(z: float, h: float, up: bool) -> float:
    """The nearest height ``(k + 1/2) h`` at or below (or above, ``up``) ``z``."""
    k = math.ceil(z / h - 0.5) if up else math.floor(z / h - 0.5)
    return (k + 0.5) * h


class _Builder:
    """The geometry of one build: the lifted model, the base and the pad's place."""

    def __init__(self, model: Skeleton, st: SupportSettings, blend: str, lowest: float, footprint):
        self.model, self.st, self.blend = model, st, blend
        self.f_model = _field(model, blend)
        h = st.layer_height
        self.step = min(h / 2, float(model.radii.min()) / 2)
        rho = st.pad_thickness / 2
        if st.elevation == 0:                             # the pad's top above the model's lowest layer
            top = lowest + h + 0.15 * rho
            self.pad_bottom = _snap_half(top - 2 * rho, h, up=True)
        else:                                             # the plate: under the model before its lift
            plate = lowest - h / 2 - st.lift
            self.pad_bottom = _snap_half(plate - (2 * rho if st.pad else 0.0), h, up=False)
        self.rho = rho
        self.pad_axis = self.pad_bottom + rho
        self.pad_top = self.pad_bottom + 2 * rho
        self.foot_len = 2 * st.pillar_radius + st.foot_radius
        self.foot_node = self.pad_bottom + _free_end_reach(st.foot_radius, self.foot_len)
        self.base = self.pad_axis if st.pad else self.foot_node + self.foot_len
        self.footprint = footprint                       # (2, 2) xy box the pad must cover, or None
        self.pillars: list = []                          # (x, y, bottom, top) of each pillar to the base

    def brace(self, out: _Struts) -> int:
        """X braces between tall neighbouring pillars (:mod:`.trees`); returns the struts added."""
        n = 0
        r = self.st.pillar_radius / 2
        for i, j in brace_pairs(self.pillars):
            for lo, hi in braces(self.f_model, self.pillars[i], self.pillars[j], r):
                out.add(lo, hi, r, r)
                n += 1
        return n

    def head_and_pillar(self, out: _Struts, x: float, y: float, zs: float, pen: float, obstacle: float) -> bool:
        """One support from the contact ``(x, y, zs)``; True when it ends on the model."""
        st = self.st
        r = st.pillar_radius if not math.isnan(obstacle) else self.clear_radius(x, y, zs - st.head_length)
        tip = (x, y, zs + pen)
        hz = zs - st.head_length
        if not math.isnan(obstacle):                       # onto the model below
            end = obstacle - min(st.penetration, 0.5 * (zs - obstacle))
            if end >= hz:                                  # the head alone reaches it
                frac = min(1.0, (zs + pen - end) / (st.head_length + pen))
                out.add((x, y, end), tip, st.tip_radius + (st.pillar_radius - st.tip_radius) * frac, st.tip_radius)
            else:
                out.add((x, y, hz), tip, st.pillar_radius, st.tip_radius)
                out.add((x, y, end), (x, y, hz), st.pillar_radius, st.pillar_radius)
            return True
        if hz <= self.base + 1e-9:                          # a short support: the head reaches the base
            out.add((x, y, self.base), tip, r, st.tip_radius)
            self.foot(out, x, y)
        else:
            out.add((x, y, hz), tip, r, st.tip_radius)
            self.pillar(out, x, y, hz, r)
        return False

    def clear_radius(self, x: float, y: float, top: float) -> float:
        """The largest of the pillar radius, half of it and the tip radius whose pillar from
        ``top`` down to the base keeps its surface out of the model (eight lines down its side
        walked on the field); the tip radius when none does (the pillar may graze the model)."""
        st = self.st
        ang = np.arange(8) * (np.pi / 4)
        for r in (st.pillar_radius, st.pillar_radius / 2, st.tip_radius):
            xy = np.column_stack([x + r * np.cos(ang), y + r * np.sin(ang)])
            hit = march(self.f_model, xy, np.full(8, top), -self.step, np.full(8, self.base), True)
            if np.all(np.isnan(hit)):
                return r
        return st.tip_radius

    def pillar(self, out: _Struts, x: float, y: float, top: float, r: float | None = None) -> None:
        """A pillar of radius ``r`` (default the pillar radius) from ``top`` down to the pad or
        onto a foot on the plate."""
        r = self.st.pillar_radius if r is None else r
        out.add((x, y, self.base), (x, y, top), r, r)
        self.pillars.append((x, y, self.base, top))
        self.foot(out, x, y)

    def foot(self, out: _Struts, x: float, y: float) -> None:
        if not self.st.pad:
            rf = self.st.foot_radius
            out.add((x, y, self.foot_node), (x, y, self.foot_node + self.foot_len), rf, rf)

    def tree(self, out: _Struts, p: np.ndarray, pen: np.ndarray, members: list) -> np.ndarray | None:
        """Heads ``members`` of ``p`` on one pillar (:mod:`.trees`); returns the pillar's xy, or
        None (nothing added) when they cannot share one."""
        st = self.st
        xy = p[members, :2]
        hz = p[members, 2] - st.head_length
        c = np.round(xy.mean(axis=0) / st.pixel_size) * st.pixel_size
        zj = junction(self.f_model, xy, hz, c, self.base, 2 * st.pillar_radius, self.step)
        if zj is None:
            return None
        r = st.pillar_radius
        for q, m in enumerate(members):
            x, y, zs = p[m]
            out.add((x, y, hz[q]), (x, y, zs + pen[m]), r, st.tip_radius)
            out.add((c[0], c[1], zj), (x, y, hz[q]), r, r)
        self.pillar(out, c[0], c[1], zj)
        return c

    def obstacles(self, xy: np.ndarray, zs: np.ndarray) -> np.ndarray:
        """The top of the model below each contact on its axis, or NaN where the way down is free."""
        if not len(zs):
            return np.zeros(0)
        gap = self.st.layer_height
        hit = march(self.f_model, xy, zs - gap, -self.step, np.full(len(zs), self.base), True)
        ok = ~np.isnan(hit)
        top = np.full(len(zs), np.nan)
        if ok.any():
            top[ok] = bisect_z(self.f_model, xy[ok], hit[ok], hit[ok] + self.step)
        return top

    def penetrations(self, xy: np.ndarray, zs: np.ndarray) -> np.ndarray:
        """``penetration``, or half the model's thickness above each contact where it is thinner."""
        if not len(zs):
            return np.zeros(0)
        st = self.st
        stop = zs + 2 * st.penetration
        out = march(self.f_model, xy, zs + self.step, self.step, stop, False)
        thick = np.where(np.isnan(out), np.inf, out - zs)
        return np.minimum(st.penetration, 0.5 * thick)

    def pad(self, out: _Struts, feet: np.ndarray) -> int:
        """The pad's rows along x under ``feet`` ((q, 2) xy, mm) and the footprint; returns the rows."""
        st = self.st
        boxes = []
        if len(feet):
            r = st.pillar_radius
            boxes.append(np.array([feet.min(axis=0) - r, feet.max(axis=0) + r]))
        if self.footprint is not None:
            boxes.append(self.footprint)
        if not boxes:
            return 0
        b = np.stack(boxes)
        lo, hi = b[:, 0].min(axis=0) - st.pad_margin, b[:, 1].max(axis=0) + st.pad_margin
        py = st.pixel_size
        s = max(1, int(self.rho // py)) * py                # rows one radius apart, on pixel rows
        j0, j1 = math.floor(lo[1] / s), math.ceil(hi[1] / s)
        x0, x1 = math.floor(lo[0] / py) * py, math.ceil(hi[0] / py) * py
        for j in range(j0, j1 + 1):
            out.add((x0, j * s, self.pad_axis), (x1, j * s, self.pad_axis), self.rho, self.rho)
        return j1 - j0 + 1


def _check_model(model) -> Skeleton:
    if isinstance(model, GroupedSkeleton) or len(getattr(model, "groups", ()) or ()) > 1:
        raise OptionError("the scene already has support groups; add supports to the model alone")
    if not isinstance(model, Skeleton):
        raise OptionError(f"supports need a lattice (a skeleton), got {type(model).__name__}")
    return model


def _points_of_regions(regions, grid, st: SupportSettings, field_fn, step: float):
    """Contact points (x, y, zs) of unheld regions, on their underside."""
    pts = []
    for k, ii, jj in regions:
        for i, j in region_points(grid, ii, jj, st.bridge_length):
            pts.append((grid.origin[0] + i * grid.pixel_size[0], grid.origin[1] - j * grid.pixel_size[1],
                        grid.origin[2] + k * grid.layer_height))
    if not pts:
        return np.zeros((0, 3))
    p = np.array(pts, dtype=np.float64)
    zs = underside(field_fn, p[:, :2], p[:, 2], step)
    return np.column_stack([p[:, :2], zs])


def _minima_points(model: Skeleton, st: SupportSettings, field_fn, step: float) -> np.ndarray:
    """Contacts under the skeleton's local minima, their xy on pixel centres."""
    nodes = skeleton_minima(model)
    if not nodes.size:
        return np.zeros((0, 3))
    p = model.nodes[nodes].copy()
    p[:, 0] = np.round(p[:, 0] / st.pixel_size) * st.pixel_size
    p[:, 1] = np.round(p[:, 1] / st.pixel_size) * st.pixel_size
    inside = field_fn(p) >= 1.0
    p = p[inside]
    if not len(p):
        return np.zeros((0, 3))
    return np.column_stack([p[:, :2], underside(field_fn, p[:, :2], p[:, 2], step)])


def _merge(points: np.ndarray, kinds: list, dist: float):
    """Drop points within ``dist`` (in xy and in z) of an earlier one."""
    keep = []
    for q in range(len(points)):
        d = np.abs(points[keep] - points[q]) if keep else np.zeros((0, 3))
        if keep and np.any((np.hypot(d[:, 0], d[:, 1]) < dist) & (d[:, 2] < dist)):
            continue
        keep.append(q)
    return points[keep], [kinds[q] for q in keep]


def _assemble(model: Skeleton, lifted: Skeleton, b: _Builder, points: np.ndarray):
    """The grouped skeleton of the lifted model and the supports from ``points``."""
    st = b.st
    held = np.zeros(len(points), bool)
    if st.elevation == 0 and len(points):               # contacts in the pad are held by it
        held = points[:, 2] <= b.pad_top
    p = points[~held]
    obst = b.obstacles(p[:, :2], p[:, 2])
    pen = b.penetrations(p[:, :2], p[:, 2])
    sup = _Struts()
    b.pillars = []
    to_model = 0
    feet = []
    trees = 0
    alone = np.ones(len(p), bool)
    for members in tree_groups(p[:, :2], np.isnan(obst), st.tree_distance):
        c = b.tree(sup, p, pen, members) if len(members) > 1 else None
        if c is not None:
            alone[members] = False
            feet.append(c)
            trees += 1
    for q in np.nonzero(alone)[0]:
        on_model = b.head_and_pillar(sup, p[q, 0], p[q, 1], p[q, 2], pen[q], obst[q])
        to_model += on_model
        if not on_model:
            feet.append(p[q, :2])
    n_braces = b.brace(sup)
    pad = _Struts()
    rows = b.pad(pad, np.array(feet).reshape(-1, 2)) if st.pad else 0
    m = model.n_segments
    nodes = [lifted.nodes]
    segs = [model.segments]
    radii = [model.radii]
    groups = [("model", 0, m)]
    offset = model.n_nodes
    for role, s in (("support", sup), ("pad", pad)):
        if not s.segs:
            continue
        nodes.append(np.array(s.nodes, dtype=np.float64))
        segs.append(np.array(s.segs, dtype=np.int64) + offset)
        radii.append(np.array(s.radii, dtype=np.float64))
        groups.append((role, m, m + len(s.segs)))
        offset += len(s.nodes)
        m += len(s.segs)
    nodes, radii = np.concatenate(nodes), np.concatenate(radii)
    scene_numbers(nodes, radii, "the supported scene")          # as a scene file would be refused
    skel = GroupedSkeleton(nodes, np.concatenate(segs), radii, model.degree, model.sigma, groups=tuple(groups))
    return skel, {"supports": int(len(p)), "to_model": int(to_model), "pad_rows": rows, "trees": trees,
                  "pillars": len(feet), "braces": n_braces}


def supported_scene(model: Skeleton, settings: SupportSettings | None = None, blend: str = "sum",
                    threads: int | None = None):
    """The model with supports and a pad.

    Parameters
    ----------
    model : Skeleton
        The model (not already supported).
    settings : SupportSettings, optional
    blend : {"sum", "union"}
        The model's blend (the supports are traced with the union blend).
    threads : int, optional
        Numba threads for the slicing rounds.

    Returns
    -------
    scene : GroupedSkeleton
        The model's nodes, segments and radii first, in order, its nodes moved
        only along z by ``settings.lift``; then the supports' and the pad's
        struts, in groups ``model``, ``support``, ``pad``.
    report : SupportReport

    Raises
    ------
    OptionError
        Bad settings, or a scene that already has support groups.

    Examples
    --------
    >>> m = Skeleton([[0, 0, 2], [4, 0, 2]], [[0, 1]], [[0.4, 0.4]])
    >>> s, rep = supported_scene(m, SupportSettings(pixel_size=0.1, layer_height=0.1, rounds=1))
    >>> bool(np.array_equal(s.nodes[:2, :2], m.nodes[:, :2])), s.groups[0], rep.islands_left
    (True, ('model', 0, 1), 0)
    """
    t0 = time.perf_counter()
    st = settings or SupportSettings()
    model = _check_model(model)
    h, px = st.layer_height, st.pixel_size
    res = slice_skeleton(model, px, None, h, blend=blend, threads=threads)
    if res.n_runs == 0:
        raise GridError(f"the model has no voxel inside at {fmt_num(px)} mm pixels and {fmt_num(h)} mm layers: "
                        f"nothing to support (see `skelslice info SCENE --pixel-size MM`)")
    g = res.grid
    lift = st.lift
    lifted = model.translated((0.0, 0.0, lift))
    first = int(res.k0.min())
    lowest = g.origin[2] + first * h + lift               # the model's lowest inside centres, lifted
    footprint = None
    if st.elevation == 0:
        low = res.pix[res.k0 <= first + int(math.ceil(st.pad_thickness / h))]
        j, i = np.divmod(low, g.width)
        footprint = np.array([[g.origin[0] + i.min() * px, g.origin[1] - j.max() * px],
                              [g.origin[0] + i.max() * px, g.origin[1] - j.min() * px]])
    b = _Builder(lifted, st, blend, lowest, footprint)
    grid_l = SliceGrid((g.origin[0], g.origin[1], g.origin[2] + lift), g.pixel_size, h, g.width, g.height, g.layers)
    f_model = b.f_model
    regions = unheld_regions(res, plate_held=st.elevation == 0)
    pts = _points_of_regions(regions, grid_l, st, f_model, b.step)
    kinds = ["island"] * len(pts)
    mins = _minima_points(lifted, st, f_model, b.step)
    pts = np.concatenate([pts, mins])
    kinds += ["minimum"] * len(mins)
    pts, kinds = _merge(pts, kinds, 2 * st.pillar_radius)
    if st.critical_angle > 0:
        over = overhang_pixels(res, grid_l, pts, st.critical_angle, st.bridge_length, st.tip_radius)
        if over:
            o = np.array([(grid_l.origin[0] + i * px, grid_l.origin[1] - j * px, grid_l.origin[2] + k * h)
                          for k, i, j in over])
            o = np.column_stack([o[:, :2], underside(f_model, o[:, :2], o[:, 2], b.step)])
            pts, kinds = _merge(np.concatenate([pts, o]), kinds + ["overhang"] * len(o), 2 * st.pillar_radius)
    skel, counts = _assemble(model, lifted, b, pts)
    left, done = None, 0
    for done in range(1, st.rounds + 1):
        check = slice_skeleton(skel, px, None, h, blend=blend, threads=threads)
        regions = unheld_regions(check, plate_held=True)
        left = len(regions)
        if not regions:
            break
        more = _points_of_regions(regions, check.grid, st, lambda p: skel.field(p, blend), b.step)
        pts = np.concatenate([pts, more])
        kinds += ["recheck"] * len(more)
        skel, counts = _assemble(model, lifted, b, pts)
        left = None
    if left is None:
        left = -1                                         # the last round's additions were not re-checked
    rep = SupportReport(pts, kinds, counts["supports"], counts["to_model"], counts["pad_rows"], lift, left, done,
                        time.perf_counter() - t0, st.to_dict(), counts["pillars"], counts["trees"], counts["braces"])
    return skel, rep


def supported_document(skel: GroupedSkeleton) -> dict:
    """The supported scene as a JSON-ready dict (format version 2, with ``"groups"``)."""
    doc = scene_document(skel)
    doc["skelslice"] = 2
    doc["groups"] = groups_document(skel.groups)
    return doc


def write_supported(skel: GroupedSkeleton, path, force: bool = False) -> None:
    """Write a supported scene atomically as JSON (format version 2, :func:`supported_document`)."""
    data = (json.dumps(supported_document(skel), allow_nan=False, separators=(", ", ": ")) + "\n").encode()
    write_bytes(path, data, force=force)


__all__ = ["SupportSettings", "SupportReport", "supported_scene", "supported_document", "write_supported"]
