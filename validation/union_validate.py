"""``validate --blend union``: the union tracer against meshed per-strut solids unioned by manifold3d.

The union blend's solid is the union of the struts' own solids
(docs/math.md §5.4), so the reference of a layer is built strut by strut:
each strut that reaches the layer is meshed on its own (the band of
:func:`validation.reference_mesh.reference_band`), the bands are unioned with
``manifold3d`` (``Manifold.batch_boolean``, Add) and the union is cut at the
layer. Our contours are the shapely union of each strut's own contours
(:func:`slicer.contours.layer_contours` of that strut alone, traced on the
same grid: for one strut the union and the sum are the same field), so they
depend on the union tracer only through the raster they are compared with.

Per layer the report has the rows of :func:`validation.validate.validate`:
IoU and XOR area against the reference, Hausdorff distance, the reference's
own bound (the largest per-strut bound of
:func:`validation.metrics.contour_error_bound`), pixel mismatches of the
union tracer's raster against the reference rasterised at pixel centres
(explained within the bound of some strut's exact contour), the union
contours against the union raster (``contour_raster_mismatch``: 0 when the
tracer's voxels are exactly the union of the struts'), and the vertices'
distance to the union surface (``|max_i f_i - 1| / |grad|``).
"""
from __future__ import annotations

import time

import manifold3d
import numpy as np
import shapely

from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.arguments import resolvable, scene_reach, scene_step
from slicer.contours import layer_contours, layer_mask, rings_to_multipolygon
from slicer.errors import GridError
from slicer.model.field import evaluate
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import slice_skeleton, trace

from validation.independent import plane_distance
from validation.metrics import contour_error_bound, hausdorff, polygon_rings, rasterize_rings
from validation.reference_mesh import Section, reference_band
from validation.validate import assemble_report, default_pitch, pick_layers


def strut(skel: Skeleton, i: int) -> Skeleton:
    """Segment ``i`` of ``skel`` alone (same nodes and kernel)."""
    return Skeleton(skel.nodes, skel.segments[i:i + 1], skel.radii[i:i + 1], skel.degree, skel.sigma)


def struts_at(skel: Skeleton, z: float) -> list[int]:
    """Segments whose support box reaches height ``z``."""
    return [i for i in range(skel.n_segments) if _reaches(strut(skel, i), z)]


def _reaches(one: Skeleton, z: float) -> bool:
    lo, hi = one.support_bounds()
    return bool(lo[2] < z < hi[2])


def union_section(skel: Skeleton, z: float, edge: float, ids: list[int], tol: float = 1e-5):
    """The reference section at ``z``: per-strut bands unioned by manifold3d, then cut.

    Returns
    -------
    Section
        ``info`` is that of the union (triangles, error_3d the largest per-strut estimate).
    list of float
        Each strut's band, for the bound (its own section's :func:`contour_error_bound`).
    """
    t0 = time.perf_counter()
    bands, infos = [], []
    for i in ids:
        band, info = reference_band(strut(skel, i), z, edge, tol)
        bands.append(band)
        infos.append(info)
    if bands:
        man = manifold3d.Manifold.batch_boolean(bands, manifold3d.OpType.Add)
        rings = [np.asarray(r, dtype=np.float64) for r in man.slice(float(z)).to_polygons()]
    else:
        rings = []
    info = infos[0] if infos else None
    if info is not None:
        info.error_3d = max(x.error_3d for x in infos)
        info.triangles = int(sum(x.triangles for x in infos))
        info.seconds = time.perf_counter() - t0
    bounds = [contour_error_bound(strut(skel, i), [np.asarray(r) for r in b.slice(float(z)).to_polygons()], z)["bound"]
              for i, b in zip(ids, bands)]
    return Section(float(z), rings_to_multipolygon(rings), info, rings), bounds


def union_contours(skel: Skeleton, grid, k: int, ids: list[int], tol: float):
    """Shapely union of each strut's own contours of layer ``k`` (traced on ``grid``)."""
    polys = [layer_contours(strut(skel, i), trace(strut(skel, i), grid), k, tol) for i in ids]
    if not polys:
        return rings_to_multipolygon([])
    merged = shapely.union_all(polys)
    if merged.geom_type == "Polygon":
        merged = shapely.MultiPolygon([merged])
    elif merged.geom_type != "MultiPolygon":
        merged = shapely.MultiPolygon([g for g in getattr(merged, "geoms", []) if g.geom_type == "Polygon"])
    return merged


