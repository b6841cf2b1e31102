"""Artistic jellyfish: 154 tapered segments, about 40 mm tall.

Mirrors the size of the artistic benchmark model of the seed paper (154
segments). Procedural and deterministic:

* bell: a dome of 12 meridians, each cut into 3 segments from the apex to the
  rim, joined by 3 rings of 12 segments (72 segments);
* 12 wavy tentacles of 6 segments hanging from the rim nodes, tapering from
  the bell radius to 0.3 mm at the tips (72 segments);
* a manubrium of 2 segments hanging from the apex inside the bell, and 4
  short curled oral arms of 2 segments each below it (10 segments).

All segments meet at shared nodes; every node radius is >= 0.3 mm and every
segment is several radii long, so no part is too thin to have a surface.
Coordinates and radii are rounded to 1e-6 mm so the model is bit-identical
across platforms.
"""
from __future__ import annotations

import numpy as np

from slicer.model.skeleton import Skeleton

N_MERIDIANS = 12
N_BANDS = 3            # segments per meridian (and number of rings)
N_TENTACLE_SEGS = 6
N_ORAL_ARMS = 4
TOP_Z = 40.0           # mm, apex of the bell
BELL_RADIUS = 12.0     # mm, rim radius before flaring
BELL_HEIGHT = 10.0     # mm
R_BELL = 0.7           # mm
R_APEX = 0.55          # mm
R_TIP = 0.3            # mm


class _Builder:
    """Collects nodes (with their radius) and segments between node indices."""

    def __init__(self) -> None:
        self.points: list[tuple[float, float, float]] = []
        self.node_radius: list[float] = []
        self.segments: list[tuple[int, int]] = []

    def node(self, p, r: float) -> int:
        self.points.append(tuple(float(c) for c in p))
        self.node_radius.append(float(r))
        return len(self.points) - 1

    def chain(self, ids) -> None:
        self.segments.extend(zip(ids[:-1], ids[1:]))

    def skeleton(self) -> Skeleton:
        nodes = np.round(np.array(self.points), 6)
        r = np.round(np.array(self.node_radius), 6)
        seg = np.array(self.segments, dtype=np.int64)
        return Skeleton(nodes, seg, r[seg])


def _bell(b: _Builder) -> tuple[int, list[int]]:
    """Dome of meridians and rings; returns the apex id and the rim ids."""
    apex = b.node((0.0, 0.0, TOP_Z), R_APEX)
    phi = 2 * np.pi * np.arange(N_MERIDIANS) / N_MERIDIANS
    rings = []
    for k in range(1, N_BANDS + 1):
        s = k / N_BANDS
        rho = BELL_RADIUS * np.sin(s * np.pi / 2) * (1.0 + 0.12 * s**3)   # slight flare at the rim
        z = TOP_Z - BELL_HEIGHT * (1.0 - np.cos(s * np.pi / 2))
        r = R_APEX + (R_BELL - R_APEX) * s
        rings.append([b.node((rho * np.cos(a), rho * np.sin(a), z), r) for a in phi])
    for i in range(N_MERIDIANS):
        b.chain([apex] + [ring[i] for ring in rings])
    for ring in rings:
        b.chain(ring + ring[:1])
    return apex, rings[-1]


def _tentacles(b: _Builder, rim: list[int]) -> None:
    """Wavy tentacles hanging from the rim nodes, tapering to R_TIP."""
    for i, start in enumerate(rim):
        x0, y0, z0 = b.points[start]
        phi = np.arctan2(y0, x0)
        radial = np.array([np.cos(phi), np.sin(phi), 0.0])
        tangent = np.array([-np.sin(phi), np.cos(phi), 0.0])
        length = 24.0 + 4.0 * ((i * 5) % 3) / 2.0           # 24, 26 or 28 mm, deterministic
        phase = 0.9 * i
        ids = [start]
        for k in range(1, N_TENTACLE_SEGS + 1):
            s = k / N_TENTACLE_SEGS
            rho = np.hypot(x0, y0) * (1.0 - 0.3 * s)
            wave = 2.0 * s * np.sin(2.5 * np.pi * s + phase)
            p = rho * radial + wave * tangent + np.array([0.0, 0.0, z0 - length * s])
            ids.append(b.node(p, R_BELL + (R_TIP - R_BELL) * s))
        b.chain(ids)


def _mouth(b: _Builder, apex: int) -> None:
    """Manubrium from the apex and short curled oral arms below it."""
    mid = b.node((0.0, 0.0, TOP_Z - 4.5), 0.65)
    hub = b.node((0.0, 0.0, TOP_Z - 9.0), 0.65)
    b.chain([apex, mid, hub])
    for j in range(N_ORAL_ARMS):
        a = 2 * np.pi * (j + 0.5) / N_ORAL_ARMS
        d = np.array([np.cos(a), np.sin(a), 0.0])
        t = np.array([-np.sin(a), np.cos(a), 0.0])
        p1 = 2.5 * d + 0.8 * t + np.array([0.0, 0.0, TOP_Z - 13.0])
        p2 = 3.0 * d + 2.2 * t + np.array([0.0, 0.0, TOP_Z - 17.0])
        b.chain([hub, b.node(p1, 0.5), b.node(p2, 0.35)])


def build() -> Skeleton:
    """The jellyfish model.

    Returns
    -------
    Skeleton
        154 segments, nodes within about 40 mm in z (z from about 2 to 40 mm),
        radii 0.3 to 0.7 mm.
    """
    b = _Builder()
    apex, rim = _bell(b)
    _tentacles(b, rim)
    _mouth(b, apex)
    return b.skeleton()
