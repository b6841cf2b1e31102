"""Struts too thin to print, named by segment, from the exact field.

The printed width of segment i is measured on the surface itself, away
from its nodes: from points of its axis (the middle, and the quarter points
where they lie at least one local radius from both ends), the distance to
the first crossing of ``F = 1`` is found by marching outward (steps of an
eighth of the local radius) and bisecting the bracket, along 12 directions
perpendicular to the axis; the width at a point is the smallest sum over
opposite directions (6 diameters), and the segment's width the smallest
over its points. A point of the axis that is outside the solid has width 0
(the strut is broken there).

Since the field is a sum (or, with ``blend="union"``, the maximum) of
non-negative terms, blending only widens a strut: a segment whose own radius is well above the threshold and that is
long enough for its middle to be a full cylinder (``2 tau_min >= 1.5 x
threshold`` and ``L >= 4 tau_max``) is not measured. Widths are also
compared with ``2 tau`` (the radius-based width, reported beside).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer.model.field import evaluate
from slicer.model.skeleton import Skeleton
from slicer.printability.stream import rounded

#: perpendicular directions per axis point (pairs make diameters)
DIRECTIONS = 12
#: march step, in local radii; march reach, in local radii
STEP, REACH = 1.0 / 8.0, 4.0
#: bisection steps (bracket shrinks to STEP / 2**BISECT radii)
BISECT = 24
#: points per batch of field evaluations
BATCH = 200_000


@dataclass(frozen=True)
class ThinSegment:
    """A segment whose printed width is below the threshold.

    Attributes
    ----------
    segment : int
        Index in the scene's segment list.
    width : float, mm
        Printed width (0: the axis is outside the solid).
    radius_width : float, mm
        ``2 tau`` at the segment's middle.
    threshold : float, mm
    x, y, z : float, mm
        Middle of the segment (in the stack's coordinates).
    layer : int
        Layer of the middle (may lie outside the stack for a strut that does not print).
    """

    segment: int
    width: float
    radius_width: float
    threshold: float
    x: float
    y: float
    z: float
    layer: int

    def to_dict(self) -> dict:
        return {"segment": self.segment, "width": rounded(self.width), "radius_width": rounded(self.radius_width),
                "threshold": rounded(self.threshold), "x": rounded(self.x), "y": rounded(self.y), "z": rounded(self.z),
                "layer": self.layer}


def printed_widths(skel: Skeleton, segments: np.ndarray | None = None, blend: str = "sum") -> np.ndarray:
    """Printed width of segments from the exact field (see the module docstring).

    Parameters
    ----------
    skel : Skeleton
    segments : (s,) int64, optional
        Which segments (default: all).
    blend : {"sum", "union"}
        The field the solid is (:mod:`slicer.model.blend`).

    Returns
    -------
    (s,) float64, mm
    """
    ids = np.arange(skel.n_segments) if segments is None else np.asarray(segments, dtype=np.int64)
    out = np.full(ids.shape[0], np.inf)
    if not ids.size:
        return out
    a, b = skel.endpoints()
    a, b = a[ids], b[ids]
    r0, r1 = skel.radii[ids, 0], skel.radii[ids, 1]
    axis = b - a
    length = np.linalg.norm(axis, axis=1)
    u = axis / length[:, None]
    e1, e2 = _frame(u)
    theta = np.arange(DIRECTIONS) * (2.0 * np.pi / DIRECTIONS)
    dirs = np.cos(theta)[None, :, None] * e1[:, None, :] + np.sin(theta)[None, :, None] * e2[:, None, :]
    for t in (0.5, 0.25, 0.75):
        tau = r0 + t * (r1 - r0)
        use = np.ones(ids.shape[0], bool) if t == 0.5 else (np.minimum(t, 1 - t) * length >= tau)
        if not use.any():
            continue
        centre = a[use] + t * axis[use]
        w = _widths_at(skel, centre, dirs[use], tau[use], blend)
        out[use] = np.minimum(out[use], w)
    return out


def _frame(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each unit vector of ``u`` (and to each other)."""
    pick = np.where(np.abs(u[:, 0:1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(u, pick)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return e1, np.cross(u, e1)


def _field(skel: Skeleton, pts: np.ndarray, blend: str = "sum") -> np.ndarray:
    flat = pts.reshape(-1, 3)
    out = np.empty(flat.shape[0])
    for s in range(0, flat.shape[0], BATCH):
        out[s:s + BATCH] = evaluate(skel, flat[s:s + BATCH], blend=blend)[0]
    return out.reshape(pts.shape[:-1])


def _widths_at(skel: Skeleton, centre: np.ndarray, dirs: np.ndarray, tau: np.ndarray,
               blend: str = "sum") -> np.ndarray:
    """Smallest diameter of the solid's section through ``centre`` (perpendicular to the axis)."""
    inside = _field(skel, centre, blend) >= 1.0
    steps = np.arange(1, int(REACH / STEP) + 1) * STEP                 # (M,), in radii
    s = steps[None, None, :] * tau[:, None, None]                      # (n, D, M) mm
    pts = centre[:, None, None, :] + s[..., None] * dirs[:, :, None, :]
    f = _field(skel, pts, blend)
    out_mask = f < 1.0
    first = np.where(out_mask.any(axis=2), np.argmax(out_mask, axis=2), -1)   # first step outside
    lo = np.where(first > 0, np.take_along_axis(s, np.maximum(first - 1, 0)[..., None], 2)[..., 0], 0.0)
    hi = np.where(first >= 0, np.take_along_axis(s, np.maximum(first, 0)[..., None], 2)[..., 0], np.inf)
    found = first >= 0
    for _ in range(BISECT):
        mid = 0.5 * (lo + hi)
        if not found.any():
            break
        fm = np.ones_like(mid)
        fm[found] = _field(skel, centre[np.nonzero(found)[0]] + mid[found][:, None] * dirs[found], blend)
        ins = fm >= 1.0
        lo = np.where(found & ins, mid, lo)
        hi = np.where(found & ~ins, mid, hi)
    reach = np.where(found, 0.5 * (lo + hi), REACH * tau[:, None])     # never outside: at least the reach
    half = DIRECTIONS // 2
    diam = reach[:, :half] + reach[:, half:]
    width = diam.min(axis=1)
    width[~inside] = 0.0
    return width


def thin_segments(skel: Skeleton, threshold: float, offset=(0.0, 0.0, 0.0), layer_of=None,
                  blend: str = "sum") -> list[ThinSegment]:
    """Segments whose printed width is below ``threshold`` mm.

    Parameters
    ----------
    skel : Skeleton
    threshold : float, mm
        Usually the larger of the pixel pitch and the minimum feature size.
    offset : (3,) float, mm
        Added to the reported positions (scene to plate coordinates).
    layer_of : callable, optional
        Height (stack mm) to layer index.
    blend : {"sum", "union"}
        The field the solid is (:mod:`slicer.model.blend`).

    Returns
    -------
    list of ThinSegment
        In segment order.
    """
    if skel.n_segments == 0:
        return []
    r = skel.radii
    a, b = skel.endpoints()
    length = np.linalg.norm(b - a, axis=1)
    safe = (2.0 * r.min(axis=1) >= 1.5 * threshold) & (length >= 4.0 * r.max(axis=1))
    cand = np.nonzero(~safe)[0]
    widths = printed_widths(skel, cand, blend)
    off = np.asarray(offset, dtype=np.float64)
    out = []
    for i, w in zip(cand, widths):
        if not w < threshold:
            continue
        mid = 0.5 * (a[i] + b[i]) + off
        out.append(ThinSegment(int(i), float(w), float(r[i].sum()), float(threshold), float(mid[0]), float(mid[1]),
                               float(mid[2]), int(layer_of(mid[2])) if layer_of is not None else -1))
    return out


__all__ = ["ThinSegment", "printed_widths", "thin_segments", "DIRECTIONS"]
