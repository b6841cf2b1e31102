"""Strut-lattice (microstructure) generator.

A lattice is a unit cell, given as node positions in the unit cube and a list
of struts, tiled over a grid of cells. Nodes and struts that neighbouring
cells share are merged, so the result is a clean graph: every node is used by
at least one strut and no strut appears twice. Radii are defined per node
(constant, graded along an axis, or any user function), so struts meeting at
a node have the same radius there and graded struts are tapered.

The result is a :class:`~slicer.model.skeleton.Skeleton`; its surface is the SIIS
iso-surface ``F = 1``. Note (docs/math.md §1.5) that free strut ends extend only
about ``0.25 * radius`` past their end node, and that an isolated strut
shorter than ``0.688 * radius`` has no surface at all.
"""
from __future__ import annotations

from itertools import combinations, permutations, product
from typing import Callable

import numpy as np

from slicer.arguments import positive_number, scene_numbers
from slicer.errors import SceneError
from slicer.model.skeleton import DEFAULT_DEGREE, DEFAULT_SIGMA, Skeleton

#: names accepted by :func:`generate_lattice` (combine with ``+``, e.g. ``"bcc+cubic"``)
CELL_TYPES = ("cubic", "bcc", "fcc", "octet", "kelvin", "diamond")
#: positions are merged when equal after rounding to this fraction of a cell
MERGE_QUANTUM = 1e-9
#: refuse to build lattices with more struts than this (memory guard)
MAX_STRUTS = 20_000_000

_AXES = {"x": 0, "y": 1, "z": 2}


# --------------------------------------------------------------------------- unit cells
def _corners() -> np.ndarray:
    return np.array(list(product((0.0, 1.0), repeat=3)))


def _face_centres() -> np.ndarray:
    out = []
    for axis, side in product(range(3), (0.0, 1.0)):
        p = [0.5, 0.5, 0.5]
        p[axis] = side
        out.append(p)
    return np.array(out)


def _pairs(nodes: np.ndarray, length: float, group=None) -> np.ndarray:
    """Index pairs of ``nodes`` at distance ``length`` (optionally only across groups)."""
    out = [(i, j) for i, j in combinations(range(len(nodes)), 2)
           if abs(np.linalg.norm(nodes[i] - nodes[j]) - length) < 1e-9
           and (group is None or group[i] != group[j])]
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def _cell_cubic():
    nodes = _corners()
    return nodes, _pairs(nodes, 1.0)


def _cell_bcc():
    nodes = np.vstack([_corners(), [[0.5, 0.5, 0.5]]])
    group = [0] * 8 + [1]
    return nodes, _pairs(nodes, np.sqrt(3) / 2, group)


def _cell_fcc():
    nodes = np.vstack([_corners(), _face_centres()])
    group = [0] * 8 + [1] * 6
    return nodes, _pairs(nodes, np.sqrt(2) / 2, group)


def _cell_octet():
    nodes = np.vstack([_corners(), _face_centres()])
    return nodes, _pairs(nodes, np.sqrt(2) / 2)


def _cell_kelvin():
    verts = set()
    for perm in permutations((0.0, 1.0, 2.0)):
        for signs in product((-1.0, 1.0), repeat=3):
            verts.add(tuple(s * c for s, c in zip(signs, perm)))
    nodes = (np.array(sorted(verts)) + 2.0) / 4.0
    return nodes, _pairs(nodes, np.sqrt(2) / 4)


def _cell_diamond():
    fcc = np.vstack([_corners(), _face_centres()])
    inner = np.array([[0.25, 0.25, 0.25], [0.75, 0.75, 0.25],
                      [0.75, 0.25, 0.75], [0.25, 0.75, 0.75]])
    nodes = np.vstack([fcc, inner])
    return nodes, _pairs(nodes, np.sqrt(3) / 4)


_CELLS: dict[str, Callable[[], tuple[np.ndarray, np.ndarray]]] = {
    "cubic": _cell_cubic, "bcc": _cell_bcc, "fcc": _cell_fcc,
    "octet": _cell_octet, "kelvin": _cell_kelvin, "diamond": _cell_diamond,
}


