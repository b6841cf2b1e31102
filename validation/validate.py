"""The validation job behind ``skelslice validate``.

Slice a scene, take a few layers, and compare each layer's contours with a
cross-section of the meshed field (:mod:`validation.reference_mesh`), with the
metrics of :mod:`validation.metrics`. Checks:

``hausdorff_within_mesh_bound``
    Contour Hausdorff distance to the meshed reference <= the reference's own
    error bound in the layer plane + the contour tolerance (the issue's
    acceptance criterion).
``vertices_on_surface``
    Every contour vertex within the contour tolerance of the exact
    iso-surface (``|F - 1| / |grad F|``, no mesh needed).
``contours_match_raster``
    Our polygons, rasterised at the pixel centres, reproduce our raster, and
    are valid.
``max_hausdorff``, ``min_iou``
    Optional user thresholds.
"""
from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from slicer.atomic import AtomicDir, check_destination
from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.arguments import resolvable, scene_reach, scene_step
from slicer.contours import layer_contours, layer_mask
from slicer.errors import GridError
from slicer.tracer.slicing import slice_skeleton

from validation.bench import square_bounds
from validation.metrics import compare_layer, contour_error_bound, polygon_rings, rasterize_rings, summarise
from validation.reference_mesh import reference_sections
from slicer.constants import DISTANCE_SLACK as SLACK



def pick_layers(result, n: int) -> list[int]:
    """``n`` layers evenly spread over the layers that have inside pixels."""
    if result.n_runs == 0 or n <= 0:
        return []
    occupied = np.zeros(result.grid.layers + 1, np.int64)
    np.add.at(occupied, result.k0, 1)
    np.add.at(occupied, result.k1, -1)
    ks = np.flatnonzero(np.cumsum(occupied)[:-1] > 0)
    if ks.size <= n:
        return [int(k) for k in ks]
    pos = np.linspace(0, ks.size - 1, n + 2)[1:-1]
    return sorted({int(ks[int(round(p))]) for p in pos})


def default_pitch(skel, pixel_size, pixels: int, bounds):
    """``(pixel_size, bounds)`` of a validation: without ``pixel_size``, a
    ``pixels`` x ``pixels`` image over the model's support box (and that
    square box as the bounds unless given)."""
    if pixel_size is None:
        if int(pixels) < 2:
            raise GridError(f"pixels must be >= 2, got {pixels}")
        sq, pixel_size = square_bounds(skel, int(pixels))
        if bounds is None:
            bounds = sq
    return pixel_size, bounds


