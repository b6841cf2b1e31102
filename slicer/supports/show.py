"""How supported scenes are shown and described: renders with supports in their own
colour, counts and resin, and the outputs that refuse support groups.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from slicer.errors import OptionError
from slicer.render.rendering import Camera, make_camera, render
from slicer.model.skeleton import Skeleton
from slicer.supports.groups import SUPPORT_ROLES, is_grouped

#: colour the supports and the pad are drawn in (RGB, 0..1): orange
SUPPORT_COLOUR = (1.0, 0.55, 0.1)


def render_scene(skel, size=(700, 700), view: str = "iso", camera="ortho", fov: float = 35.0, eye=None, target=None,
                 **kw):
    """:func:`slicer.render.rendering.render` of a scene; a supported scene's supports and pad are
    rendered on their own with the same camera, tinted :data:`SUPPORT_COLOUR` and drawn
    behind the model (the model's picture over the supports', each transparent).

    Returns
    -------
    slicer.render.rendering.RenderResult
    """
    if not is_grouped(skel):
        return render(skel, size, view, camera, fov, eye, target, **kw)
    if kw.get("keep_roots"):
        raise OptionError("the crossings (--roots-out) of a scene with support groups are not kept: render the "
                          "model and the supports as separate scenes")
    cam = camera if isinstance(camera, Camera) else make_camera(skel, size, view, camera, fov, eye, target)
    model = render(skel.group_skeleton(0), camera=cam, **kw)
    mask = skel.role_mask(SUPPORT_ROLES)
    sup = render(Skeleton(skel.nodes, skel.segments[mask], skel.radii[mask], skel.degree, skel.sigma),
                 camera=cam, **kw)
    tint = np.array(SUPPORT_COLOUR)
    grey = sup.rgba[..., :3].mean(axis=2, keepdims=True)
    s = np.concatenate([grey * tint, sup.rgba[..., 3:4]], axis=2)
    rgba = model.rgba + (1.0 - model.rgba[..., 3:4]) * s
    stats = {k: (v + sup.stats.get(k, 0) if k.endswith("evaluations") or k in ("roots", "rays_cut", "seconds")
                 else v) for k, v in model.stats.items()}
    return dataclasses.replace(model, rgba=rgba, count=model.count + sup.count, roots=None, stats=stats)


def support_stats(skel) -> dict | None:
    """Counts and an estimate of the resin of a supported scene's supports (None for a
    scene without support groups).

    The resin estimate sums each support and pad strut as a truncated cone
    (``pi L (r1^2 + r1 r2 + r2^2) / 3``): overlaps count twice and the rounded
    ends not at all; ``skelslice check`` measures the voxels instead.

    Returns
    -------
    dict
        ``model_struts``, ``support_struts``, ``pad_struts``, ``heads`` (struts
        whose tip is the smallest radius of the supports), ``resin_ml_estimate``.
    """
    if not is_grouped(skel):
        return None
    a, b = skel.endpoints()
    length = np.linalg.norm(b - a, axis=1)
    r1, r2 = skel.radii[:, 0], skel.radii[:, 1]
    vol = np.pi * length * (r1 * r1 + r1 * r2 + r2 * r2) / 3.0
    sup, pad, model = skel.role_mask(("support",)), skel.role_mask(("pad",)), skel.role_mask(("model",))
    heads = int(np.sum(sup & (np.minimum(r1, r2) < np.maximum(r1, r2))))
    return {"model_struts": int(model.sum()), "support_struts": int(sup.sum()), "pad_struts": int(pad.sum()),
            "heads": heads, "resin_ml_estimate": round(float(vol[sup | pad].sum()) / 1000.0, 6)}


def support_line(sup: dict) -> str:
    """One line of :func:`support_stats` for people."""
    return (f"supports:        {sup['heads']} heads, {sup['support_struts']} support and "
            f"{sup['pad_struts']} pad struts "
            f"after the model's {sup['model_struts']}; resin about {sup['resin_ml_estimate']:.3g} ml (struts as cones)")


def support_voxels(skel, result) -> dict | None:
    """What the supports add to a traced job: voxels and resin (ml) beyond the model's own
    (from :func:`slicer.supports.groups.trace_groups`' counts), or None."""
    st = getattr(result, "stats", {}) or {}
    if not is_grouped(skel) or "support_voxels" not in st:
        return None
    g = result.grid
    vol = g.pixel_size[0] * g.pixel_size[1] * g.layer_height
    n = int(st["support_voxels"])
    return {"voxels": n, "resin_ml": round(n * vol / 1000.0, 6)}


def refuse_grouped(skel, what: str) -> None:
    """Refuse a supported scene where only the summed field is implemented (``what``: the
    contours, validate), by name (:class:`OptionError`)."""
    inner = getattr(skel, "skeleton", skel)
    if is_grouped(inner):
        raise OptionError(f"{what} of a scene with support groups is not supported (it would evaluate the "
                          f"supports blended into the model); slice it to images or a printer format")


__all__ = ["SUPPORT_COLOUR", "render_scene", "support_stats", "support_line", "support_voxels", "refuse_grouped"]
