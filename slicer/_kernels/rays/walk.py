"""Ray-walk helpers shared by the slicing tracer and the renderer (EG22 §3-4).

Both walk a ray ``r(t) = o + t d`` (``|d| = 1``; slicing: ``o = (x, y, 0)``,
``d = e_z`` and ``t = z``) through the supports of the primitives it meets:
hits are sorted by support entry, grouped into clusters of overlapping
supports, cut at breakpoints, and every piece between two breakpoints is
bounded per primitive from the values and directional derivatives at its
ends. These are those common steps; the two walkers differ only in what they
do with an ambiguous piece (split at layer centres, or bisect toward a root).

Hit records are rows of ``hrec`` in the layout of
:mod:`slicer._kernels.rays.support` (``H_TIN``, ``H_TOUT``, ...). Per-primitive
values and slopes at the ends of pieces are rows of 2-D arrays ``F``, ``FP``
(one row per stack slot, one column per active primitive), passed with row
indices: slicing a row out would cost an atomic reference-count increment
and decrement per call, a third of the run time in this inner loop.
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import inline_kernel, kernel, unrefcounted_kernel
from slicer._kernels.field.segment import LANE_TAG, LANES, SCRATCH, lane_load, lane_result, segment_eval, segment_first_lanes
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT, lipschitz
from slicer.constants import PAD, SURFACE_BAND



@kernel
def walk_buffers(nl, stack):
    """Work arrays of one ray walk over a bucket list of ``nl`` segments,
    allocated once per bucket and reused by its rays.

    Returns
    -------
    scratch : (SCRATCH,) float64
        :func:`slicer._kernels.field.segment.segment_eval`'s work array.
    hprim, order, sarr : (nl,) int64
        Segment of each hit, hits sorted by entry, active hits of a piece.
    hrec : (nl, NHIT) float64
        Hit records.
    bps : (3 nl + 4,) float64
        Breakpoints of a cluster.
    st_f, st_fp : (stack + 1, nl) float64
        Per-primitive f and f' at the ends of stacked pieces; the last row
        holds the current point.
    st_t : (stack,) float64
        Right end of each stacked piece.
    ct, cf, cfp : (nl,) float64
        Each hit's last evaluation (t, f, f'), see :func:`eval_along`.
    """
    return (np.empty(SCRATCH), np.empty(nl, dtype=np.int64), np.empty((nl, NHIT)),
            np.empty(nl, dtype=np.int64), np.empty(3 * nl + 4), np.empty(nl, dtype=np.int64),
            np.empty((stack + 1, nl)), np.empty((stack + 1, nl)), np.empty(stack),
            np.empty(nl), np.empty(nl), np.empty(nl))


@unrefcounted_kernel
def first_centre(t, z0, h, K):
    """Smallest k with ``z0 + k h >= t`` (clamped to [0, K]): the first voxel centre
    at or above height ``t`` of a column of ``K`` centres ``z0 + k h``."""
    u = math.ceil((t - z0) / h)
    if not u > 0.0:
        k = 0
    elif u >= K:
        k = K
    else:
        k = int(u)
    while k > 0 and z0 + (k - 1) * h >= t:
        k -= 1
    while k < K and z0 + k * h < t:
        k += 1
    return k


@unrefcounted_kernel
def sort_hits(hrec, order, nh):
    """``order[:nh]`` = the hits ``hrec[:nh]`` sorted by support entry t_in
    (insertion sort, stable: bucket lists arrive nearly sorted)."""
    for a in range(nh):
        order[a] = a
    for a in range(1, nh):
        v = order[a]
        key = hrec[v, H_TIN]
        b = a - 1
        while b >= 0 and hrec[order[b], H_TIN] > key:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = v


@unrefcounted_kernel
def next_cluster(hrec, order, a, nh):
    """The cluster of overlapping supports that starts at sorted hit ``a``.

    Returns
    -------
    b : int
        Hits ``order[a:b]`` overlap into one span.
    cs, ce : float
        The span ``[min t_in, max t_out]``.
    """
    cs = hrec[order[a], H_TIN]
    ce = hrec[order[a], H_TOUT]
    b = a + 1
    while b < nh and hrec[order[b], H_TIN] < ce:
        ce = max(ce, hrec[order[b], H_TOUT])
        b += 1
    return b, cs, ce


@unrefcounted_kernel
def piece_members(hrec, order, a, b, ta, tb, sarr):
    """The members of the cluster ``order[a:b]`` whose support interval meets
    the piece ``(ta, tb)``, into ``sarr`` (hit rows, cluster order).

    Returns
    -------
    ns : int
        How many.
    fmax : float
        The sum of their bounds on the whole ray (``H_FMAX``): a piece with
        ``fmax`` below 1 holds no crossing.
    """
    ns = 0
    fmax = 0.0
    for c in range(a, b):
        r = order[c]
        if hrec[r, H_TIN] < tb and hrec[r, H_TOUT] > ta:
            sarr[ns] = r
            ns += 1
            fmax += hrec[r, H_FMAX]
    return ns, fmax


@unrefcounted_kernel
def cluster_breakpoints(hrec, order, a, b, cs, ce, cut_support, x0, x1, bps, weak=0.0):
    """The breakpoints of the cluster ``order[a:b]`` spanning ``[cs, ce]``
    into ``bps``, sorted and unique; returns their count.

    They are ``cs``, ``ce``, every member's cut ``t*`` inside its support
    (EG22), with ``cut_support`` every member's support entry and exit, and
    the extra cuts ``x0``, ``x1``; each one only strictly inside ``(cs, ce)``.
    A member whose bound on the whole ray (``H_FMAX``) is below ``weak``
    adds no cut: it stays bounded on the pieces it spans, monotone or not
    (docs/math.md §5.7). The tracer and the renderer both cut their
    clusters here.
    """
    bps[0] = cs
    bps[1] = ce
    nb = 2
    for x in (x0, x1):
        if x > cs and x < ce:
            bps[nb] = x
            nb += 1
    for c in range(a, b):
        r = order[c]
        if hrec[r, H_FMAX] < weak:
            continue
        t_in = hrec[r, H_TIN]
        t_out = hrec[r, H_TOUT]
        ts = hrec[r, H_TSTAR]
        if ts > t_in and ts < t_out and ts > cs and ts < ce:
            bps[nb] = ts
            nb += 1
        if cut_support:
            if t_in > cs and t_in < ce:
                bps[nb] = t_in
                nb += 1
            if t_out > cs and t_out < ce:
                bps[nb] = t_out
                nb += 1
    return sort_unique(bps, nb)


@unrefcounted_kernel
def sort_unique(vals, nv):
    """Sort ``vals[:nv]`` in place and drop repeated values; returns the new count."""
    for a in range(1, nv):
        v = vals[a]
        b = a - 1
        while b >= 0 and vals[b] > v:
            vals[b + 1] = vals[b]
            b -= 1
        vals[b + 1] = v
    if nv == 0:
        return 0
    w = 1
    for a in range(1, nv):
        if vals[a] != vals[w - 1]:
            vals[w] = vals[a]
            w += 1
    return w


@inline_kernel
def eval_along(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, F, FP, row, cache):
    """Value and directional derivative ``grad f . d`` of the active primitives
    ``hprim[sarr[:ns]]`` at ``o + t d`` (``ray = (ox, oy, oz, dx, dy, dz)``,
    ``kp = (m, 1/sigma^2, N)``).

    A primitive is zero (value and derivative) outside the open support
    interval ``(t_in, t_out)`` of its hit record, and at its ends (the kernel
    vanishes to order n/2 there), so it is not evaluated there; each hit
    caches its last (t, f, f') in ``cache = (ct, cf, cfp)``, so a breakpoint
    shared by two pieces is evaluated once. With the default kernel (n = 6)
    and ``LANES_FROM`` or more members, :func:`eval_lanes_along` evaluates
    them in lanes, with the same results to the bit. Inlined into the walks
    (a call would pass its arrays on the stack at every point).

    Returns
    -------
    tot : float
        Sum of the values; ``F[row, s]``, ``FP[row, s]`` receive each one's f
        and f'.
    nev : int
        Primitive evaluations done.
    """
    ct, cf, cfp = cache
    m, inv_s2, norm = kp
    if m == 3 and ns >= LANES_FROM:
        return eval_lanes_along(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, F, FP, row, ct, cf, cfp)
    ox, oy, oz, dx, dy, dz = ray
    px = ox + t * dx
    py = oy + t * dy
    pz = oz + t * dz
    tot = 0.0
    nev = 0
    for s in range(ns):
        r = sarr[s]
        if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
            f = 0.0
            fp = 0.0
        elif ct[r] == t:
            f = cf[r]
            fp = cfp[r]
        else:
            f, gx, gy, gz = segment_eval(seg, hprim[r], px, py, pz, m, inv_s2, norm, bool(True), scratch)
            fp = gx * dx + gy * dy + gz * dz
            ct[r] = t
            cf[r] = f
            cfp[r] = fp
            nev += 1
        F[row, s] = f
        FP[row, s] = fp
        tot += f
    return tot, nev


#: fewest members of a piece whose evaluations go through the lanes
#: (:func:`eval_lanes_along`): two evaluations cost less in half the lanes
#: than one after the other (docs/benchmarks.md, "Two members in the lanes")
LANES_FROM = 2


@inline_kernel
def eval_lanes_along(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, F, FP, row, ct, cf, cfp):
    """:func:`eval_along` with the members to evaluate gathered into lanes
    (:func:`slicer._kernels.field.segment.segment_lanes`): loaded in member order, each
    lane tagged with its member, evaluated eight at a time, a last group of
    four or fewer in half the lanes, a last lone one by :func:`segment_eval`.
    The results are :func:`segment_eval`'s to the bit and the sum runs in
    member order, so the returns are :func:`eval_along`'s."""
    k = 0
    nev = 0
    for s in range(ns):
        r = sarr[s]
        if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
            F[row, s] = 0.0
            FP[row, s] = 0.0
        elif ct[r] == t:
            F[row, s] = cf[r]
            FP[row, s] = cfp[r]
        else:
            lane_load(scratch, k, seg, hprim[r])
            scratch[LANE_TAG + k] = s
            k += 1
            nev += 1
            if k == LANES:
                _lanes_done(seg, hprim, sarr, k, ray, t, kp, scratch, F, FP, row, ct, cf, cfp)
                k = 0
    if k == 1:
        _lane_alone(seg, hprim, sarr, ray, t, kp, scratch, F, FP, row, ct, cf, cfp)
    elif k > 1:
        _lanes_done(seg, hprim, sarr, k, ray, t, kp, scratch, F, FP, row, ct, cf, cfp)
    tot = 0.0
    for s in range(ns):
        tot += F[row, s]
    return tot, nev


@inline_kernel
def _lane_alone(seg, hprim, sarr, ray, t, kp, scratch, F, FP, row, ct, cf, cfp):
    """Evaluate the one loaded lane's member by :func:`segment_eval` (one
    segment costs less alone than in the lanes)."""
    ox, oy, oz, dx, dy, dz = ray
    m, inv_s2, norm = kp
    s = int(scratch[LANE_TAG])
    r = sarr[s]
    f, gx, gy, gz = segment_eval(seg, hprim[r], ox + t * dx, oy + t * dy, oz + t * dz, m, inv_s2, norm, bool(True),
                                 scratch)
    _store(F, FP, row, s, r, t, f, gx * dx + gy * dy + gz * dz, ct, cf, cfp)


@inline_kernel
def _store(F, FP, row, s, r, t, f, fp, ct, cf, cfp):
    """One evaluation into its member's column and its hit's cache."""
    F[row, s] = f
    FP[row, s] = fp
    ct[r] = t
    cf[r] = f
    cfp[r] = fp


@inline_kernel
def _lanes_done(seg, hprim, sarr, k, ray, t, kp, scratch, F, FP, row, ct, cf, cfp):
    """Evaluate the first ``k`` loaded lanes and store each in its member's
    column and its hit's cache (:func:`eval_lanes_along`): ``HALF_LANES`` or
    fewer in half the lanes, unused lanes repeating the first; lanes flagged
    ``redo`` are evaluated by :func:`segment_eval`."""
    ox, oy, oz, dx, dy, dz = ray
    m, inv_s2, norm = kp
    px = ox + t * dx
    py = oy + t * dy
    pz = oz + t * dz
    segment_first_lanes(scratch, k, px, py, pz, inv_s2, norm)
    for j in range(k):
        s = int(scratch[LANE_TAG + j])
        r = sarr[s]
        f, gx, gy, gz, redo = lane_result(scratch, j)
        if redo:
            f, gx, gy, gz = segment_eval(seg, hprim[r], px, py, pz, m, inv_s2, norm, bool(True), scratch)
        _store(F, FP, row, s, r, t, f, gx * dx + gy * dy + gz * dz, ct, cf, cfp)


#: inside leaps (:func:`leap_chain`): breakpoints tried ahead at first, and at most
FIRST_LEAP = 4
MAX_LEAP = 64


@unrefcounted_kernel
def inside_leap(seg, hprim, hrec, sarr, ns, F, FP, cur, ray, tb, goal, kp, scratch, cache):
    """Whether ``F >= 1`` holds on all of ``[ta, tb]`` along the ray, proven
    from values (docs/math.md §5.6).

    Each primitive is unimodal along the ray (§5.3), so on any interval its
    minimum is at an end: ``F >= sum_s min(f_s(ta), f_s(tb))`` over any
    subset of the primitives, whatever breakpoints lie between. Row ``cur``
    of ``F`` holds lower bounds at ``ta``; only primitives positive there
    whose support holds ``tb`` can add to the sum. They are evaluated at
    ``tb``, largest bound at ``ta`` first, until the sum exceeds ``goal``
    (1 plus the verdict pad) or cannot reach it. ``ray = (ox, oy, oz, dx,
    dy, dz)``, ``kp = (m, 1/sigma^2, N)``; evaluations go to the hits'
    caches ``cache = (ct, cf, cfp)`` exactly as :func:`eval_along` writes them.

    Row 0 of ``F`` and ``FP`` is overwritten: on success, ``FP[0]`` holds
    lower bounds at ``tb`` (the value where evaluated, else 0).

    Returns
    -------
    proven : bool
    nevals : int
        Primitive evaluations performed.
    """
    ox, oy, oz, dx, dy, dz = ray
    m, inv_s2, norm = kp
    ct, cf, cfp = cache
    rest = 0.0      # what the primitives not yet evaluated can still add
    for s in range(ns):
        r = sarr[s]
        v = F[cur, s] if tb > hrec[r, H_TIN] and tb < hrec[r, H_TOUT] else 0.0
        F[0, s] = v
        FP[0, s] = 0.0
        rest += v
    lo = 0.0
    nev = 0
    while lo + rest > goal:
        best = -1
        fbest = 0.0
        for s in range(ns):
            if F[0, s] > fbest:
                fbest = F[0, s]
                best = s
        if best < 0:
            break
        F[0, best] = 0.0
        rest -= fbest
        r = sarr[best]
        if ct[r] == tb:
            f = cf[r]
        else:
            f, gx, gy, gz = segment_eval(seg, hprim[r], ox + tb * dx, oy + tb * dy, oz + tb * dz, m, inv_s2, norm,
                                         bool(True), scratch)
            ct[r] = tb
            cf[r] = f
            cfp[r] = gx * dx + gy * dy + gz * dz
            nev += 1
        FP[0, best] = f
        lo += min(fbest, f)
        if lo > goal:
            return True, nev
    return False, nev


@unrefcounted_kernel
def leap_chain(seg, hprim, hrec, sarr, ns, rows, cur, ray, bps, j, nb, fcur, kp, scratch, cache):
    """How far the ray is proven inside from breakpoint ``bps[j]``, where
    row ``cur`` of ``F`` (``rows = (F, FP)``) holds the exact values of the
    piece's primitives (their sum ``fcur >= 1``), in leaps of
    :func:`inside_leap` from breakpoint to breakpoint.

    Each leap tries ``step`` breakpoints ahead (:data:`FIRST_LEAP` at
    first), doubles the step after a success (up to :data:`MAX_LEAP`) and
    halves it after a failure, and starts from the lower bounds the previous
    leap left, so the breakpoints it lands on are not evaluated in full; the
    chain ends when the step falls below 2. After a success, row ``cur``
    holds those lower bounds; rows 0 of ``F`` and ``FP`` are overwritten.

    Returns
    -------
    jj : int
        The ray is inside on ``[bps[j], bps[jj]]`` (``jj = j``: no leap held).
    nevals : int
    """
    F, FP = rows
    goal = 1.0 + PAD * (1.0 + fcur)
    jj = j
    step = min(FIRST_LEAP, nb - 1 - j)
    nev = 0
    while step >= 2:
        ok, ne = inside_leap(seg, hprim, hrec, sarr, ns, F, FP, cur, ray, bps[jj + step], goal, kp, scratch, cache)
        nev += ne
        if ok:
            jj += step
            for s in range(ns):
                F[cur, s] = FP[0, s]
            step = min(2 * step, MAX_LEAP, nb - 1 - jj)
        else:
            step //= 2
    return jj, nev


@unrefcounted_kernel
def piece_bounds(hrec, sarr, ns, F, FP, ia, ib, ta, tb, strict):
    """Interval ``[lo, hi]`` of the summed field of the active primitives on
    the ray piece ``[ta, tb]``, and whether the sum is monotone there.

    Rows ``ia`` and ``ib`` of ``F``/``FP`` hold each primitive's value and
    directional derivative at ``ta`` and ``tb``. Per primitive
    (docs/math.md §5.1): increasing (``f'(tb) > 0``, ``f'(ta) >= 0``) gives
    ``[f(ta), f(tb)]``, decreasing the reverse; anything else is ambiguous
    and bounded with the directional Lipschitz constant K:
    ``hi = (f(ta) + f(tb) + K (tb - ta)) / 2``, ``lo = min(f(ta), f(tb))``
    (unimodality) or, with ``strict``, ``max(0, (f(ta) + f(tb) - K (tb - ta)) / 2)``.

    Returns
    -------
    lo, hi : float
    mono : int
        +1 every primitive increasing, -1 every one decreasing (so the sum is
        monotone and crosses 1 at most once), 0 otherwise. ``strict`` never
        reports a monotone piece.
    """
    return piece_bounds_iv(hrec, sarr, ns, F, F, FP, ia, ib, ta, tb, strict, None)


@inline_kernel
def prim_bound(hrec, r, f0, f1, g0, g1, d0, d1, ta, tb, strict):
    """One primitive's share of :func:`piece_bounds_iv` on ``[ta, tb]``:
    lower bounds ``f0, f1``, upper bounds ``g0, g1`` and slopes ``d0, d1``
    at the ends.

    An end that is only bounded (``g != f``) with no known direction
    (both slopes 0) gives ``[min(f0, f1), fmax]`` (``H_FMAX``, the bound on
    the whole ray) without a Lipschitz bound.

    Returns
    -------
    lo, hi : float
    kind : int
        +1 increasing, -1 decreasing, 0 zero on the piece, 2 ambiguous.
    """
    if g0 == 0.0 and g1 == 0.0 and f0 == 0.0 and f1 == 0.0 and d0 == 0.0 and d1 == 0.0:
        # zero with zero slope at both ends (outside the support, or a
        # piece that swallows a whole bump): Lipschitz, never monotone
        # unless the bound says the primitive is zero on the piece
        K = lipschitz(hrec, r, ta, tb)
        return 0.0, min(0.5 * K * (tb - ta), hrec[r, H_FMAX]), 0 if K == 0.0 else 2
    if not strict and d1 > 0.0 and d0 >= 0.0:
        return f0, g1, 1
    if not strict and d0 < 0.0 and d1 <= 0.0:
        return f1, g0, -1
    if d0 == 0.0 and d1 == 0.0 and (g0 != f0 or g1 != f1):
        return min(f0, f1), hrec[r, H_FMAX], 2
    K = lipschitz(hrec, r, ta, tb)
    hi = min(0.5 * (g0 + g1 + K * (tb - ta)), hrec[r, H_FMAX])
    if strict:
        return max(0.0, 0.5 * (f0 + f1 - K * (tb - ta))), hi, 2
    return min(f0, f1), hi, 2


@inline_kernel
def piece_bounds_iv(hrec, sarr, ns, F, FH, FP, ia, ib, ta, tb, strict, mstat):
    """:func:`piece_bounds` from per-primitive *bounds* at the piece's ends.

    ``F[row, s] <= f_s <= FH[row, s]`` (equal where the value is known), and
    ``FP`` a slope whose sign is the primitive's there (0 where unknown);
    each primitive's share is :func:`prim_bound`. With exact ends (``FH`` is
    ``F``) the result is the eager walk's, to the bit. ``mstat`` (None, or
    (ns,) int64, out) receives each primitive's kind on the piece.

    Inlined: a call passes its six arrays as about fifty machine words on
    the stack, once per piece of every ray; on the jellyfish those pushes
    were 18 % of the slicing walk's own time (docs/benchmarks.md).
    """
    lo = 0.0
    hi = 0.0
    n_inc = 0
    n_dec = 0
    for s in range(ns):
        a, b, kind = prim_bound(hrec, sarr[s], F[ia, s], F[ib, s], FH[ia, s], FH[ib, s], FP[ia, s], FP[ib, s],
                                ta, tb, strict)
        lo += a
        hi += b
        if kind == 1:
            n_inc += 1
        elif kind == -1:
            n_dec += 1
        elif kind == 0:
            n_inc += 1
            n_dec += 1
        if mstat is not None:
            mstat[s] = kind
    mono = 0
    if not strict:
        if n_inc == ns:
            mono = 1
        elif n_dec == ns:
            mono = -1
    return lo, hi, mono


@unrefcounted_kernel
def piece_ends(F, FP, ia, ib, ns):
    """Sums over the ``ns`` active primitives of a piece whose ends are rows
    ``ia`` (left) and ``ib`` (right): F at its right end, and F' at its left
    and right ends."""
    fe = 0.0
    da = 0.0
    db = 0.0
    for s in range(ns):
        fe += F[ib, s]
        da += FP[ia, s]
        db += FP[ib, s]
    return fe, da, db


#: :func:`hermite_point` iterates until a Newton step moves less than this
#: fraction of the bracket: the cubic's root, to rounding
CUBIC_ROOT = 1e-15


@unrefcounted_kernel
def hermite_point(ta, tb, ga, gb, da, db, step=CUBIC_ROOT):
    """Root estimate in ``[ta, tb]`` of g from ``g`` and ``g'`` at both ends.

    The cubic Hermite interpolant is solved by Newton steps from the secant
    point, each kept inside the bracket (a step leaving it, or a flat
    derivative, falls back to the midpoint of the sub-bracket the cubic's
    sign designates), until a step moves less than ``step`` times the
    bracket. With the default, ``CUBIC_ROOT``, the result is the cubic's
    root, a continuous function of the inputs, so pieces that differ by
    rounding (another tiling) give the same estimate to rounding: crossings
    (spans) and rendered roots need that. A caller that needs the estimate
    only to a fraction of a length (a voxel centre to split on, the next
    point of a root refinement) passes that length over the bracket as
    ``step`` and saves the last Newton steps.
    ``ga`` and ``gb`` should have opposite signs; the result always lies in
    ``[ta, tb]``.
    """
    w = tb - ta
    if not w > 0.0:
        return ta
    if ga == gb:
        return ta + 0.5 * w
    m0 = da * w
    m1 = db * w
    lo = 0.0
    hi = 1.0
    s = ga / (ga - gb)
    if not (s > 0.0 and s < 1.0):
        s = 0.5
    for _ in range(64):   # Newton converges in a few steps; halvings bound the rest
        s2 = s * s
        s3 = s2 * s
        p = (2.0 * s3 - 3.0 * s2 + 1.0) * ga + (s3 - 2.0 * s2 + s) * m0 \
            + (-2.0 * s3 + 3.0 * s2) * gb + (s3 - s2) * m1
        if p == 0.0:
            break
        # keep a bracket of the cubic's own root
        if (p < 0.0) == (ga < 0.0):
            lo = s
        else:
            hi = s
        dp = (6.0 * s2 - 6.0 * s) * ga + (3.0 * s2 - 4.0 * s + 1.0) * m0 \
            + (-6.0 * s2 + 6.0 * s) * gb + (3.0 * s2 - 2.0 * s) * m1
        sn = s - p / dp if dp != 0.0 else -1.0
        if not (sn > lo and sn < hi):
            sn = 0.5 * (lo + hi)
        if abs(sn - s) <= step:
            s = sn
            break
        s = sn
    return ta + s * w