def validate(skel, *, pixel_size: float | None = None, pixels: int = 512, pixel_size_y=None,
             layer_height=None, bounds=None, method: str = "interval", bucket: int = DEFAULT_BUCKET,
             threads=None, strict: bool = False, mesh_edge: float | None = None,
             layers_checked: int = 8, tol: float = 1e-3, max_hausdorff: float | None = None,
             min_iou: float | None = None, blend: str = "sum", progress=None) -> dict:
    """Slice ``skel`` and compare sampled layers with the meshed reference.

    Parameters
    ----------
    skel : Skeleton
    pixel_size : float, optional, mm
        Default: a ``pixels`` x ``pixels`` image over the model's support box
        (then ``bounds`` is that square box unless given).
    pixels : int
    pixel_size_y, layer_height, bounds, method, bucket, threads, strict
        As for :func:`slicer.tracer.slicing.slice_skeleton`.
    mesh_edge : float, optional, mm
        Reference mesh grid spacing; default half the smallest pixel pitch.
    layers_checked : int
    tol : float, mm
        Contour tolerance.
    max_hausdorff : float, optional, mm
    min_iou : float, optional
    blend : {"sum", "union"}
        Passed to the slicer. The reference and the contour metrics are those of the
        summed field, so ``skelslice validate`` refuses ``union``.

    Returns
    -------
    dict
        ``settings``, ``grid``, ``layers`` (per-layer metrics), ``summary``,
        ``checks`` (name -> bool), ``passed``, ``timings``; ``_sections`` and
        ``_result`` hold the objects the report images are drawn from.
    """
    tol = resolvable(tol, "contour tolerance", scene_reach(skel), GridError)
    if mesh_edge is not None:                           # before any work
        scene_step(mesh_edge, "mesh edge", skel, GridError)
    pixel_size, bounds = default_pitch(skel, pixel_size, pixels, bounds)
    t0 = time.perf_counter()
    res = slice_skeleton(skel, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
                         blend=blend)
    t_slice = time.perf_counter() - t0
    g = res.grid
    px, py = g.pixel_size
    edge = float(mesh_edge) if mesh_edge is not None else 0.5 * min(px, py)
    edge = scene_step(edge, "mesh edge", skel, GridError)
    ks = pick_layers(res, int(layers_checked))
    zs = [g.origin[2] + k * g.layer_height for k in ks]
    t1 = time.perf_counter()
    sections = reference_sections(skel, zs, edge)
    t_ref = time.perf_counter() - t1
    rows = []
    t_contours = 0.0
    t_metrics = 0.0
    ours_all = []
    for k, z, sec in zip(ks, zs, sections):
        t2 = time.perf_counter()
        ours = layer_contours(skel, res, k, tol)
        t_contours += time.perf_counter() - t2
        t3 = time.perf_counter()
        bound = contour_error_bound(skel, polygon_rings(sec.polygons), z)
        row = compare_layer(skel, ours, sec.polygons, z, layer_mask(res, k), g.origin[:2], g.pixel_size,
                            ref_bound=bound["bound"], tol=tol)
        t_metrics += time.perf_counter() - t3
        row.update({"k": k, "mesh_bound": bound["bound"], "mesh_first_order": bound["first_order"],
                    "mesh_unbracketed": bound["unbracketed"], "mesh_error_3d": sec.info.error_3d,
                    "mesh_triangles": sec.info.triangles, "mesh_seconds": sec.info.seconds})
        row["hausdorff_margin"] = row["mesh_bound"] + tol - row["hausdorff"]
        rows.append(row)
        ours_all.append(ours)
        if progress:
            progress(row)
    settings = {"method": method, "bucket": bucket, "strict": strict, "tol": tol, "mesh_edge": edge,
                "layers_checked": int(layers_checked), "max_hausdorff": max_hausdorff, "min_iou": min_iou}
    timings = {"slice_s": t_slice, "reference_s": t_ref, "contours_s": t_contours, "metrics_s": t_metrics}
    return assemble_report(rows, settings, g, timings, tol, max_hausdorff, min_iou, res, sections, ours_all)


def assemble_report(rows: list[dict], settings: dict, grid, timings: dict, tol: float, max_hausdorff, min_iou,
                    result, sections, ours) -> dict:
    """The report of :func:`validate` from its per-layer rows: summary, checks, verdict."""

    summary = summarise(rows)
    if rows:
        summary["max_mesh_bound"] = max(r["mesh_bound"] for r in rows)
        summary["max_mesh_error_3d"] = max(r["mesh_error_3d"] for r in rows)
        summary["min_hausdorff_margin"] = min(r["hausdorff_margin"] for r in rows)
    checks = {
        "hausdorff_within_mesh_bound": all(r["hausdorff_margin"] >= -SLACK for r in rows),
        "vertices_on_surface": all(r["vertex_max_3d"] <= tol + SLACK for r in rows),
        "contours_match_raster": all(r["contour_raster_unexplained"] == 0 and r["valid"] for r in rows),
    }
    if max_hausdorff is not None:
        checks["max_hausdorff"] = all(r["hausdorff"] <= max_hausdorff for r in rows)
    if min_iou is not None:
        checks["min_iou"] = all(r["iou"] >= min_iou for r in rows)
    return {
        "settings": settings, "grid": grid.to_dict(), "layers": rows, "summary": summary, "checks": checks,
        "passed": bool(rows) and all(checks.values()), "timings": timings,
        "_result": result, "_sections": sections, "_ours": ours,
    }