def unit_cell(cell_type: str) -> tuple[np.ndarray, np.ndarray]:
    """Node positions and struts of one unit cell.

    Cells (all struts of one cell lie in the closed unit cube):

    ``cubic``
        The 12 cube edges.
    ``bcc``
        Body-centred cubic: the 4 body diagonals, split at the centre node
        (8 half-diagonal struts), no edges.
    ``fcc``
        Face-centred cubic: the 2 diagonals of each face, split at the face
        centre (24 struts), no edges.
    ``octet``
        Octet truss: ``fcc`` plus the 12 edges of the inner octahedron joining
        adjacent face centres (36 struts); every node is joined to its 12
        nearest neighbours of the FCC point lattice.
    ``kelvin``
        Edges of a truncated octahedron (24 nodes, 36 struts) whose square
        faces lie on the cube faces; neighbouring cells share those squares.
    ``diamond``
        Diamond cubic: 4 inner nodes, each joined to 4 FCC sites (16 struts).

    Several types joined by ``+`` (e.g. ``"bcc+cubic"``) give the union.

    Parameters
    ----------
    cell_type : str

    Returns
    -------
    nodes : (p, 3) float64, cell units
    struts : (q, 2) int64
        Indices into ``nodes``.

    Examples
    --------
    >>> nodes, struts = unit_cell("octet")
    >>> nodes.shape, struts.shape
    ((14, 3), (36, 2))
    """
    if not isinstance(cell_type, str) or not cell_type.strip():
        raise SceneError(f"cell_type must be a name from {', '.join(CELL_TYPES)}, got {cell_type!r}")
    all_nodes, all_struts, count = [], [], 0
    for part in cell_type.lower().split("+"):
        make = _CELLS.get(part.strip())
        if make is None:
            raise SceneError(f"unknown cell type {part.strip()!r} in cell_type={cell_type!r}; "
                             f"valid types: {', '.join(CELL_TYPES)} (combine with '+')")
        nodes, struts = make()
        all_nodes.append(nodes)
        all_struts.append(struts + count)
        count += len(nodes)
    return np.vstack(all_nodes), np.vstack(all_struts)


# --------------------------------------------------------------------------- validation
def _show(value) -> str:
    """repr of a value, with numpy scalars shown as plain Python numbers."""
    return repr(value.item() if isinstance(value, np.generic) else value)


def check_positive(value, name: str) -> float:
    """``value`` as a finite float > 0, else SceneError naming ``name``."""
    return positive_number(value, name, SceneError)


def _numbers(value, n: int, name: str) -> np.ndarray:
    """``value`` as (n,) finite float64, else SceneError naming ``name``."""
    try:
        out = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        out = None
    if out is None or out.shape != (n,) or not np.all(np.isfinite(out)):
        raise SceneError(f"{name} must be {n} finite numbers, got {value!r}")
    return out


def _size3(value, name: str) -> np.ndarray:
    """A positive scalar (used on all axes) or three positive numbers, as (3,) float64."""
    if np.ndim(value) == 0:
        return np.full(3, check_positive(value, name))
    if len(value) != 3:
        raise SceneError(f"{name} must be one number or three numbers, got {value!r}")
    return np.array([check_positive(v, f"{name}[{i}]") for i, v in enumerate(value)])


def _cells(value) -> np.ndarray:
    if np.ndim(value) == 0:
        value = (value,) * 3
    if len(value) != 3:
        raise SceneError(f"cells must be three counts (nx, ny, nz), got {value!r}")
    for i, v in enumerate(value):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
            raise SceneError(f"cells[{i}] must be an integer >= 1, got {_show(v)}")
    return np.array(value, dtype=np.int64)


def _envelope_mask(nodes: np.ndarray, envelope, tol: float) -> np.ndarray:
    """Which nodes lie inside the closed envelope, with tolerance ``tol`` mm; (n,) bool."""
    kind = envelope[0] if isinstance(envelope, (tuple, list)) and envelope else None
    if kind == "box" and len(envelope) == 3:
        lo = _numbers(envelope[1], 3, "envelope box lo")
        hi = _numbers(envelope[2], 3, "envelope box hi")
        if np.any(hi <= lo):
            raise SceneError(f"envelope box must have hi > lo, got lo={lo.tolist()}, hi={hi.tolist()}")
        return np.all((nodes >= lo - tol) & (nodes <= hi + tol), axis=1)
    if kind == "cylinder" and len(envelope) == 5:
        centre = _numbers(envelope[1], 2, "envelope cylinder centre (x, y)")
        r = check_positive(envelope[2], "envelope cylinder radius")
        z0, z1 = _numbers(envelope[3:5], 2, "envelope cylinder (z0, z1)")
        if z1 <= z0:
            raise SceneError(f"envelope cylinder must have z1 > z0, got z0={z0}, z1={z1}")
        d2 = np.sum((nodes[:, :2] - centre) ** 2, axis=1)
        return (d2 <= (r + tol) ** 2) & (nodes[:, 2] >= z0 - tol) & (nodes[:, 2] <= z1 + tol)
    raise SceneError("envelope must be None, ('box', lo(3), hi(3)) or "
                     f"('cylinder', centre_xy(2), radius, z0, z1), got {envelope!r}")


