"""Transparent rendering kernels: every crossing of every camera ray (EG22 §4).

A camera ray is ``r(t) = o + t d`` with ``|d| = 1`` and ``t >= 0`` (mm). For
each pixel the kernels

1. intersect the ray with the support of every segment of the pixel's
   screen-space bucket (:func:`slicer._kernels.rays.support.ray_support`),
   sort the hits by support entry and group overlapping supports into
   clusters;
2. cut each cluster at every member's support entry ``t_in``, exit ``t_out``
   and homothetic-distance minimum ``t*``;
3. bound the field on each piece per primitive (:func:`slicer._kernels.rays.walk.piece_bounds`): a
   monotone primitive gives its end values, an ambiguous one its directional
   Lipschitz bound. A piece whose interval excludes the iso-value 1 is
   settled; a piece on which every primitive is monotone the same way holds
   at most one crossing; any other piece is bisected until it is narrower
   than the tolerance (so a crossing pair wider than the tolerance is never
   missed, not even on a grazing ray);
4. converge on each bracketed crossing with safeguarded cubic Hermite steps
   (:func:`slicer._kernels.rays.walk.hermite_point`, end values and directional derivatives), or pure
   bisection when asked, until the bracket is narrower than the tolerance;
5. shade each crossing (outward normal ``-grad F / |grad F|``, Lambert +
   Blinn-Phong) and composite front to back; the ray stops once the
   accumulated opacity reaches ``max_opacity``, unless every root is wanted.

A pixel is computed by one thread from its own data only, so the result does
not depend on the thread count. Kernels never raise; status codes: 0 ok,
1 root buffer full (the caller retries the bucket with more room).

Camera array ``cam`` (13 float64): ``cam[0:3]`` the ray origin of pixel
corner (0, 0) (orthographic) or the eye (perspective); ``cam[3:6]`` and
``cam[6:9]`` the steps ``ex``, ``ey`` of one pixel along a row and down a
column; ``cam[9:12]`` the unit view direction (orthographic) or the
direction to pixel corner (0, 0) (perspective); ``cam[12]`` 0 orthographic,
1 perspective.

Shading array ``shade`` (17 float64): light direction (3, unit, toward the
light), front colour (3), back colour (3), ambient, diffuse, specular,
shininess, opacity per crossing, max opacity, opaque flag (0/1), unused.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.field.segment import segment_eval
from slicer._kernels.rays.lazy import complete_row, lazy_ends
from slicer._kernels.rays.walk import (PAD, cluster_breakpoints, eval_along, hermite_point, leap_chain, next_cluster, piece_bounds,
                   piece_ends, piece_members, sort_hits, walk_buffers)
from slicer._kernels.rays.support import H_TOUT, ray_support

OK = 0
ROOTS_FULL = 1
#: pieces waiting on a ray's bisection stack; a split adds one, and splitting
#: stops below the tolerance, so 2 + log2(piece / tol) entries are ever used
MAX_STACK = 128
#: per-bucket counters written to ``stats``
ST_STATUS, ST_EV_ISOLATE, ST_EV_REFINE, ST_EV_SHADE, ST_ROOTS, ST_CUT, ST_EV_SPLIT = range(7)
NSTAT = 7
# layout of ``shade``
SH_LIGHT, SH_FRONT, SH_BACK, SH_AMB, SH_DIFF, SH_SPEC, SH_SHINE, SH_ALPHA, SH_MAXA, SH_OPAQUE = \
    0, 3, 6, 9, 10, 11, 12, 13, 14, 15
NSHADE = 17

# the camera array ``cam`` (module docstring): origin, the steps along a row and down a column, the
# direction, and the projection (0 orthographic, 1 perspective)
(CAM_OX, CAM_OY, CAM_OZ, CAM_EXX, CAM_EXY, CAM_EXZ, CAM_EYX, CAM_EYY, CAM_EYZ, CAM_DX, CAM_DY, CAM_DZ,
 CAM_PERSPECTIVE) = range(13)
# a pixel's evaluation counts (``counts`` of :func:`render_ray`): isolation, refinement, shading, rays the
# opacity cut-off stopped, and the isolation evaluations spent splitting ambiguous pieces
N_ISOLATE, N_REFINE, N_SHADE, N_CUT, N_SPLIT = range(5)


@unrefcounted_kernel
def pixel_ray(cam, i, j):
    """Origin and unit direction of the ray through the centre of pixel (i, j).

    Returns
    -------
    ox, oy, oz, dx, dy, dz : float
        Origin (mm) and unit direction.
    """
    u = i + 0.5
    v = j + 0.5
    if cam[CAM_PERSPECTIVE] == 0.0:
        ox = cam[CAM_OX] + u * cam[CAM_EXX] + v * cam[CAM_EYX]
        oy = cam[CAM_OY] + u * cam[CAM_EXY] + v * cam[CAM_EYY]
        oz = cam[CAM_OZ] + u * cam[CAM_EXZ] + v * cam[CAM_EYZ]
        return ox, oy, oz, cam[CAM_DX], cam[CAM_DY], cam[CAM_DZ]
    dx = cam[CAM_DX] + u * cam[CAM_EXX] + v * cam[CAM_EYX]
    dy = cam[CAM_DY] + u * cam[CAM_EXY] + v * cam[CAM_EYY]
    dz = cam[CAM_DZ] + u * cam[CAM_EXZ] + v * cam[CAM_EYZ]
    s = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return cam[CAM_OX], cam[CAM_OY], cam[CAM_OZ], dx * s, dy * s, dz * s


@parallel_kernel
def pixel_rays(cam, W, H, origin, direction):
    """Fill ``origin`` and ``direction`` ((H, W, 3) float64) with every pixel's ray."""
    for j in prange(H):
        for i in range(W):
            ox, oy, oz, dx, dy, dz = pixel_ray(cam, i, j)
            origin[j, i, 0] = ox
            origin[j, i, 1] = oy
            origin[j, i, 2] = oz
            direction[j, i, 0] = dx
            direction[j, i, 1] = dy
            direction[j, i, 2] = dz


