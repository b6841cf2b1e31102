"""Stiff and extreme cases: a named suite that tries to break the field and the tracer.

``python -m validation.stiff [--fast] [--json FILE] [--cases NAME ...]`` runs every
case, prints one table row per case and writes the measurements as JSON.

Each case is a small :class:`slicer.Skeleton` (or a scene that must be refused)
and a voxel grid. For every case the suite measures:

* **field error**: max relative error of ``Skeleton.field`` against the
  independent extended-precision Gauss-Legendre reference
  (:mod:`validation.reference_field`) at points near the surface: random points
  at 0.5-1.5 radii from the struts (inside the case's window, if any) and the
  voxel centres with ``|F - 1| < 0.5``. Points where the reference is below
  1e-12 are measured in absolute error instead.
* **root error**: along pixel columns (rays along +z), every bracket of two
  consecutive layer centres where ``F - 1`` changes sign is refined to a root of
  ``F = 1`` by bisection on our float64 field, then polished by Newton steps on
  the reference field; the distance between the two, in mm. With the tracer's
  span output (``trace(..., spans=True)``, default tolerance), also the
  distance from each reference root to the nearest span end (``span_err``,
  mm; the tracer's tolerance ``span_tol`` is reported with it). Roots where
  the reference ``|dF/dz| * tau < 1e-3`` (double roots, columns lying in the
  surface) have no well-defined position: they are counted, not measured.
* **voxel mismatches** of :func:`slicer.tracer.slicing.trace` with each method
  (interval, sampling, segment) against the dense field at every voxel centre,
  excluding centres with ``|F - 1| <= 1e-9``; and ``ref_mismatch``: dense
  float64 classification against the reference at every centre with
  ``|F - 1| < 1e-4`` (again excluding ``|F_ref - 1| <= 1e-9``).
* **time**: trace wall time of each method (warm JIT cache), seconds.

A case passes when the field error is within :func:`field_tolerance` (1e-10
relative, 1e-14 absolute below 1e-12, 5e-9 for degree 16, never below the
input-rounding conditioning 2 eps l |grad F|), there are no voxel mismatches
of any kind and no runs outside the grid, the span ends are within
``span_tol`` of the reference roots, and each scene that must be refused
raises :class:`slicer.SceneError` naming the offending entry.
"""
from __future__ import annotations

import argparse
import inspect
import itertools
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from slicer._kernels.runtime.launch import numba_threads
from slicer.atomic import write_bytes
from slicer.errors import SceneError
from slicer.tracer.grid import make_grid
from slicer.scene.read import load_scene
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import trace

from validation import machine
from validation import reference_field as ref
from validation.bench import _warmup
from slicer.constants import STIFF_FIELD_TOL as TOL

#: field error bound: relative where the reference is >= TINY, absolute below
FIELD_REL = 1e-10
FIELD_ABS = 1e-14
TINY = 1e-12
#: degree 16: the power-basis sum of R(y)^8 cancels by ~1e7 (tests/test_field.py)
DEGREE16_REL = 5e-9
#: a root is well conditioned when |dF/dz| * tau is at least this
ROOT_SLOPE = 1e-3
METHODS = ("interval", "sampling", "segment")


@dataclass
class Setup:
    """One case at one size.

    Attributes
    ----------
    skel : Skeleton
        The scene that is sliced and measured.
    pixel_size, layer_height : float, mm
        Grid spacing (layer height defaults to the pixel size).
    bounds : (6,) float or None, mm
        Explicit grid box (a window on a large scene); default: the support box.
    refuse : list of (callable, tuple of str)
        Degenerate scenes: each callable builds one and must raise
        :class:`slicer.SceneError` whose message holds every listed substring.
    tau : float, mm
        Typical radius: roots with ``|dF/dz| * tau < ROOT_SLOPE`` are not measured.
    """

    skel: object = None
    pixel_size: float = 0.1
    layer_height: float | None = None
    bounds: tuple | None = None
    refuse: list = field(default_factory=list)
    tau: float = 1.0


@dataclass(frozen=True)
class Case:
    """A named case: ``build(fast)`` returns its :class:`Setup` (small when fast)."""

    name: str
    what: str
    build: Callable[[bool], Setup]


def _skel(nodes, segs, radii, **kw):
    return Skeleton(np.asarray(nodes, float), np.asarray(segs, np.int64).reshape(-1, 2),
                    np.asarray(radii, float).reshape(-1, 2), **kw)


# ----------------------------------------------------------------------------- cases
def _taper(rel):
    def build(fast):
        # oblique strut, r0 = 1, r1 = 1 + rel, plus a second strut tapering the other way
        s = _skel([[0, 0, 0], [3, 1.5, 4], [3, 1.5, 4], [6, 0, 5]], [[0, 1], [2, 3]],
                  [[1.0, 1.0 + rel], [1.0 + rel, 1.0]])
        return Setup(s, 0.3 if fast else 0.12, tau=1.0)
    return build


