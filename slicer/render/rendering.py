"""Transparent rendering of a skeleton's integral surface (EG22 §4, Figure 1).

Every crossing of every camera ray with the surface ``F = 1`` is found with
the slicer's per-primitive machinery (support intervals, cuts at ``t_in``,
``t_out`` and ``t*``, per-primitive inclusion and directional Lipschitz
bounds), then shaded and composited front to back as semi-transparent
layers. See :mod:`slicer._kernels.render.walk` for the per-ray algorithm.

Pipeline: :func:`make_camera` (the rays) -> :func:`screen_buckets`
(per-bucket primitive lists, sorted by support entry along the view) ->
:func:`render` (kernels, in parallel over buckets) -> :class:`RenderResult`
(image, roots) -> :func:`run_render` (the CLI's job: files written
atomically).

Examples
--------
>>> from slicer import Skeleton
>>> from slicer.render.rendering import render
>>> strut = Skeleton([[0, 0, 0], [0, 0, 10]], [[0, 1]], [[1.0, 1.0]])
>>> res = render(strut, size=(8, 8), view="front", keep_roots=True)
>>> int(res.count[4, 4])      # the central ray enters and leaves the strut
2
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from slicer._kernels.field.binning import bin_boxes
from slicer._kernels.runtime.launch import launch_until_fits, numba_threads, one_item_per_thread
from slicer._kernels.rays.support import kprime_max
from slicer.compiling import ABOUT, compiling
from slicer._kernels.render.walk import (NSHADE, NSTAT, ROOTS_FULL, ST_CUT, ST_EV_ISOLATE, ST_EV_REFINE, ST_EV_SHADE,
                              ST_EV_SPLIT, ST_ROOTS, ST_STATUS, pixel_rays, render_buckets)
from slicer.arguments import MAX_COUNT, coordinates, integer, positive_number, resolvable, scene_reach
from slicer.model.field import segment_table
from slicer.tracer.buckets import Buckets, thread_order
from slicer.errors import GridError
from slicer.model.skeleton import Skeleton
from slicer.constants import RENDER_TOLERANCE as TOLERANCE

#: view name -> (view direction, up hint)
VIEWS = {
    "top": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "front": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "side": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "iso": ((-1.0, 1.0, -1.0), (0.0, 0.0, 1.0)),
}
CAMERAS = ("ortho", "perspective")
#: largest accepted image edge, pixels
MAX_SIZE = 16384
#: empty border around the framed model, fraction of the image
MARGIN = 0.03

#: default look: a clear blue for surfaces facing the viewer (entries), a deep
#: blue for surfaces facing away (exits); the light comes from behind the
#: viewer's left shoulder: ``-forward + LIGHT[0] right + LIGHT[1] up``
LIGHT = (-0.45, 0.65)
FRONT_COLOUR = (0.10, 0.52, 0.80)
BACK_COLOUR = (0.04, 0.24, 0.42)
AMBIENT, DIFFUSE, SPECULAR, SHININESS = 0.30, 0.70, 0.35, 40.0


@dataclass(frozen=True)
class Camera:
    """Rays of an image: ``o + t d``, ``t >= 0``, one per pixel centre.

    Attributes
    ----------
    kind : {"ortho", "perspective"}
    width, height : int
        Pixels.
    forward, right, up : (3,) float64
        Orthonormal camera frame (``right = forward x up``); rows of the image
        run toward ``-up``, columns toward ``right``.
    origin : (3,) float64, mm
        Perspective: the eye. Orthographic: the ray origin of pixel corner
        (0, 0), on a plane in front of the whole model.
    pixel : float
        Orthographic: pixel size, mm. Perspective: pixel size on the image
        plane at unit distance (``2 tan(fov/2) / height``).
    array : (13,) float64
        The kernels' camera array (see :mod:`slicer._kernels.render.walk`).
    """

    kind: str
    width: int
    height: int
    forward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    origin: np.ndarray
    pixel: float
    array: np.ndarray = field(repr=False)

    @classmethod
    def ortho(cls, corner, forward, right, up, pixel: float, width: int, height: int) -> "Camera":
        """Orthographic camera: the ray of pixel (i, j) starts at
        ``corner + (i + 1/2) pixel right - (j + 1/2) pixel up`` and runs along
        ``forward``. The frame must be orthonormal."""
        corner = np.asarray(corner, dtype=np.float64)
        f, r, u = (np.asarray(x, dtype=np.float64) for x in (forward, right, up))
        arr = np.concatenate([corner, pixel * r, -pixel * u, f, [0.0]])
        return cls("ortho", int(width), int(height), f, r, u, corner, float(pixel), arr)

    @classmethod
    def perspective(cls, eye, forward, right, up, pixel: float, width: int, height: int) -> "Camera":
        """Perspective camera at ``eye``: the ray of pixel (i, j) points to
        ``forward + (i + 1/2 - width/2) pixel right - (j + 1/2 - height/2) pixel up``
        (normalised). The frame must be orthonormal."""
        eye = np.asarray(eye, dtype=np.float64)
        f, r, u = (np.asarray(x, dtype=np.float64) for x in (forward, right, up))
        c00 = f - 0.5 * width * pixel * r + 0.5 * height * pixel * u
        arr = np.concatenate([eye, pixel * r, -pixel * u, c00, [1.0]])
        return cls("perspective", int(width), int(height), f, r, u, eye, float(pixel), arr)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Origin and unit direction of every pixel's ray.

        Returns
        -------
        origin, direction : (height, width, 3) float64
            mm and unit vectors, computed by the very kernel that renders.
        """

        o = np.empty((self.height, self.width, 3))
        d = np.empty((self.height, self.width, 3))
        pixel_rays(self.array, self.width, self.height, o, d)
        return o, d


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(v))
    if not (n > 0 and math.isfinite(n)):
        raise GridError(f"{what} must be a non-zero finite vector, got {v.tolist()}")
    return v / n