@unrefcounted_kernel
def field_grad_along(seg, hprim, sarr, ns, ray, t, kp, scratch):
    """F, its gradient (1/mm) and ``grad F . d`` at ``o + t d`` over the active
    primitives (no cache: refinement points are never revisited);
    ``ray = (ox, oy, oz, dx, dy, dz)``, ``kp = (m, 1/sigma^2, N)``."""
    ox, oy, oz, dx, dy, dz = ray
    m, inv_s2, norm = kp
    px = ox + t * dx
    py = oy + t * dy
    pz = oz + t * dz
    F = 0.0
    Gx = 0.0
    Gy = 0.0
    Gz = 0.0
    for s in range(ns):
        f, gx, gy, gz = segment_eval(seg, hprim[sarr[s]], px, py, pz, m, inv_s2, norm, bool(True), scratch)
        F += f
        Gx += gx
        Gy += gy
        Gz += gz
    return F, Gx, Gy, Gz, Gx * dx + Gy * dy + Gz * dz


@unrefcounted_kernel
def refine_root(seg, hprim, sarr, ns, ray, bracket, how, kp, scratch):
    """Converge on the crossing bracketed by ``bracket = (a, b, ga, gb, da,
    db)`` of the ray ``ray = (ox, oy, oz, dx, dy, dz)`` until the bracket is
    narrower than ``tol`` (``how = (tol, bisect, exact)``, ``kp = (m,
    1/sigma^2, N)``).

    ``ga = F(a) - 1`` and ``gb = F(b) - 1`` lie on opposite sides of the
    iso-value (``F >= 1`` is inside); ``da``, ``db`` are ``F'`` along the ray.
    Hermite mode takes the Hermite estimate, kept ``tol / 2`` away from the
    bracket ends so a well-predicted root is bracketed to ``tol`` by the next
    step (the estimate's Newton steps stop at ``tol / 8``); two steps in a
    row that fail to halve the bracket force a bisection. ``bisect`` uses
    pure bisection.

    Returns
    -------
    t : float
        The crossing: with ``exact``, or when no point was evaluated, the
        final bracket's estimate (its cubic's root; with ``bisect``, its
        midpoint); otherwise only the final bracket's midpoint, for a caller
        that needs the gradient near the crossing but not where it is (the
        cubic's root costs several Newton steps).
    gx, gy, gz : float
        Gradient of F at the last point evaluated (within ``tol`` of t).
    nev : int
        Primitive evaluations.
    have_grad : bool
        False when no point was evaluated (the bracket was already narrow).
    """
    a, b, ga, gb, da, db = bracket
    tol, bisect, exact = how
    ina = ga >= 0.0
    nev = 0
    fails = 0
    gx = 0.0
    gy = 0.0
    gz = 0.0
    have = False
    while b - a > tol:
        w = b - a
        if bisect or fails >= 2:
            tm = a + 0.5 * w
            fails = 0
        else:
            tm = hermite_point(a, b, ga, gb, da, db, 0.125 * tol / w)
            q = 0.5 * tol
            if tm < a + q:
                tm = a + q
            elif tm > b - q:
                tm = b - q
        if not (tm > a and tm < b):
            break
        F, Gx, Gy, Gz, Fp = field_grad_along(seg, hprim, sarr, ns, ray, tm, kp, scratch)
        nev += ns
        gx = Gx
        gy = Gy
        gz = Gz
        have = True
        g = F - 1.0
        if (g >= 0.0) == ina:
            a = tm
            ga = g
            da = Fp
        else:
            b = tm
            gb = g
            db = Fp
        if b - a > 0.5 * w:
            fails += 1
        else:
            fails = 0
    if bisect or (have and not exact):
        t = 0.5 * (a + b)
    else:
        t = hermite_point(a, b, ga, gb, da, db)
    return t, gx, gy, gz, nev, have


