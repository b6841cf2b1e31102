"""``skelslice validate`` for parts: slices against manifold3d booleans of the meshed lattice and the meshes.

The reference of each checked layer is built independently of the slicer's
mesh code: the lattice's meshed band around the layer plane
(:func:`validation.reference_mesh.reference_band`, marching tetrahedra on the
field) is combined with the part's meshes by manifold3d's 3-D booleans,
``((band ∩ CI) − CO) ∪ S``, and cut with ``Manifold.slice``. Our side is the
part's layer contours (:func:`slicer.contours.part_layer_contours`) and
raster. The report has the layout of :func:`validation.validate.validate`
(so the table and the report folder are the same); per layer:

* IoU, XOR area and Hausdorff distance between our contours and the
  reference section; the check ``hausdorff_within_mesh_bound`` allows the
  lattice band's own error bound in the plane plus the contour tolerance
  (mesh parts are exact in the reference);
* ``vertex_max_3d``: the largest distance of our contour vertices to the
  part's surface -- the lattice's (``|F - 1| / |grad F|``) or a mesh section's
  boundary, whichever is nearer; the check ``vertices_on_surface`` wants it
  within the contour tolerance;
* pixel mismatches of our raster against the reference rasterised at the
  pixel centres; "unexplained" ones are farther than the reference's bound
  from both the lattice's exact contour and the meshes' sections.
"""
from __future__ import annotations

import time

import manifold3d
import numpy as np
import shapely

from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.arguments import resolvable, scene_reach, scene_step
from slicer.contours import layer_mask, part_layer_contours, rings_to_multipolygon
from slicer.errors import GridError
from slicer.model.field import evaluate
from slicer.parts.mesh_slicing import Sections
from slicer.parts.slicing import slice_part
from slicer.parts.part import ROLES

from validation.independent import project
from validation.metrics import _edge_points, hausdorff, polygon_rings, rasterize_rings
from validation.reference_mesh import reference_band
from validation.validate import assemble_report, pick_layers
from slicer.constants import DISTANCE_SLACK as SLACK



def _manifold(mesh):
    return manifold3d.Manifold(manifold3d.Mesh64(np.array(mesh.vertices, dtype=np.float64),
                                                 np.array(mesh.faces, dtype=np.uint64)))


def _union(manifolds):
    if not manifolds:
        return None
    return manifold3d.Manifold.batch_boolean(manifolds, manifold3d.OpType.Add) if len(manifolds) > 1 \
        else manifolds[0]


def reference_section(part, z: float, edge: float, roles: dict, tol: float = 1e-5):
    """The reference polygons of ``part`` at height ``z`` (see the module docstring).

    Returns
    -------
    polygons : shapely.MultiPolygon
    bound : float, mm
        The lattice band's error bound in the plane, where its section is on the part's
        boundary (0 without a lattice).
    info : MeshInfo or None
    """
    ref = None
    info, lat_rings = None, []
    if part.skeleton is not None:
        band, info = reference_band(part.skeleton, z, edge, tol)
        lat_rings = [np.asarray(r, dtype=np.float64) for r in band.slice(float(z)).to_polygons()]
        ref = band
        if roles.get("clip-inside") is not None:
            ref = ref ^ roles["clip-inside"]                # manifold3d: ^ is intersection
        if roles.get("clip-outside") is not None:
            ref = ref - roles["clip-outside"]
    if roles.get("solid") is not None:
        ref = roles["solid"] if ref is None else ref + roles["solid"]
    cs = ref.slice(float(z)) if ref is not None else manifold3d.CrossSection()
    rings = [np.asarray(r, dtype=np.float64) for r in cs.to_polygons()]
    polys = rings_to_multipolygon(rings)
    return polys, _lattice_bound(part, lat_rings, polys, z, tol), info


def _lattice_bound(part, lat_rings: list, polys, z: float, tol: float) -> float:
    """The lattice band's error bound in the plane (as :func:`validation.metrics.contour_error_bound`),
    over the part of its section that is still on the part's boundary (clipped-away lattice
    does not count; mesh boundaries are exact)."""
    if not lat_rings or polys.is_empty:
        return 0.0
    pts = _edge_points(lat_rings, 2)
    pts = pts[shapely.distance(polys.boundary, shapely.points(pts)) < 1e-6]
    if not pts.shape[0]:
        return 0.0
    roots, ok, first = project(part.skeleton, pts, z, tol)
    d = np.where(ok, np.hypot(*(roots - pts).T) + tol, first)
    d = d[np.isfinite(d)]
    return float(d.max()) if d.size else 0.0