def _cone(ratio, length=3.0):
    def build(fast):
        d = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
        s = _skel([[0, 0, 0], length * d], [[0, 1]], [[1.0 / ratio, 1.0]])
        return Setup(s, 0.12 if fast else 0.05, tau=1.0)
    return build


def _critical(fast):
    # sigma * (r1 - r0) = 2 exactly, with the strut's length or its extent across the
    # ray exactly 2: E = 0 (linear support quadratic) and/or A = 0 (docs/math.md §2.2, §3.1)
    nodes = [[0, 0, 0], [0, 0, 2], [1.5, 0, 0], [3.5, 0, 0], [0, 2, 0], [2, 2, 1.5], [3, 2.5, 0], [3, 4.5, 3]]
    s = _skel(nodes, [[0, 1], [2, 3], [4, 5], [6, 7]], [[0.25, 1.25]] * 4)
    return Setup(s, 0.2 if fast else 0.08, tau=0.5)


def _near_vertical(fast):
    # struts tilted 1e-6, 1e-9 and 1e-12 rad off the ray direction, constant and
    # tapered radius, each with its foot on a pixel column
    nodes, segs, radii = [], [], []
    for i, tilt in enumerate([1e-6, 1e-9, 1e-12]):
        for j, (r0, r1) in enumerate([(0.4, 0.4), (0.2, 0.6)]):
            x, y = 2.0 * i, 2.0 * j
            nodes += [[x, y, 0.0], [x + 3 * math.sin(tilt), y, 3 * math.cos(tilt)]]
            segs.append([len(nodes) - 2, len(nodes) - 1])
            radii.append([r0, r1])
    s = _skel(nodes, segs, radii)
    return Setup(s, 0.1 if fast else 0.05, tau=0.4)


def _axis(tapered):
    def build(fast):
        # vertical strut on the column x = y = 0 (the default grid is aligned to
        # multiples of the pixel size, so that column exists), plus a node on it
        r = [[0.3, 0.8], [0.8, 0.5]] if tapered else [[0.5, 0.5], [0.5, 0.5]]
        s = _skel([[0, 0, 0], [0, 0, 3], [0, 0, 3], [0, 0, 5]], [[0, 1], [2, 3]], r)
        return Setup(s, 0.1 if fast else 0.05, tau=0.5)
    return build


def _tilted_taper(fast):
    # a tapered strut tilted 0.3 rad off the ray direction: the ray lies inside the
    # opening angle of its support cone (A <= 0 in docs/math.md §3.1), and a nested
    # one: sigma * (r1 - r0) > L (E <= 0, the thin end's support inside the thick one's)
    d = np.array([math.sin(0.3), 0.0, math.cos(0.3)])
    s = _skel([[0, 0, 0], 3 * d, [3, 0, 0], [3, 0, 1]], [[0, 1], [2, 3]], [[0.1, 1.0], [0.1, 1.0]])
    return Setup(s, 0.12 if fast else 0.05, tau=0.5)


def _grazing(fast):
    # horizontal struts along x, radius 0.3 (1 + eps): the pixel column y = 0.3 grazes
    # each surface (a double root of F = 1 at a layer centre), and the layer plane
    # z = z_i + 0.3 is tangent to its top. Long enough (L = 20 tau) that the
    # middle is a cylinder of radius exactly tau.
    eps = [1e-3, 1e-6, 1e-8, 0.0]
    nodes, segs, radii = [], [], []
    for i, e in enumerate(eps):
        z = 2.0 * i
        nodes += [[-3.0, 0.0, z], [3.0, 0.0, z]]
        segs.append([2 * i, 2 * i + 1])
        radii.append([0.3 * (1 + e)] * 2)
    s = _skel(nodes, segs, radii)
    return Setup(s, 0.1 if fast else 0.05, tau=0.3)


def _thin(fast):
    # struts much thinner than a voxel: one on a pixel column, one on a voxel row
    # (in a row and a layer plane), one oblique, one tapered to a needle
    s = _skel([[0, 0, 0], [0, 0, 2], [-1, 0.4, 1.0], [1, 0.4, 1.0], [0.5, -0.5, 0], [1.5, 0.3, 2],
               [-1, -1, 0], [-0.2, -0.6, 1.8]],
              [[0, 1], [2, 3], [4, 5], [6, 7]],
              [[0.02, 0.02], [0.01, 0.01], [0.015, 0.03], [0.001, 0.04]])
    return Setup(s, 0.1, tau=0.02)