@unrefcounted_kernel
def shade_crossing(shade, dx, dy, dz, gx, gy, gz, rgb):
    """Colour of one crossing into ``rgb`` (3,): outward normal ``-grad F``;
    the front colour where it faces the viewer (entry surface), the back
    colour where it faces away (exit surface); two-sided Lambert +
    Blinn-Phong with the viewer at ``-d``."""
    g = math.sqrt(gx * gx + gy * gy + gz * gz)
    if g > 0.0:
        nx = -gx / g
        ny = -gy / g
        nz = -gz / g
    else:
        nx = -dx
        ny = -dy
        nz = -dz
    nd = nx * dx + ny * dy + nz * dz
    base = SH_FRONT
    if nd > 0.0:
        base = SH_BACK
        nx = -nx
        ny = -ny
        nz = -nz
    lx = shade[SH_LIGHT]
    ly = shade[SH_LIGHT + 1]
    lz = shade[SH_LIGHT + 2]
    lam = max(nx * lx + ny * ly + nz * lz, 0.0)
    hx = lx - dx
    hy = ly - dy
    hz = lz - dz
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    spec = 0.0
    if hn > 0.0:
        c = (nx * hx + ny * hy + nz * hz) / hn
        if c > 0.0 and lam > 0.0:
            spec = shade[SH_SPEC] * c ** shade[SH_SHINE]
    k = shade[SH_AMB] + shade[SH_DIFF] * lam
    for c3 in range(3):
        v = shade[base + c3] * k + spec
        rgb[c3] = min(max(v, 0.0), 1.0)