# --------------------------------------------------------------------------- building blocks
def _tile(cell_nodes: np.ndarray, cell_struts: np.ndarray, cells: np.ndarray):
    """Tile a unit cell, merging shared nodes and struts.

    Returns
    -------
    coords : (n, 3) float64, cell units, sorted by (z, y, x)
    struts : (m, 2) int64, each row ascending, rows sorted
    """
    idx = np.stack(np.meshgrid(*(np.arange(c) for c in cells), indexing="ij"), axis=-1).reshape(-1, 3)
    pts = (idx[:, None, :] + cell_nodes[None, :, :]).reshape(-1, 3)
    struts = (cell_struts[None, :, :] + len(cell_nodes) * np.arange(len(idx))[:, None, None]).reshape(-1, 2)
    keys = np.rint(pts * (1.0 / MERGE_QUANTUM)).astype(np.int64)
    # z-major order: reverse the columns so np.unique sorts by z, then y, then x
    ukeys, inverse = np.unique(keys[:, ::-1], axis=0, return_inverse=True)
    struts = np.sort(inverse.reshape(-1)[struts], axis=1)
    struts = np.unique(struts, axis=0)
    return ukeys[:, ::-1] * MERGE_QUANTUM, struts


def _compact(nodes: np.ndarray, struts: np.ndarray):
    """Drop nodes no strut uses and renumber (keeping node order)."""
    used = np.zeros(len(nodes), dtype=bool)
    used[struts.reshape(-1)] = True
    new_index = np.cumsum(used) - 1
    return nodes[used], new_index[struts]


