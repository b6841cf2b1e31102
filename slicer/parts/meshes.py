"""Triangle meshes of parts: reading, checking, placing.

A :class:`Mesh` is a closed, consistently oriented triangle mesh in mm whose
faces point outward. It is checked once, when it is built
(:func:`make_mesh`), and everything downstream trusts it. A mesh that is not
a solid's boundary is refused with :class:`~slicer.errors.SceneError`
naming the mesh and every problem found, with counts and an example::

    shell.stl: not a closed solid (1,204 faces): 6 open edges (used by one face only; e.g. between
    vertices 17 and 18 at [10, 0, 5] and [10, 1, 5] mm); fix the mesh in a mesh editor

Checks (all exact where it matters: collinearity and intersections use exact
orientation predicates, :mod:`slicer.parts.mesh_intersect`):

* every coordinate finite, every index in range, at least 4 faces;
* no degenerate face (two equal corners, or three collinear ones);
* closed and manifold: every edge used by exactly two faces, in opposite
  directions (consistent orientation), and no vertex where the surface
  touches itself (a "pinched" vertex whose faces form several fans);
* positive volume (normals point outward; an inside-out mesh would carve a
  void or print nothing);
* no self-intersection, except in 3MF files: the 3MF core specification
  says consumers must accept self-intersecting meshes and overlapping
  objects and fill them by the positive fill rule, which the slicer applies
  (:mod:`slicer.parts.mesh_slicing`).

Reading: STL, OBJ and PLY through trimesh (``process=False``: nothing is
merged, moved or dropped by tolerance); coincident vertices (bit-equal
coordinates) are merged, which an STL needs to have any connectivity.
Meshes carry no unit: the caller gives the scale to mm. 3MF mesh objects are
read by :mod:`slicer.scene.threemf`, with the file's unit (:func:`slicer.parts.part.read_meshes`
reads either kind).

``repair=True`` fixes only what can be fixed without guessing geometry, and
says what it changed: faces with a repeated corner are dropped, and faces are
re-oriented consistently and outward. Open, non-manifold, degenerate or
self-intersecting meshes stay refused.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slicer.arguments import fmt_num
from slicer.errors import SceneError
from slicer.input_limits import check_mesh_header
from slicer.parts.mesh_intersect import collinear, self_intersections

#: mesh file suffixes read through trimesh
MESH_SUFFIXES = (".stl", ".obj", ".ply")
#: face pairs listed in a self-intersection message
_EXAMPLES = 3


@dataclass(frozen=True, eq=False)
class Mesh:
    """A closed, outward-oriented triangle mesh (see :func:`make_mesh`).

    Attributes
    ----------
    vertices : (n, 3) float64, mm
    faces : (m, 3) int64
        Corners counter-clockwise seen from outside.
    name : str
        How messages name it (``"shell.stl"``, ``"part.3mf, object 1 'cage'"``).
    notes : tuple of str
        What a repair changed.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str
    notes: tuple[str, ...] = field(default=())

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def triangles(self) -> np.ndarray:
        """(m, 3, 3) float64, mm: the corners of every face."""
        return self.vertices[self.faces]

    def bounds(self) -> np.ndarray:
        """(2, 3) float64, mm: ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` of the vertices used."""
        v = self.vertices[np.unique(self.faces)]
        return np.array([v.min(axis=0), v.max(axis=0)])

    def volume(self) -> float:
        """Enclosed volume, mm^3 (> 0 for a checked mesh)."""
        return signed_volume(self.vertices, self.faces)

    def area(self) -> float:
        """Surface area, mm^2."""
        t = self.triangles()
        return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())

    def transformed(self, matrix, name: str | None = None) -> "Mesh":
        """The mesh moved by an affine map (faces reversed by a mirror).

        Parameters
        ----------
        matrix : (4, 4) or (3, 4) float64
            Acts on column vectors: ``p' = A p + t``, ``A = matrix[:3, :3]``,
            ``t = matrix[:3, 3]`` (mm).
        """
        A, t = _affine(matrix, self.name)
        v = self.vertices @ A.T + t
        f = self.faces[:, ::-1] if np.linalg.det(A) < 0 else self.faces
        return Mesh(np.ascontiguousarray(v), np.ascontiguousarray(f), name or self.name, self.notes)


