"""Layer contours: the inside region of each layer as polygons with holes.

Marching squares runs on the layer raster, whose pixel centres the tracer
classified exactly (``F >= 1``). Every boundary edge, between an inside and an
outside pixel centre, gets its vertex by a bracketed root solve of
``F(x, y, z_k) = 1`` along that edge, to ``tol`` mm (Illinois steps with a
bisection safeguard, all edges of a layer per batch of compiled field
evaluations). Chords between neighbouring vertices are then subdivided, with
the new vertices put on the surface too, until each chord's midpoint and
quarter points are within ``tol / 2`` of the surface (in the layer plane), so
the contour error is set by ``tol``, not by the pixel size.

Conventions: coordinates in mm, seen from above (+z); outer rings are
counter-clockwise, holes clockwise. Pixels outside the grid count as
outside; where the solid reaches the grid's border, the contour follows the
border of the grid's box (half a pixel beyond the last centres).

Examples
--------
>>> from slicer import Skeleton
>>> from slicer.tracer.slicing import slice_skeleton
>>> s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
>>> r = slice_skeleton(s, 0.1)
>>> mp = layer_contours(s, r, r.grid.layers // 2)
>>> round(mp.area, 2), mp.is_valid           # a disc of radius 1
(3.14, True)
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Iterator

import numpy as np
import shapely
import shapely.affinity

from slicer._kernels.runtime.launch import numba_threads, serial
from slicer.atomic import AtomicFile, check_destination
from slicer.errors import GridError
from slicer.scale.ordered_map import map_in_order
from slicer.parts.mesh_slicing import Sections
from slicer.parts.slicing import PartResult, PartStreamedResult
from slicer.parts.part import ROLES
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult
from slicer.contours.cells import check_resolvable, guaranteed_rings
from slicer.contours.marching import layer_mask
from slicer.contours.rings import _polygons_only, rings_to_multipolygon
from slicer.contours.roots import _check_tol
from slicer.contours.simplify import SIMPLIFY_FRACTION, _keep_simple, refine_rings, simplify


def grid_box(grid):
    """The grid's box in the layer plane, half a pixel beyond the outer pixel
    centres: ``(xmin, ymin, xmax, ymax)``, mm."""
    (x0, y0), (px, py) = grid.origin[:2], grid.pixel_size
    return (float(x0 - 0.5 * px), float(y0 - (grid.height - 0.5) * py),
            float(x0 + (grid.width - 0.5) * px), float(y0 + 0.5 * py))


def plane_contours(skel: Skeleton, z: float, tol: float = 1e-3, box=None, stats: dict | None = None,
                   refine: bool = True):
    """Guaranteed contours of the plane ``z`` (:mod:`slicer.contours.cells`).

    Vertices lie on the surface to ``tol``; chords are refined to ``tol / 2``
    (:func:`slicer.contours.simplify.refine_rings`), then vertices a chord can
    skip within ``tol / 4`` are dropped (:func:`slicer.contours.simplify.simplify`);
    every part of the section wider than ``tol`` is present, whatever the pixel size.

    Parameters
    ----------
    skel : Skeleton
    z : float, mm
    tol : float, mm
    box : (4,) float, optional, mm
        ``(xmin, ymin, xmax, ymax)``: the section is clipped to it (where the
        solid reaches a grid's border, the contour follows the border).
    stats : dict, optional
        Work counts (:func:`slicer.contours.cells.guaranteed_rings`, ``refined``).
    refine : bool

    Returns
    -------
    shapely.MultiPolygon
        Valid; outer rings counter-clockwise, holes clockwise.
    """
    st: dict = {}
    cert: list = []
    rings = guaranteed_rings(skel, z, tol, st, certified=cert)
    if refine and rings:
        rings = _keep_simple(refine_rings(skel, rings, float(z), tol, st, certified=cert), rings, st)
    if stats is not None:
        for key, v in st.items():
            stats[key] = stats.get(key, 0) + v
    return finish_rings(rings, tol if refine else None, box)


def finish_rings(rings: list[np.ndarray], tol: float | None = None, box=None):
    """A layer's MultiPolygon from its contour rings, as the contour outputs write it.

    Parameters
    ----------
    rings : list of (n_q, 2) float64, mm
        Simple, disjoint rings: outer ones counter-clockwise, holes clockwise.
    tol : float, optional, mm
        The rings' chord tolerance: vertices a chord can skip within
        ``SIMPLIFY_FRACTION * tol`` are dropped (:func:`slicer.contours.simplify.simplify`).
        None: all vertices kept.
    box : (4,) float, optional, mm
        ``(xmin, ymin, xmax, ymax)``: the section is clipped to it.

    Returns
    -------
    shapely.MultiPolygon
    """
    mp = rings_to_multipolygon(rings)
    if tol is not None and not mp.is_empty:
        mp = simplify(mp, SIMPLIFY_FRACTION * tol)
    if box is not None and not mp.is_empty:
        xa, ya, xb, yb = mp.bounds
        if xa < box[0] or ya < box[1] or xb > box[2] or yb > box[3]:
            mp = _polygons_only(mp.intersection(shapely.box(*box)))
    return mp


def layer_contours(skel: Skeleton, result: SliceResult, k: int, tol: float = 1e-3):
    """Contours of layer ``k`` of a slicing result.

    Parameters
    ----------
    skel : Skeleton
        The skeleton that was sliced.
    result : SliceResult
    k : int
        Layer index; the layer lies at ``z = z0 + k h``.
    tol : float, mm
        Distance of every vertex (and chord midpoint) to the surface, in the
        layer plane; default 1 um.

    Returns
    -------
    shapely.MultiPolygon
        mm; valid, outer rings counter-clockwise, holes clockwise.
    """
    tol = check_resolvable(skel, _check_tol(tol))
    g = result.grid
    layer_mask(result, k)                      # refuses a layer out of range
    z = g.origin[2] + int(k) * g.layer_height
    return plane_contours(skel, z, tol, grid_box(g))


def each_plane(skel: Skeleton, zs, tol: float, box=None, stats: dict | None = None,
               workers: int | None = None) -> Iterator[tuple[float, object]]:
    """``(z, plane_contours(skel, z, tol, box))`` for each plane of ``zs``, in order.

    Planes are independent: with ``workers > 1`` they are computed on that
    many threads (:func:`slicer.scale.ordered_map.map_in_order`), each plane's kernels
    on one thread; the contours and ``stats`` are those of a serial run.

    Parameters
    ----------
    skel : Skeleton
    zs : sequence of float, mm
    tol : float, mm
    box : (4,) float, optional, mm
    stats : dict, optional
        Work counts, summed over the planes.
    workers : int, optional
        Default: the Numba threads of the calling thread.
    """
    zs = [float(z) for z in zs]
    if workers is None:
        with numba_threads(None) as workers:
            pass
    workers = min(int(workers), max(len(zs), 1))

    def one(z):
        st: dict = {}
        if workers > 1:
            with serial():
                return plane_contours(skel, z, tol, box, st), st
        return plane_contours(skel, z, tol, box, st), st

    for z, (mp, st) in map_in_order(one, zs, workers, name="contours"):
        if stats is not None:
            for key, v in st.items():
                stats[key] = stats.get(key, 0) + v
        yield z, mp


def iter_contours(skel: Skeleton, result: SliceResult, tol: float = 1e-3,
                  stats: dict | None = None, placement=None,
                  workers: int | None = None) -> Iterator[tuple[int, float, object]]:
    """Contours of every layer, bottom first.

    Parameters
    ----------
    skel : Skeleton
    result : SliceResult
    tol : float, mm
    stats : dict, optional
        Filled with totals (``evaluations``, ``vertices``, ``refined``,
        ``unbracketed``).
    placement : formats.printer_profiles.Placement, optional
        Put the contours on a printer's plate, as the images are: only the
        placed layers (``k_first`` on), numbered from 0, translated by
        :meth:`~formats.printer_profiles.Placement.offset` (plate mm, z of plate
        layer centres).
    workers : int, optional
        Threads computing layer planes at once (:func:`each_plane`; default:
        the Numba threads of the calling thread). The result does not depend
        on it.

    Yields
    ------
    k : int
    z : float, mm
    polys : shapely.MultiPolygon
    """
    tol = _check_tol(tol)
    if isinstance(result, (PartResult, PartStreamedResult)):     # a lattice with meshes
        yield from iter_part_contours(result, tol, stats, placement, workers)
        return
    tol = check_resolvable(skel, tol)
    g = result.grid
    k_lo, k_hi = 0, g.layers
    if placement is not None:
        k_lo, k_hi = placement.k_first, placement.k_first + placement.layers
        dx, dy, _ = placement.offset(g)
    box = grid_box(g)
    zs = [g.origin[2] + k * g.layer_height for k in range(k_lo, k_hi)]
    for k, (z, polys) in zip(range(k_lo, k_hi), each_plane(skel, zs, tol, box, stats, workers)):
        if placement is None:
            yield k, z, polys
        else:
            yield k - k_lo, (k - k_lo + 0.5) * g.layer_height, shapely.affinity.translate(polys, dx, dy)


def _part_sections(part) -> dict:
    return {role: Sections(part.of_role(role)) for role in ROLES if part.of_role(role)}


def _lattice_z(result, k: int) -> float:
    """Height of part layer ``k`` in the lattice's own grid (its layer centre), mm."""
    lat = result.lattice
    return lat.grid.origin[2] + (k + result.lattice_offset[2]) * lat.grid.layer_height


def _with_sections(geom, sections: dict, z: float):
    """The lattice's contours ``geom`` at height ``z`` combined with the meshes'
    cross-sections: ``((lattice ∩ CI) − CO) ∪ S``."""
    for role, op in (("clip-inside", "intersection"), ("clip-outside", "difference"), ("solid", "union")):
        if role in sections:
            geom = getattr(geom, op)(rings_to_multipolygon(sections[role].rings(z)))
    return _polygons_only(geom)


def part_layer_contours(result, k: int, tol: float = 1e-3):
    """Contours of layer ``k`` of a sliced part (:class:`slicer.parts.slicing.PartResult`):
    a valid MultiPolygon, mm, as :func:`layer_contours` gives for a lattice."""
    tol = _check_tol(tol)
    k = int(k)
    lat = result.lattice
    geom = shapely.MultiPolygon()
    if lat is not None:                        # the lattice's own contours, clipped to its own (uncut) grid
        layer_mask(lat, k + result.lattice_offset[2])          # refuses a layer out of range
        geom = plane_contours(result.part.skeleton, _lattice_z(result, k), tol, grid_box(lat.grid))
    z = result.grid.origin[2] + k * result.grid.layer_height
    return _with_sections(geom, _part_sections(result.part), z)


def iter_part_contours(result, tol: float = 1e-3, stats: dict | None = None,
                       placement=None, workers: int | None = None) -> Iterator[tuple[int, float, object]]:
    """Contours of a sliced part (:mod:`slicer.parts.slicing`), every layer, bottom first.

    Each layer's lattice contours (the guaranteed contours of the lattice's
    skeleton, clipped to the lattice's own grid) are combined with the meshes' exact cross-sections
    (:class:`slicer.parts.mesh_slicing.Sections`) by polygon booleans:
    ``((lattice ∩ CI) − CO) ∪ S``. Arguments and conventions as
    :func:`iter_contours`.
    """
    if isinstance(result, PartStreamedResult):
        if placement is not None:
            raise GridError("contours on a printer's plate need the whole job in memory: raise --max-memory")
        k = 0
        for slab in result.iter_slabs():
            for kk, z, mp in iter_part_contours(slab, tol, stats, workers=workers):
                yield k + kk, z, mp
            k += slab.grid.layers
        return
    g = result.grid
    sections = _part_sections(result.part)
    k_lo, k_hi = 0, g.layers
    if placement is not None:
        k_lo, k_hi = placement.k_first, placement.k_first + placement.layers
        dx, dy, _ = placement.offset(g)
    lat = result.lattice
    ks = range(k_lo, k_hi)
    if lat is not None:                        # the lattice's own contours, clipped to its own (uncut) grid
        geoms = (mp for _, mp in each_plane(result.part.skeleton, [_lattice_z(result, k) for k in ks], tol,
                                            grid_box(lat.grid), stats, workers))
    else:
        geoms = (shapely.MultiPolygon() for _ in ks)
    for k, geom in zip(ks, geoms):
        z = g.origin[2] + k * g.layer_height
        polys = _with_sections(geom, sections, z)
        if placement is None:
            yield k, z, polys
        else:
            yield k - k_lo, (k - k_lo + 0.5) * g.layer_height, shapely.affinity.translate(polys, dx, dy)


def write_contours(skel: Skeleton, result: SliceResult, path, tol: float = 1e-3, force: bool = False,
                   meta: dict | None = None, placement=None) -> dict:
    """Write the contours of every layer to one GeoJSON or JSON file, atomically.

    ``.geojson``: a FeatureCollection, one Feature per layer (a MultiPolygon
    in mm, properties ``layer`` and ``z``). Any other suffix: plain JSON,
    ``{"layers": [{"layer", "z", "polygons": [[outer, hole, ...], ...]}]}``
    with each ring a list of ``[x, y]`` (mm, not repeated at the end). Both
    carry the grid and ``meta`` (key ``skelslice``). Outer rings are
    counter-clockwise seen from +z, holes clockwise. Layers are streamed: the
    file is written to a temporary file beside ``path`` and renamed when
    complete. With ``placement`` (a printer job) the layers and coordinates
    are the plate's, as in the images (see :func:`iter_contours`), and the
    grid written is the plate's.

    Returns
    -------
    dict
        ``layers``, ``vertices``, ``seconds``, ``path``.
    """
    tol = _check_tol(tol)
    path = Path(path)
    check_destination(path, force)
    geo = path.suffix.lower() == ".geojson"
    grid = result.grid if placement is None else placement.grid
    head = {"generator": "skelslice", "units": "mm", "tolerance": tol, "grid": grid.to_dict(),
            **(meta or {})}
    t0 = time.perf_counter()
    out = AtomicFile(path)    # published after the last layer
    nv = 0
    n = 0
    try:
        fh = out.fh
        if geo:
            fh.write(b'{"type": "FeatureCollection", "skelslice": ' + json.dumps(head).encode()
                     + b', "features": [\n')
        else:
            fh.write(b'{"skelslice": ' + json.dumps(head).encode() + b', "layers": [\n')
        for k, z, mp in iter_contours(skel, result, tol, placement=placement):
            polys = []
            for poly in mp.geoms:
                rs = [poly.exterior, *poly.interiors]
                coords = [np.asarray(r.coords)[:, :2] for r in rs]
                nv += sum(c.shape[0] - 1 for c in coords)
                polys.append([(c if geo else c[:-1]).tolist() for c in coords])
            if geo:
                item = {"type": "Feature", "properties": {"layer": k, "z": z},
                        "geometry": {"type": "MultiPolygon", "coordinates": polys}}
            else:
                item = {"layer": k, "z": z, "polygons": polys}
            fh.write((b",\n" if n else b"") + json.dumps(item).encode())
            n += 1
        fh.write(b"\n]}\n")
        out.publish(force)
    except BaseException:
        out.discard()
        raise
    return {"layers": n, "vertices": nv, "seconds": time.perf_counter() - t0, "path": str(path)}


__all__ = ["plane_contours", "finish_rings", "each_plane", "grid_box", "layer_contours", "iter_contours", "iter_part_contours", "part_layer_contours", "write_contours"]