def _surface_distance(part, xy: np.ndarray, z: float, sections: list) -> np.ndarray:
    """In-plane distance of points to the part's surfaces: the nearer of the lattice's
    first-order distance ``|F - 1| / |grad_xy F|`` and the meshes' section boundaries."""
    d = np.full(xy.shape[0], np.inf)
    if part.skeleton is not None and xy.shape[0]:
        p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
        f, g = evaluate(part.skeleton, p, gradient=True)
        gxy = np.hypot(g[:, 0], g[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.minimum(d, np.where(gxy > 0, np.abs(f - 1.0) / gxy, np.inf))
    pts = shapely.points(xy) if xy.shape[0] else None
    for mp in sections:
        if mp.is_empty or pts is None:
            continue
        d = np.minimum(d, shapely.distance(mp.boundary, pts))
    return d


def validate_part(part, *, pixel_size: float | None = None, pixels: int = 512, pixel_size_y=None,
                  layer_height=None, bounds=None, method: str = "interval", bucket: int = DEFAULT_BUCKET, threads=None,
                  strict: bool = False, mesh_edge: float | None = None, layers_checked: int = 8,
                  tol: float = 1e-3, max_hausdorff: float | None = None, min_iou: float | None = None,
                  blend: str = "sum", progress=None) -> dict:
    """Slice a part and compare sampled layers with the manifold3d reference.

    Parameters and result as :func:`validation.validate.validate` (with
    ``part`` a :class:`slicer.parts.part.Part`).
    """
    tol = resolvable(tol, "contour tolerance", scene_reach(part), GridError)
    if mesh_edge is not None:                           # before any work
        scene_step(mesh_edge, "mesh edge", part, GridError)
    if pixel_size is None:
        if int(pixels) < 2:
            raise GridError(f"pixels must be >= 2, got {pixels}")
        lo, hi = part.support_bounds()
        pixel_size = float(max(hi[0] - lo[0], hi[1] - lo[1])) / int(pixels)
    t0 = time.perf_counter()
    res = slice_part(part, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                     blend=blend)
    t_slice = time.perf_counter() - t0
    g = res.grid
    px, py = g.pixel_size
    edge = scene_step(float(mesh_edge) if mesh_edge is not None else 0.5 * min(px, py), "mesh edge", part,
                      GridError)
    roles = {role: _union([_manifold(m) for m in part.of_role(role)]) for role in ROLES}
    sections = {role: Sections(part.of_role(role)) for role in ROLES if part.of_role(role)}
    ks = pick_layers(res, int(layers_checked))
    rows, ours_all, refs = [], [], []
    t_ref = t_contours = t_metrics = 0.0
    for k in ks:
        z = g.origin[2] + k * g.layer_height
        t1 = time.perf_counter()
        ref, bound, info = reference_section(part, z, edge, roles)
        t_ref += time.perf_counter() - t1
        t2 = time.perf_counter()
        ours = part_layer_contours(res, k, tol)
        t_contours += time.perf_counter() - t2
        t3 = time.perf_counter()
        mask = layer_mask(res, k)
        mesh_secs = [rings_to_multipolygon(s.rings(z)) for s in sections.values()]
        our_rings, ref_rings = polygon_rings(ours), polygon_rings(ref)
        union = ours.union(ref).area
        haus = hausdorff(our_rings, ref_rings)
        ref_raster = rasterize_rings(ref_rings, g.origin[:2], g.pixel_size, g.height, g.width)
        own_raster = rasterize_rings(our_rings, g.origin[:2], g.pixel_size, g.height, g.width)
        mism = ref_raster != mask
        jj, ii = np.nonzero(mism)
        xy = np.column_stack([g.origin[0] + ii * px, g.origin[1] - jj * py])
        unexplained = int((~(_surface_distance(part, xy, z, mesh_secs) <= bound + SLACK)).sum())
        verts = np.concatenate(our_rings) if our_rings else np.zeros((0, 2))
        vmax = float(_surface_distance(part, verts, z, mesh_secs).max()) if verts.shape[0] else 0.0
        off = _off_boundary(ours, own_raster != mask, g)        # mismatches not explained by the boundary
        row = {"k": int(k), "z": float(z), "iou": float(ours.intersection(ref).area / union) if union > 0 else 1.0,
               "xor_area": float(ours.symmetric_difference(ref).area), "area": float(ours.area),
               "ref_area": float(ref.area), "hausdorff": haus, "hausdorff_px": haus / min(px, py),
               "pixel_mismatch": int(mism.sum()), "pixel_mismatch_unexplained": unexplained,
               "contour_raster_mismatch": off, "contour_raster_unexplained": off,
               "vertex_max_3d": vmax, "vertex_max_plane": vmax, "vertices": int(verts.shape[0]),
               "valid": bool(ours.is_valid and shapely.is_valid(ref)), "mesh_bound": bound,
               "mesh_first_order": bound, "mesh_unbracketed": 0,
               "mesh_error_3d": info.error_3d if info is not None else 0.0,
               "mesh_triangles": info.triangles if info is not None else 0,
               "mesh_seconds": info.seconds if info is not None else 0.0}
        row["hausdorff_margin"] = bound + tol - haus
        t_metrics += time.perf_counter() - t3
        rows.append(row)
        ours_all.append(ours)
        refs.append(_Section(z, ref, ref_rings))
        if progress:
            progress(row)
    settings = {"method": method, "bucket": bucket, "strict": strict, "tol": tol, "mesh_edge": edge,
                "layers_checked": int(layers_checked), "max_hausdorff": max_hausdorff, "min_iou": min_iou,
                "part": part.describe()}
    timings = {"slice_s": t_slice, "reference_s": t_ref, "contours_s": t_contours, "metrics_s": t_metrics}
    return assemble_report(rows, settings, g, timings, tol, max_hausdorff, min_iou, res, refs, ours_all)


def _off_boundary(polys, mism: np.ndarray, g) -> int:
    """Mismatched pixels whose centre is not on the polygons' boundary (a centre on it is
    inside for the slicer, by the closed convention, and either way for a rasteriser)."""
    jj, ii = np.nonzero(mism)
    if not ii.size:
        return 0
    pts = shapely.points(np.column_stack([g.origin[0] + ii * g.pixel_size[0], g.origin[1] - jj * g.pixel_size[1]]))
    return int((shapely.distance(polys.boundary, pts) > SLACK).sum())


class _Section:
    """What :func:`validation.validate.write_report` reads of a reference section."""

    def __init__(self, z, polygons, rings):
        self.z, self.polygons, self.rings = z, polygons, rings


__all__ = ["validate_part", "reference_section"]