def _affine(matrix, name: str) -> tuple[np.ndarray, np.ndarray]:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(m)):
        raise SceneError(f"{name}: a transform must be a finite 3 x 4 or 4 x 4 matrix, got shape {m.shape}")
    if m.shape == (4, 4) and not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise SceneError(f"{name}: the last row of a 4 x 4 transform must be [0, 0, 0, 1], got {m[3].tolist()}")
    A, t = m[:3, :3], m[:3, 3]
    if not abs(np.linalg.det(A)) > 0:
        raise SceneError(f"{name}: the transform is singular (it flattens the mesh)")
    return A, t


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by oriented faces, mm^3 (positive: normals outward)."""
    if faces.shape[0] == 0:
        return 0.0
    c = vertices[faces].reshape(-1, 3).mean(axis=0)
    t = vertices[faces] - c
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


# ----------------------------------------------------------------------------- checks
@dataclass
class MeshReport:
    """What :func:`mesh_problems` found (counts, and an example of each)."""

    faces: int = 0
    vertices: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _n(count: int, word: str, plural: str | None = None) -> str:
    """``1 open edge``, ``3 open edges``."""
    return f"{count:,} {word if count == 1 else (plural or word + 's')}"


def _at(vertices: np.ndarray, i: int) -> str:
    return "[" + ", ".join(fmt_num(float(x)) for x in vertices[i]) + "]"


def _edges(faces: np.ndarray):
    """Directed edges ``e`` (3m, 2) (edge k belongs to face ``k % m``), the index of each
    one's undirected edge, and the use count of every undirected edge."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    n = int(faces.max()) + 1 if faces.size else 0
    _, inv, cnt = np.unique(lo * n + hi, return_inverse=True, return_counts=True)
    return e, inv.reshape(-1), cnt


def twin_corners(faces: np.ndarray) -> np.ndarray:
    """For each corner ``3 f + c`` (the half-edge from ``faces[f, c]`` to the next corner's vertex),
    the corner where the half-edge running the other way starts (-1: none).

    Parameters
    ----------
    faces : (m, 3) int64

    Returns
    -------
    (3 m,) int64
        ``twin_corners(faces) // 3`` is the face across each edge (where it is not -1).
    """
    if not len(faces):
        return np.zeros(0, np.int64)
    n = int(faces.max()) + 1
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()                     # the next corner's vertex
    key = a * n + b                                     # half-edge a -> b, keyed at its start corner
    order = np.argsort(key)
    want = b * n + a
    j = np.minimum(np.searchsorted(key[order], want), len(key) - 1)
    return np.where(key[order][j] == want, order[j], -1).astype(np.int64)