def format_table(report: dict) -> str:
    """The per-layer table printed by ``skelslice validate``."""
    head = (f"{'layer':>6}{'z mm':>10}{'IoU':>10}{'XOR mm2':>11}{'Haus um':>9}{'px':>7}"
            f"{'mesh um':>9}{'vert um':>9}{'pix':>6}{'unexpl':>7}")
    lines = [head, "-" * len(head)]
    for r in report["layers"]:
        lines.append(f"{r['k']:>6}{r['z']:>10.4f}{r['iou']:>10.6f}{r['xor_area']:>11.2e}"
                     f"{r['hausdorff'] * 1e3:>9.3f}{r['hausdorff_px']:>7.3f}{r['mesh_bound'] * 1e3:>9.3f}"
                     f"{r['vertex_max_3d'] * 1e3:>9.4f}{r['pixel_mismatch']:>6}"
                     f"{r['pixel_mismatch_unexplained']:>7}")
    s = report["summary"]
    if s:
        lines.append("-" * len(head))
        lines.append(f"worst: IoU {s['min_iou']:.6f}, Hausdorff {s['max_hausdorff'] * 1e3:.3f} um "
                     f"({s['max_hausdorff_px']:.3f} px), mesh bound {s['max_mesh_bound'] * 1e3:.3f} um, "
                     f"vertex distance {s['vertex_max_3d'] * 1e3:.4f} um, pixel mismatches "
                     f"{s['pixel_mismatch']} ({s['pixel_mismatch_unexplained']} unexplained)")
    for name, ok in report["checks"].items():
        lines.append(f"  [{'pass' if ok else 'FAIL'}] {name}")
    return "\n".join(lines)


def overlay_image(mask: np.ndarray, ref_rings: list[np.ndarray], ref_raster: np.ndarray, origin,
                  pixel_size, max_side: int = 1024):
    """A PIL image: our raster in grey, pixels only we have in red, pixels only
    the reference has in blue, the reference outline in green."""

    H, W = mask.shape
    scale = max(1, min(8, max_side // max(H, W)))
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[mask] = (150, 150, 150)
    rgb[mask & ~ref_raster] = (230, 40, 40)
    rgb[~mask & ref_raster] = (40, 90, 255)
    img = Image.fromarray(rgb).resize((W * scale, H * scale), Image.NEAREST)
    draw = ImageDraw.Draw(img)
    for r in ref_rings:
        u = ((r[:, 0] - origin[0]) / pixel_size[0] + 0.5) * scale
        v = ((origin[1] - r[:, 1]) / pixel_size[1] + 0.5) * scale
        pts = list(zip(u.tolist(), v.tolist()))
        draw.line(pts + pts[:1], fill=(40, 220, 60), width=1)
    return img


def write_report(report: dict, out, force: bool = False, images: int = 4) -> Path:
    """Write ``report.json`` and overlay PNGs of the worst layers to folder ``out``, atomically."""

    out = Path(out)
    check_destination(out, force)
    tmp = AtomicDir(out)
    try:
        res = report["_result"]
        g = res.grid
        rows = report["layers"]
        worst = sorted(range(len(rows)), key=lambda q: -rows[q]["hausdorff_px"])[:images]
        files = []
        for q in sorted(worst):
            r = rows[q]
            sec = report["_sections"][q]
            mask = layer_mask(res, r["k"])
            rings = polygon_rings(sec.polygons)
            ref_raster = rasterize_rings(rings, g.origin[:2], g.pixel_size, g.height, g.width)
            name = f"overlay_{r['k']:05d}.png"
            buf = io.BytesIO()
            overlay_image(mask, rings, ref_raster, g.origin[:2], g.pixel_size).save(buf, format="PNG")
            tmp.write_file(name, buf.getvalue())
            files.append(name)
        public = {k: v for k, v in report.items() if not k.startswith("_")}
        public["images"] = files
        public["legend"] = {"grey": "inside (ours and reference)", "red": "inside only in ours",
                            "blue": "inside only in the reference", "green": "reference outline"}
        tmp.write_file("report.json", (json.dumps(public, indent=1) + "\n").encode())
        tmp.publish(force)
    except BaseException:
        tmp.discard()
        raise
    return out


__all__ = ["validate", "assemble_report", "format_table", "write_report", "pick_layers", "overlay_image"]