def _node_radii(nodes, radius, radius_top, grading_axis, radius_fn) -> np.ndarray:
    """Radius at each node, (n,) float64 mm."""
    if radius_fn is not None:
        if radius is not None or radius_top is not None:
            raise SceneError("give either radius (and radius_top) or radius_fn, not both "
                             "(pass radius=None with radius_fn)")
        if not callable(radius_fn):
            raise SceneError(f"radius_fn must be callable, got {radius_fn!r}")
        try:
            r = np.asarray(radius_fn(nodes.copy()), dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise SceneError(f"radius_fn must return an array of numbers ({exc})") from None
        if r.shape != (len(nodes),):
            raise SceneError(f"radius_fn must return shape ({len(nodes)},) (one radius per node), "
                             f"got {r.shape}")
        bad = np.nonzero(~(np.isfinite(r) & (r > 0)))[0]
        if bad.size:
            i = int(bad[0])
            raise SceneError(f"radius_fn returned {float(r[i])!r} at node {i} {nodes[i].tolist()}; "
                             "radii must be finite and > 0")
        return r
    r0 = check_positive(radius, "radius")
    if radius_top is None:
        return np.full(len(nodes), r0)
    r1 = check_positive(radius_top, "radius_top")
    c = nodes[:, _AXES[grading_axis]]
    lo, hi = c.min(), c.max()
    t = (c - lo) / (hi - lo) if hi > lo else np.zeros_like(c)
    return r0 + (r1 - r0) * t


# --------------------------------------------------------------------------- public API
def generate_lattice(cell_type: str, cells, cell_size, radius: float | None,
                     radius_top: float | None = None, grading_axis: str = "z",
                     radius_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                     envelope=None, origin=(0.0, 0.0, 0.0),
                     degree: int = DEFAULT_DEGREE, sigma: float = DEFAULT_SIGMA) -> Skeleton:
    """Tile a strut unit cell over a grid of cells.

    Cell ``(i, j, k)`` spans ``origin + [i, i+1] x [j, j+1] x [k, k+1] * cell_size``.
    Nodes that coincide (after rounding to ``1e-9`` of a cell) are merged,
    duplicate struts (either orientation) are kept once, and nodes used by
    no strut are removed. Nodes are ordered by z, then y, then x; each strut
    is stored with its lower node index first.

    Parameters
    ----------
    cell_type : str
        One of :data:`CELL_TYPES` (see :func:`unit_cell`), or several joined
        by ``+`` such as ``"bcc+cubic"``. Case-insensitive.
    cells : (3,) int, or int
        Number of cells ``(nx, ny, nz)``, each >= 1.
    cell_size : float or (3,) float, mm
        Cell edge length (or one per axis), > 0.
    radius : float or None, mm
        Strut radius, > 0; with ``radius_top``, the radius at the lowest
        coordinate along ``grading_axis``. Must be None when ``radius_fn`` is
        given.
    radius_top : float, optional, mm
        Radius at the highest coordinate along ``grading_axis``; the radius
        varies linearly in between, evaluated at each strut's end nodes, so
        struts are tapered. The range is that of the final (trimmed) nodes.
    grading_axis : {"x", "y", "z"}, default "z"
    radius_fn : callable, optional
        ``radius_fn(points) -> radii`` with points ``(k, 3) float64, mm`` (the
        final nodes) and radii ``(k,) float64, mm``, all finite and > 0.
    envelope : tuple, optional
        Trim the lattice to ``("box", lo (3,), hi (3,))`` or to
        ``("cylinder", centre_xy (2,), radius, z0, z1)`` (a cylinder along z),
        in mm, absolute coordinates. A strut is kept when **both** its end
        nodes lie inside the closed envelope (with a tolerance of ``1e-9``
        cell); nodes left without struts are dropped.
    origin : (3,) float, mm, default (0, 0, 0)
        Lowest corner of cell ``(0, 0, 0)``.
    degree : int, default 6
        Kernel degree of the returned skeleton.
    sigma : float, default 2.0
        Kernel support factor of the returned skeleton.

    Returns
    -------
    Skeleton
        ``nodes : (n, 3) float64, mm``, ``segments : (m, 2) int64`` and
        ``radii : (m, 2) float64, mm`` (radius at each strut end).

    Raises
    ------
    SceneError
        Naming the parameter and value: unknown cell type (the message lists
        the valid ones), non-positive or non-integer counts, non-positive or
        non-finite sizes and radii, a malformed envelope or one that keeps no
        strut, a ``radius_fn`` result of the wrong shape or with values
        <= 0, or a lattice of more than :data:`MAX_STRUTS` struts.

    Examples
    --------
    >>> skel = generate_lattice("bcc", (2, 2, 2), 5.0, 0.5)
    >>> skel.n_nodes, skel.n_segments
    (35, 64)
    >>> graded = generate_lattice("cubic", (1, 1, 2), 4.0, 0.3, radius_top=0.6)
    >>> sorted(set(graded.radii.ravel().round(3).tolist()))
    [0.3, 0.45, 0.6]
    """
    cell_nodes, cell_struts = unit_cell(cell_type)
    counts = _cells(cells)
    size = _size3(cell_size, "cell_size")
    org = _numbers(origin, 3, "origin")
    # fail fast, before building anything
    if radius_fn is None:
        check_positive(radius, "radius")
        if radius_top is not None:
            check_positive(radius_top, "radius_top")
    if grading_axis not in _AXES:
        raise SceneError(f"grading_axis must be one of 'x', 'y', 'z', got {grading_axis!r}")
    if envelope is not None:
        _envelope_mask(np.zeros((0, 3)), envelope, 0.0)
    n_struts = int(np.prod(counts)) * len(cell_struts)
    if n_struts > MAX_STRUTS:
        raise SceneError(f"cells={counts.tolist()} of type {cell_type!r} would need {n_struts} struts "
                         f"(limit {MAX_STRUTS})")
    coords, struts = _tile(cell_nodes, cell_struts, counts)
    coords, struts = _compact(coords, struts)
    nodes = org + coords * size
    if envelope is not None:
        inside = _envelope_mask(nodes, envelope, MERGE_QUANTUM * float(size.max()))
        struts = struts[inside[struts].all(axis=1)]
        if len(struts) == 0:
            raise SceneError(f"envelope {envelope!r} keeps no strut of the lattice "
                             f"(node bounds {nodes.min(axis=0).tolist()} .. {nodes.max(axis=0).tolist()})")
        nodes, struts = _compact(nodes, struts)
    r = _node_radii(nodes, radius, radius_top, grading_axis, radius_fn)
    scene_numbers(nodes, r[struts], None,            # origin, cell size and radius within float64's reach
                  node_entry=lambda i, k: f"the lattice's node {i} {'xyz'[k]} (origin + cells x cell size)",
                  radius_entry=lambda i, j: f"the radius at node {int(struts[i, j])}")
    return Skeleton(nodes, struts, r[struts], degree, sigma)


__all__ = ["generate_lattice", "unit_cell", "CELL_TYPES", "MERGE_QUANTUM", "MAX_STRUTS"]