def _pinched(faces: np.ndarray, twin: np.ndarray | None = None) -> np.ndarray:
    """Vertices whose faces form more than one fan (the surface touches itself there).

    Assumes every edge is used twice in opposite directions; ``twin`` (3m,), if
    given, is the directed edge running the other way of each of :func:`_edges`'
    (edge ``c m + f`` runs from ``faces[f, c]`` to the next corner). Corner ``(f, c)``
    (vertex ``v = faces[f, c]``) is followed, around ``v``, by the corner of
    ``v`` in the face across the edge ``v -> faces[f, c + 1]``; the cycles of
    this permutation are the fans.
    """
    m = faces.shape[0]
    n = int(faces.max()) + 1
    a = faces.ravel()                                   # corner 3f + c: vertex faces[f, c]
    if twin is None:
        # for corner (f, c) the twin half-edge is b -> a; its start corner is b's corner in face g,
        # and v's corner there is the next one
        g_corner = twin_corners(faces)
    else:                                               # twin of _edges' directed edge c m + f
        t = twin.reshape(3, m).T.ravel()                # ... of corner 3f + c
        g_corner = 3 * (t % m) + t // m
    nxt = (g_corner // 3) * 3 + (g_corner % 3 + 1) % 3
    lab = np.arange(3 * m)
    p = nxt
    for _ in range(int(np.ceil(np.log2(3 * m + 1))) + 1):
        new = np.minimum(lab, lab[p])
        if np.array_equal(new, lab):                    # constant on every cycle: each fan has its minimum
            break
        lab, p = new, p[p]
    count = np.bincount(a[lab == np.arange(3 * m)], minlength=n)   # a fan's least corner is its label
    return np.flatnonzero(count > 1)


def mesh_problems(vertices: np.ndarray, faces: np.ndarray, check_self_intersections: bool = True) -> MeshReport:
    """Every problem that keeps a triangle mesh from bounding a solid.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    check_self_intersections : bool
        Also look for faces that cross or touch (exact; skipped for 3MF, whose
        fill rule accepts them).

    Returns
    -------
    MeshReport
        ``problems`` is empty for a valid mesh; each entry names a problem
        with its count and an example (vertex indices, coordinates).
    """
    rep = MeshReport(int(faces.shape[0]), int(vertices.shape[0]))
    out = rep.problems
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        out.append(f"{_n(int(bad.sum()), 'vertex', 'vertices')} with non-finite coordinates (e.g. vertex {i}: "
                   f"{vertices[i].tolist()})")
        return rep
    if faces.shape[0] < 4:
        out.append(f"only {faces.shape[0]} faces; a closed surface needs at least 4")
        return rep
    oob = (faces < 0) | (faces >= vertices.shape[0])
    if oob.any():
        f, c = (int(x) for x in np.argwhere(oob)[0])
        out.append(f"{_n(int(oob.any(axis=1).sum()), 'face')} refer to vertices that do not exist (e.g. face {f} "
                   f"corner {c} = {int(faces[f, c])}; there are {vertices.shape[0]:,} vertices)")
        return rep
    rep_corner = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    tri = vertices[faces]
    flat = ~rep_corner & collinear(tri[:, 0], tri[:, 1], tri[:, 2])
    if rep_corner.any():
        i = int(np.flatnonzero(rep_corner)[0])
        out.append(f"{_n(int(rep_corner.sum()), 'degenerate face')} with a repeated corner (e.g. face {i}: "
                   f"vertices {faces[i].tolist()})")
    if flat.any():
        i = int(np.flatnonzero(flat)[0])
        out.append(f"{_n(int(flat.sum()), 'degenerate face')} of zero area (three corners on a line; e.g. face {i} "
                   f"at {_at(vertices, faces[i, 0])}, {_at(vertices, faces[i, 1])}, {_at(vertices, faces[i, 2])} mm)")
    e, inv, cnt = _edges(faces[~rep_corner])
    edge_ok = True
    for what, why, mask in (("open edge", "used by one face only", cnt == 1),
                            ("non-manifold edge", "shared by more than two faces", cnt > 2)):
        if mask.any():
            edge_ok = False
            k = int(np.flatnonzero(mask[inv])[0])
            a, b = (int(x) for x in e[k])
            out.append(f"{_n(int(mask.sum()), what)} ({why}); e.g. between vertices {a} and {b} at "
                       f"{_at(vertices, a)} and {_at(vertices, b)} mm")
    two, twin = cnt == 2, None
    if two.any():
        # a pair of uses of one edge must run in opposite directions
        sel = np.flatnonzero(two[inv])
        order = sel[np.argsort(inv[sel], kind="stable")]
        first, second = order[0::2], order[1::2]
        same = e[first, 0] == e[second, 0]
        if sel.size == e.shape[0]:                      # every edge used twice: each one's twin
            twin = np.empty(e.shape[0], np.int64)
            twin[first], twin[second] = second, first
        if same.any():
            edge_ok = False
            k = int(first[np.flatnonzero(same)[0]])
            a, b = (int(x) for x in e[k])
            out.append(f"{_n(int(same.sum()), 'edge')} where the faces' orientations disagree (the mesh is not "
                       f"consistently oriented; e.g. edge {a}-{b} at {_at(vertices, a)} mm)")
    if edge_ok and not rep_corner.any():
        pinch = _pinched(faces, twin)
        if pinch.size:
            i = int(pinch[0])
            out.append(f"{_n(int(pinch.size), 'non-manifold vertex', 'non-manifold vertices')} where the surface "
                       f"touches itself (e.g. vertex {i} "
                       f"at {_at(vertices, i)} mm)")
    if out:
        return rep
    vol = signed_volume(vertices, faces)
    if not vol > 0:
        out.append(f"the volume is {fmt_num(vol)} mm^3: the mesh is inside out (its faces point inward)"
                   if vol < 0 else "the volume is zero")
        return rep
    if check_self_intersections:
        count, ex = self_intersections(vertices, faces, limit=_EXAMPLES)
        if count:
            shown = ", ".join(f"{a} and {b}" for a, b in ex)
            out.append(f"{_n(count, 'pair')} of faces intersect or touch (e.g. faces {shown})")
    return rep


def make_mesh(vertices, faces, name: str, *, check_self_intersections: bool = True, repair: bool = False) -> Mesh:
    """A checked :class:`Mesh` (see the module docstring for the checks).

    Parameters
    ----------
    vertices : (n, 3) array-like, mm
    faces : (m, 3) array-like of int
    name : str
        Used in messages.
    check_self_intersections : bool
        False for 3MF meshes (positive fill rule).
    repair : bool
        Drop faces with a repeated corner, orient the faces consistently and
        outward; every change is listed in ``Mesh.notes``.

    Raises
    ------
    SceneError
        Naming the mesh and every problem found.
    """
    try:
        v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64).reshape(-1, 3))
        f = np.asarray(faces)
        if f.size == 0:
            f = f.reshape(0, 3)
        if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
            raise ValueError(f"faces must be (m, 3) integers, got shape {f.shape}, dtype {f.dtype}")
        f = np.ascontiguousarray(f, dtype=np.int64)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{name}: not a triangle mesh ({exc})") from None
    notes: list[str] = []
    if repair:
        f, notes = _repair(v, f, name)
    rep = mesh_problems(v, f, check_self_intersections)
    if not rep.ok:
        hint = ("; --repair does not fix these" if repair else
                "; try --repair (it drops faces with a repeated corner and re-orients faces) or fix the mesh"
                if _repairable(rep) else "; fix the mesh in a mesh editor")
        raise SceneError(f"{name}: not a closed solid ({rep.faces:,} faces): " + "; ".join(rep.problems) + hint)
    seen = np.zeros(v.shape[0], bool)
    seen[f.ravel()] = True
    used = np.flatnonzero(seen)                           # np.unique(f), without sorting
    if used.size != v.shape[0]:           # drop unused vertices: bounds and volume see only the surface
        remap = np.full(v.shape[0], -1, np.int64)
        remap[used] = np.arange(used.size)
        v, f = np.ascontiguousarray(v[used]), remap[f]
    for a in (v, f):
        a.setflags(write=False)
    return Mesh(v, f, name, tuple(notes))