def _zero_length(fast):
    # refused scenes; plus a near-zero-length segment in a chain (L = 1e-9 mm with
    # a radius jump, so sigma * |dr| >> L) and an isolated one (no surface at all)
    refuse = [
        (lambda: Skeleton([[0, 0, 0], [1, 0, 0]], [[0, 0]], [[0.5, 0.5]]), ("segment 0", "zero length")),
        (lambda: Skeleton([[0, 0, 0], [0, 0, 0]], [[0, 1]], [[0.5, 0.5]]), ("segment 0", "zero length")),
        (lambda: _load_json({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [1, 0, 0]], "segments": [[0, 1], [1, 1]],
                             "radii": [0.5, 0.5]}), ("segments[1]", "zero-length")),
        (lambda: _load_json({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [1, 0, 0], [1, 0, 0]],
                             "segments": [[0, 1], [1, 2]], "radii": [0.5, 0.5, 0.5]}),
         ("segment 1", "zero length")),
        (lambda: Skeleton([[0, 0, 0], [1, 0, 0]], [[0, 1]], [[0.0, 0.5]]), ("segment 0", "radii must be > 0")),
    ]
    s = _skel([[0, 0, 0], [1.2, 0, 0], [1.2, 0, 1e-9], [1.2, 0, 1.5], [3, 0, 0], [3, 0, 1e-12]],
              [[0, 1], [1, 2], [2, 3], [4, 5]],
              [[0.4, 0.4], [0.4, 0.55], [0.55, 0.5], [0.5, 0.5]])
    return Setup(s, 0.1 if fast else 0.04, refuse=refuse, tau=0.4)


def _load_json(scene):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "scene.json"
        path.write_text(json.dumps(scene))
        return load_scene(path)


def _duplicate(fast):
    # the same strut three times (once reversed) and a second one with other radii
    # on the same nodes: the fields add up (the scene loader warns, see `info`)
    s = _skel([[0, 0, 0], [1.5, 0.5, 2.5], [2.5, -0.5, 3]], [[0, 1], [1, 0], [0, 1], [0, 1], [1, 2]],
              [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3], [0.2, 0.4], [0.3, 0.2]])
    return Setup(s, 0.1 if fast else 0.04, tau=0.3)


def _offset(off):
    def build(fast):
        base = np.array([[0, 0, 0], [1, 2, 2.5], [2, 0, 1], [0.3, -1, 2]])
        s = _skel(base + np.array([off, -off, off]), [[0, 1], [1, 2], [1, 3]],
                  [[0.3, 0.5], [0.5, 0.25], [0.5, 0.1]])
        return Setup(s, 0.1 if fast else 0.04, tau=0.3)
    return build


def _node26(fast):
    dirs = [d for d in itertools.product((-1, 0, 1), repeat=3) if d != (0, 0, 0)]
    nodes = [[0.0, 0.0, 0.0]] + [list(1.6 * np.array(d, float)) for d in dirs]
    s = _skel(nodes, [[0, i + 1] for i in range(26)], [[0.25, 0.12]] * 26)
    return Setup(s, 0.1 if fast else 0.04, tau=0.2)


def _needle(fast):
    # radius 1e-6 mm (1e-5 voxel, 2e6 radii long): one needle on a pixel column,
    # one along a row in a layer plane, so voxel centres lie on their axes
    s = _skel([[0, 0, 0], [0, 0, 2], [-1, 0.4, 1.0], [1, 0.4, 1.0]], [[0, 1], [2, 3]],
              [[1e-6, 1e-6], [1e-6, 2e-6]])
    return Setup(s, 0.1, tau=1e-6)


def _long(kind, L=1e4):
    def build(fast):
        # mm, tau = 1: L radii
        if kind == "axis_x":
            s = _skel([[0, 0, 0], [L, 0, 0]], [[0, 1]], [[1.0, 1.0]])
            c = np.array([0.5 * L + 0.03, 0.0, 0.0])
        elif kind == "end":
            s = _skel([[0, 0, 0], [L, 0, 0]], [[0, 1]], [[1.0, 1.0]])
            c = np.array([L, 0.0, 0.0])
        elif kind == "axis_z":
            # vertical: the columns run along the strut; the window cuts it (the
            # strut goes on above and below the grid)
            s = _skel([[0, 0, 0], [0, 0, L]], [[0, 1]], [[1.0, 1.0]])
            c = np.array([0.0, 0.0, 20.0 if fast else 0.5 * L])
        else:          # oblique and tapered 1 -> 2 (delta = 1e-4)
            d = np.array([1.0, 0.6, 0.8]) / np.linalg.norm([1.0, 0.6, 0.8])
            s = _skel([[0, 0, 0], L * d], [[0, 1]], [[1.0, 2.0]])
            c = 0.5 * L * d
        half = np.array([3.0, 3.5, 3.5]) if not fast else np.array([2.0, 3.5, 3.5])
        lo, hi = c - half, c + half
        return Setup(s, 0.2 if fast else 0.08, bounds=tuple(lo) + tuple(hi), tau=1.0)
    return build


