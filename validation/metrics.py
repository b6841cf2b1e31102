"""Comparison of layer contours with a reference, and their distance to the
exact iso-surface.

All lengths are mm. Distances "in the plane" are measured within the layer
plane, which is what a printer reproduces; near horizontal surfaces they are
larger than 3-D distances by ``1 / |n_xy|``.
"""
from __future__ import annotations

import numpy as np

from slicer.model.field import evaluate

from validation.independent import plane_distance, project


def polygon_rings(mp) -> list[np.ndarray]:
    """Every ring (exteriors and holes) of a (Multi)Polygon, as (n, 2) arrays
    without the closing vertex."""
    rings = []
    for poly in getattr(mp, "geoms", [mp]):
        if poly.is_empty:
            continue
        for ring in [poly.exterior, *poly.interiors]:
            c = np.asarray(ring.coords)[:-1, :2]
            if c.shape[0]:
                rings.append(c)
    return rings


def _edge_points(rings: list[np.ndarray], per_edge: int) -> np.ndarray:
    """Vertices plus ``per_edge - 1`` evenly spaced points inside every edge."""
    p = np.concatenate(rings)
    q = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
    s = (np.arange(per_edge) / per_edge)[None, :, None]
    return (p[:, None, :] + s * (q - p)[:, None, :]).reshape(-1, 2)


def _segments(rings: list[np.ndarray]):
    import shapely

    p = np.concatenate(rings)
    q = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
    return shapely.linestrings(np.stack([p, q], axis=1))


def hausdorff(rings_a: list[np.ndarray], rings_b: list[np.ndarray], per_edge: int = 4) -> float:
    """Hausdorff distance between two sets of closed polylines, mm.

    Points of each set (vertices and ``per_edge - 1`` points per edge, as
    shapely's ``densify=1/per_edge``) are measured exactly to the nearest
    edge of the other set (an STR-tree of the edges), so the cost is
    O(n log m), not shapely's O(n m).
    """
    import shapely

    if not rings_a and not rings_b:
        return 0.0
    if not rings_a or not rings_b:
        return float("inf")
    worst = 0.0
    for src, dst in ((rings_a, rings_b), (rings_b, rings_a)):
        tree = shapely.STRtree(_segments(dst))
        pts = shapely.points(_edge_points(src, per_edge))
        _, d = tree.query_nearest(pts, return_distance=True, all_matches=False)
        worst = max(worst, float(d.max()))
    return worst


def rasterize_rings(rings: list[np.ndarray], origin, pixel_size, height: int, width: int) -> np.ndarray:
    """Pixel centres inside closed rings (even-odd rule), exactly.

    A scanline rasteriser: each ring edge toggles, on every row whose centre
    ``y`` it crosses (half-open in y), the pixels whose centre lies right of
    the crossing.

    Parameters
    ----------
    rings : list of (n_q, 2) float64, mm
    origin : (2,) float64, mm
        Centre of pixel (row 0, column 0); rows run toward -y.
    pixel_size : (2,) float64, mm
    height, width : int

    Returns
    -------
    (height, width) bool
    """
    x0, y0 = float(origin[0]), float(origin[1])
    px, py = float(pixel_size[0]), float(pixel_size[1])
    toggles = np.zeros((height, width + 1), np.int64)
    if rings:
        p = np.concatenate(rings)
        q = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
        ylo = np.minimum(p[:, 1], q[:, 1])
        yhi = np.maximum(p[:, 1], q[:, 1])
        jmin = np.clip(np.floor((y0 - yhi) / py).astype(np.int64), 0, height)
        jmax = np.clip(np.ceil((y0 - ylo) / py).astype(np.int64) + 1, 0, height)
        count = np.maximum(jmax - jmin, 0)
        e = np.repeat(np.arange(p.shape[0]), count)
        j = np.repeat(jmin - np.cumsum(count) + count, count) + np.arange(count.sum())
        yj = y0 - j * py
        keep = (ylo[e] <= yj) & (yj < yhi[e])
        e, j, yj = e[keep], j[keep], yj[keep]
        xp, yp, xq, yq = p[e, 0], p[e, 1], q[e, 0], q[e, 1]
        x = xp + (yj - yp) * (xq - xp) / (yq - yp)
        i0 = np.clip(np.floor((x - x0) / px).astype(np.int64) + 1, 0, width)
        np.add.at(toggles, (j, i0), 1)
    return (np.cumsum(toggles, axis=1)[:, :width] & 1).astype(bool)


