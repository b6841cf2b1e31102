"""Node bulge: how far the blended surface strays outside the designed beams at a node.

A node where ``valence`` struts of radius ``r`` and length ``L`` meet (12: the
directions to the vertices of a cuboctahedron, as in an FCC or octet node).
Rays leave the node in ``rays`` directions (a Fibonacci sphere); along each,
every crossing of ``F = 1`` within ``reach`` of the node is found (a sign
scan, then bisection to 1e-9 mm). The bulge of a crossing is its distance
outside the union of the designed beams (capsules of radius ``r``; 0 inside
one); the node's bulge is the largest. The same surface points give the
printed radius around each strut at ``1.5 r`` from the node.

``--blend sum`` (the paper's summation) adds the struts' fields, so near the
node the surface lies outside every strut's own; ``--blend union`` takes their
maximum, so every point of the surface is on some strut's own surface, which
lies inside its designed capsule.

Run: ``python -m validation.bulge [--valence 12] [--radius 0.5] [--length 5] [--json FILE]``
or ``skelslice bench bulge``.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from slicer.atomic import write_bytes
from slicer.model.field import evaluate
from slicer.model.skeleton import Skeleton

#: unit directions of a 12-valent node (the cuboctahedron's vertices)
CUBOCTAHEDRON = np.array([[a, b, 0] for a in (-1, 1) for b in (-1, 1)] + [[a, 0, b] for a in (-1, 1) for b in (-1, 1)]
                         + [[0, a, b] for a in (-1, 1) for b in (-1, 1)], dtype=np.float64) / np.sqrt(2.0)


def node(valence: int = 12, radius: float = 0.5, length: float = 5.0) -> Skeleton:
    """A node at the origin with ``valence`` struts (12: cuboctahedral; else Fibonacci directions)."""
    d = CUBOCTAHEDRON if valence == 12 else _fibonacci(valence)
    nodes = np.vstack([[0.0, 0.0, 0.0], length * d])
    segs = [[0, i + 1] for i in range(len(d))]
    return Skeleton(nodes, segs, np.full((len(d), 2), radius))


def _fibonacci(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def capsule_excess(skel: Skeleton, p: np.ndarray) -> np.ndarray:
    """Distance of points outside the union of the designed beams (round cones; 0 inside)."""
    a, b = skel.endpoints()
    d = b - a
    L2 = (d * d).sum(axis=1)
    t = np.clip(((p[:, None, :] - a[None]) * d[None]).sum(axis=2) / L2[None], 0.0, 1.0)
    foot = a[None] + t[..., None] * d[None]
    r = skel.radii[:, 0][None] + t * (skel.radii[:, 1] - skel.radii[:, 0])[None]
    excess = np.linalg.norm(p[:, None, :] - foot, axis=2) - r
    return np.maximum(excess.min(axis=1), 0.0)


def surface_points(skel: Skeleton, blend: str, reach: float, rays: int = 4000, steps: int = 400) -> np.ndarray:
    """Every crossing of ``F = 1`` within ``reach`` of the origin along ``rays`` directions."""
    u = _fibonacci(rays)
    s = np.linspace(0.0, reach, steps + 1)
    pts = (s[None, :, None] * u[:, None, :]).reshape(-1, 3)
    g = (evaluate(skel, pts, blend=blend)[0] - 1.0).reshape(rays, steps + 1)
    ri, si = np.nonzero((g[:, :-1] >= 0) != (g[:, 1:] >= 0))
    lo, hi = s[si], s[si + 1]
    glo = g[ri, si]
    dirs = u[ri]
    for _ in range(60):                                 # bisection: below 1e-9 mm for reach ~ mm
        mid = 0.5 * (lo + hi)
        gm = evaluate(skel, mid[:, None] * dirs, blend=blend)[0] - 1.0
        same = (gm >= 0) == (glo >= 0)
        lo, glo = np.where(same, mid, lo), np.where(same, gm, glo)
        hi = np.where(same, hi, mid)
    return 0.5 * (lo + hi)[:, None] * dirs


def bulge(valence: int = 12, radius: float = 0.5, length: float = 5.0, rays: int = 4000) -> list[dict]:
    """The node bulge of each blend (see the module docstring).

    Returns
    -------
    list of dict
        Per blend: ``blend``, ``bulge_mm``, ``bulge_over_radius``, ``radius_near_node_mm`` (median
        distance of the surface from the nearest strut's axis, for surface points 1.5 r from the
        node along that strut, within 0.05 r),
        ``points`` (surface points found).
    """
    skel = node(valence, radius, length)
    reach = 3.0 * radius + radius / np.sin(np.pi / 6)      # the node region, clear of the struts' far ends
    out = []
    for blend in ("sum", "union"):
        p = surface_points(skel, blend, reach, rays)
        ex = capsule_excess(skel, p)
        a, b = skel.endpoints()
        d = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
        along = p @ d.T                                     # (k, struts): distance along each strut's axis
        radial = np.sqrt(np.maximum((p * p).sum(axis=1)[:, None] - along ** 2, 0.0))
        own = np.argmin(radial, axis=1)                     # the strut each point is around
        k = np.arange(p.shape[0])
        near = np.abs(along[k, own] - 1.5 * radius) < 0.05 * radius
        out.append({"blend": blend, "bulge_mm": float(ex.max()), "bulge_over_radius": float(ex.max() / radius),
                    "radius_near_node_mm": float(np.median(radial[k, own][near])) if near.any() else float("nan"),
                    "points": int(p.shape[0])})
    return out


def format_table(rows: list[dict], valence: int, radius: float) -> str:
    head = f"node of valence {valence}, strut radius {radius:g} mm"
    lines = [head, f"{'blend':<7}{'bulge mm':>11}{'bulge / r':>11}{'radius at 1.5 r':>17}{'points':>8}",
             "-" * 54]
    for r in rows:
        lines.append(f"{r['blend']:<7}{r['bulge_mm']:>11.4f}{r['bulge_over_radius']:>11.3f}"
                     f"{r['radius_near_node_mm']:>17.4f}{r['points']:>8}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--valence", type=int, default=12)
    ap.add_argument("--radius", type=float, default=0.5)
    ap.add_argument("--length", type=float, default=5.0)
    ap.add_argument("--rays", type=int, default=4000)
    ap.add_argument("--json", default=None, help="Write the rows here.")
    a = ap.parse_args(argv)
    rows = bulge(a.valence, a.radius, a.length, a.rays)
    print(format_table(rows, a.valence, a.radius))
    if a.json:
        write_bytes(a.json, (json.dumps(rows, indent=1) + "\n").encode(), force=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
