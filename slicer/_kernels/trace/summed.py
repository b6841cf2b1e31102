"""Slicing tracer: classify every voxel centre of vertical rays (EG22 §3-4).

A *bucket* is a B x B block of pixel columns with the list of segments whose
support footprint touches it, sorted by the support's lowest z. For each ray
(pixel column) the kernels produce *runs*: half-open ranges ``[k0, k1)`` of
layer indices whose voxel centres are inside (``F >= 1``), in increasing
order. Runs are the compact output of a tile; layers are assembled from them
later (:mod:`slicer._kernels.layers`), so the voxel volume never exists.

Three methods share buckets, field and output:

* ``trace_interval``: per-primitive interval bounds + directional Lipschitz
  bounds, pre-segmentation at t_in, t_out and t*, bisection aligned to layer
  centres; every centre is classified exactly as ``F(centre) >= 1``.
* ``trace_sampling``: the field at every centre, over a z-sorted active window
  of the bucket list (Liu et al. 2021).
* ``trace_segment``: segment tracing on the directional Lipschitz bound
  (Galin et al. 2020), stepping over centres the bound proves unambiguous and
  evaluating the rest.

Status codes: 0 ok, 1 run or crossing buffer full (caller retries with
more room).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from slicer._jit import inline_kernel, kernel, parallel_kernel, unrefcounted_kernel
from slicer._kernels.runtime.borrow import borrow, keep_alive
from slicer._kernels.field.segment import segment_eval
from slicer._kernels.rays.lazy import lazy_ends, settle, split_lazy
from slicer._kernels.rays.walk import (PAD, SURFACE_BAND, cluster_breakpoints, eval_along, first_centre, hermite_point, leap_chain,
                   next_cluster, piece_bounds_iv, piece_ends, piece_members, sort_hits, walk_buffers)
from slicer._kernels.rays.support import H_TIN, H_TOUT, lipschitz, ray_support

OK = 0
RUNS_FULL = 1

MAX_STACK = 256
# Split placement at a Hermite estimate of the crossing can shrink a piece by
# as little as one centre (or w/8) per level when the estimate is poor; past
# these stack depths the splits fall back to the middle, which bounds the
# depth by DEEP_CENTRES + 2 log2(K) + 2 and DEEP_SPANS + log2(h / span_tol) + 1.
DEEP_CENTRES = 96
DEEP_SPANS = 150
#: a centre split's Hermite estimate is refined until a Newton step moves
#: less than this many layer heights (:func:`_centre_split`)
CENTRE_STEP = 0.125
#: members whose bound on the whole ray is below this add no cut to their
#: cluster (:func:`slicer._kernels.rays.walk.cluster_breakpoints`): fewer pieces,
#: each bounded as soundly (docs/math.md §5.7)
WEAK_CUT = 0.2


@unrefcounted_kernel
def _emit(k0, k1, inside, rk0, rk1, nrun, cap):
    """Append centres k0..k1 (inclusive) with one class to the ray's runs.

    Returns the new run count, or -1 when the buffer is full.
    """
    if not inside or k1 < k0:
        return nrun
    if nrun > 0 and rk1[nrun - 1] == k0:
        rk1[nrun - 1] = k1 + 1
        return nrun
    if nrun >= cap:
        return -1
    rk0[nrun] = k0
    rk1[nrun] = k1 + 1
    return nrun + 1


@unrefcounted_kernel
def _ray_hits(seg, boxes, ids, i0, i1, px, py, prim, zlo, zhi, hprim, hrec, order):
    """Hit records of the bucket's segments ids[i0:i1] with the vertical ray
    at (px, py), kept if they reach [zlo, zhi]; returns the count, sorted by t_in
    into ``order``; ``prim = (n, sigma, N, kmax)``. A segment whose support
    box misses the ray is skipped before the exact test."""
    n, sigma, norm, kmax = prim
    nh = 0
    for r in range(i0, i1):
        g = ids[r]
        if px < boxes[g, 0] or px > boxes[g, 3] or py < boxes[g, 1] or py > boxes[g, 4]:
            continue
        if ray_support(seg, ids[r], px, py, 0.0, 0.0, 0.0, 1.0, n, sigma, norm, kmax, hrec, nh):
            if hrec[nh, H_TOUT] > zlo and hrec[nh, H_TIN] < zhi:
                hprim[nh] = ids[r]
                nh += 1
    sort_hits(hrec, order, nh)
    return nh


@unrefcounted_kernel
def _cluster_field(seg, hprim, hrec, order, a, b, px, py, z, m, inv_s2, norm, scratch):
    """Field at (px, py, z) of the cluster members order[a:b] whose support
    interval holds z; returns (F, evaluations)."""
    f = 0.0
    nev = 0
    for c in range(a, b):
        r = order[c]
        if hrec[r, H_TIN] < z and hrec[r, H_TOUT] > z:
            fi, gx, gy, gz = segment_eval(seg, hprim[r], px, py, z, m, inv_s2, norm, bool(False), scratch)
            f += fi
            nev += 1
    return f, nev


@unrefcounted_kernel
def trace_ray_interval(seg, boxes, ids, i0, i1, xy, col, prim, opt, bufs, rows, stack, cache, out):
    """Classify the K voxel centres of one ray (interval method).

    Parameters
    ----------
    seg, boxes, ids, i0, i1
        The segment table, the support boxes and the bucket list ``ids[i0:i1]``.
    xy : tuple
        ``(px, py)``: the vertical ray's position (mm).
    col, prim, opt : tuple
        ``(z0, h, K)``: first centre and layer height (mm), number of
        centres; ``(n, sigma, N, kmax)``; ``(strict, cut_support, lazy,
        spans, span_tol)``.
    bufs, rows, stack, cache : tuple
        The walk's work arrays (:func:`slicer._kernels.rays.walk.walk_buffers`):
        ``(scratch, hprim, hrec, order, bps, sarr, mstat)``; per-primitive
        rows ``(F, FH, FP)``; the piece stack ``(kind, t, k0, k1)``; each
        hit's last evaluation ``(ct, cf, cfp)``.
    out : tuple
        ``(rk0, rk1, cz)``: room for the ray's runs and crossings (their
        lengths are the capacities).

    With ``spans``, also locate every crossing of F = 1 inside the grid's z
    range [z0 - h/2, z0 + (K - 1/2) h] to within ``span_tol``
    (:func:`_walk_piece`). Crossings go to ``cz`` in increasing order; the
    ray is outside below the first one, and they alternate entry / exit. A
    ray inside at the grid's bottom (or top) gets a crossing exactly there.

    With ``lazy`` (and neither spans nor ``strict``), the walk is lazy
    (:func:`slicer._kernels.rays.lazy.split_lazy`): ``F`` / ``FH`` hold
    per-primitive lower / upper bounds, equal where the value is known.

    Returns
    -------
    nrun : int
        Number of runs written to rk0/rk1 (-1 when ``rk0`` or ``cz`` was
        too short).
    nevals : int
        Primitive evaluations performed.
    nx : int
        Number of crossings written to ``cz``.
    """
    z0, h, K = col
    n, sigma, norm, kmax = prim
    strict, cut_support, lazy, spans, span_tol = opt
    scratch, hprim, hrec, order, bps, sarr, mstat = bufs
    ct, _, _ = cache
    px, py = xy
    zlo = z0 - 0.5 * h
    zhi = z0 + (K - 0.5) * h
    nh = _ray_hits(seg, boxes, ids, i0, i1, px, py, prim, zlo, zhi, hprim, hrec, order)
    for r in range(nh):
        ct[r] = math.nan
    walk = (seg, hprim, hrec, sarr, (px, py, 0.0, 0.0, 0.0, 1.0), (n // 2, 1.0 / (sigma * sigma), norm),
            scratch, rows, cache, mstat)
    zs = (z0, h, K, zlo, zhi)
    opt = (strict, cut_support, lazy and not spans and not strict, spans, span_tol)
    tally = (0, 0, 0, False)
    a = 0
    while a < nh:
        b, cs, ce = next_cluster(hrec, order, a, nh)
        tally = _trace_cluster(walk, order, bps, (a, b, cs, ce), zs, opt, stack, out, tally)
        nrun, _, _, _ = tally
        if nrun < 0:
            break
        a = b
    nrun, nev, nx, _ = tally
    return nrun, nev, nx


@inline_kernel
def _trace_cluster(walk, order, bps, clu, zs, opt, stack, out, tally):
    """Walk the pieces of the cluster ``clu = (a, b, cs, ce)``: hits
    ``order[a:b]`` spanning ``[cs, ce]``.

    ``walk = (seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache,
    mstat)`` holds the ray's work data; ``zs = (z0, h, K, zlo, zhi)`` the
    centres and the grid's z range (mm); ``opt`` as
    :func:`trace_ray_interval` (``lazy`` only where the lazy walk applies);
    ``tally = (nrun, nevals, nx, inside)`` the ray's counts so far and, with
    spans, whether it is inside at the cluster's start. Returns the updated
    tally (``nrun`` -1 when a buffer is full).

    The pieces run between the cluster's breakpoints: every member's cut t*
    (EG22), optionally every support entry and exit, and with spans the
    grid's ends. A piece the members' bounds on the whole ray keep below 1
    is skipped; inside at its start, the unimodal lower bound may settle
    several pieces at once (:func:`slicer._kernels.rays.walk.leap_chain`); any
    other piece is walked (:func:`_walk_piece`).
    """
    seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache, mstat = walk
    st_f, st_fh, st_fp = rows
    z0, h, K, zlo, zhi = zs
    strict, cut_support, lazy, spans, span_tol = opt
    a, b, cs, ce = clu
    rk0, rk1, cz = out
    nrun, nev, nx, inside = tally
    if first_centre(ce, z0, h, K) <= first_centre(cs, z0, h, K) and not (spans and ce > zlo and cs < zhi):
        return tally
    weak = 0.0 if spans or strict else WEAK_CUT
    nb = cluster_breakpoints(hrec, order, a, b, cs, ce, cut_support, zlo if spans else cs, zhi if spans else cs, bps,
                             weak)
    cur = st_f.shape[0] - 1
    tlast = cs
    j = -1
    while j < nb - 2 and nrun >= 0 and nx >= 0:
        j += 1
        ta, tb = bps[j], bps[j + 1]
        k0, k1 = first_centre(ta, z0, h, K), first_centre(tb, z0, h, K) - 1
        if k1 < k0 and not (spans and tb > zlo and ta < zhi):
            continue
        ns, fmax = piece_members(hrec, order, a, b, ta, tb, sarr)
        if ns == 0 or fmax < 1.0 - PAD * (1.0 + fmax):
            continue
        if lazy:   # the ends' values only as far as the piece's verdict needs them
            _, ne = lazy_ends(seg, hprim, hrec, sarr, ns, ray, ta, tb, kp, scratch, rows, cur, 0, mstat, cache)
            fcur = _row_sum(st_f, cur, ns)
        else:
            fcur, ne = eval_along(seg, hprim, hrec, sarr, ns, ray, ta, kp, scratch, st_f, st_fp, cur, cache)
        nev += ne
        if spans and (fcur >= 1.0) != inside:   # only after a skipped stretch (below the grid): enter here
            nx = _crossing(cz, nx, ta)
            inside = not inside
        if not strict and not lazy and fcur >= 1.0 and j + 2 < nb:
            # inside at ta: settle as many breakpoints ahead as the unimodal lower bound proves inside at once
            jj, ne = leap_chain(seg, hprim, hrec, sarr, ns, (st_f, st_fp), cur, ray, bps, j, nb, fcur, kp, scratch,
                                cache)
            nev += ne
            if jj > j:
                nrun = _emit(k0, first_centre(bps[jj], z0, h, K) - 1, True, rk0, rk1, nrun, rk0.shape[0])
                tlast = bps[jj]
                j = jj - 1
                continue
        if not lazy:
            _, ne = eval_along(seg, hprim, hrec, sarr, ns, ray, tb, kp, scratch, st_f, st_fp, 0, cache)
            nev += ne
        nrun, nev, nx, inside = _walk_piece(walk, ns, (ta, tb, k0, k1, fcur), zs, opt, stack, out,
                                            (nrun, nev, nx, inside))
        tlast = tb
    if spans and inside:   # the rest of the cluster lies above the grid: leave at its top
        nx = _crossing(cz, nx, min(tlast, zhi))
        inside = False
    return (nrun, nev, nx, inside) if nx >= 0 else (-1, nev, nx, inside)


@inline_kernel
def _row_sum(F, row, ns):
    """Sum of ``F[row, :ns]``."""
    f = 0.0
    for s in range(ns):
        f += F[row, s]
    return f


@inline_kernel
def _crossing(cz, nx, t):
    """Append the crossing ``t`` to ``cz``; the new count, or -1 when full
    (or already -1)."""
    if nx < 0 or nx >= cz.shape[0]:
        return -1
    cz[nx] = t
    return nx + 1


@inline_kernel
def _push(st_kind, st_t, st_k0, st_k1, p, kind, t, k0, k1):
    """Write stack slot ``p``: a piece (kind 0) ending at ``t`` and holding
    centres ``k0..k1``, or a centre ``k0`` already classified (kind 1,
    ``k1`` 1 inside, 0 outside)."""
    st_kind[p] = kind
    st_t[p] = t
    st_k0[p] = k0
    st_k1[p] = k1


@inline_kernel
def _walk_piece(walk, ns, piece, zs, opt, stack, out, tally):
    """Classify the centres ``k0..k1`` of the piece ``piece = (ta, tb, k0,
    k1, F(ta))``, whose end values are in the current row and slot 0
    (arguments as :func:`_trace_cluster`).

    Pieces wait on the stack; a split leaves the right part in its slot and
    pushes the split centre and the left part. A piece the interval bound
    settles emits its centres' class (:func:`_settle_end`); a piece whose
    first centre sits on its left end classifies it from the known value;
    any other is split at a centre (:func:`_centre_split`). With spans, an
    ambiguous piece holding no centre is split further
    (:func:`_span_split`) until it is settled or narrower than ``span_tol``
    (:func:`_span_done`), and every crossing is placed.
    """
    seg, hprim, hrec, sarr, ray, kp, scratch, rows, cache, mstat = walk
    st_f, st_fh, st_fp = rows
    st_kind, st_t, st_k0, st_k1 = stack
    z0, h, K, zlo, zhi = zs
    strict, cut_support, lazy, spans, span_tol = opt
    ta, tb, k0, k1, fcur = piece
    nrun, nev, nx, inside = tally
    rk0, rk1, cz = out
    fh = st_fh if lazy else st_f     # eager: every bound is a value
    cur = st_f.shape[0] - 1
    tcur = ta
    _push(st_kind, st_t, st_k0, st_k1, 0, 0, tb, k0, k1)
    sp = 1
    while sp > 0 and nrun >= 0 and nx >= 0:
        sp -= 1
        p = sp
        q0, q1, e_t = st_k0[p], st_k1[p], st_t[p]
        if st_kind[p] == 1:
            nrun = _emit(q0, q0, q1 == 1, rk0, rk1, nrun, rk0.shape[0])
            continue
        if q1 >= q0 or spans:
            lo, hi, mono = piece_bounds_iv(hrec, sarr, ns, st_f, fh, st_fp, cur, p, tcur, e_t, strict, mstat)
            pad = PAD * (1.0 + abs(hi))
            if lo > 1.0 + pad:
                nrun = _emit(q0, q1, True, rk0, rk1, nrun, rk0.shape[0])
            elif hi < 1.0 - pad or (q1 < q0 and _span_done(st_f, ns, p, (tcur, e_t, fcur), zs, span_tol)):
                pass
            elif sp + 3 > st_kind.shape[0]:
                return -1, nev, nx, inside   # cannot happen for K < 2^70; keep the kernel total anyway
            elif q1 < q0:   # spans: no centre left; refine the crossing(s) to span_tol
                ts = _span_split(st_f, st_fp, ns, p, (tcur, e_t, fcur, mono), span_tol)
                _, ne = eval_along(seg, hprim, hrec, sarr, ns, ray, ts, kp, scratch, st_f, st_fp, p + 1, cache)
                nev += ne
                _push(st_kind, st_t, st_k0, st_k1, p + 1, 0, ts, q0, q1)
                sp = p + 2
                continue
            elif z0 + q0 * h == tcur:
                # the first centre sits on the left end: its value is known (lazy: as far as its class needs)
                in0 = fcur >= 1.0
                if lazy:
                    in0, ne = settle(seg, hprim, hrec, sarr, ns, ray, tcur, kp, scratch, rows, cur, mstat, (cur, p),
                                     False, cache)
                    nev += ne
                nrun = _emit(q0, q0, in0, rk0, rk1, nrun, rk0.shape[0])
                st_k0[p] = q0 + 1
                sp += 1
                continue
            else:
                km = _centre_split(st_f, st_fp, ns, p, (tcur, e_t, fcur, mono, q0, q1), z0, h)
                zm = z0 + km * h
                st_k0[p] = km + 1
                if lazy:
                    inm, ne = split_lazy(seg, hprim, hrec, sarr, ns, ray, zm, kp, scratch, rows, cur, p, p + 2, mstat,
                                         cache)
                else:
                    fm, ne = eval_along(seg, hprim, hrec, sarr, ns, ray, zm, kp, scratch, st_f, st_fp, p + 2, cache)
                    inm = fm >= 1.0
                nev += ne
                _push(st_kind, st_t, st_k0, st_k1, p + 1, 1, zm, km, 1 if inm else 0)
                _push(st_kind, st_t, st_k0, st_k1, p + 2, 0, zm, q0, km - 1)
                sp = p + 3
                continue
        fcur, nx, inside = _settle_end(st_f, st_fh, st_fp, ns, p, (tcur, e_t, fcur), spans, inside, cz, nx)
        tcur = e_t
    return nrun, nev, nx, inside


@inline_kernel
def _span_done(F, ns, p, piece, zs, span_tol):
    """Whether an ambiguous piece ``piece = (tcur, e_t, F(tcur))`` (right end
    in slot ``p``) holding no centre needs no more splits: narrow enough,
    outside the grid, or F within rounding of 1 at both ends (a column lying
    in the surface)."""
    z0, h, K, zlo, zhi = zs
    tcur, e_t, fcur = piece
    fe = _row_sum(F, p, ns)
    return (e_t - tcur <= span_tol or e_t <= zlo or tcur >= zhi
            or (abs(fcur - 1.0) <= SURFACE_BAND and abs(fe - 1.0) <= SURFACE_BAND))


@inline_kernel
def _span_split(F, FP, ns, p, piece, span_tol):
    """Where to split the ambiguous piece ``piece = (tcur, e_t, F(tcur),
    mono)`` (right end in slot ``p``, no centre) to locate its crossing: at
    the Hermite estimate offset by ``span_tol / 2`` toward the nearer end
    where F is monotone and brackets 1 (up to DEEP_SPANS deep), else at the
    middle; never within w/8 of an end."""
    tcur, e_t, fcur, mono = piece
    fe, dcur, de = piece_ends(F, FP, F.shape[0] - 1, p, ns)
    w = e_t - tcur
    ts = tcur + 0.5 * w
    if mono != 0 and (fcur - 1.0) * (fe - 1.0) < 0.0 and p < DEEP_SPANS:
        tr = hermite_point(tcur, e_t, fcur - 1.0, fe - 1.0, dcur, de)
        if tr - tcur <= e_t - tr:
            ts = tr + 0.5 * span_tol
        else:
            ts = tr - 0.5 * span_tol
        ts = min(max(ts, tcur + 0.125 * w), e_t - 0.125 * w)
    return ts


@inline_kernel
def _centre_split(F, FP, ns, p, piece, z0, h):
    """The centre at which to split the piece ``piece = (tcur, e_t, F(tcur),
    mono, q0, q1)`` (right end in slot ``p``): where F is monotone and
    brackets 1 (one crossing), the centre nearest the Hermite estimate of
    the crossing (up to DEEP_CENTRES deep); elsewhere the middle centre.

    The estimate is only rounded to a centre, so its Newton steps stop once
    one moves less than ``CENTRE_STEP`` layer heights: only a root within
    that of the midpoint between two centres can round to the other one.
    Which centre is split on changes the evaluation count, never a voxel:
    every centre is classified from its own value or a sound bound."""
    tcur, e_t, fcur, mono, q0, q1 = piece
    km = (q0 + q1) // 2
    if mono != 0 and q1 > q0 and p < DEEP_CENTRES:
        fe, dcur, de = piece_ends(F, FP, F.shape[0] - 1, p, ns)
        if (fcur - 1.0) * (fe - 1.0) < 0.0:
            tr = hermite_point(tcur, e_t, fcur - 1.0, fe - 1.0, dcur, de, CENTRE_STEP * h / (e_t - tcur))
            kr = int(math.floor((tr - z0) / h + 0.5))
            km = min(max(kr, q0), q1)
    return km


@inline_kernel
def _settle_end(F, FH, FP, ns, p, piece, spans, inside, cz, nx):
    """Finish the settled piece ``piece = (tcur, e_t, F(tcur))`` whose right
    end is in slot ``p``: with spans, place its one crossing (an odd number
    lies in it when the class changes) at the Hermite estimate; the right
    end becomes the current point. Returns (F(e_t), nx, inside), ``nx`` -1
    when ``cz`` is full."""
    tcur, e_t, fcur = piece
    cur = F.shape[0] - 1
    fe = _row_sum(F, p, ns)
    if spans and (fe >= 1.0) != inside:
        fe, dcur, de = piece_ends(F, FP, cur, p, ns)
        tr = hermite_point(tcur, e_t, fcur - 1.0, fe - 1.0, dcur, de)
        if not (tr > tcur and tr < e_t):
            tr = 0.5 * (tcur + e_t)
        nx = _crossing(cz, nx, tr)
        inside = not inside
    for s in range(ns):
        F[cur, s] = F[p, s]
        FH[cur, s] = FH[p, s]
        FP[cur, s] = FP[p, s]
    return fe, nx, inside


@unrefcounted_kernel
def trace_ray_sampling(seg, boxes, ids, i0, i1, px, py, col, kp, scratch, active, rk0, rk1, cap):
    """Classify the K centres of one ray by evaluating the field at each,
    over the z-sorted active window of the bucket list ids[i0:i1];
    ``col = (z0, h, K)``, ``kp = (m, 1/sigma^2, N)``."""
    z0, h, K = col
    m, inv_s2, norm = kp
    nrun = 0
    nev = 0
    na = 0
    nxt = i0
    for k in range(K):
        z = z0 + k * h
        while nxt < i1 and boxes[ids[nxt], 2] <= z:
            g = ids[nxt]
            nxt += 1
            if px < boxes[g, 0] or px > boxes[g, 3] or py < boxes[g, 1] or py > boxes[g, 4]:
                continue
            active[na] = g
            na += 1
        w = 0
        for q in range(na):
            if boxes[active[q], 5] >= z:
                active[w] = active[q]
                w += 1
        na = w
        if na == 0:
            if nxt >= i1:
                break
            continue
        f = 0.0
        for q in range(na):
            fi, gx, gy, gz = segment_eval(seg, active[q], px, py, z, m, inv_s2, norm, bool(False), scratch)
            f += fi
        nev += na
        nrun = _emit(k, k, f >= 1.0, rk0, rk1, nrun, cap)
        if nrun < 0:
            return -1, nev
    return nrun, nev


@unrefcounted_kernel
def trace_ray_segment(seg, boxes, ids, i0, i1, xy, col, prim, scratch, hprim, hrec, order, rk0, rk1, cap):
    """Classify the K centres of the ray at ``xy = (px, py)`` with segment
    tracing (GGPP20); ``col = (z0, h, K)``, ``prim = (n, sigma, N, kmax)``.

    From t with value F(t), no crossing lies within |F(t) - 1| / lambda, where
    lambda bounds |F'| on [t, t + s] (sum of per-primitive directional
    Lipschitz bounds); every centre in that safe step takes the class of F(t).
    When the step would not reach the next unclassified centre, the field is
    evaluated at that centre instead, so centres are classified exactly.
    """
    px, py = xy
    z0, h, K = col
    n, sigma, norm, kmax = prim
    m = n // 2
    inv_s2 = 1.0 / (sigma * sigma)
    zlo = z0 - 0.5 * h
    zhi = z0 + (K - 0.5) * h
    nh = _ray_hits(seg, boxes, ids, i0, i1, px, py, (n, sigma, norm, kmax), zlo, zhi, hprim, hrec, order)
    nrun = 0
    nev = 0
    a = 0
    while a < nh:
        b, cs, ce = next_cluster(hrec, order, a, nh)
        k = first_centre(cs, z0, h, K)
        kend = first_centre(ce, z0, h, K)
        t = cs
        s = ce - cs
        while k < kend:
            f, ne = _cluster_field(seg, hprim, hrec, order, a, b, px, py, t, m, inv_s2, norm, scratch)
            nev += ne
            lam = 0.0
            for c in range(a, b):
                r = order[c]
                if hrec[r, H_TIN] < t + s and hrec[r, H_TOUT] > t:
                    lam += lipschitz(hrec, r, t, t + s)
            step = abs(f - 1.0) / lam if lam > 0.0 else math.inf
            if step > s:
                step = s
            tn = t + step
            k1 = first_centre(tn, z0, h, K)   # centres in [t, tn) are safe
            zk = z0 + k * h
            if k1 > k and zk >= t:
                nrun = _emit(k, k1 - 1, f >= 1.0, rk0, rk1, nrun, cap)
                if nrun < 0:
                    return -1, nev
                k = k1
                t = tn
                s = 1.5 * step if step > 0.0 else h
            else:
                # too close to a crossing to step over the next centre: evaluate it
                fz, ne = _cluster_field(seg, hprim, hrec, order, a, b, px, py, zk, m, inv_s2, norm, scratch)
                nev += ne
                nrun = _emit(k, k, fz >= 1.0, rk0, rk1, nrun, cap)
                if nrun < 0:
                    return -1, nev
                k += 1
                t = zk
                s = max(2.0 * h, 1.5 * step)
        a = b
    return nrun, nev


@parallel_kernel
def trace_buckets(method, buckets, first, bk, grid, prim, opt, out):
    """Trace every ray of the given buckets in parallel.

    Parameters
    ----------
    method : int
        0 interval, 1 sampling, 2 segment tracing.
    buckets : (nb,) int64
        Flat bucket indices (``by * nbx + bx``) to trace.
    first : (nb,) int64
        The first ray of each bucket to trace (row-major inside the bucket):
        0, or where an earlier launch ran out of room, so that a bucket
        whose buffers filled up resumes instead of starting over.
    bk : tuple
        ``(nbx, B, bucket_off, ids, seg, boxes)``: buckets per row and
        bucket edge (pixels); the CSR bucket lists (int64), each sorted by
        support zmin; the segment table ((m, 10) float64) and the support
        boxes ``xlo ylo zlo xhi yhi zhi`` ((m, 6) float64: ray culling,
        sampling window).
    grid : tuple
        ``(W, H, x0, y0, pxs, pys, z0, h, K)``: image size (pixels); the
        centre of voxel (0, 0, 0), pixel sizes and layer height (mm; rows
        run toward -y); the number of layers.
    prim : tuple
        ``(n, sigma, N, kmax)``: kernel degree, support factor,
        normalisation, max |k'|.
    opt : tuple
        ``(strict, cut_support, lazy, spans, span_tol)``, interval method:
        ``lazy`` the lazy walk (docs/math.md §5.5: same voxels, fewer
        evaluations); ``spans`` also locates every crossing to ``span_tol`` (mm).
    out : tuple, out
        ``(ray_nrun, run_k0, run_k1, stats, ray_nx, cross_z)``: runs per ray
        ((nb, B*B) int64, row-major inside the bucket); the runs of all the
        bucket's rays traced, ray after ray ((nb, cap) int32 each);
        [status, primitive evaluations, the first ray not traced] per
        bucket ((nb, 3) int64; with status RUNS_FULL, the runs of the rays
        before that one are complete, and the evaluations are theirs);
        crossings per ray ((nb, B*B) int64) and their heights, ray after
        ray ((nb, xcap) float64, mm).
    """
    nbx, B, bucket_off, ids, seg, boxes = bk
    # borrowed views (slicer._kernels.runtime.borrow): the arguments outlive the launch
    bk = (nbx, B, bucket_off, borrow(ids), borrow(seg), borrow(boxes))
    for q in prange(buckets.shape[0]):
        # np.int64: a prange index is uint64 inside the parallel body, int64 when typed
        # outside it; one type, one compiled copy of the bucket (docs/development.md)
        _trace_bucket(method, np.int64(q), buckets[q], first[q], bk, grid, prim, opt, out)


@kernel
def _trace_bucket(method, q, bidx, first, bk, grid, prim, opt, out):
    """Trace the rays ``first, first + 1, ...`` of bucket ``bidx`` into row
    ``q`` of the outputs (arguments as :func:`trace_buckets`), ray after
    ray with one set of work arrays, until they are done or the buffers are
    full."""
    nbx, B, bucket_off, ids, seg, boxes = bk
    W, H, x0, y0, pxs, pys, z0, h, K = grid
    n, sigma, norm, kmax = prim
    strict, cut_support, lazy, spans, span_tol = opt
    ray_nrun, run_k0, run_k1, stats, ray_nx, cross_z = out
    cap = run_k0.shape[1]
    by = bidx // nbx
    bx = bidx - by * nbx
    i0 = bucket_off[bidx]
    i1 = bucket_off[bidx + 1]
    nl = max(i1 - i0, 1)
    own = walk_buffers(nl, MAX_STACK)
    own_st = (np.empty((MAX_STACK + 1, nl)), np.empty(nl, dtype=np.int64), np.empty(MAX_STACK, dtype=np.int64),
              np.empty(MAX_STACK, dtype=np.int64), np.empty(MAX_STACK, dtype=np.int64),
              np.empty(nl, dtype=np.int64))
    scratch, hprim, hrec, order, bps, sarr, st_f, st_fp, st_t, ct, cf, cfp = borrow(own)
    st_fh, mstat, st_kind, st_k0, st_k1, active = borrow(own_st)
    bufs = (scratch, hprim, hrec, order, bps, sarr, mstat)
    stack = (st_kind, st_t, st_k0, st_k1)
    rk0_all = borrow(run_k0[q])
    rk1_all = borrow(run_k1[q])
    cz_all = borrow(cross_z[q])
    used = 0
    xused = 0
    nev_tot = 0
    status = OK
    stop = B * B
    for ly in range(B):
        j = by * B + ly
        for lx in range(B):
            i = bx * B + lx
            lr = ly * B + lx
            ray_nrun[q, lr] = 0
            ray_nx[q, lr] = 0
            if lr < first or i >= W or j >= H or i1 == i0 or status != OK:
                continue
            px = x0 + i * pxs
            py = y0 - j * pys
            rk0 = rk0_all[used:]
            rk1 = rk1_all[used:]
            room = cap - used
            nx = 0
            if method == 0:
                nr, ne, nx = trace_ray_interval(seg, boxes, ids, i0, i1, (px, py), (z0, h, K), prim, opt, bufs,
                                                (st_f, st_fh, st_fp), stack, (ct, cf, cfp),
                                                (rk0, rk1, cz_all[xused:]))
            elif method == 1:
                nr, ne = trace_ray_sampling(seg, boxes, ids, i0, i1, px, py, (z0, h, K),
                                            (n // 2, 1.0 / (sigma * sigma), norm), scratch, active, rk0, rk1,
                                            room)
            else:
                nr, ne = trace_ray_segment(seg, boxes, ids, i0, i1, (px, py), (z0, h, K), prim, scratch, hprim, hrec,
                                           order, rk0, rk1, room)
            if nr < 0:   # resumed at this ray, with more room
                status = RUNS_FULL
                stop = lr
                continue
            nev_tot += ne
            ray_nrun[q, lr] = nr
            used += nr
            ray_nx[q, lr] = nx
            xused += nx
    stats[q, 0] = status
    stats[q, 1] = nev_tot
    stats[q, 2] = stop
    keep_alive(own)
    keep_alive(own_st)