def _scaled(k):
    def build(fast):
        s = _skel([[0, 0, 0], [0.4, 0.2, 2.0], [1.5, 0.3, 2.5]], [[0, 1], [1, 2]],
                  [[0.02, 0.5], [0.5, 0.3]]).scaled(k)
        return Setup(s, (0.1 if fast else 0.04) * k, tau=0.3 * k)
    return build


def _kernel(degree, sigma):
    def build(fast):
        s = _skel([[0, 0, 0], [1.5, 0.3, 2.0], [-1, 0.5, 2.5]], [[0, 1], [1, 2]],
                  [[0.3, 0.5], [0.5, 0.2]], degree=degree, sigma=sigma)
        return Setup(s, 0.1 if fast else 0.04, tau=0.3)
    return build


CASES: list[Case] = [
    Case("taper_1e-12", "r1/r0 - 1 = 1e-12 (near-constant taper, docs/math.md §2.6.1)", _taper(1e-12)),
    Case("taper_1e-9", "r1/r0 - 1 = 1e-9", _taper(1e-9)),
    Case("taper_1e-6", "r1/r0 - 1 = 1e-6", _taper(1e-6)),
    Case("taper_1e-3", "r1/r0 - 1 = 1e-3", _taper(1e-3)),
    Case("cone_1e2", "cone tip, radius ratio 1e2", _cone(1e2)),
    Case("cone_1e3", "cone tip, radius ratio 1e3", _cone(1e3)),
    Case("cone_1e4", "cone tip, radius ratio 1e4", _cone(1e4)),
    Case("cone_1e4_nested", "ratio 1e4, sigma (r1 - r0) > L: nested end balls (E < 0)", _cone(1e4, 1.5)),
    Case("axis_ray", "vertical struts on a pixel column: rays along the axis", _axis(False)),
    Case("axis_ray_taper", "the same, tapered (ray inside the support cone's opening)", _axis(True)),
    Case("tilted_taper", "taper tilted 0.3 rad (A < 0) and a nested taper (E < 0)", _tilted_taper),
    Case("critical_taper", "sigma (r1 - r0) equal to the length (E = 0) or the cross extent (A = 0)",
         _critical),
    Case("near_vertical", "struts 1e-6, 1e-9, 1e-12 rad off the ray direction", _near_vertical),
    Case("grazing", "columns/planes tangent to struts: double roots at r = tau (1 + 1e-3..0)", _grazing),
    Case("thin", "struts of radius 0.001-0.04 mm with 0.1 mm voxels", _thin),
    Case("needle", "struts of radius 1e-6 mm (2e6 radii long) through voxel centres", _needle),
    Case("zero_length", "zero-length segments refused; L = 1e-9 and 1e-12 mm sliced", _zero_length),
    Case("duplicate", "a strut listed 4 times (once reversed), fields add up", _duplicate),
    Case("offset_1e4", "scene 1e4 mm from the origin", _offset(1e4)),
    Case("offset_1e5", "scene 1e5 mm from the origin", _offset(1e5)),
    Case("offset_1e6", "scene 1e6 mm from the origin", _offset(1e6)),
    Case("node_26", "26 struts meeting at one node on a pixel column", _node26),
    Case("long_1e4_mid", "strut of length 1e4 tau, window at mid-length", _long("axis_x")),
    Case("long_1e4_end", "strut of length 1e4 tau, window at its free end", _long("end")),
    Case("long_1e4_axis", "vertical strut 1e4 tau long, rays along it, window cutting it", _long("axis_z")),
    Case("long_1e6_mid", "strut of length 1e6 tau, window at mid-length", _long("axis_x", 1e6)),
    Case("long_1e4_oblique", "oblique tapered strut, 1e4 tau long, window at mid-length", _long("oblique")),
    Case("scale_1e-3", "a scene scaled by 1e-3 (micrometre struts)", _scaled(1e-3)),
    Case("scale_1e3", "a scene scaled by 1e3 (metre struts)", _scaled(1e3)),
    Case("kernel_n2", "degree 2 kernel", _kernel(2, 2.0)),
    Case("kernel_n16_s1.2", "degree 16, sigma 1.2 kernel", _kernel(16, 1.2)),
]
CASE_NAMES = [c.name for c in CASES]


# ----------------------------------------------------------------------------- measurements
def reference_field(skel, points, gradient=False):
    """The reference field of a whole skeleton (brute-force sum of segments)."""
    return ref.skeleton_field(skel.nodes, skel.segments, skel.radii, points, skel.degree, skel.sigma,
                              gradient=gradient)


