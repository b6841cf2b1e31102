"""``skelslice info SCENE``: scene statistics and warnings about struts that will not print."""
from __future__ import annotations

import json

import click
import numpy as np

from ..scene_io import load_scene
from .options import positive

#: an isolated segment shorter than this times its mean radius has no surface (docs/math.md §1.5)
MIN_ISOLATED_LENGTH = 0.688
#: how many offending segment/node indices a warning lists
_LISTED = 10


def scene_stats(skel, pixel_size: float | None = None) -> dict:
    """Statistics and warnings for a skeleton, as a JSON-ready dict (lengths in mm).

    Parameters
    ----------
    skel : Skeleton
    pixel_size : float, optional
        Pixel size in mm; enables the "thinner than a pixel" warning.

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
    add("duplicate", dup,
        lambda k: f"{k} duplicate segment{_s(k)} (same two nodes as an earlier one): "
                  f"the field counts them twice")
    add("unused_nodes", degree == 0,
        lambda k: f"{k} node{_s(k)} not used by any segment", what="nodes")
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
    """The text report of :func:`scene_stats`."""
    k, r, ln = stats["kernel"], stats["radius"], stats["segment_length"]
    lines = [
        f"scene:           {path}",
        f"nodes:           {stats['nodes']}",
        f"segments:        {stats['segments']}",
        f"kernel:          degree {k['degree']}, sigma {_g(k['sigma'])}",
        f"skeleton bounds: {_box(stats['bounds']['skeleton'])} mm",
        f"support bounds:  {_box(stats['bounds']['support'])} mm",
        f"radius:          {_g(r['min'])} .. {_g(r['max'])} mm (mean {_g(r['mean'])})",
        f"segment length:  {_g(ln['min'])} .. {_g(ln['max'])} mm (mean {_g(ln['mean'])})",
    ]
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
def command(scene: str, radius: float | None, pixel_size: float | None, as_json: bool) -> None:
    """Print statistics of SCENE (.json scene or .obj polylines) and warnings.

    Warnings: struts thinner than a pixel (radius < pixel/2), isolated
    segments too short to have any surface, segments whose end balls nest,
    duplicate segments and unused nodes.
    """
    skel = load_scene(scene, radius=radius)
    stats = scene_stats(skel, pixel_size)
    if as_json:
        click.echo(json.dumps({"scene": scene, **stats}, indent=2))
    else:
        click.echo(format_stats(scene, stats))
