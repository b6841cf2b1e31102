"""``skelslice info SCENE``: scene statistics and warnings about struts that will not print."""
from __future__ import annotations

import json

import click
import numpy as np

from slicer.arguments import fmt_num
from slicer.errors import GridError
from slicer.tracer.grid import MAX_VOXELS, make_grid
from slicer.supports.show import support_line, support_stats
from slicer.cli.commands.options import blend_option, load_part_from, part_options, positive

#: an isolated segment shorter than this times its mean radius has no surface (docs/math.md §1.5)
MIN_ISOLATED_LENGTH = 0.688
#: image size of a default ``render`` (the "nothing visible" warning)
RENDER_SIZE = 700
#: how many offending segment/node indices a warning lists
_LISTED = 10


def scene_stats(skel, pixel_size: float | None = None, blend: str = "sum") -> dict:
    """Statistics and warnings for a skeleton, as a JSON-ready dict (lengths in mm).

    Parameters
    ----------
    skel : Skeleton
    pixel_size : float, optional
        Pixel size in mm; enables the "thinner than a pixel" warning.
    blend : {"sum", "union"}
        With ``union`` a duplicate segment changes nothing (no warning).

    Returns
    -------
    dict
        ``nodes``, ``segments``, ``kernel``, ``bounds`` (``skeleton`` and
        ``support``, each ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``),
        ``radius`` and ``segment_length`` (``min``/``max``/``mean``),
        ``pixel_size`` and ``warnings`` (a list of dicts with ``kind``,
        ``count``, ``message`` and the first offending ``segments`` or
        ``nodes``).
    """
    nodes, seg, radii = skel.nodes, skel.segments, skel.radii
    a, b = skel.endpoints()
    length = np.linalg.norm(b - a, axis=1)
    degree = np.bincount(seg.ravel(), minlength=skel.n_nodes)
    used = nodes[degree > 0]
    stats = {
        "nodes": skel.n_nodes,
        "segments": skel.n_segments,
        "kernel": {"degree": skel.degree, "sigma": skel.sigma},
        "bounds": {
            "skeleton": [used.min(axis=0).tolist(), used.max(axis=0).tolist()],
            "support": skel.support_bounds().tolist(),
        },
        "radius": _range(radii),
        "segment_length": _range(length),
        "pixel_size": pixel_size,
        "blend": blend,
        "warnings": [],
    }
    warn = stats["warnings"]

    def add(kind, mask, message, what="segments"):
        idx = np.nonzero(mask)[0]
        if idx.size:
            listed = ", ".join(str(int(i)) for i in idx[:_LISTED]) + (", ..." if idx.size > _LISTED else "")
            warn.append({"kind": kind, "count": int(idx.size),
                         "message": message(idx.size) + f" ({what[:-1] if idx.size == 1 else what} {listed})",
                         what: idx[:_LISTED].tolist()})

    if pixel_size is not None:
        thin = radii.min(axis=1) < pixel_size / 2
        add("thin", thin,
            lambda k: f"{k} segment{_s(k)} thinner than a pixel: radius < {pixel_size / 2:.6g} mm "
                      f"(half the pixel size {pixel_size:.6g} mm), down to {float(radii.min()):.6g} mm")
    isolated = (degree[seg[:, 0]] == 1) & (degree[seg[:, 1]] == 1)
    short = isolated & (length < MIN_ISOLATED_LENGTH * radii.mean(axis=1))
    add("short_isolated", short,
        lambda k: f"{k} isolated segment{_s(k)} shorter than {MIN_ISOLATED_LENGTH} x mean radius: "
                  f"no surface at all")
    nested = skel.sigma * np.abs(radii[:, 1] - radii[:, 0]) > length
    add("nested_ends", nested,
        lambda k: f"{k} segment{_s(k)} whose end support balls nest "
                  f"(sigma x |r1 - r0| > length): the thinner end's support lies inside the thicker end's")
    key = np.sort(seg, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    dup = np.ones(skel.n_segments, dtype=bool)
    dup[first] = False
    if blend == "union":
        dup[:] = False                    # the maximum of two equal fields is the field
    add("duplicate", dup,
        lambda k: f"{k} duplicate segment{_s(k)} (same two nodes as an earlier one): "
                  f"the field counts them twice")
    add("unused_nodes", degree == 0,
        lambda k: f"{k} node{_s(k)} not used by any segment", what="nodes")
    warn.extend(_degenerate(skel, pixel_size))
    return stats


def _degenerate(skel, pixel_size: float | None) -> list[dict]:
    """Warnings about scenes that cannot be printed or seen as a whole: an extent far beyond the
    thinnest strut, struts all far below the pixel, a grid the slicer would refuse, and a default
    render in which no strut is as wide as a pixel."""
    out = []
    box = skel.support_bounds()
    span = np.ptp(box, axis=0)
    rmin, rmax = float(skel.radii.min()), float(skel.radii.max())
    cells = float(np.prod(np.floor(span / (2.0 * rmin)) + 1.0))
    if cells > MAX_VOXELS:
        out.append({"kind": "extreme_extent", "count": 1, "message":
                    f"extreme extent: the scene spans {fmt_num(float(span.max()))} mm, "
                    f"{fmt_num(float(span.max()) / rmin)} times its thinnest radius {fmt_num(rmin)} mm; a grid fine "
                    f"enough for that strut (pixel {fmt_num(2 * rmin)} mm) would have {cells:.3g} voxels "
                    f"(limit {MAX_VOXELS:.0e})"})
    if pixel_size is not None:
        if rmax < pixel_size / 2:
            out.append({"kind": "all_thin", "count": 1, "message":
                        f"every strut is thinner than a pixel (largest radius {fmt_num(rmax)} mm < half the pixel "
                        f"size {fmt_num(pixel_size)} mm): the layers may show nothing at all"})
        try:
            make_grid(box, pixel_size)
        except GridError as exc:
            out.append({"kind": "grid", "count": 1, "message": f"slicing at pixel size {fmt_num(pixel_size)} mm "
                                                               f"would be refused: {exc}"})
    pixel = float(span.max()) / RENDER_SIZE
    if rmax < pixel / 2:
        out.append({"kind": "render_empty", "count": 1, "message":
                    f"nothing visible in a default render: a {RENDER_SIZE}-pixel image of the whole scene has "
                    f"{fmt_num(pixel)} mm pixels, more than twice the largest radius {fmt_num(rmax)} mm"})
    return out


def part_stats(part, pixel_size: float | None = None, blend: str = "sum") -> dict:
    """:func:`scene_stats` of a part: the lattice's statistics (if any) and its meshes.

    Returns
    -------
    dict
        The keys of :func:`scene_stats` (``nodes`` and ``segments`` 0 and no
        lattice bounds for a mesh-only part), plus ``meshes`` (per mesh:
        ``name``, ``role``, ``faces``, ``vertices``, ``volume`` mm^3,
        ``area`` mm^2, ``bounds``), ``bounds.part`` and ``notes``.
    """
    if part.skeleton is not None:
        stats = scene_stats(part.skeleton, pixel_size, blend)
    else:
        stats = {"nodes": 0, "segments": 0, "kernel": None, "bounds": {}, "radius": None, "segment_length": None,
                 "pixel_size": pixel_size, "blend": blend, "warnings": []}
    stats["meshes"] = [{"name": pm.mesh.name, "role": pm.role, "faces": pm.mesh.n_faces,
                        "vertices": int(pm.mesh.vertices.shape[0]), "volume": pm.mesh.volume(),
                        "area": pm.mesh.area(), "bounds": pm.mesh.bounds().tolist()} for pm in part.meshes]
    stats["bounds"]["part"] = part.support_bounds().tolist()
    stats["notes"] = list(part.notes)
    return stats


def _s(k: int) -> str:
    return "" if k == 1 else "s"


def _range(x: np.ndarray) -> dict:
    return {"min": float(x.min()), "max": float(x.max()), "mean": float(x.mean())}


def _g(x: float) -> str:
    return f"{x:.6g}"


def _box(box) -> str:
    lo, hi = box
    size = [h - l for l, h in zip(lo, hi)]
    return (f"[{', '.join(map(_g, lo))}] .. [{', '.join(map(_g, hi))}]"
            f"  (size {' x '.join(map(_g, size))})")


def format_stats(path: str, stats: dict) -> str:
    """The text report of :func:`scene_stats` (or :func:`part_stats`)."""
    k, r, ln = stats["kernel"], stats["radius"], stats["segment_length"]
    lines = [f"scene:           {path}"]
    if stats["segments"]:
        lines += [
            f"nodes:           {stats['nodes']}",
            f"segments:        {stats['segments']}",
            f"kernel:          degree {k['degree']}, sigma {_g(k['sigma'])}"
            + (f", blend {stats['blend']}" if stats.get("blend", "sum") != "sum" else ""),
            f"skeleton bounds: {_box(stats['bounds']['skeleton'])} mm",
            f"support bounds:  {_box(stats['bounds']['support'])} mm",
            f"radius:          {_g(r['min'])} .. {_g(r['max'])} mm (mean {_g(r['mean'])})",
            f"segment length:  {_g(ln['min'])} .. {_g(ln['max'])} mm (mean {_g(ln['mean'])})",
        ]
    else:
        lines.append("lattice:         none (a mesh-only part)")
    for m in stats.get("meshes", ()):
        lines.append(f"mesh ({m['role']}):" + " " * max(1, 11 - len(m["role"])) + f"{m['name']}: {m['faces']:,} faces, "
                     f"volume {_g(m['volume'])} mm^3, {_box(m['bounds'])} mm")
    if stats.get("meshes"):
        lines.append(f"part bounds:     {_box(stats['bounds']['part'])} mm")
    for n in stats.get("notes", ()):
        lines.append(f"note:            {n}")
    if stats["pixel_size"] is None:
        lines.append("pixel size:      not given (pass --pixel-size to check strut thickness)")
    else:
        lines.append(f"pixel size:      {_g(stats['pixel_size'])} mm")
    if stats["warnings"]:
        lines.append(f"warnings:        {len(stats['warnings'])}")
        lines.extend(f"  warning: {w['message']}" for w in stats["warnings"])
    else:
        lines.append("warnings:        none")
    return "\n".join(lines)


@click.command("info")
@click.argument("scene", type=click.Path(path_type=str))
@click.option("--radius", type=float, default=None, callback=positive, metavar="MM",
              help="Radius for segment ends the file gives none for (radii in the file win).")
@click.option("--pixel-size", type=float, default=None, callback=positive, metavar="MM",
              help="Pixel size; warn about struts thinner than one pixel.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of text.")
@part_options
@blend_option
def command(scene: str, radius: float | None, pixel_size: float | None, as_json: bool, solids, clips_inside,
            clips_outside, repair, blend) -> None:
    """Print statistics of SCENE (a .json scene, .obj polylines, a .3mf build, or an .stl / .ply mesh) and warnings.

    Warnings: struts thinner than a pixel (radius < pixel/2), isolated
    segments too short to have any surface, segments whose end balls nest,
    duplicate segments and unused nodes. Meshes (of the scene, and
    --solid/--clip-inside/--clip-outside) are listed with their role, faces,
    volume and bounds; a mesh that is not a closed solid is an error.
    """
    part = load_part_from(scene, radius, solids, clips_inside, clips_outside, repair, quiet=True)
    stats = part_stats(part, pixel_size, blend)
    sup = support_stats(part.skeleton)                     # a supported scene's groups
    if sup is not None:
        stats["supports"] = sup
    if as_json:
        click.echo(json.dumps({"scene": scene, **stats}, indent=2))
    else:
        click.echo(format_stats(scene, stats) + (f"\n{support_line(sup)}" if sup is not None else ""))
