"""Transparent rendering of parts: the lattice's crossings and the meshes', composited in depth order.

The lattice is rendered by :func:`slicer.render.rendering.render` with every crossing
kept (``keep_roots``); each mesh role's crossings come from its faces: a face
covers the pixel centres inside its screen projection
(:func:`slicer.parts.mesh_slicing.column_hits`, each centre on a shared edge counted
once) and meets the pixel's ray where the ray meets its plane. Along every
ray the inside intervals of the lattice (between consecutive roots, the ray
starting outside) and of each role (positive fill rule) are combined as the
part is, ``((lattice ∩ CI) − CO) ∪ S``; the ends of the combined intervals are
the part's crossings. Each is shaded with the normal of the surface it comes
from (the field's gradient, or the face's normal) by the renderer's own
shading and composited front to back
(:func:`slicer._kernels.render.composite.composite_crossings`).
"""
from __future__ import annotations

import time

import numpy as np

from slicer._kernels.render.composite import composite_crossings
from slicer.errors import GridError
from slicer.model.field import evaluate
from slicer.parts.mesh_slicing import Soup, column_hits, combine_intervals, fill_spans, part_op
from slicer.parts.part import Part, as_part
from slicer.render.rendering import RenderResult, _fraction, _shade_array, make_camera, render
from slicer.model.skeleton import Skeleton

_ROLES = ("clip-inside", "clip-outside", "solid")


def _frame_proxy(part: Part) -> Skeleton:
    """A skeleton whose supports span the part's printed box (the camera frames it)."""
    lo, hi = part.print_bounds()
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    r = 1e-6 * float(np.linalg.norm(hi - lo)) + 1e-12
    return Skeleton(c, [[0, 7], [1, 6], [2, 5], [3, 4]], np.full((4, 2), r))