def near_surface_points(skel, n, rng, bounds=None):
    """(k, 3) points at 0.5-1.5 radii from random skeleton points, s in [-0.15, 1.15].

    With ``bounds`` only points inside that box are kept (candidates are drawn
    until ``n`` are found or a budget runs out).
    """
    a, b = skel.endpoints()
    out = []
    got = 0
    for _ in range(50):
        k = max(4 * n, 1000) if bounds is not None else n
        seg = rng.integers(0, skel.n_segments, k)
        s = rng.uniform(-0.15, 1.15, k)
        sc = np.clip(s, 0.0, 1.0)
        tau = skel.radii[seg, 0] + sc * (skel.radii[seg, 1] - skel.radii[seg, 0])
        if bounds is not None:
            # draw s on the part of each segment that can be in the box
            lo, hi = np.asarray(bounds[:3]), np.asarray(bounds[3:])
            c = 0.5 * (lo + hi)
            D = b[seg] - a[seg]
            s0 = np.clip(np.sum((c - a[seg]) * D, axis=1) / np.sum(D * D, axis=1), 0, 1)
            span = np.linalg.norm(hi - lo) / np.linalg.norm(D, axis=1)
            s = s0 + rng.uniform(-1, 1, k) * span
            sc = np.clip(s, 0.0, 1.0)
            tau = skel.radii[seg, 0] + sc * (skel.radii[seg, 1] - skel.radii[seg, 0])
        v = rng.normal(size=(k, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        rho = rng.uniform(0.5, 1.5, k)
        p = a[seg] + s[:, None] * (b[seg] - a[seg]) + v * (rho * tau)[:, None]
        if bounds is not None:
            p = p[np.all((p >= lo) & (p <= hi), axis=1)]
        out.append(p)
        got += len(p)
        if got >= n:
            break
    return np.concatenate(out)[:n]


def field_tolerance(skel, points, f_ref, g_ref):
    """Per-point error bound of the float64 field (module docstring).

    ``max(FIELD_REL |f_ref|, 2 eps l |grad f_ref|)`` where the reference is at
    least ``TINY``, else ``max(FIELD_ABS, 2 eps l |grad f_ref|)``; ``l`` is the
    largest distance from the point to an end of a segment whose support can
    reach it (the lever arm: moving p by one rounding error of a computation in
    coordinates local to a segment changes f by about eps l |grad f|, the
    problem's own conditioning; see tests/test_field.py). Degree 16 gets
    ``DEGREE16_REL`` instead of ``FIELD_REL`` (a documented limit of the
    power-basis closed form at that degree).
    """
    a, b = skel.endpoints()
    reach = skel.sigma * skel.radii.max(axis=1)
    lever = np.zeros(len(points))
    for c0 in range(0, len(points), 512):
        p = points[c0:c0 + 512, None, :]
        D = b - a
        s = np.clip(np.sum((p - a) * D, axis=2) / np.sum(D * D, axis=1), 0.0, 1.0)
        near = np.linalg.norm(p - (a + s[..., None] * D), axis=2) <= reach * (1 + 1e-6)
        arm = np.maximum(np.linalg.norm(p - a, axis=2), np.linalg.norm(p - b, axis=2))
        lever[c0:c0 + 512] = np.max(np.where(near, arm, 0.0), axis=1)
    floor = 2 * np.finfo(float).eps * lever * np.linalg.norm(g_ref, axis=1)
    rel = DEGREE16_REL if skel.degree >= 16 else FIELD_REL
    big = np.abs(f_ref) >= TINY
    return np.maximum(np.where(big, rel * np.abs(f_ref), FIELD_ABS), floor)


def field_error(skel, points):
    """Error of ``skel.field`` against the reference at ``points``.

    Returns
    -------
    dict
        ``points``; ``rel``: max relative error where the reference is
        >= 1e-12; ``abs_tiny``: max absolute error below; ``floor_used``:
        points within tolerance only thanks to the conditioning floor;
        ``worst``: the point with the largest error-to-tolerance ratio (our
        value, the reference's, the tolerance); ``ok``: every point within
        :func:`field_tolerance`.
    """
    if len(points) == 0:
        return {"points": 0, "rel": 0.0, "abs_tiny": 0.0, "floor_used": 0, "worst": None, "ok": True}
    f = skel.field(points)
    fr, gr = reference_field(skel, points, gradient=True)
    tol = field_tolerance(skel, points, fr, gr)
    big = np.abs(fr) >= TINY
    err = np.abs(f - fr)
    rel = np.where(big, err / np.where(big, np.abs(fr), 1.0), 0.0)
    plain = np.where(big, (DEGREE16_REL if skel.degree >= 16 else FIELD_REL) * np.abs(fr), FIELD_ABS)
    abs_tiny = float(err[~big].max()) if (~big).any() else 0.0
    i = int(np.argmax(err / tol))
    return {"points": int(len(points)), "rel": float(rel.max()), "abs_tiny": abs_tiny,
            "floor_used": int(np.count_nonzero((err > plain) & (err <= tol))),
            "worst": {"p": points[i].tolist(), "f": float(f[i]), "f_ref": float(fr[i]), "tol": float(tol[i])},
            "ok": bool(np.all(err <= tol))}


def dense_field(skel, grid):
    """(layers, height, width) field at every voxel centre of ``grid``."""
    X, Y, Z = np.meshgrid(grid.centres_x(), grid.centres_y(), grid.centres_z(), indexing="xy")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return skel.field(P).reshape(grid.height, grid.width, grid.layers).transpose(2, 0, 1)


def _column_xy(grid, pix):
    j, i = np.divmod(np.asarray(pix, np.int64), grid.width)
    return grid.centres_x()[i], grid.centres_y()[j]


def roots_along_columns(skel, grid, F, max_roots, rng):
    """Roots of F = 1 on pixel columns, ours (float64 bisection) and the reference's.

    Brackets are consecutive layer centres whose ``F - 1`` differ in sign.

    Returns
    -------
    pix : (r,) int64
        Flat pixel index of each root.
    z, z_ref : (r,) float64, mm
        Our root and the reference root (Newton-polished from ours).
    slope : (r,) float64, 1/mm
        The reference dF/dz at ``z_ref`` (near zero at a double root, or on a
        column lying in the surface, where the root position is undefined).
    """
    s = F >= 1.0
    k, j, i = np.nonzero(s[1:] != s[:-1])
    if len(k) > max_roots:
        pick = np.sort(rng.choice(len(k), max_roots, replace=False))
        k, j, i = k[pick], j[pick], i[pick]
    if len(k) == 0:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e, e
    x = grid.centres_x()[i]
    y = grid.centres_y()[j]
    zc = grid.centres_z()
    lo, hi = zc[k].copy(), zc[k + 1].copy()
    up = s[k, j, i]          # inside at lo: F decreases through the root
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if np.all((mid == lo) | (mid == hi)):
            break
        fin = skel.field(np.stack([x, y, mid], axis=1)) >= 1.0
        go_hi = fin != up    # the root is below mid
        hi = np.where(go_hi, mid, hi)
        lo = np.where(go_hi, lo, mid)
    z = 0.5 * (lo + hi)
    zr = z.copy()
    blo, bhi = zc[k], zc[k + 1]
    for it in range(4):
        fr, gr = reference_field(skel, np.stack([x, y, zr], axis=1), gradient=True)
        if it == 3:
            break
        step = np.where(gr[:, 2] != 0, (fr - 1.0) / np.where(gr[:, 2] != 0, gr[:, 2], 1.0), 0.0)
        zr = np.clip(zr - step, blo, bhi)
    return (j * grid.width + i).astype(np.int64), z, zr, gr[:, 2]


def span_errors(skel, grid, pix, z_ref):
    """Distance from each reference root to the nearest end of the tracer's spans.

    Returns
    -------
    dict or None
        ``max`` (mm), ``span_tol`` (the tracer's default, mm), ``roots``,
        ``missing`` (roots on a pixel without spans); None when the tracer
        has no span output.
    """
    if "spans" not in inspect.signature(trace).parameters:
        return None
    # the default tolerance: a tighter one costs ~ stretch / span_tol on columns
    # lying in the surface (F = 1 to rounding), e.g. the axis_ray case
    res = trace(skel, grid, method="interval", spans=True)
    tol = float(res.stats["span_tol"])
    if len(pix) == 0:
        return {"max": 0.0, "span_tol": tol, "roots": 0}
    ends_pix = np.concatenate([res.span_pix, res.span_pix])
    ends_z = np.concatenate([res.span_t0, res.span_t1])
    order = np.lexsort((ends_z, ends_pix))
    ends_pix, ends_z = ends_pix[order], ends_z[order]
    a = np.searchsorted(ends_pix, pix, side="left")
    b = np.searchsorted(ends_pix, pix, side="right")
    err = np.full(len(pix), np.inf)
    for r in range(len(pix)):
        if b[r] > a[r]:
            err[r] = float(np.min(np.abs(ends_z[a[r]:b[r]] - z_ref[r])))
    return {"max": float(err.max()), "span_tol": tol, "roots": int(len(pix)),
            "missing": int(np.sum(~np.isfinite(err)))}


def run_defects(res) -> int:
    """Runs that break the SliceResult contract: outside ``[0, layers]``,
    empty, or overlapping/unsorted within a pixel (volume() would hide them)."""
    K = res.grid.layers
    pix, k0, k1 = res.pix, res.k0, res.k1
    bad = (k0 < 0) | (k1 > K) | (k1 <= k0) | (pix < 0) | (pix >= res.grid.width * res.grid.height)
    same = pix[1:] == pix[:-1]
    order = np.zeros(len(pix), bool)
    order[1:] = (pix[1:] < pix[:-1]) | (same & (k0[1:] < k1[:-1]))
    return int(np.count_nonzero(bad | order))


def voxel_mismatches(skel, grid, F, method, bucket=16):
    """Voxels where ``trace(method)`` disagrees with ``F >= 1`` away from |F - 1| <= TOL.

    Returns
    -------
    dict
        ``mismatch`` (voxels), ``runs_bad`` (:func:`run_defects`),
        ``example`` (first mismatch: k, j, i, F, traced class) or None,
        ``seconds`` (trace wall time), ``evaluations`` (primitive
        evaluations), ``error`` (an exception raised by the tracer, or None).
    """
    try:
        res = trace(skel, grid, method=method, bucket=bucket)
    except Exception as exc:  # a crash is a result here: report it, keep going
        return {"mismatch": -1, "runs_bad": -1, "example": None, "seconds": math.nan,
                "evaluations": -1, "error": f"{type(exc).__name__}: {str(exc)[:200]}"}
    vol = res.volume()
    bad = (vol != (F >= 1.0)) & (np.abs(F - 1.0) > TOL)
    n = int(bad.sum())
    ex = None
    if n:
        k, j, i = (int(v) for v in np.argwhere(bad)[0])
        ex = {"k": k, "j": j, "i": i, "F": float(F[k, j, i]), "traced_inside": bool(vol[k, j, i])}
    return {"mismatch": n, "runs_bad": run_defects(res), "example": ex,
            "seconds": float(res.stats["trace_seconds"]), "evaluations": int(res.stats["evaluations"]),
            "error": None}


def reference_mismatches(skel, grid, F, cap, rng):
    """Dense float64 classification vs the reference at centres with |F - 1| < 1e-4."""
    near = np.argwhere(np.abs(F - 1.0) < 1e-4)
    checked = len(near)
    if len(near) > cap:
        near = near[np.sort(rng.choice(len(near), cap, replace=False))]
    if len(near) == 0:
        return 0, 0
    k, j, i = near.T
    P = np.stack([grid.centres_x()[i], grid.centres_y()[j], grid.centres_z()[k]], axis=1)
    fr = reference_field(skel, P)
    f = F[k, j, i]
    bad = ((f >= 1.0) != (fr >= 1.0)) & (np.abs(fr - 1.0) > TOL)
    return int(bad.sum()), int(min(checked, cap))


def run_case(case: Case, fast: bool, seed: int = 0) -> dict:
    """Build and measure one case; returns a JSON-ready dict (see module docstring)."""
    rng = np.random.default_rng(seed)
    t_start = time.perf_counter()
    st = case.build(fast)
    row: dict = {"case": case.name, "what": case.what, "fast": fast}
    problems = []
    if st.refuse:
        refused = []
        for build, expect in st.refuse:
            try:
                build()
            except SceneError as exc:
                msg = str(exc)
                ok = all(e in msg for e in expect)
                refused.append({"message": machine.portable(msg), "ok": ok})
                if not ok:
                    problems.append(f"refused with an unexpected message: {msg}")
            else:
                refused.append({"message": None, "ok": False})
                problems.append("a degenerate scene was accepted")
        row["refused"] = refused
    skel = st.skel
    row["segments"] = skel.n_segments
    grid = make_grid(skel.support_bounds(), st.pixel_size, layer_height=st.layer_height, bounds=st.bounds)
    row["grid"] = [grid.width, grid.height, grid.layers]
    row["voxels"] = grid.n_voxels
    F = dense_field(skel, grid)
    row["inside_voxels"] = int(np.count_nonzero(F >= 1.0))
    # field error near the surface
    npts = 300 if fast else 3000
    pts = near_surface_points(skel, npts, rng, st.bounds)
    near = np.argwhere(np.abs(F - 1.0) < 0.5)
    if len(near):
        near = near[rng.choice(len(near), min(len(near), npts), replace=False)]
        k, j, i = near.T
        pts = np.concatenate([pts, np.stack([grid.centres_x()[i], grid.centres_y()[j],
                                             grid.centres_z()[k]], axis=1)])
    row["field"] = fe = field_error(skel, pts)
    if not fe["ok"]:
        problems.append(f"field error {fe['rel']:.2e} relative / {fe['abs_tiny']:.2e} absolute")
    # roots along columns
    pix, z, zr, slope = roots_along_columns(skel, grid, F, 40 if fast else 400, rng)
    good = np.abs(slope) * st.tau >= ROOT_SLOPE
    err = np.abs(z - zr)[good]
    row["roots"] = {"count": int(good.sum()), "ill_conditioned": int((~good).sum()),
                    "max_mm": float(err.max()) if len(err) else 0.0,
                    "max_tau": float(err.max() / st.tau) if len(err) else 0.0}
    try:
        sp = span_errors(skel, grid, pix[good], zr[good])
    except Exception as exc:  # the span API is new: report, do not hide, a failure
        sp = {"error": f"{type(exc).__name__}: {exc}"}
        problems.append(f"spans failed: {sp['error']}")
    row["spans"] = sp
    if sp and "max" in sp and not sp["max"] <= sp["span_tol"] * 1.0001 + 4 * np.spacing(np.abs(zr).max(initial=1.0)):
        problems.append(f"span end {sp['max']:.2e} mm from a reference root (tolerance {sp['span_tol']:.2e})")
    # voxels
    row["mismatch"] = {}
    row["runs_bad"] = {}
    row["example"] = {}
    row["seconds"] = {}
    row["evaluations"] = {}
    for m in METHODS:
        v = voxel_mismatches(skel, grid, F, m)
        row["mismatch"][m] = v["mismatch"]
        row["runs_bad"][m] = v["runs_bad"]
        row["seconds"][m] = v["seconds"]
        row["evaluations"][m] = v["evaluations"]
        if v["error"]:
            row["example"][m] = v["error"]
            problems.append(f"{m}: the tracer failed: {v['error']}")
            continue
        if v["mismatch"]:
            row["example"][m] = v["example"]
            problems.append(f"{m}: {v['mismatch']} voxel mismatches, e.g. {v['example']}")
        if v["runs_bad"]:
            problems.append(f"{m}: {v['runs_bad']} runs outside the grid's layers or out of order")
    nref, checked = reference_mismatches(skel, grid, F, 2000 if fast else 20000, rng)
    row["ref_mismatch"] = nref
    row["ref_checked"] = checked
    if nref:
        problems.append(f"{nref} near-surface voxels classified differently by the reference")
    row["problems"] = problems
    row["ok"] = not problems
    row["total_seconds"] = time.perf_counter() - t_start
    return row


def run_suite(names=None, fast=False, progress=None) -> list[dict]:
    """Run the named cases (all by default); ``progress(row)`` is called after each."""
    _warmup()
    rows = []
    for case in CASES:
        if names and case.name not in names:
            continue
        row = run_case(case, fast)
        rows.append(row)
        if progress:
            progress(row)
    return rows


# ----------------------------------------------------------------------------- report
HEADER = ("| case | voxels (inside) | field rel. err | root err (mm) | span err (mm) | "
          "mismatches int / samp / seg | ref mism. (checked) | time int / samp / seg (s) | ok |")
SEPARATOR = "|" + "---|" * (HEADER.count("|") - 1)


def format_row(r: dict) -> str:
    """One markdown table row (see HEADER) for a :func:`run_case` result."""
    sp = r.get("spans")
    if sp is None:
        span = "n/a"
    elif "error" in sp:
        span = "error"
    else:
        span = f"{sp['max']:.1e}"

    def cell(m):
        if r["mismatch"][m] < 0:
            return "crash"
        return str(r["mismatch"][m]) + (f" ({r['runs_bad'][m]} bad runs)" if r["runs_bad"][m] else "")

    mism = " / ".join(cell(m) for m in METHODS)
    secs = " / ".join(f"{r['seconds'][m]:.3f}" for m in METHODS)
    status = "yes" if r["ok"] else "**NO**"
    if r.get("refused"):
        status += f" ({sum(x['ok'] for x in r['refused'])}/{len(r['refused'])} refused)"
    return (f"| {r['case']} | {r['voxels']:,} ({r['inside_voxels']:,}) | {r['field']['rel']:.1e} | "
            f"{r['roots']['max_mm']:.1e} ({r['roots']['count']}) | {span} | {mism} | "
            f"{r['ref_mismatch']} ({r['ref_checked']}) | {secs} | {status} |")


def format_table(rows) -> str:
    return "\n".join([HEADER, SEPARATOR] + [format_row(r) for r in rows])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m validation.stiff", description=__doc__.split("\n")[0])
    ap.add_argument("--fast", action="store_true", help="small grids and fewer points (the test subset)")
    ap.add_argument("--json", metavar="FILE", help="write the measurements as JSON")
    ap.add_argument("--cases", nargs="+", choices=CASE_NAMES, metavar="NAME",
                    help=f"run only these cases ({', '.join(CASE_NAMES)})")
    args = ap.parse_args(argv)
    print(HEADER)
    print(SEPARATOR)
    t0 = time.perf_counter()
    rows = run_suite(args.cases, args.fast, progress=lambda r: print(format_row(r), flush=True))
    total = time.perf_counter() - t0
    bad = [r for r in rows if not r["ok"]]
    for r in bad:
        for p in r["problems"]:
            print(f"{r['case']}: {p}")
    print(f"{len(rows) - len(bad)}/{len(rows)} cases pass; {total:.1f} s")
    if args.json:
        with numba_threads(None) as threads:
            pass
        out = {"command": machine.command_line("python -m validation.stiff", argv),
               "machine": machine.describe(), "threads": threads, "seconds": total,
               "cases": rows}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        write_bytes(args.json, json.dumps(out, indent=1).encode(), force=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