def union_vertex_distance(skel: Skeleton, rings, z: float) -> float:
    """Largest ``|max_i f_i - 1| / |grad|`` over the vertices of ``rings`` (the union's surface)."""
    if not rings:
        return 0.0
    xy = np.concatenate(rings)
    p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
    f, g = evaluate(skel, p, gradient=True, blend="union")
    gn = np.sqrt((g * g).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
    return float(d.max())


def unexplained_pixels(skel: Skeleton, ids: list[int], mism: np.ndarray, origin, pixel_size, z: float,
                       bound: float) -> int:
    """Mismatched pixels whose centre is farther than ``bound`` from every strut's exact contour."""
    jj, ii = np.nonzero(mism)
    if not jj.size:
        return 0
    xy = np.column_stack([origin[0] + ii * pixel_size[0], origin[1] - jj * pixel_size[1]])
    d = np.full(xy.shape[0], np.inf)
    for i in ids:
        d = np.minimum(d, plane_distance(strut(skel, i), xy, z)[0])
    return int((~(d <= bound)).sum())


def compare_union_layer(skel: Skeleton, res, k: int, ids: list[int], sec: Section, bounds: list[float],
                        tol: float) -> dict:
    """The metrics of one layer (module docstring), keyed as :func:`validation.metrics.compare_layer`."""
    g = res.grid
    z = g.origin[2] + k * g.layer_height
    mask = layer_mask(res, k)
    H, W = mask.shape
    ours = union_contours(skel, g, k, ids, tol)
    ref = sec.polygons
    inter = ours.intersection(ref).area
    uni = ours.union(ref).area
    our_rings, ref_rings = polygon_rings(ours), polygon_rings(ref)
    haus = hausdorff(our_rings, ref_rings)
    bound = max(bounds) if bounds else 0.0
    mism = rasterize_rings(ref_rings, g.origin[:2], g.pixel_size, H, W) != mask
    own = rasterize_rings(our_rings, g.origin[:2], g.pixel_size, H, W)
    return {"z": float(z), "k": int(k), "iou": float(inter / uni) if uni > 0 else 1.0,
            "xor_area": float(ours.symmetric_difference(ref).area), "area": float(ours.area),
            "ref_area": float(ref.area), "hausdorff": haus, "hausdorff_px": haus / min(g.pixel_size),
            "pixel_mismatch": int(mism.sum()),
            "pixel_mismatch_unexplained": unexplained_pixels(skel, ids, mism, g.origin[:2], g.pixel_size, z, bound),
            "contour_raster_mismatch": int((own != mask).sum()),
            "contour_raster_unexplained": unexplained_pixels(skel, ids, own != mask, g.origin[:2], g.pixel_size, z,
                                                             tol),
            "vertex_max_3d": union_vertex_distance(skel, our_rings, z), "vertex_max_plane": float("nan"),
            "vertices": int(sum(len(r) for r in our_rings)), "valid": bool(ours.is_valid),
            "mesh_bound": bound, "mesh_first_order": float("nan"), "mesh_unbracketed": 0,
            "mesh_error_3d": sec.info.error_3d if sec.info else 0.0,
            "mesh_triangles": sec.info.triangles if sec.info else 0,
            "mesh_seconds": sec.info.seconds if sec.info else 0.0,
            "hausdorff_margin": bound + tol - haus, "struts": len(ids)}


def validate_union(skel: Skeleton, *, pixel_size=None, pixels: int = 512, pixel_size_y=None, layer_height=None,
                   bounds=None, method: str = "interval", bucket: int = DEFAULT_BUCKET, threads=None, strict: bool = False,
                   mesh_edge=None, layers_checked: int = 8, tol: float = 1e-3, max_hausdorff=None, min_iou=None,
                   progress=None) -> dict:
    """:func:`validation.validate.validate` for ``blend="union"`` (module docstring); same report layout."""
    tol = resolvable(tol, "contour tolerance", scene_reach(skel), GridError)
    if mesh_edge is not None:                           # before any work
        scene_step(mesh_edge, "mesh edge", skel, GridError)
    pixel_size, bounds = default_pitch(skel, pixel_size, pixels, bounds)
    t0 = time.perf_counter()
    res = slice_skeleton(skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                         blend="union")
    t_slice = time.perf_counter() - t0
    g = res.grid
    edge = scene_step(float(mesh_edge) if mesh_edge is not None else 0.5 * min(g.pixel_size), "mesh edge", skel,
                      GridError)
    rows, sections, ours_all = [], [], []
    t_ref = t_cmp = 0.0
    for k in pick_layers(res, int(layers_checked)):
        z = g.origin[2] + k * g.layer_height
        ids = struts_at(skel, z)
        t1 = time.perf_counter()
        sec, bnds = union_section(skel, z, edge, ids)
        t2 = time.perf_counter()
        row = compare_union_layer(skel, res, k, ids, sec, bnds, tol)
        t_cmp += time.perf_counter() - t2
        t_ref += t2 - t1
        rows.append(row)
        sections.append(sec)
        ours_all.append(None)
        if progress:
            progress(row)
    settings = {"method": method, "bucket": bucket, "strict": strict, "tol": tol, "mesh_edge": edge,
                "layers_checked": int(layers_checked), "max_hausdorff": max_hausdorff, "min_iou": min_iou,
                "blend": "union"}
    timings = {"slice_s": t_slice, "reference_s": t_ref, "contours_s": t_cmp, "metrics_s": 0.0}
    return assemble_report(rows, settings, g, timings, tol, max_hausdorff, min_iou, res, sections, ours_all)


__all__ = ["validate_union", "union_section", "union_contours", "compare_union_layer", "strut", "struts_at"]