@unrefcounted_kernel
def render_ray(seg, boxes2d, ids, i0, i1, cam, ij, prim, opt, shade, bufs, rows, cache, out):
    """All crossings of the ray of pixel ``ij = (i, j)``, shaded and composited.

    With ``lazy`` (and not ``strict``), a piece is first bounded lazily
    (:func:`slicer._kernels.rays.lazy.lazy_ends`: each primitive from its last
    evaluation, evaluated only while the bound straddles 1); a piece that
    bound settles holds no crossing and is skipped, any other is walked
    exactly as before from the exact values at its ends, so the crossings
    and the image are those of the eager walk.

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table.
    boxes2d : (m, 4) float64
        Screen box of each segment's support, pixels: ``umin vmin umax vmax``
        (pixel (i, j) has its centre at ``(i + 0.5, j + 0.5)``).
    ids : int64
        Bucket list; ``ids[i0:i1]`` is this pixel's bucket.
    cam, shade : float64
        Camera and shading arrays (module docstring).
    prim : tuple
        ``(n, sigma, N, kmax)``: kernel degree, support factor,
        normalisation, max |k'|.
    opt : tuple
        ``(tol, strict, bisect, cut_support, lazy, keep_roots)``: crossing
        tolerance (mm); Lipschitz bounds only; pure bisection refinement;
        cut at support entries and exits as well as at every t*; the lazy
        walk; find every root (no early stop; write them to ``roots``).
    bufs, rows, cache : tuple
        The walk's work arrays (:func:`slicer._kernels.rays.walk.walk_buffers`):
        ``(scratch, hprim, hrec, order, bps, sarr, mstat, st_t)``;
        per-primitive rows ``(F, FH, FP)``; each hit's last evaluation
        ``(ct, cf, cfp)``.
    out : tuple
        ``(rgb, roots, out4, counts)``: (3,) work array; (cap,) float64, the
        pixel's crossings, sorted (only with ``keep_roots``); (4,) float64,
        premultiplied RGB and alpha, out; (5,) int64, evaluations added:
        isolation, refinement, shading; 1 added to ``counts[N_CUT]`` when the
        opacity cut-off stopped the ray; ``counts[N_SPLIT]``: the part of the
        isolation evaluations spent splitting ambiguous pieces.

    Returns
    -------
    int
        Number of crossings found, or -1 when ``roots`` was too small.
    """
    n, sigma, norm, kmax = prim
    scratch, hprim, hrec, order, bps, sarr, mstat, st_t = bufs
    i, j = ij
    ray = pixel_ray(cam, i, j)
    nh = _pixel_hits(seg, boxes2d, ids, i0, i1, ij, ray, prim, hprim, hrec)
    ct, _, _ = cache
    for r in range(nh):
        ct[r] = math.nan
    sort_hits(hrec, order, nh)
    walk = (seg, hprim, hrec, sarr, ray, (n // 2, 1.0 / (sigma * sigma), norm), scratch, rows, cache, mstat)
    # composite so far: premultiplied RGB, alpha, opacity cut passed, crossings, ray finished
    acc = (0.0, 0.0, 0.0, 0.0, False, 0, False)
    a = 0
    while a < nh and not _finished(acc):
        b, cs, ce = next_cluster(hrec, order, a, nh)
        acc = _render_cluster(walk, order, bps, st_t, (a, b, max(cs, 0.0), ce), opt, shade, out, acc)
        a = b
    _, _, out4, _ = out
    acc_r, acc_g, acc_b, acc_a, _, nroot, _ = acc
    if nroot >= 0:
        out4[0] = acc_r
        out4[1] = acc_g
        out4[2] = acc_b
        out4[3] = acc_a
    return nroot


@inline_kernel
def _finished(acc):
    """Whether the composite ``acc`` (:func:`render_ray`) ends the ray: the opacity cut-off, the first
    crossing of an opaque render, or a full roots buffer."""
    _, _, _, _, _, _, done = acc
    return done


@unrefcounted_kernel
def _pixel_hits(seg, boxes2d, ids, i0, i1, ij, ray, prim, hprim, hrec):
    """Hit records (unsorted) of the bucket's segments ``ids[i0:i1]`` with
    the camera ray ``ray = (ox, oy, oz, dx, dy, dz)`` of pixel ``ij``, kept
    if the support is not wholly behind the origin; returns the count. A
    segment whose screen box misses the pixel centre is skipped before the
    exact test."""
    n, sigma, norm, kmax = prim
    ox, oy, oz, dx, dy, dz = ray
    i, j = ij
    u = i + 0.5
    v = j + 0.5
    nh = 0
    for r in range(i0, i1):
        g = ids[r]
        if u < boxes2d[g, 0] or u > boxes2d[g, 2] or v < boxes2d[g, 1] or v > boxes2d[g, 3]:
            continue
        if ray_support(seg, g, ox, oy, oz, dx, dy, dz, n, sigma, norm, kmax, hrec, nh):
            if hrec[nh, H_TOUT] > 0.0:
                hprim[nh] = g
                nh += 1
    return nh


@inline_kernel
def _render_cluster(walk, order, bps, st_t, clu, opt, shade, out, acc):
    """Walk the pieces of the cluster ``clu = (a, b, cs, ce)`` (hits
    ``order[a:b]`` spanning ``[cs, ce]``, ``cs >= 0``) of a camera ray.

    ``walk = (seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache,
    mstat)`` holds the ray's work data, ``st_t`` the piece stack; ``opt``,
    ``shade`` and ``out`` as :func:`render_ray`; ``acc`` the composite so
    far (:func:`render_ray`). A piece the members' bounds on the whole ray
    keep below 1 is skipped; eager, a piece inside at its start may be
    settled with the ones after it (:func:`slicer._kernels.rays.walk.leap_chain`);
    lazy, a piece the lazy bounds settle is skipped. Any other piece is
    walked from the exact values at its ends (:func:`_render_piece`).
    Returns the updated composite.
    """
    seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache, mstat = walk
    st_f, st_fh, st_fp = rows
    tol, strict, bisect, cut_support, lazy, keep_roots = opt
    _, _, _, counts = out
    a, b, cs, ce = clu
    cur = st_f.shape[0] - 1
    nb = cluster_breakpoints(hrec, order, a, b, cs, ce, cut_support, cs, cs, bps)
    piece = -1
    while piece < nb - 2 and not _finished(acc):
        piece += 1
        ta = bps[piece]
        tb = bps[piece + 1]
        ns, fmax = piece_members(hrec, order, a, b, ta, tb, sarr)
        if ns == 0 or fmax < 1.0 - PAD * (1.0 + fmax):
            continue   # the primitives' bounds on the whole ray exclude 1
        if strict or not lazy:
            fcur, ne1 = eval_along(seg, hprim, hrec, sarr, ns, ray, ta, kp, scratch, st_f, st_fp, cur, cache)
            if not strict and fcur >= 1.0 and piece + 2 < nb:
                # inside at ta: no crossing as far as the unimodal lower bound reaches
                jj, ne = leap_chain(seg, hprim, hrec, sarr, ns, (st_f, st_fp), cur, ray, bps, piece, nb, fcur,
                                    kp, scratch, cache)
                counts[N_ISOLATE] += ne
                if jj > piece:
                    counts[N_ISOLATE] += ne1
                    piece = jj - 1
                    continue
            _, ne2 = eval_along(seg, hprim, hrec, sarr, ns, ray, tb, kp, scratch, st_f, st_fp, 0, cache)
        else:
            settled, ne = lazy_ends(seg, hprim, hrec, sarr, ns, ray, ta, tb, kp, scratch, rows, cur, 0, mstat, cache)
            counts[N_ISOLATE] += ne
            if settled:
                continue   # no crossing on the piece
            # an ambiguous piece is walked from the exact values at its ends
            fcur, ne1 = complete_row(seg, hprim, hrec, sarr, ns, ray, ta, kp, scratch, rows, cur, cache)
            _, ne2 = complete_row(seg, hprim, hrec, sarr, ns, ray, tb, kp, scratch, rows, 0, cache)
        counts[N_ISOLATE] += ne1 + ne2
        acc = _render_piece(walk, ns, st_t, (ta, tb, fcur), opt, shade, out, acc)
    return acc


@inline_kernel
def _render_piece(walk, ns, st_t, piece, opt, shade, out, acc):
    """Find the crossings of the piece ``piece = (ta, tb, F(ta))``, whose end
    values are in the current row and slot 0 (arguments as
    :func:`_render_cluster`).

    Pieces wait on the stack ``st_t`` (right ends; a split leaves the right
    part in its slot). A piece whose interval excludes 1 is settled; a
    piece on which every primitive is monotone the same way holds at most
    one crossing; any other is split at its middle until it is narrower
    than the tolerance. A class change over a settled or narrow piece is a
    crossing, refined and composited (:func:`_add_crossing`).
    """
    seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache, mstat = walk
    st_f, st_fh, st_fp = rows
    tol, strict, bisect, cut_support, lazy, keep_roots = opt
    _, _, _, counts = out
    tcur, tb, fcur = piece
    cur = st_f.shape[0] - 1
    st_t[0] = tb
    sp = 1
    while sp > 0 and not _finished(acc):
        p = sp - 1
        te = st_t[p]
        fe, d0, d1 = piece_ends(st_f, st_fp, cur, p, ns)
        lo, hi, mono = piece_bounds(hrec, sarr, ns, st_f, st_fp, cur, p, tcur, te, strict)
        pad = PAD * (1.0 + abs(hi))
        width = te - tcur
        tm = tcur + 0.5 * width
        settle = lo > 1.0 + pad or hi < 1.0 - pad
        if not settle and mono == 0 and width > tol and p + 2 <= MAX_STACK and tm > tcur and tm < te:
            # ambiguous: split at the middle; the right part keeps slot p
            _, ne = eval_along(seg, hprim, hrec, sarr, ns, ray, tm, kp, scratch, st_f, st_fp, p + 1, cache)
            counts[N_ISOLATE] += ne
            counts[N_SPLIT] += ne
            st_t[p + 1] = tm
            sp = p + 2
            continue
        if not settle and (fcur >= 1.0) != (fe >= 1.0):
            # one crossing (monotone piece) or an odd number within tol
            acc = _add_crossing(walk, ns, (tcur, te, fcur - 1.0, fe - 1.0, d0, d1), opt, shade, out, acc)
        # piece done: its right end becomes the current point
        for s in range(ns):
            st_f[cur, s] = st_f[p, s]
            st_fp[cur, s] = st_fp[p, s]
        fcur = fe
        tcur = te
        sp = p
    return acc


@inline_kernel
def _add_crossing(walk, ns, bracket, opt, shade, out, acc):
    """Refine the crossing bracketed by ``bracket = (a, b, F(a) - 1, F(b) -
    1, F'(a), F'(b))`` (:func:`refine_root`), record it (with
    ``keep_roots``) and, until the opacity cut-off, shade it and composite
    it behind ``acc`` (arguments as :func:`_render_cluster`). Returns the
    updated composite; finished when the roots buffer is full (crossings
    -1) or the cut-off stops the ray."""
    seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache, mstat = walk
    tol, strict, bisect, cut_support, lazy, keep_roots = opt
    rgb, roots, out4, counts = out
    acc_r, acc_g, acc_b, acc_a, cut, nroot, done = acc
    # where the crossing lies is needed only to keep it: shading takes the gradient at the last point evaluated
    t, gx, gy, gz, ne, have = refine_root(seg, hprim, sarr, ns, ray, bracket, (tol, bisect, keep_roots), kp,
                                          scratch)
    counts[N_REFINE] += ne
    if keep_roots:
        if nroot >= roots.shape[0]:
            return acc_r, acc_g, acc_b, acc_a, cut, -1, True
        roots[nroot] = t
    nroot += 1
    if not cut:
        if not have:
            _, gx, gy, gz, _ = field_grad_along(seg, hprim, sarr, ns, ray, t, kp, scratch)
            counts[N_SHADE] += ns
        _, _, _, dx, dy, dz = ray
        shade_crossing(shade, dx, dy, dz, gx, gy, gz, rgb)
        alpha = 1.0 if shade[SH_OPAQUE] != 0.0 else shade[SH_ALPHA]
        wgt = (1.0 - acc_a) * alpha
        acc_r += wgt * rgb[0]
        acc_g += wgt * rgb[1]
        acc_b += wgt * rgb[2]
        acc_a += wgt
        if shade[SH_OPAQUE] != 0.0 or (shade[SH_MAXA] < 1.0 and acc_a >= shade[SH_MAXA]):
            cut = True
            counts[N_CUT] += 1
            done = not keep_roots
    return acc_r, acc_g, acc_b, acc_a, cut, nroot, done


@parallel_kernel
def render_buckets(buckets, bk, screen, prim, opt, shade, out):
    """Render the pixels of the given buckets in parallel (one bucket per task).

    Parameters
    ----------
    buckets : (nb,) int64
        Flat bucket indices ``by * nbx + bx``.
    bk : tuple
        ``(nbx, B, offsets, ids, seg, boxes2d)``: buckets per row and bucket
        edge (pixels); CSR bucket lists (int64, each sorted by support entry
        depth); the segment table and each segment's screen box.
    screen : tuple
        ``(W, H, cam)``: image size (pixels) and camera array.
    prim : tuple
        ``(n, sigma, N, kmax)``: kernel degree, support factor,
        normalisation, max |k'|.
    opt : tuple
        ``(tol, strict, bisect, cut_support, lazy, keep_roots)``, as
        :func:`render_ray`.
    shade : (NSHADE,) float64
        Shading array (module docstring).
    out : tuple, out
        ``(rgba, count, ray_nroot, roots, stats)``: premultiplied colour and
        alpha of each pixel ((H, W, 4) float64); crossings found per pixel
        ((H, W) int64); crossings per ray of each bucket ((nb, B*B) int64,
        row-major inside the bucket); with ``keep_roots``, each bucket's
        crossings, ray after ray ((nb, cap) float64); status and counters
        per bucket ((nb, NSTAT) int64, ``ST_*``).
    """
    nbx, B, offsets, ids, seg, boxes2d = bk
    W, H, cam = screen
    # borrowed views (slicer._kernels.runtime.borrow): the arguments outlive the launch
    bk = (nbx, B, offsets, borrow(ids), borrow(seg), borrow(boxes2d))
    screen = (W, H, borrow(cam))
    for q in prange(buckets.shape[0]):
        # np.int64: one index type, one compiled copy (see trace_buckets)
        _render_bucket(np.int64(q), buckets[q], bk, screen, prim, opt, shade, out)


@kernel
def _render_bucket(q, bidx, bk, screen, prim, opt, shade, out):
    """Render the pixels of bucket ``bidx`` into the images and row ``q``
    of the per-bucket outputs (arguments as :func:`render_buckets`)."""
    nbx, B, offsets, ids, seg, boxes2d = bk
    W, H, cam = screen
    n, sigma, norm, kmax = prim
    tol, strict, bisect, cut_support, lazy, keep_roots = opt
    rgba, count, ray_nroot, roots, stats = out
    by = bidx // nbx
    bx = bidx - by * nbx
    i0 = offsets[bidx]
    i1 = offsets[bidx + 1]
    nl = max(i1 - i0, 1)
    own = walk_buffers(nl, MAX_STACK)
    own_more = (np.empty((MAX_STACK + 1, nl)), np.empty(nl, dtype=np.int64), np.empty(3), np.empty(4),
                np.zeros(5, dtype=np.int64))
    scratch, hprim, hrec, order, bps, sarr, st_f, st_fp, st_t, ct, cf, cfp = borrow(own)
    st_fh, mstat, rgb, out4, counts = borrow(own_more)
    bufs = (scratch, hprim, hrec, order, bps, sarr, mstat, st_t)
    roots_q = borrow(roots[q])
    used = 0
    nroot_tot = 0
    status = OK
    for ly in range(B):
        j = by * B + ly
        for lx in range(B):
            i = bx * B + lx
            ray_nroot[q, ly * B + lx] = 0
            if i >= W or j >= H or status != OK:
                continue
            nr = render_ray(seg, boxes2d, ids, i0, i1, cam, (i, j), prim, opt, shade, bufs, (st_f, st_fh, st_fp),
                            (ct, cf, cfp), (rgb, roots_q[used:], out4, counts))
            if nr < 0:
                status = ROOTS_FULL
                continue
            for c in range(4):
                rgba[j, i, c] = out4[c]
            count[j, i] = nr
            ray_nroot[q, ly * B + lx] = nr
            nroot_tot += nr
            if keep_roots:
                used += nr
    stats[q, ST_STATUS] = status
    stats[q, ST_EV_ISOLATE] = counts[N_ISOLATE]
    stats[q, ST_EV_REFINE] = counts[N_REFINE]
    stats[q, ST_EV_SHADE] = counts[N_SHADE]
    stats[q, ST_ROOTS] = nroot_tot
    stats[q, ST_CUT] = counts[N_CUT]
    stats[q, ST_EV_SPLIT] = counts[N_SPLIT]
    keep_alive(own)
    keep_alive(own_more)