def mesh_hits(soup: Soup, cam) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of every pixel's ray with a soup of faces.

    Returns
    -------
    pix : (c,) int64
        Row-major pixel index.
    t : (c,) float64, mm
        Distance along the ray.
    sign : (c,) int8
        +1 where the ray enters (the face looks toward the viewer).
    normal : (c, 3) float64
        Unit outward normal of the face.
    """
    W, H = cam.width, cam.height
    origin, direction = cam.rays()
    o, d = origin.reshape(-1, 3), direction.reshape(-1, 3)
    tri = soup.tri
    w = tri - cam.origin
    if cam.kind == "ortho":
        xs = (w @ cam.right) / cam.pixel - 0.5
        ys = -(w @ cam.up) / cam.pixel - 0.5
        front = np.ones(tri.shape[0], bool)
    else:
        depth = w @ cam.forward
        front = np.all(depth > 0, axis=1)
        dz = np.where(depth > 0, depth, 1.0)
        xs = (w @ cam.right) / dz / cam.pixel + 0.5 * W - 0.5
        ys = -(w @ cam.up) / dz / cam.pixel + 0.5 * H - 0.5
    keep = np.flatnonzero(front)
    xy = np.stack([xs[keep], -ys[keep]], axis=2)           # pixel centre (i, j) at (i, -j)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nn = n / np.linalg.norm(n, axis=1)[:, None]
    out = [], [], [], []
    for pix, f in column_hits(xy, 0.0, 0.0, 1.0, 1.0, W, H):
        f = keep[f]
        dn = np.einsum("ij,ij->i", d[pix], n[f])
        ok = dn != 0
        pix, f, dn = pix[ok], f[ok], dn[ok]
        t = np.einsum("ij,ij->i", tri[f, 0] - o[pix], n[f]) / dn
        fwd = t >= 0
        out[0].append(pix[fwd])
        out[1].append(t[fwd])
        out[2].append(np.where(dn[fwd] < 0, 1, -1).astype(np.int8))
        out[3].append(nn[f[fwd]])
    if not out[0]:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int8), np.zeros((0, 3))
    return tuple(np.concatenate(x) for x in out)


def render_part(part, size=(700, 700), view: str = "iso", camera: str = "ortho", fov: float = 35.0, eye=None,
                target=None, opacity: float = 0.3, max_opacity: float = 0.99, opaque: bool = False,
                tolerance: float | None = None, keep_roots: bool = False, bisection: bool = False,
                strict: bool = False, bucket: int = 16, threads: int | None = None) -> RenderResult:
    """:func:`slicer.render.rendering.render` for a part: lattice and meshes in one picture.

    A part without meshes is rendered by :func:`~slicer.render.rendering.render` itself.
    Parameters and result as there; ``stats`` adds ``mesh_crossings``;
    ``roots`` holds the part's crossings.
    """
    part = as_part(part)
    if not part.has_meshes:
        return render(part.skeleton, size, view, camera, fov, eye, target, opacity, max_opacity, opaque,
                      tolerance, keep_roots, bisection, strict, bucket=bucket, threads=threads)
    opacity = _fraction(opacity, "opacity")
    max_opacity = _fraction(max_opacity, "max-opacity")
    cam = make_camera(_frame_proxy(part), size, view, camera, fov, eye, target)
    W, H = cam.width, cam.height
    t0 = time.perf_counter()
    groups, sources = [], []
    stats = {"evaluations": 0, "isolate_evaluations": 0, "refine_evaluations": 0, "shade_evaluations": 0,
             "split_evaluations": 0, "threads": None, "bucket": bucket, "tolerance": tolerance,
             "refine": "bisection" if bisection else "hermite"}
    o, d = cam.rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    if part.skeleton is not None:
        lat = render(part.skeleton, camera=cam, opacity=opacity, max_opacity=max_opacity, opaque=opaque,
                     tolerance=tolerance, keep_roots=True, bisection=bisection, strict=strict, bucket=bucket,
                     threads=threads)
        stats.update({k: v for k, v in lat.stats.items() if k in stats})
        cnt = lat.count.reshape(-1)
        pix = np.repeat(np.arange(W * H), cnt)
        rank = np.arange(pix.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        t = lat.roots
        # consecutive roots bound the inside (the ray starts outside); an odd last one runs to infinity
        a = rank % 2 == 0
        nxt = np.r_[t[1:], np.inf]
        last = np.r_[pix[1:] != pix[:-1], True]
        groups.append((pix[a], t[a], np.where(last[a], np.inf, nxt[a])))
        pts = o[pix] + t[:, None] * d[pix]
        g = evaluate(part.skeleton, pts, gradient=True)[1] if pix.size else np.zeros((0, 3))
        stats["shade_evaluations"] += int(pix.size)
        sources.append((pix, t, g))
    else:
        groups.append((np.zeros(0, np.int64), np.zeros(0), np.zeros(0)))
    n_mesh = 0
    for role in _ROLES:
        ms = part.of_role(role)
        if not ms:
            groups.append((np.zeros(0, np.int64), np.zeros(0), np.zeros(0)))
            continue
        hp, ht, hs, hn = mesh_hits(Soup.of(ms), cam)
        n_mesh += int(hp.size)
        groups.append(fill_spans(hp, ht, hs) if hp.size else (np.zeros(0, np.int64), np.zeros(0), np.zeros(0)))
        sources.append((hp, ht, -hn))
    sp, a0, a1 = combine_intervals(groups, part_op(bool(part.of_role("clip-inside"))))
    # the part's crossings: every finite end of the combined intervals, with its source's normal
    cp = np.concatenate([sp, sp])
    ct = np.concatenate([a0, a1])
    fin = np.isfinite(ct)
    cp, ct = cp[fin], ct[fin]
    order = np.lexsort((ct, cp))
    cp, ct = cp[order], ct[order]
    grads = _lookup(cp, ct, sources)
    offsets = np.searchsorted(cp, np.arange(W * H + 1))
    rgba = np.zeros((W * H, 4))
    cut = np.zeros(W * H, bool)
    shade = _shade_array(cam, opacity, max_opacity, opaque)
    composite_crossings(shade, offsets, np.ascontiguousarray(d[cp]), np.ascontiguousarray(grads), rgba, cut)
    count = np.diff(offsets).reshape(H, W)
    stats.update({"roots": int(cp.size), "mesh_crossings": n_mesh, "rays_cut": int(cut.sum()),
                  "seconds": time.perf_counter() - t0, "camera": cam.kind, "width": W, "height": H})
    if stats["tolerance"] is None and part.skeleton is not None:
        stats["tolerance"] = lat.stats["tolerance"]
    return RenderResult(cam, rgba.reshape(H, W, 4), count, ct.copy() if keep_roots else None, stats)


def _lookup(cp: np.ndarray, ct: np.ndarray, sources) -> np.ndarray:
    """The gradient (inward normal) of the source crossing at each (pixel, t)."""
    sp = np.concatenate([s[0] for s in sources]) if sources else np.zeros(0, np.int64)
    st = np.concatenate([s[1] for s in sources]) if sources else np.zeros(0)
    sg = np.concatenate([s[2] for s in sources]) if sources else np.zeros((0, 3))
    if cp.size == 0:
        return np.zeros((0, 3))
    values, inv = np.unique(np.concatenate([ct, st]), return_inverse=True)
    n = values.size
    qkey = cp.astype(np.int64) * n + inv[:ct.size]
    skey = sp.astype(np.int64) * n + inv[ct.size:]
    order = np.argsort(skey, kind="stable")
    pos = np.searchsorted(skey[order], qkey)
    if np.any(pos >= skey.size) or np.any(skey[order][np.minimum(pos, skey.size - 1)] != qkey):
        raise GridError("internal error: a crossing of the part has no source")   # pragma: no cover
    return sg[order[pos]]


__all__ = ["render_part", "mesh_hits"]
