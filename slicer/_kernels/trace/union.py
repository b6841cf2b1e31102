"""Slicing tracer for the union blend ``F = max_i f_i`` (docs/math.md §5.4).

A voxel centre is inside the union exactly when some strut's own field is
``>= 1`` there, so each ray is traced strut by strut and the results are
merged: per ray and per strut of the bucket whose support the ray meets,

1. the strut's field ``f_i`` along the ray is unimodal on its support
   interval ``[t_in, t_out]`` (docs/math.md §3.3), and zero at both ends;
2. the interval ``[t_in, t_out]`` is cut at the strut's ``t*`` and walked
   left to right with a stack of pieces: a piece is bounded from ``f_i`` and
   ``f_i'`` at its ends (monotone: the end values; otherwise the smaller end
   value and the directional Lipschitz bound, as the sum tracer does for one
   primitive); a piece whose bound excludes 1 settles all its centres, any
   other one is split at a voxel centre (the one nearest the Hermite estimate
   of the crossing where the piece is monotone and brackets 1, else the
   middle one), which is classified by its own value ``f_i(centre) >= 1``;
3. with spans, pieces holding no centre are split further until the strut's
   crossings are located to ``span_tol`` (each crossing lies strictly
   between two points of known class, so the strut's spans hold exactly its
   inside centres).

The runs of all struts are merged (union of integer ranges), and so are the
spans (union of real intervals): every voxel centre's class is
``max_i f_i(centre) >= 1`` as evaluated at points by
:func:`slicer._kernels.field.union.field_max_at_points`, and centre k lies in a
span exactly when it is inside. A strut whose whole-ray bound ``H_FMAX`` is
below 1 costs no evaluation; without spans, a strut whose support's centres
are already inside another strut's run is skipped.

The launch interface of :func:`trace_union_buckets` is that of
:func:`slicer._kernels.trace.summed.trace_buckets`; methods 0 (interval) and 1
(sampling: ``max_i f_i`` at every centre) are implemented.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import prange

from slicer._jit import parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.field.segment import SCRATCH, segment_eval
from slicer._kernels.rays.walk import PAD, SURFACE_BAND, first_centre
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT, lipschitz, ray_support

OK = 0
RUNS_FULL = 1

MAX_STACK = 256
#: past this stack depth splits go to the middle (bounds the depth by DEEP + 2 log2(K) + 2)
DEEP = 96
# counters of one ray: runs, crossings, evaluations
C_RUN, C_X, C_EV = range(3)
# float state of a strut walk: current point t, f, f'; then the ray's px, py
W_T, W_F, W_D, W_PX, W_PY = range(5)

#: what every strut walk of a bucket needs of the grid and the options: the first centre's height ``z0``
#: and the layer height ``h`` (mm), the traced range ``zlo..zhi`` (mm), ``span_tol`` (mm), ``inv_s2``
#: (1/sigma^2, mm^-2), the kernel's normalisation ``norm``, the centres per ray ``K``, half the kernel
#: degree ``m``, and the flags ``strict`` and ``spans``
UnionWalk = namedtuple("UnionWalk", ["z0", "h", "zlo", "zhi", "span_tol", "inv_s2", "norm", "K", "m",
                                     "strict", "spans"])


@unrefcounted_kernel
def strut_value(seg, g, hrec, r, px, py, t, m, inv_s2, norm, scratch):
    """``(f, df/dz)`` of segment ``g`` at ``(px, py, t)``; zero outside the open
    support interval of hit record ``r``."""
    if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
        return 0.0, 0.0
    f, gx, gy, gz = segment_eval(seg, g, px, py, t, m, inv_s2, norm, bool(True), scratch)
    return f, gz


@unrefcounted_kernel
def strut_bounds(hrec, r, ta, tb, f0, d0, f1, d1, strict):
    """Interval ``[lo, hi]`` of one strut's field on ``[ta, tb]`` and whether it
    is monotone there (+1 / -1, else 0), from its values and slopes at the ends
    (the one-primitive case of :func:`slicer._kernels.rays.walk.piece_bounds`)."""
    w = tb - ta
    if f0 == 0.0 and f1 == 0.0 and d0 == 0.0 and d1 == 0.0:
        return 0.0, 0.5 * lipschitz(hrec, r, ta, tb) * w, 0
    if not strict and d1 > 0.0 and d0 >= 0.0:
        return f0, f1, 1
    if not strict and d0 < 0.0 and d1 <= 0.0:
        return f1, f0, -1
    K = lipschitz(hrec, r, ta, tb)
    hi = 0.5 * (f0 + f1 + K * w)
    if strict:
        return max(0.0, 0.5 * (f0 + f1 - K * w)), hi, 0
    return min(f0, f1), hi, 0


@unrefcounted_kernel
def hermite_root(ta, tb, ga, gb, da, db):
    """Root in ``[ta, tb]`` of the cubic Hermite interpolant of ``g`` (values
    ``ga``, ``gb`` of opposite signs, slopes ``da``, ``db``), by bisection of the
    cubic: a continuous function of the inputs, always inside ``[ta, tb]``."""
    w = tb - ta
    if not w > 0.0 or ga == gb:
        return ta + 0.5 * w
    m0 = da * w
    m1 = db * w
    lo = 0.0
    hi = 1.0
    for _ in range(48):
        s = 0.5 * (lo + hi)
        s2 = s * s
        s3 = s2 * s
        p = (2.0 * s3 - 3.0 * s2 + 1.0) * ga + (s3 - 2.0 * s2 + s) * m0 \
            + (-2.0 * s3 + 3.0 * s2) * gb + (s3 - s2) * m1
        if p == 0.0:
            lo = s
            hi = s
            break
        if (p < 0.0) == (ga < 0.0):
            lo = s
        else:
            hi = s
    return ta + 0.5 * (lo + hi) * w


@unrefcounted_kernel
def emit(runs, cnt, k0, k1):
    """Append centres ``k0..k1`` (inclusive) as an inside run, joined to the
    previous run when they touch; False when the buffer is full."""
    if k1 < k0:
        return True
    n = cnt[C_RUN]
    if n > 0 and runs[n - 1, 1] == k0:
        runs[n - 1, 1] = k1 + 1
        return True
    if n >= runs.shape[0]:
        n = merge_runs(runs, n)
        cnt[C_RUN] = n
        if n >= runs.shape[0]:
            return False
    runs[n, 0] = k0
    runs[n, 1] = k1 + 1
    cnt[C_RUN] = n + 1
    return True


@unrefcounted_kernel
def add_crossing(xs, cnt, t):
    """Append a crossing height; False when the buffer is full (after merging
    the complete spans already there)."""
    n = cnt[C_X]
    if n >= xs.shape[0]:
        n = merge_spans(xs, n - (n % 2), 0.0, 0.0, 1.0) + (n % 2)
        if n % 2:
            xs[n - 1] = xs[cnt[C_X] - 1]
        cnt[C_X] = n
        if n >= xs.shape[0]:
            return False
    xs[n] = t
    cnt[C_X] = n + 1
    return True


@unrefcounted_kernel
def merge_runs(runs, n):
    """Sort the half-open runs ``runs[:n]`` by start and join those that
    overlap or touch; returns the new count."""
    for a in range(1, n):
        r0 = runs[a, 0]
        r1 = runs[a, 1]
        b = a - 1
        while b >= 0 and runs[b, 0] > r0:
            runs[b + 1, 0] = runs[b, 0]
            runs[b + 1, 1] = runs[b, 1]
            b -= 1
        runs[b + 1, 0] = r0
        runs[b + 1, 1] = r1
    w = 0
    for a in range(n):
        if w > 0 and runs[a, 0] <= runs[w - 1, 1]:
            runs[w - 1, 1] = max(runs[w - 1, 1], runs[a, 1])
        else:
            runs[w, 0] = runs[a, 0]
            runs[w, 1] = runs[a, 1]
            w += 1
    return w


@unrefcounted_kernel
def merge_spans(xs, n, gap, z0, h):
    """Sort the spans ``(xs[2i], xs[2i+1])`` of ``xs[:n]`` by start and join
    those that overlap or touch, and those less than ``gap`` (mm) apart with
    no voxel centre ``z0 + k h`` between them; returns the new count of
    heights.

    Two struts' spans that meet (one ends where the other starts) are
    located independently, each end to ``span_tol``: they may come out
    apart by up to ``2 span_tol`` where the union is inside all along. A
    centre between them is outside both (each strut's spans hold exactly
    its inside centres), so such a gap is never closed.
    """
    ns = n // 2
    for a in range(1, ns):
        s0 = xs[2 * a]
        s1 = xs[2 * a + 1]
        b = a - 1
        while b >= 0 and xs[2 * b] > s0:
            xs[2 * b + 2] = xs[2 * b]
            xs[2 * b + 3] = xs[2 * b + 1]
            b -= 1
        xs[2 * b + 2] = s0
        xs[2 * b + 3] = s1
    w = 0
    for a in range(ns):
        if w > 0 and (xs[2 * a] <= xs[2 * w - 1] or _closable(xs[2 * w - 1], xs[2 * a], gap, z0, h)):
            xs[2 * w - 1] = max(xs[2 * w - 1], xs[2 * a + 1])
        else:
            xs[2 * w] = xs[2 * a]
            xs[2 * w + 1] = xs[2 * a + 1]
            w += 1
    return 2 * w


@unrefcounted_kernel
def _closable(end, start, gap, z0, h):
    """Whether the gap ``(end, start)`` between two spans is narrower than
    ``gap`` and holds no voxel centre ``z0 + k h``."""
    if not start - end < gap:
        return False
    k = math.ceil((end - z0) / h)
    while z0 + (k - 1) * h > end:
        k -= 1
    while z0 + k * h <= end:
        k += 1
    return not z0 + k * h < start


@unrefcounted_kernel
def centre_split(q0, q1, ta, fa, da, tb, fb, db, z0, h, mono, deep):
    """The centre at which an ambiguous piece holding centres ``q0..q1`` is split."""
    km = (q0 + q1) // 2
    if mono != 0 and q1 > q0 and not deep and (fa - 1.0) * (fb - 1.0) < 0.0:
        tr = hermite_root(ta, tb, fa - 1.0, fb - 1.0, da, db)
        kr = int(math.floor((tr - z0) / h + 0.5))
        km = min(max(kr, q0), q1)
    return km


@unrefcounted_kernel
def gap_split(ta, fa, da, tb, fb, db, mono, deep, span_tol):
    """The height at which an ambiguous piece holding no centre is split
    (spans): next to the Hermite estimate of a bracketed crossing, else the middle."""
    w = tb - ta
    ts = ta + 0.5 * w
    if mono != 0 and (fa - 1.0) * (fb - 1.0) < 0.0 and not deep:
        tr = hermite_root(ta, tb, fa - 1.0, fb - 1.0, da, db)
        ts = tr + 0.5 * span_tol if tr - ta <= tb - tr else tr - 0.5 * span_tol
        ts = min(max(ts, ta + 0.125 * w), tb - 0.125 * w)
    return ts


@unrefcounted_kernel
def push_piece(st, sti, p, t, f, d, q0, q1):
    """Stack slot ``p`` := a piece ending at ``t`` (value f, slope d) holding centres q0..q1."""
    st[p, 0] = t
    st[p, 1] = f
    st[p, 2] = d
    sti[p, 0] = 0
    sti[p, 1] = q0
    sti[p, 2] = q1


@unrefcounted_kernel
def settle_gap(cur, te, fe, zlo, zhi, span_tol):
    """Whether a centre-free ambiguous piece from ``cur`` to ``te`` needs no
    more splits: narrow enough, outside the grid, or f within rounding of 1
    at both ends (a column lying in the surface)."""
    tc = cur[W_T]
    return (te - tc <= span_tol or te <= zlo or tc >= zhi
            or (abs(cur[W_F] - 1.0) <= SURFACE_BAND and abs(fe - 1.0) <= SURFACE_BAND))


@unrefcounted_kernel
def split_piece(seg, g, hrec, r, wk, scratch, st, sti, cur, cnt, p, mono, deep):
    """Split the ambiguous piece in stack slot ``p`` (see :func:`walk_strut`);
    returns the new stack size.

    A piece holding centres is split at one (:func:`centre_split`), which is
    evaluated and pushed as a classified centre between the two halves (the
    right half keeps slot ``p``); a centre-free piece (spans) at
    :func:`gap_split`.
    """
    z0, h, span_tol, inv_s2, norm, m = wk.z0, wk.h, wk.span_tol, wk.inv_s2, wk.norm, wk.m
    px, py = cur[W_PX], cur[W_PY]
    te, fe, de = st[p, 0], st[p, 1], st[p, 2]
    q0 = sti[p, 1]
    q1 = sti[p, 2]
    if q1 < q0:
        ts = gap_split(cur[W_T], cur[W_F], cur[W_D], te, fe, de, mono, deep, span_tol)
        fm, dm = strut_value(seg, g, hrec, r, px, py, ts, m, inv_s2, norm, scratch)
        cnt[C_EV] += 1
        push_piece(st, sti, p + 1, ts, fm, dm, q0, q1)
        return p + 2
    km = centre_split(q0, q1, cur[W_T], cur[W_F], cur[W_D], te, fe, de, z0, h, mono, deep)
    zm = z0 + km * h
    fm, dm = strut_value(seg, g, hrec, r, px, py, zm, m, inv_s2, norm, scratch)
    cnt[C_EV] += 1
    sti[p, 1] = km + 1
    sti[p + 1, 0] = 1
    sti[p + 1, 1] = km
    sti[p + 1, 2] = 1 if fm >= 1.0 else 0
    push_piece(st, sti, p + 2, zm, fm, dm, q0, km - 1)
    return p + 3


@unrefcounted_kernel
def place_crossing(cur, te, fe, de, xs, cnt):
    """One crossing (an odd number) in ``(cur t, te)``, a piece whose ends differ
    in class: at the Hermite estimate (the middle if it falls outside)."""
    tr = hermite_root(cur[W_T], te, cur[W_F] - 1.0, fe - 1.0, cur[W_D], de)
    if not (tr > cur[W_T] and tr < te):
        tr = 0.5 * (cur[W_T] + te)
    return add_crossing(xs, cnt, tr)


@unrefcounted_kernel
def start_strut(seg, g, hrec, r, wk, scratch, st, sti, cur, cnt):
    """Push the strut's pieces ``[t_in, t*]`` and ``[t*, t_out]`` (one piece when
    ``t*`` is not inside) and set the current point to ``t_in`` (f = f' = 0);
    returns the stack size."""
    z0, h, inv_s2, norm, K, m = wk.z0, wk.h, wk.inv_s2, wk.norm, wk.K, wk.m
    tin, tout, tst = hrec[r, H_TIN], hrec[r, H_TOUT], hrec[r, H_TSTAR]
    kin = first_centre(tin, z0, h, K)
    kout = first_centre(tout, z0, h, K) - 1
    push_piece(st, sti, 0, tout, 0.0, 0.0, kin, kout)
    sp = 1
    if tst > tin and tst < tout:
        fs, ds = strut_value(seg, g, hrec, r, cur[W_PX], cur[W_PY], tst, m, inv_s2, norm, scratch)
        cnt[C_EV] += 1
        ks = first_centre(tst, z0, h, K)
        sti[0, 1] = ks
        push_piece(st, sti, 1, tst, fs, ds, kin, ks - 1)
        sp = 2
    cur[W_T] = tin
    cur[W_F] = 0.0
    cur[W_D] = 0.0
    return sp


@unrefcounted_kernel
def walk_strut(seg, g, hrec, r, wk, scratch, st, sti, cur, cnt, runs, xs):
    """Classify the centres of one strut's support on a ray (module docstring).

    Parameters
    ----------
    seg : (m, 10) float64
        Segment table; ``g`` the strut, ``hrec[r]`` its hit record.
    wk : UnionWalk
        The grid and the options (:data:`UnionWalk`).
    scratch : (SCRATCH,) float64
    st, sti : (MAX_STACK, 3) float64 / int64
        Stack: right end (t, f, f') / (kind, q0, q1); kind 1 is a classified centre.
    cur : (5,) float64
        Current point (t, f, f') and the ray's (px, py).
    cnt : (3,) int64
        Runs, crossings and evaluations of the ray so far.
    runs : (c, 2) int64; xs : (cx,) float64
        The ray's runs (half-open) and crossings, appended to.

    Returns
    -------
    bool
        False when a buffer or the stack is full.
    """
    z0, h, zlo, zhi, span_tol = wk.z0, wk.h, wk.zlo, wk.zhi, wk.span_tol
    strict, spans = wk.strict, wk.spans
    sp = start_strut(seg, g, hrec, r, wk, scratch, st, sti, cur, cnt)
    inside = False
    while sp > 0:
        sp -= 1
        p = sp
        q0 = sti[p, 1]
        q1 = sti[p, 2]
        if sti[p, 0] == 1:
            if q1 == 1 and not emit(runs, cnt, q0, q0):
                return False
            continue
        te, fe, de = st[p, 0], st[p, 1], st[p, 2]
        if q1 >= q0 or spans:
            lo, hi, mono = strut_bounds(hrec, r, cur[W_T], te, cur[W_F], cur[W_D], fe, de, strict)
            pad = PAD * (1.0 + abs(hi))
            if lo > 1.0 + pad:
                if not emit(runs, cnt, q0, q1):
                    return False
            elif hi < 1.0 - pad or (q1 < q0 and settle_gap(cur, te, fe, zlo, zhi, span_tol)):
                pass
            elif q1 >= q0 and z0 + q0 * h == cur[W_T]:
                # the first centre sits on the left end: its value is known
                if cur[W_F] >= 1.0 and not emit(runs, cnt, q0, q0):
                    return False
                sti[p, 1] = q0 + 1
                sp += 1
                continue
            else:
                if sp + 3 > MAX_STACK:
                    return False
                sp = split_piece(seg, g, hrec, r, wk, scratch, st, sti, cur, cnt, p, mono, sp >= DEEP)
                continue
        if spans and (fe >= 1.0) != inside:
            if not place_crossing(cur, te, fe, de, xs, cnt):
                return False
            inside = not inside
        cur[W_T] = te
        cur[W_F] = fe
        cur[W_D] = de
    return True


@unrefcounted_kernel
def covered(runs, n, k0, k1):
    """Whether centres ``k0..k1`` all lie in one of the runs ``runs[:n]``."""
    for a in range(n):
        if runs[a, 0] <= k0 and runs[a, 1] > k1:
            return True
    return False


@unrefcounted_kernel
def union_ray(seg, boxes, ids, i0, i1, wk, kp, bufs, runs, xs, cnt):
    """Runs (and crossings) of one ray of the union, merged; see the module docstring.

    ``kp`` is ``(n, sigma, norm, kmax)``; ``bufs`` the ray walk's work arrays
    ``(scratch, hrec, st, sti, cur)``; ``cur[W_PX], cur[W_PY]`` hold the ray.
    Returns False when a buffer is full; ``cnt`` then is meaningless.
    """
    scratch, hrec, st, sti, cur = bufs
    n, sigma, norm, kmax = kp
    z0, h, zlo, zhi, K, spans = wk.z0, wk.h, wk.zlo, wk.zhi, wk.K, wk.spans
    px, py = cur[W_PX], cur[W_PY]
    cnt[C_RUN] = 0
    cnt[C_X] = 0
    for q in range(i0, i1):
        g = ids[q]
        if px < boxes[g, 0] or px > boxes[g, 3] or py < boxes[g, 1] or py > boxes[g, 4]:
            continue
        if not ray_support(seg, g, px, py, 0.0, 0.0, 0.0, 1.0, n, sigma, norm, kmax, hrec, 0):
            continue
        if not (hrec[0, H_TOUT] > zlo and hrec[0, H_TIN] < zhi):
            continue
        fmax = hrec[0, H_FMAX]
        if fmax < 1.0 - PAD * (1.0 + fmax):
            continue        # the strut's bound on the whole ray excludes 1
        if not spans:
            ka = first_centre(hrec[0, H_TIN], z0, h, K)
            kb = first_centre(hrec[0, H_TOUT], z0, h, K) - 1
            if kb < ka or covered(runs, cnt[C_RUN], ka, kb):
                continue
        if not walk_strut(seg, g, hrec, 0, wk, scratch, st, sti, cur, cnt, runs, xs):
            return False
    cnt[C_RUN] = merge_runs(runs, cnt[C_RUN])
    if spans:
        cnt[C_X] = merge_spans(xs, cnt[C_X], 2.0 * wk.span_tol, z0, h)
    return True


@unrefcounted_kernel
def sampling_ray(seg, boxes, ids, i0, i1, wk, kp, bufs, runs, cnt):
    """Runs of one ray of the union by evaluating ``max_i f_i`` at every centre
    (the sampling method), over the z-sorted bucket list ``ids[i0:i1]``."""
    scratch, active, cur = bufs
    z0, h, inv_s2, norm, K, m = wk.z0, wk.h, wk.inv_s2, wk.norm, wk.K, wk.m
    px, py = cur[W_PX], cur[W_PY]
    cnt[C_RUN] = 0
    cnt[C_X] = 0
    na = 0
    nxt = i0
    for k in range(K):
        z = z0 + k * h
        while nxt < i1 and boxes[ids[nxt], 2] <= z:
            g = ids[nxt]
            nxt += 1
            if not (px < boxes[g, 0] or px > boxes[g, 3] or py < boxes[g, 1] or py > boxes[g, 4]):
                active[na] = g
                na += 1
        w = 0
        for a in range(na):
            if boxes[active[a], 5] >= z:
                active[w] = active[a]
                w += 1
        na = w
        if na == 0 and nxt >= i1:
            break
        best = 0.0
        for a in range(na):
            f, gx, gy, gz = segment_eval(seg, active[a], px, py, z, m, inv_s2, norm, bool(False), scratch)
            best = max(best, f)
        cnt[C_EV] += na
        if best >= 1.0 and not emit(runs, cnt, k, k):
            return False
    return True


@unrefcounted_kernel
def store_ray(runs, xs, cnt, rk0, rk1, room, cz, xroom):
    """Copy a ray's merged runs and crossings to the bucket's output; False
    when they do not fit."""
    nr = cnt[C_RUN]
    nx = cnt[C_X]
    if nr > room or nx > xroom:
        return False
    for a in range(nr):
        rk0[a] = runs[a, 0]
        rk1[a] = runs[a, 1]
    for a in range(nx):
        cz[a] = xs[a]
    return True


@parallel_kernel
def trace_union_buckets(method, buckets, first, bk, grid, prim, opt, out):
    """Trace every ray of the given buckets with the union blend, in parallel.

    Arguments and outputs as :func:`slicer._kernels.trace.summed.trace_buckets`
    (``method`` 0 interval, 1 sampling; ``cut_support`` and ``lazy`` have
    no effect: a strut's pieces always end at its support's ends).
    """
    nbx, B, bucket_off, ids, seg, boxes = bk
    W, H, x0, y0, pxs, pys, z0, h, K = grid
    n, sigma, norm, kmax = prim
    strict, cut_support, lazy, spans, span_tol = opt
    ray_nrun, run_k0, run_k1, stats, ray_nx, cross_z = out
    cap = run_k0.shape[1]
    xcap = cross_z.shape[1]
    nb = buckets.shape[0]
    # borrowed views (slicer._kernels.runtime.borrow): the arguments outlive the launch
    ids = borrow(ids)
    seg = borrow(seg)
    boxes = borrow(boxes)
    zlo = z0 - 0.5 * h
    zhi = z0 + (K - 0.5) * h
    for q in prange(nb):
        bidx = buckets[q]
        by = bidx // nbx
        bx = bidx - by * nbx
        i0 = bucket_off[bidx]
        i1 = bucket_off[bidx + 1]
        wk = UnionWalk(z0, h, zlo, zhi, span_tol, 1.0 / (sigma * sigma), norm, K, n // 2, strict, spans)
        kp = (n, sigma, norm, kmax)
        own = (np.empty(SCRATCH), np.zeros(5), np.empty((1, NHIT)), np.empty((MAX_STACK, 3)),
               np.empty((MAX_STACK, 3), dtype=np.int64), np.empty(max(i1 - i0, 1), dtype=np.int64),
               np.empty((max(cap, 16), 2), dtype=np.int64), np.empty(max(xcap, 16) if spans else 2),
               np.zeros(3, dtype=np.int64))
        scratch, cur, hrec1, st, sti, active, runs, xs, cnt = borrow(own)
        bufs = (scratch, hrec1, st, sti, cur)
        sbufs = (scratch, active, cur)
        rk0_all = borrow(run_k0[q])
        rk1_all = borrow(run_k1[q])
        cz_all = borrow(cross_z[q])
        used = 0
        xused = 0
        status = OK
        stop = B * B
        nev = 0
        for ly in range(B):
            j = by * B + ly
            for lx in range(B):
                i = bx * B + lx
                lr = ly * B + lx
                ray_nrun[q, lr] = 0
                ray_nx[q, lr] = 0
                if lr < first[q] or i >= W or j >= H or i1 == i0 or status != OK:
                    continue
                cur[W_PX] = x0 + i * pxs
                cur[W_PY] = y0 - j * pys
                if method == 1:
                    ok = sampling_ray(seg, boxes, ids, i0, i1, wk, kp, sbufs, runs, cnt)
                else:
                    ok = union_ray(seg, boxes, ids, i0, i1, wk, kp, bufs, runs, xs, cnt)
                if ok:
                    ok = store_ray(runs, xs, cnt, rk0_all[used:], rk1_all[used:], cap - used,
                                   cz_all[xused:], xcap - xused)
                if not ok:   # resumed at this ray, with more room
                    status = RUNS_FULL
                    stop = lr
                    continue
                nev = cnt[C_EV]
                ray_nrun[q, lr] = cnt[C_RUN]
                used += cnt[C_RUN]
                ray_nx[q, lr] = cnt[C_X]
                xused += cnt[C_X]
        stats[q, 0] = status
        stats[q, 1] = nev
        stats[q, 2] = stop
        keep_alive(own)