def vertex_surface_distance(skel, rings: list[np.ndarray], z: float) -> dict:
    """Distance of contour vertices to the exact iso-surface (no mesh needed).

    Returns
    -------
    dict
        ``max_3d``: largest ``|F - 1| / |grad F|``; ``max_plane``: largest
        ``|F - 1| / |grad_xy F|``; ``vertices``.
    """
    if not rings:
        return {"max_3d": 0.0, "max_plane": 0.0, "vertices": 0}
    xy = np.concatenate(rings)
    p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
    f, g = evaluate(skel, p, gradient=True)
    gn = np.sqrt((g * g).sum(axis=1))
    gxy = np.hypot(g[:, 0], g[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        d3 = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
        d2 = np.where(gxy > 0, np.abs(f - 1.0) / gxy, np.inf)
    return {"max_3d": float(d3.max()), "max_plane": float(d2.max()), "vertices": int(xy.shape[0])}


def contour_error_bound(skel, rings: list[np.ndarray], z: float, tol: float = 1e-5,
                        samples: int = 12) -> dict:
    """How far a polyline contour (e.g. a mesh section) is from the exact one.

    Each edge is sampled at ``samples`` points (vertices included); every
    sample is projected onto the exact contour along its in-plane gradient
    line (:func:`validation.independent.project`), and its distance to
    that root, plus ``tol``, bounds its distance to the exact contour. A point
    of an edge is at most half the sample spacing from a sample, so the
    largest sample bound plus half the largest sample spacing bounds the
    distance of every point of the polyline to the exact contour (``bound``,
    rigorous where every sample bracketed a root; the exact contour's parts
    the polyline misses are not covered: the dense section tests are).

    Returns
    -------
    dict
        ``bound``: largest such distance plus half the sample spacing, mm
        (first-order estimate where no root was bracketed); ``first_order``: largest ``|F - 1| / |grad_xy F|``;
        ``unbracketed``: samples without a root; ``samples``.
    """
    if not rings:
        return {"bound": 0.0, "first_order": 0.0, "unbracketed": 0, "samples": 0}
    longest = max((float(np.hypot(*(np.roll(r, -1, axis=0) - r).T).max()) for r in rings if len(r)), default=0.0)
    pts = _edge_points(rings, samples)
    roots, ok, first = project(skel, pts, z, tol)
    d = np.where(ok, np.hypot(*(roots - pts).T) + tol, first)
    half = 0.5 * longest / samples
    finite = d[np.isfinite(d)]
    fo = first[np.isfinite(first)]
    return {"bound": float(finite.max()) + half if finite.size else 0.0,
            "first_order": float(fo.max()) if fo.size else 0.0,
            "unbracketed": int((~ok).sum()), "samples": int(pts.shape[0])}


def compare_layer(skel, ours, ref, z: float, mask: np.ndarray, origin, pixel_size,
                  ref_bound: float | None = None, tol: float = 0.0) -> dict:
    """All metrics of one layer.

    Parameters
    ----------
    skel : Skeleton
    ours, ref : shapely.MultiPolygon, mm
        Our contours and the reference section.
    z : float, mm
    mask : (H, W) bool
        Our raster (pixel centres classified by the tracer).
    origin, pixel_size : (2,) float64, mm
        Raster placement (centre of pixel (0, 0); rows run toward -y).
    ref_bound : float, optional, mm
        The reference's own error bound; mismatched pixels whose centre is
        within it of the exact contour are counted as explained.

    Returns
    -------
    dict
        ``iou``, ``xor_area`` (mm^2), ``area``, ``ref_area``,
        ``hausdorff`` (mm), ``hausdorff_px``, ``pixel_mismatch`` (ours vs the
        reference rasterised at pixel centres), ``pixel_mismatch_unexplained``,
        ``contour_raster_mismatch`` (our polygons rasterised vs our raster),
        ``contour_raster_unexplained`` (those whose centre is farther than
        ``tol`` from the surface: 0 for consistent contours), ``vertex_max_3d``, ``vertex_max_plane``.
    """
    H, W = mask.shape
    inter = ours.intersection(ref).area
    union = ours.union(ref).area
    iou = inter / union if union > 0 else 1.0
    xor = ours.symmetric_difference(ref).area
    our_rings = polygon_rings(ours)
    ref_rings = polygon_rings(ref)
    haus = hausdorff(our_rings, ref_rings)
    ref_raster = rasterize_rings(ref_rings, origin, pixel_size, H, W)
    own_raster = rasterize_rings(our_rings, origin, pixel_size, H, W)
    mism = ref_raster != mask
    jj, ii = np.nonzero(mism)
    unexplained = int(mism.sum())
    if unexplained and ref_bound is not None:
        xy = np.column_stack([origin[0] + ii * pixel_size[0], origin[1] - jj * pixel_size[1]])
        d, _, _ = plane_distance(skel, xy, z)
        unexplained = int((~(d <= ref_bound)).sum())
    own = own_raster != mask
    own_unexplained = int(own.sum())
    if own_unexplained:        # a pixel centre within tol of the surface may fall on either side of a vertex
        oj, oi = np.nonzero(own)
        xy = np.column_stack([origin[0] + oi * pixel_size[0], origin[1] - oj * pixel_size[1]])
        d, _, _ = plane_distance(skel, xy, z)
        own_unexplained = int((~(d <= tol * (1 + 1e-9))).sum())
    vd = vertex_surface_distance(skel, our_rings, z)
    return {"z": float(z), "iou": float(iou), "xor_area": float(xor), "area": float(ours.area),
            "ref_area": float(ref.area), "hausdorff": haus,
            "hausdorff_px": haus / min(pixel_size[0], pixel_size[1]),
            "pixel_mismatch": int(mism.sum()), "pixel_mismatch_unexplained": unexplained,
            "contour_raster_mismatch": int(own.sum()), "contour_raster_unexplained": own_unexplained,
            "vertex_max_3d": vd["max_3d"], "vertex_max_plane": vd["max_plane"],
            "vertices": vd["vertices"], "valid": bool(ours.is_valid)}


def summarise(rows: list[dict]) -> dict:
    """Worst values over layers."""
    if not rows:
        return {}
    def mx(key):
        return max(r[key] for r in rows)
    return {"layers": len(rows), "min_iou": min(r["iou"] for r in rows), "max_xor_area": mx("xor_area"),
            "max_hausdorff": mx("hausdorff"), "max_hausdorff_px": mx("hausdorff_px"),
            "pixel_mismatch": sum(r["pixel_mismatch"] for r in rows),
            "pixel_mismatch_unexplained": sum(r["pixel_mismatch_unexplained"] for r in rows),
            "contour_raster_mismatch": sum(r["contour_raster_mismatch"] for r in rows),
            "vertex_max_3d": mx("vertex_max_3d"), "vertex_max_plane": mx("vertex_max_plane"),
            "all_valid": all(r["valid"] for r in rows)}


__all__ = ["polygon_rings", "hausdorff", "rasterize_rings", "vertex_surface_distance", "contour_error_bound",
           "compare_layer", "summarise"]