def _frame(forward, up_hint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = _unit(forward, "the view direction")
    up = np.asarray(up_hint, dtype=np.float64)
    if abs(float(f @ _unit(up, "up"))) > 0.999:
        up = np.array([0.0, 1.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    return f, r, u / np.linalg.norm(u)


def _balls(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Centres (2m, 3) and radii (2m,) of the segments' end support balls; the
    support of a segment is their convex hull."""
    a, b = skel.endpoints()
    c = np.concatenate([a, b])
    r = skel.sigma * np.concatenate([skel.radii[:, 0], skel.radii[:, 1]])
    return c, r


def _size(size) -> tuple[int, int]:
    try:
        w, h = size
    except (TypeError, ValueError):
        raise GridError(f"size must be two integers W H, got {size!r}") from None
    out = []
    for name, v in (("width", w), ("height", h)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_SIZE:
            raise GridError(f"image {name} must be an integer in [1, {MAX_SIZE}] pixels, got {v!r}")
        out.append(int(v))
    return out[0], out[1]


def _point(v, name: str):
    if v is None:
        return None
    p = np.asarray(v, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise GridError(f"{name} must be three finite numbers X Y Z (mm), got {np.asarray(v).tolist()}")
    return np.asarray(coordinates(p, 3, name, GridError))


def make_camera(skel: Skeleton, size=(700, 700), view: str = "iso", camera: str = "ortho",
                fov: float = 35.0, eye=None, target=None) -> Camera:
    """The camera of an image that frames the whole model.

    Parameters
    ----------
    skel : Skeleton
    size : (2,) int
        Width and height, pixels.
    view : {"top", "front", "side", "iso"}
        Direction to look from (top: down -z; front: toward +y; side: toward
        -x; iso: from (+1, -1, +1)), ignored when ``eye`` is given.
    camera : {"ortho", "perspective"}
    fov : float
        Perspective only: vertical field of view, degrees, in (0, 180).
    eye, target : (3,) float64, mm, optional
        Look from ``eye`` toward ``target`` (both or neither). Orthographic:
        the image is centred on ``target`` and the rays start on the plane
        through ``eye``. Default: the view direction, with the image framing
        every segment's support (orthographic) or the eye far enough for the
        support's bounding sphere to fit (perspective).

    Returns
    -------
    Camera
    """

    W, H = _size(size)
    if view not in VIEWS:
        raise GridError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")
    if camera not in CAMERAS:
        raise GridError(f"unknown camera {camera!r}; choose one of {', '.join(CAMERAS)}")
    fov = positive_number(fov, "fov", GridError)
    if not fov < 180.0:
        raise GridError(f"fov must be in (0, 180) degrees, got {fov!r}")
    eye, target = _point(eye, "eye"), _point(target, "target")
    if (eye is None) != (target is None):
        raise GridError("give both --eye and --target, or neither")
    if skel.n_segments == 0:
        raise GridError("the scene has no segments: nothing to render")
    c, R = _balls(skel)
    if eye is not None:
        if np.allclose(eye, target, rtol=0.0, atol=1e-12 * (1.0 + np.abs(eye).max())):
            raise GridError(f"eye and target are the same point {eye.tolist()}")
        f, r, u = _frame(target - eye, (0.0, 0.0, 1.0))
    else:
        f, r, u = _frame(*VIEWS[view])
    if camera == "ortho":
        cu, cv, cz = c @ r, c @ u, c @ f
        if eye is None:
            u0, u1 = float((cu - R).min()), float((cu + R).max())
            v0, v1 = float((cv - R).min()), float((cv + R).max())
            uc, vc = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
            hu, hv = 0.5 * (u1 - u0), 0.5 * (v1 - v0)
            diag = float(np.linalg.norm(np.ptp(skel.support_bounds(), axis=0)))
            zplane = float((cz - R).min()) - 0.05 * diag
        else:
            uc, vc = float(target @ r), float(target @ u)
            hu = float((np.abs(cu - uc) + R).max())
            hv = float((np.abs(cv - vc) + R).max())
            zplane = float(eye @ f)
        pix = max(2.0 * hu / W, 2.0 * hv / H) / (1.0 - 2.0 * MARGIN)
        base = uc * r + vc * u + zplane * f - 0.5 * W * pix * r + 0.5 * H * pix * u
        return Camera.ortho(base, f, r, u, pix, W, H)
    half_v = math.radians(fov) / 2.0
    s = 2.0 * math.tan(half_v) / H
    if eye is None:
        lo, hi = skel.support_bounds()
        centre = 0.5 * (lo + hi)
        rad = float((np.linalg.norm(c - centre, axis=1) + R).max())
        half = min(half_v, math.atan(math.tan(half_v) * W / H)) * (1.0 - 2.0 * MARGIN)
        eye = centre - f * rad / math.sin(half)
    return Camera.perspective(eye, f, r, u, s, W, H)


def screen_boxes(skel: Skeleton, cam: Camera) -> np.ndarray:
    """Screen box of each segment's support, in pixels.

    The support is the convex hull of two balls; its image is the convex hull
    of the balls' images (a disc in orthographic view; in perspective the
    exact tangent-plane bounds of each ball in front of the eye). A segment
    whose support reaches behind the eye plane covers the whole screen.

    Returns
    -------
    (m, 4) float64
        ``umin vmin umax vmax``; pixel (i, j) has its centre at
        ``(i + 0.5, j + 0.5)``.
    """
    c, R = _balls(skel)
    m = skel.n_segments
    if cam.kind == "ortho":
        u = (c - cam.origin) @ cam.right / cam.pixel
        v = (cam.origin - c) @ cam.up / cam.pixel
        ru = R / cam.pixel
        box = np.stack([u - ru, v - ru, u + ru, v + ru], axis=1)
    else:
        w = c - cam.origin
        x, y, z = w @ cam.right, -(w @ cam.up), w @ cam.forward
        box = np.empty((2 * m, 4))
        front = z - R > 1e-9 * (np.abs(z) + R)
        den = np.where(front, z * z - R * R, 1.0)
        for k, q in ((0, x), (1, y)):
            sq = R * np.sqrt(np.maximum(q * q + z * z - R * R, 0.0))
            lo = (q * z - sq) / den / cam.pixel
            hi = (q * z + sq) / den / cam.pixel
            off = 0.5 * (cam.width if k == 0 else cam.height)
            box[:, k] = np.where(front, lo + off, -np.inf)
            box[:, k + 2] = np.where(front, hi + off, np.inf)
    box = np.stack([np.minimum(box[:m, 0], box[m:, 0]), np.minimum(box[:m, 1], box[m:, 1]),
                    np.maximum(box[:m, 2], box[m:, 2]), np.maximum(box[:m, 3], box[m:, 3])], axis=1)
    pad = 1e-6 + 1e-9 * np.abs(np.where(np.isfinite(box), box, 0.0))
    box[:, :2] -= pad[:, :2]
    box[:, 2:] += pad[:, 2:]
    return np.ascontiguousarray(box)


@dataclass(frozen=True)
class ScreenBuckets(Buckets):
    """CSR lists of the segments whose support touches each B x B pixel bucket
    of an image, each sorted by the depth where the support starts along the
    view: :class:`slicer.tracer.buckets.Buckets` in screen space.

    Attributes
    ----------
    size, nbx, nby, offsets, ids, table
        As in :class:`~slicer.tracer.buckets.Buckets`.
    boxes : (m, 4) float64
        Screen boxes ``umin vmin umax vmax``, pixels (:func:`screen_boxes`).
    """


def screen_buckets(skel: Skeleton, cam: Camera, size: int = 16) -> ScreenBuckets:
    """Bin the segments' screen boxes into ``size`` x ``size`` pixel buckets.

    Within a bucket, segments are sorted by the depth of their support's
    nearest point (orthographic: along the view direction; perspective:
    distance from the eye), so rays find their hits nearly sorted.
    """

    B = integer(size, "bucket", GridError, lo=1, hi=MAX_COUNT)
    if isinstance(size, bool) or B < 1:
        raise GridError(f"bucket size must be an integer >= 1 pixel, got {size!r}")
    W, H = cam.width, cam.height
    nbx, nby = -(-W // B), -(-H // B)
    box = screen_boxes(skel, cam)
    c, R = _balls(skel)
    m = skel.n_segments
    if cam.kind == "ortho":
        depth = c @ cam.forward - R
    else:
        depth = np.linalg.norm(c - cam.origin, axis=1) - R
    depth = np.minimum(depth[:m], depth[m:])
    keep = (box[:, 2] > 0.0) & (box[:, 0] < W) & (box[:, 3] > 0.0) & (box[:, 1] < H)
    cand = np.nonzero(keep)[0]
    order = cand[np.argsort(depth[cand], kind="stable")].astype(np.int64)
    clip = np.clip(box, -1.0, float(max(W, H) + 1))
    lo = np.stack([clip[:, 0], clip[:, 1], np.zeros(m)], axis=1)
    hi = np.stack([clip[:, 2], clip[:, 3], np.zeros(m)], axis=1)
    offsets, ids = bin_boxes(lo, hi, order, np.array([0.0, 0.0, -1.0]), np.array([B, B, 2.0]),
                             np.array([nbx, nby, 1], dtype=np.int64))
    return ScreenBuckets(B, nbx, nby, offsets, ids, segment_table(skel), box)


@dataclass
class RenderResult:
    """Output of :func:`render`.

    Attributes
    ----------
    camera : Camera
    rgba : (H, W, 4) float64
        Premultiplied colour and opacity, in [0, 1].
    count : (H, W) int64
        Crossings found per pixel (all of them with ``keep_roots``; otherwise
        those before the opacity cut-off).
    roots : (count.sum(),) float64 or None, mm
        With ``keep_roots``: every crossing distance along its ray, pixels in
        row-major order, each pixel's sorted.
    stats : dict
        ``evaluations`` (total primitive evaluations) and its parts
        ``isolate_evaluations`` (at breakpoints and splits; ``split_evaluations``
        of them at splits of ambiguous pieces), ``refine_evaluations``,
        ``shade_evaluations``;
        ``roots``, ``rays_cut`` (rays stopped by the opacity cut-off),
        ``seconds``, ``threads``, ``bucket``, ``tolerance`` (mm),
        ``refine`` ("hermite" or "bisection").
    """

    camera: Camera
    rgba: np.ndarray
    count: np.ndarray
    roots: np.ndarray | None
    stats: dict

    def image(self, transparent: bool = False) -> np.ndarray:
        """8-bit image: (H, W, 3) RGB over white, or (H, W, 4) RGBA with a
        transparent background (``transparent``)."""
        a = self.rgba[..., 3:4]
        if transparent:
            rgb = np.where(a > 0, self.rgba[..., :3] / np.where(a > 0, a, 1.0), 0.0)
            out = np.concatenate([rgb, a], axis=2)
        else:
            out = self.rgba[..., :3] + (1.0 - a)
        return np.clip(np.rint(out * 255.0), 0, 255).astype(np.uint8)

    def roots_arrays(self) -> dict:
        """The ``--roots-out`` arrays: ``origin``, ``direction`` (H, W, 3),
        ``count`` (H, W) and ``roots`` (1-D), plus ``tolerance`` (mm)."""
        if self.roots is None:
            raise GridError("the roots were not kept: render with keep_roots=True")
        o, d = self.camera.rays()
        return {"origin": o, "direction": d, "count": self.count, "roots": self.roots,
                "tolerance": np.float64(self.stats["tolerance"])}


def _shade_array(cam: Camera, opacity: float, max_opacity: float, opaque: bool) -> np.ndarray:

    light = _unit(-cam.forward + LIGHT[0] * cam.right + LIGHT[1] * cam.up, "the light direction")
    return np.array(list(light) + list(FRONT_COLOUR) + list(BACK_COLOUR)
                    + [AMBIENT, DIFFUSE, SPECULAR, SHININESS, opacity, max_opacity, float(opaque)]
                    + [0.0] * (NSHADE - 16))


def _fraction(v, name: str) -> float:

    x = positive_number(v, name, GridError)
    if x > 1.0:
        raise GridError(f"{name} must be in (0, 1], got {v!r}")
    return x


def render(skel: Skeleton, size=(700, 700), view: str = "iso", camera: str = "ortho", fov: float = 35.0,
           eye=None, target=None, opacity: float = 0.3, max_opacity: float = 0.99, opaque: bool = False,
           tolerance: float | None = None, keep_roots: bool = False, bisection: bool = False,
           strict: bool = False, cut_support: bool = True, bucket: int = 16,
           threads: int | None = None, lazy: bool = False) -> RenderResult:
    """Render every crossing of every pixel's ray, composited front to back.

    Parameters
    ----------
    skel : Skeleton
    size, view, camera, fov, eye, target
        See :func:`make_camera`; ``camera`` may also be a :class:`Camera`
        (then the other five are ignored).
    opacity : float
        Opacity of one crossing (entry and exit surfaces both count), (0, 1].
    max_opacity : float
        A ray stops once its accumulated opacity reaches this, (0, 1];
        1 never stops.
    opaque : bool
        First crossing only, fully opaque.
    tolerance : float, optional, mm
        Crossing tolerance: every crossing is bracketed to this width, and no
        crossing pair farther apart is missed. Default ``1e-4`` of the
        support box diagonal.
    keep_roots : bool
        Find and return every crossing (the cut-off then only stops the
        compositing, so the image is the same).
    bisection : bool
        Refine crossings by pure bisection instead of cubic Hermite steps
        (to measure the evaluations Hermite saves).
    strict : bool
        Bound every piece with the Lipschitz bound only (no reliance on the
        unimodality of each primitive's field along a ray).
    cut_support : bool
        Cut rays at every support entry and exit as well as at each t*
        (False: at t* only, as EG22).
    bucket : int
        Screen bucket edge, pixels.
    threads : int, optional
        Numba threads (default: all). The output does not depend on it.
    lazy : bool
        Skip pieces whose lazy bound (docs/math.md §5.5) proves them free of
        crossings; the image is the same, with fewer evaluations.
    """

    cam = camera if isinstance(camera, Camera) else make_camera(skel, size, view, camera, fov, eye, target)
    opacity = _fraction(opacity, "opacity")
    max_opacity = _fraction(max_opacity, "max-opacity")
    diag = float(np.linalg.norm(np.ptp(skel.support_bounds(), axis=0)))
    if tolerance is None:
        tol = TOLERANCE * diag
    else:
        tol = resolvable(tolerance, "tolerance", scene_reach(skel), GridError)
        if tol < 1e-12 * diag:
            raise GridError(f"tolerance {tolerance!r} mm is below 1e-12 of the model size ({diag:.6g} mm)")
    bk = screen_buckets(skel, cam, bucket)
    B = bk.size
    W, H = cam.width, cam.height
    n, sigma, norm = skel.degree, skel.sigma, skel.normalisation
    kmax = kprime_max(n, sigma, norm)
    shade = _shade_array(cam, opacity, max_opacity, opaque)
    todo = bk.nonempty()
    rgba = np.zeros((H, W, 4))
    count = np.zeros((H, W), np.int64)
    tot = np.zeros(NSTAT, np.int64)
    parts = []   # (bucket, per-ray counts, roots)
    t0 = time.perf_counter()
    with numba_threads(threads) as nthreads:
        todo = thread_order(todo, np.diff(bk.offsets)[todo], nthreads)
        cap0 = B * B * 16 if keep_roots else 1
        # the launcher's argument bundles (slicer._kernels.render.walk.render_buckets), one type each
        buckets = (int(bk.nbx), int(B), bk.offsets, bk.ids, bk.table, bk.boxes)
        prim = (int(n), float(sigma), float(norm), float(kmax))
        opt = (float(tol), bool(strict), bool(bisection), bool(cut_support), bool(lazy), bool(keep_roots))

        def launch(pending, scale):
            cap = cap0 * scale
            nb = len(pending)
            ray_nroot = np.zeros((nb, B * B), np.int64)
            roots = np.zeros((nb, cap))
            stats = np.zeros((nb, NSTAT), np.int64)
            # dynamic schedules hand out one bucket at a time (thread_order covers static ones)
            with compiling("the renderer", [render_buckets], ABOUT["renderer"]), one_item_per_thread():
                render_buckets(pending, buckets, (int(W), int(H), cam.array), prim, opt, shade,
                               (rgba, count, ray_nroot, roots, stats))
            full = stats[:, ST_STATUS] == ROOTS_FULL
            done = ~full
            tot[:] += stats[done].sum(axis=0)
            if keep_roots:
                for q in np.nonzero(done)[0]:
                    parts.append((int(pending[q]), ray_nroot[q], roots[q, :ray_nroot[q].sum()].copy()))
            return full

        launch_until_fits(launch, todo, "renderer")
    elapsed = time.perf_counter() - t0
    all_roots = _gather_roots(parts, bk, W, H) if keep_roots else None
    ev = tot[[ST_EV_ISOLATE, ST_EV_REFINE, ST_EV_SHADE]]
    st = {"evaluations": int(ev.sum()), "isolate_evaluations": int(ev[0]), "refine_evaluations": int(ev[1]),
          "shade_evaluations": int(ev[2]), "split_evaluations": int(tot[ST_EV_SPLIT]), "roots": int(tot[ST_ROOTS]), "rays_cut": int(tot[ST_CUT]),
          "seconds": elapsed, "threads": int(nthreads), "bucket": B, "tolerance": tol,
          "refine": "bisection" if bisection else "hermite", "camera": cam.kind, "width": W, "height": H}
    return RenderResult(cam, rgba, count, all_roots, st)


def _gather_roots(parts, bk: ScreenBuckets, W: int, H: int) -> np.ndarray:
    """Concatenate the buckets' roots in row-major pixel order."""
    B = bk.size
    ly, lx = np.divmod(np.arange(B * B), B)
    pix, vals = [], []
    for bidx, nr, r in parts:
        by, bx = divmod(bidx, bk.nbx)
        j, i = by * B + ly, bx * B + lx
        ok = (i < W) & (j < H)
        pix.append(np.repeat((j * W + i)[ok], nr[ok]))
        vals.append(r)
    if not pix:
        return np.zeros(0)
    pix = np.concatenate(pix)
    vals = np.concatenate(vals)
    return vals[np.argsort(pix, kind="stable")]


__all__ = ["Camera", "RenderResult", "ScreenBuckets", "VIEWS", "CAMERAS", "make_camera", "screen_boxes",
           "screen_buckets", "render"]
