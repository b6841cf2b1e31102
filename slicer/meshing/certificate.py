"""The pieces of a mesh's certificate shared by the uniform and the compact mesh (docs/mesh.md).

:class:`MeshField` holds a skeleton's field with its support grid and counts the points
and balls it bounds; :func:`piece_distances` certifies the distance from triangles (or
pieces of them) to the surface, through :func:`enclosing_balls` and
:func:`distances_to_surface` (the argument is in :mod:`slicer.meshing.surface`'s
docstring, step 3); :class:`SurfaceMesh` is the result of both meshers.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import trimesh

from slicer._kernels.meshing.ballbounds import ball_bounds
from slicer.model.field import evaluate, point_grid
from slicer.model.skeleton import Skeleton


@dataclass
class SurfaceMesh:
    """A certified mesh of a lattice's surface (see :func:`mesh_scene`).

    Attributes
    ----------
    vertices : (v, 3) float64, mm
    faces : (t, 3) int64
        Counter-clockwise seen from outside (outward normals).
    tol : float, mm
        The tolerance asked for.
    bound : float, mm
        The certified two-sided Hausdorff distance between the mesh and the
        surface ``F = 1`` (inf when not certified).
    mesh_to_surface, surface_to_mesh : float, mm
        Its two sides.
    cell : float, mm
        Side ``h`` of the band's cubes.
    stats : dict
        Counts (band cubes, settled cubes, field evaluations), seconds, attempts.
    patches : list of ((p, 3) float64 mm, (q, 3) int64, (q,) float64 mm)
        Finer meshes (vertices, faces, the faces' bounds) where the cubes of side ``cell``
        could not be certified (a uniform mesh made for simplifying,
        :func:`slicer.meshing.surface.uniform_mesh`): every surface point is within
        ``surface_to_mesh`` of the mesh and these together. Empty for a mesh certified on its own.
    face_bounds : (t,) float64, mm, optional
        With patches: per face, a bound that holds for the surface points it serves: every
        surface point is within some face's bound of that face (of the mesh or of a patch).
        None: ``surface_to_mesh`` for every face. nan (a tile's mesh, :mod:`slicer.meshing.tiles`):
        the face serves none of the tile's surface points (its caps, the overlap round its box).
    """

    vertices: np.ndarray
    faces: np.ndarray
    tol: float
    bound: float
    mesh_to_surface: float
    surface_to_mesh: float
    cell: float
    stats: dict = field(default_factory=dict)
    patches: list = field(default_factory=list, repr=False)
    face_bounds: np.ndarray | None = field(default=None, repr=False)

    @property
    def certified(self) -> bool:
        """Whether ``bound <= tol``."""
        return bool(self.bound <= self.tol)

    def trimesh(self):
        """The mesh as a :class:`trimesh.Trimesh` (not processed: vertices and faces as they are)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


#: relative tolerance of :func:`straight_chains`' tests (collinear, radius continuing)
CHAIN_TOL = 1e-12


def straight_chains(skel: Skeleton) -> Skeleton:
    """The skeleton with each straight run of segments joined into one segment: the same field.

    The field is an integral over the skeleton (docs/math.md §1), so two segments
    that meet end to end, point in opposite directions from the shared node and
    have one linear radius along both (equal at the node, with the same rate of
    change) are one segment of the field. A lattice's struts that continue through
    a node become one line; the ball bounds of a line then hold its exact
    curvatures where no ball reaches its ends, and the end terms of the pieces at
    the node (which cancel in the field) are not counted (docs/math.md §11). Used
    for bounds only; the field's values come from the skeleton itself.

    Parameters
    ----------
    skel : Skeleton

    Returns
    -------
    Skeleton
        ``skel`` itself when nothing joins; otherwise the joined segments, then
        the others, over the same nodes.
    """
    seg, rad, nodes = skel.segments, skel.radii, skel.nodes
    vec = nodes[seg[:, 1]] - nodes[seg[:, 0]]
    length = np.linalg.norm(vec, axis=1)
    unit = vec / length[:, None]
    slope = (rad[:, 1] - rad[:, 0]) / length              # radius per mm along the segment
    partner = {}
    ends = {}
    for i in range(len(seg)):
        for e in (0, 1):
            ends.setdefault(int(seg[i, e]), []).append((i, e))
    for node, at in ends.items():
        for a in range(len(at)):
            i, e = at[a]
            if (i, e) in partner:
                continue
            di = unit[i] if e == 0 else -unit[i]                   # away from the node
            si = slope[i] if e == 0 else -slope[i]
            for b in range(a + 1, len(at)):
                j, f = at[b]
                if (j, f) in partner or j == i:
                    continue
                dj = unit[j] if f == 0 else -unit[j]
                sj = slope[j] if f == 0 else -slope[j]
                scale = float(max(rad[i, e], rad[j, f]))
                if (np.linalg.norm(np.cross(di, dj)) <= CHAIN_TOL and float(di @ dj) < 0.0
                        and abs(rad[i, e] - rad[j, f]) <= CHAIN_TOL * scale
                        and abs(si + sj) <= CHAIN_TOL * max(1.0, abs(si), abs(sj))):
                    partner[(i, e)] = (j, f)
                    partner[(j, f)] = (i, e)
                    break
    if not partner:
        return skel
    used = np.zeros(len(seg), bool)
    out_seg, out_rad = [], []
    for i in range(len(seg)):
        for e in (0, 1):
            if used[i] or (i, e) in partner:
                continue
            # a free end: walk the run from here
            start, r0 = int(seg[i, e]), float(rad[i, e])
            j, f = i, e
            while True:
                used[j] = True
                nxt = (j, 1 - f)
                if nxt not in partner:
                    break
                j, f = partner[nxt]
            out_seg.append((start, int(seg[j, 1 - f])))
            out_rad.append((r0, float(rad[j, 1 - f])))
    for i in np.flatnonzero(~used):       # (no free end: cannot happen for straight runs; kept as they are)
        out_seg.append(tuple(int(x) for x in seg[i]))
        out_rad.append(tuple(float(x) for x in rad[i]))
    return Skeleton(nodes, np.array(out_seg, np.int64), np.array(out_rad), degree=skel.degree, sigma=skel.sigma)


class MeshField:
    """The field of one skeleton, with the support grid of its straight runs
    (:func:`straight_chains`, for the ball bounds) and counters (kept right when tiles are
    meshed on several threads, :mod:`slicer.meshing.tiles`)."""

    def __init__(self, skel: Skeleton):
        self.skel = skel
        self.lines = straight_chains(skel)
        self.table, self.grid = point_grid(self.lines)
        self.points = 0
        self.balls = 0
        self._counting = threading.Lock()

    def _count(self, points: int = 0, balls: int = 0):
        with self._counting:
            self.points += points
            self.balls += balls

    def values(self, p: np.ndarray, gradient: bool = False):
        self._count(points=len(p))
        return evaluate(self.skel, p, gradient=gradient)

    def balls_bounds(self, centres: np.ndarray, radii: np.ndarray, normals: np.ndarray | None = None):
        """``(U, L, H, H_P)`` over the balls (:func:`slicer._kernels.meshing.ballbounds.ball_bounds`)."""
        self._count(balls=len(centres))
        g, s = self.grid, self.lines
        nu = np.zeros((len(centres), 3)) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
        return ball_bounds(self.table, g.offsets, g.ids, g.origin, g.cell, g.dims,
                           np.ascontiguousarray(centres, dtype=np.float64), np.ascontiguousarray(radii, np.float64),
                           nu, s.degree, s.sigma, s.normalisation)


def enclosing_balls(tri: np.ndarray):
    """Smallest balls holding triangles: centres (t, 3) and radii (t,), mm.

    For an acute triangle, its circumcircle; otherwise the ball on its
    longest edge.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        off = (np.cross(n, ab) * np.einsum("ij,ij->i", ac, ac)[:, None]
               + np.cross(ac, n) * np.einsum("ij,ij->i", ab, ab)[:, None]) / (2.0 * nn[:, None])
    centre = a + off
    radius = np.linalg.norm(off, axis=1)
    edges = np.stack([np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1), np.linalg.norm(a - b, axis=1)], 1)
    longest = edges.argmax(axis=1)
    e2 = edges**2
    big = e2[np.arange(len(tri)), longest]
    obtuse = ~(2.0 * big < e2.sum(axis=1)) | ~(nn > 0)
    mids = 0.5 * (tri[np.arange(len(tri)), (longest + 1) % 3] + tri[np.arange(len(tri)), (longest + 2) % 3])
    centre = np.where(obtuse[:, None], mids, centre)
    radius = np.where(obtuse, 0.5 * np.sqrt(big), radius)
    # rounding: the ball must hold all three corners
    radius = np.maximum(radius, np.linalg.norm(tri - centre[:, None, :], axis=2).max(axis=1)) * (1.0 + 1e-12)
    return centre, radius


#: how far along the gradient the surface is looked for, as fractions of the largest reach
REACH_STEPS = (0.0625, 0.125, 0.25, 0.5, 1.0)


def distances_to_surface(fld: MeshField, centres: np.ndarray, radii: np.ndarray, e: np.ndarray, g: np.ndarray,
               cap: float, cover: tuple[np.ndarray, float] | None = None,
               floor: np.ndarray | None = None) -> np.ndarray:
    """Certified distances from sets to the surface along the gradient (inf: not certified).

    Each set lies in the ball ``B(c, r)`` and has ``|F − 1| <= e`` (or the matching
    one-sided statement); ``g = ‖∇F(c)‖``. Within ``B(c, r + s)`` the slope along
    ``∇F(c)`` is at least ``g − H (r + s)``, so the surface (or the crossing) is within
    ``e / (g − H (r + s))`` of every point of the set when that is at most ``s``. The
    reach s is tried at each of :data:`REACH_STEPS` times ``cap`` (a smaller ball gives a
    smaller H), the first that certifies kept; ``cap`` is at most the thinnest strut's
    radius, beyond which the curvature bound only grows (a tolerance coarser than the
    struts is then certified at that scale).

    ``cover = (sub, ρ)``, sub (k, q, 3): the sets lie in the union of the balls ``B(sub, ρ)``
    (a cube in its eight half cubes' balls); the points within s of a set then lie in the
    balls ``B(sub, ρ + s)``, and H is the largest over those (smaller balls, tighter bounds);
    the slope still counts the distance ``r + s`` from c.

    ``floor`` (per set): H over a ball inside every ball tried (``B(c, r)``). The bounds grow
    with the ball, so a reach s where ``s (g − floor (r + s)) < e`` could not certify (the
    slope would be at most ``g − floor (r + s)``) and its balls are not bounded: fewer ball
    bounds (most uncertified pieces of a large triangle fail at every reach). Skipping can
    only leave a set uncertified, never certify one.
    """
    out = np.full(len(e), np.inf)
    todo = np.arange(len(e))
    cap = min(cap, float(fld.skel.radii.min()))
    for frac in REACH_STEPS:
        if not len(todo):
            break
        s = cap * frac
        if floor is not None:
            hope = s * (g[todo] - floor[todo] * (radii[todo] + s)) >= e[todo] * (1.0 - 1e-9)
            if not hope.all():
                wait = todo[~hope]
                todo = todo[hope]
                if not len(todo):
                    todo = wait
                    continue
            else:
                wait = todo[:0]
        if cover is None:
            _, _, H, _ = fld.balls_bounds(centres[todo], radii[todo] + s)
        else:
            sub, rho = cover
            q = sub.shape[1]
            H = fld.balls_bounds(sub[todo].reshape(-1, 3), np.full(len(todo) * q, rho + s))[2].reshape(-1, q).max(axis=1)
        slope = g[todo] - H * (radii[todo] + s)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where(slope > 0, e[todo] / slope, np.inf)
        ok = d <= s
        out[todo[ok]] = d[ok]
        todo = todo[~ok]
        if floor is not None and len(wait):
            todo = np.sort(np.concatenate([todo, wait]))
    return out


def piece_distances(fld: MeshField, tri: np.ndarray, tol: float, resid: np.ndarray | None = None) -> np.ndarray:
    """Certified distance from each triangle's points to the surface (module docstring,
    step 3, *mesh to surface*).

    Parameters
    ----------
    tri : (t, 3, 3) float64, mm
        Triangles (or pieces of triangles).
    tol : float, mm
        The largest distance looked for.
    resid : (t, 3) float64, optional
        ``|F − 1|`` at the corners, when already known.

    Returns
    -------
    (t,) float64, mm
        The bound, at most ``tol``; inf where not certified.
    """
    if resid is None:
        resid = np.abs(fld.values(tri.reshape(-1, 3))[0] - 1.0).reshape(-1, 3)
    m, R = enclosing_balls(tri)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1)
    n = np.where(ln[:, None] > 0, n / np.where(ln > 0, ln, 1.0)[:, None], 0.0)
    _, _, H, HP = fld.balls_bounds(m, R, n)
    e = (resid.max(axis=1) + 0.5 * HP * R * R) * (1.0 + 1e-9)
    _, g = fld.values(m, gradient=True)
    return distances_to_surface(fld, m, R, e, np.linalg.norm(g, axis=1), tol, floor=H)


__all__ = ["SurfaceMesh", "MeshField", "straight_chains", "enclosing_balls", "distances_to_surface", "piece_distances", "REACH_STEPS"]