def _repairable(rep: MeshReport) -> bool:
    return all(("repeated corner" in p or "orientations disagree" in p or "inside out" in p) for p in rep.problems)


def _repair(v: np.ndarray, f: np.ndarray, name: str) -> tuple[np.ndarray, list[str]]:
    notes = []
    rep_corner = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    if rep_corner.any():
        f = f[~rep_corner]
        notes.append(f"{name}: dropped {_n(int(rep_corner.sum()), 'face')} with a repeated corner")
    if f.shape[0] == 0:
        return f, notes
    e, inv, cnt = _edges(f)
    if np.all(cnt == 2):
        g, flip = _orient(f, e, inv)
        if np.all(np.isfinite(v)) and signed_volume(v, g) < 0:
            g, flip = g[:, ::-1].copy(), ~flip
        if flip.all():
            notes.append(f"{name}: reversed all {_n(f.shape[0], 'face')} (the mesh was inside out)")
        elif flip.any():
            notes.append(f"{name}: reversed {_n(int(flip.sum()), 'face')} to orient the mesh consistently "
                         f"and outward")
        f = g
    return f, notes


def _orient(f: np.ndarray, e: np.ndarray, inv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flip faces so that every shared edge runs both ways; each connected shell is
    oriented like its lowest face. Returns the faces and which were flipped."""
    m = f.shape[0]
    face_of = np.arange(3 * m) % m
    order = np.argsort(inv, kind="stable")
    a, b = order[0::2], order[1::2]                       # the two uses of each edge
    fa, fb = face_of[a], face_of[b]
    same = e[a, 0] == e[b, 0]                             # both faces run the edge the same way
    nbr = [[] for _ in range(m)]
    for x, y, s in zip(fa.tolist(), fb.tolist(), same.tolist()):
        nbr[x].append((y, s))
        nbr[y].append((x, s))
    flip = np.zeros(m, bool)
    seen = np.zeros(m, bool)
    for root in range(m):
        if seen[root]:
            continue
        seen[root] = True
        stack = [root]
        while stack:
            x = stack.pop()
            for y, s in nbr[x]:
                if not seen[y]:
                    seen[y] = True
                    flip[y] = flip[x] ^ s
                    stack.append(y)
    out = f.copy()
    out[flip] = out[flip][:, ::-1]
    return out, flip


# ----------------------------------------------------------------------------- reading
def merge_coincident(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-equal coordinates (no tolerance).

    Returns
    -------
    vertices : (n', 3) float64
    faces : (m, 3) int64
    """
    uniq, inv = np.unique(vertices, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)[faces]


def read_mesh_file(path, scale: float = 1.0, name: str | None = None, repair: bool = False) -> Mesh:
    """Read the triangle mesh of an STL, OBJ or PLY file, in mm.

    Parameters
    ----------
    path : str or os.PathLike
        ``.stl``, ``.obj`` or ``.ply`` (read by trimesh, nothing merged by
        tolerance; bit-equal vertices are merged).
    scale : float
        mm per file unit (these formats carry no unit).
    name : str, optional
        Name used in messages (default: the path).
    repair : bool
        See :func:`make_mesh`.

    Raises
    ------
    SceneError
        Unreadable file, unknown suffix, no triangles, or a mesh that is not
        a closed solid.
    """
    src = os.fsdecode(os.fspath(path))
    label = name or src
    suffix = Path(src).suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise SceneError(f"unknown mesh file type {suffix or '(no suffix)'!r}; expected .stl, .obj, .ply or .3mf",
                         src)
    if not Path(src).is_file():
        why = "Is a directory" if Path(src).is_dir() else "No such file or directory"
        raise SceneError(f"cannot read the mesh file: {why}", src)
    check_mesh_header(src, suffix)
    import trimesh

    try:
        loaded = trimesh.load(src, file_type=suffix[1:], process=False, force="mesh")
    except Exception as exc:       # trimesh raises many kinds on bad input
        raise SceneError(f"cannot read the mesh ({type(exc).__name__}: {exc})", src) from None
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    verts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    if faces.shape[0] == 0:
        raise SceneError("the file has no triangles", src)
    if not np.all(np.isfinite(verts)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(verts), axis=1))[0])
        raise SceneError(f"not a closed solid: vertex {bad} has non-finite coordinates {verts[bad].tolist()}", src)
    verts, faces = merge_coincident(verts, faces)
    if scale != 1.0:
        verts = verts * scale
    return make_mesh(verts, faces, label, repair=repair)


__all__ = ["Mesh", "MeshReport", "make_mesh", "mesh_problems", "read_mesh_file", "merge_coincident", "twin_corners",
           "signed_volume", "MESH_SUFFIXES"]
