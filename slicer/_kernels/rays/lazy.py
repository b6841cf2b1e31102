"""Lazy split points of the slicing walk: evaluate only what can change the verdict.

When the tracer splits an ambiguous piece ``[ta, tb]`` at a voxel centre
``zm`` it needs the class of ``zm`` and, for the two halves, per-primitive
data at ``zm``. A primitive that :func:`slicer._kernels.rays.walk.piece_bounds_iv`
found monotone on ``[ta, tb]`` (it is unimodal along the ray, and its slopes
at both ends have one sign) is bounded at ``zm`` by its known bounds at the
ends — ``[lo(ta), hi(tb)]`` when increasing, ``[lo(tb), hi(ta)]`` when
decreasing — and stays monotone, with the same slope sign, on both halves; a
primitive proven zero on the piece is zero at ``zm``. Only the ambiguous
primitives are evaluated at once; the others are evaluated, widest bound
first, only while the summed bound at ``zm`` still straddles 1 (with the
tracer's ``1e-10`` pad, :data:`slicer._kernels.rays.walk.PAD`). When every
primitive ends up evaluated the class is ``sum >= 1`` with the sum taken in
the same order as :func:`slicer._kernels.rays.walk.eval_along`, so verdicts are
those of the eager walk.

``rows = (F, FH, FP)``: per-primitive lower bounds, upper bounds and slopes,
one row per stack slot (:func:`slicer._kernels.rays.walk.walk_buffers`);
``cache = (ct, cf, cfp)``: each hit's last evaluation (t, f, f').
"""
from __future__ import annotations

from slicer._jit import inline_kernel, unrefcounted_kernel
from slicer._kernels.field.segment import segment_eval
from slicer._kernels.rays.walk import PAD, piece_bounds_iv, prim_bound
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT

#: kinds written by piece_bounds_iv into ``mstat``
M_INC, M_DEC, M_ZERO, M_AMBIGUOUS = 1, -1, 0, 2


@inline_kernel
def eval_dir(seg, hprim, hrec, r, ray, t, kp, scratch, cache):
    """Value and directional slope of hit ``r`` at ``o + t d``
    (``ray = (ox, oy, oz, dx, dy, dz)``, ``kp = (m, 1/sigma^2, N)``), computed
    as :func:`slicer._kernels.rays.walk.eval_along` does (same cache, zero outside
    the open support interval; ``cache = (ct, cf, cfp)``, each hit's last
    evaluation); returns ``(f, f', evaluations)``."""
    ct, cf, cfp = cache
    if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
        return 0.0, 0.0, 0
    if ct[r] == t:
        return cf[r], cfp[r], 0
    ox, oy, oz, dx, dy, dz = ray
    m, inv_s2, norm = kp
    f, gx, gy, gz = segment_eval(seg, hprim[r], ox + t * dx, oy + t * dy, oz + t * dz, m, inv_s2, norm, bool(True),
                                 scratch)
    fp = gx * dx + gy * dy + gz * dz
    ct[r] = t
    cf[r] = f
    cfp[r] = fp
    return f, fp, 1


@inline_kernel
def _carry(F, FH, FP, ia, ib, row, s, kind):
    """Write the bound of monotone / zero primitive ``s`` at a split point
    between rows ``ia`` and ``ib`` into ``row``."""
    if kind == M_INC:
        F[row, s] = F[ia, s]
        FH[row, s] = FH[ib, s]
        FP[row, s] = FP[ib, s]
    elif kind == M_DEC:
        F[row, s] = F[ib, s]
        FH[row, s] = FH[ia, s]
        FP[row, s] = FP[ia, s]
    else:
        F[row, s] = 0.0
        FH[row, s] = 0.0
        FP[row, s] = 0.0


@inline_kernel
def _sums(F, FH, row, ns):
    """Summed lower and upper bounds of a row, and the index of the widest
    not yet evaluated bound (-1 when every value is known)."""
    lo = 0.0
    hi = 0.0
    wmax = 0.0
    smax = -1
    for s in range(ns):
        a = F[row, s]
        b = FH[row, s]
        lo += a
        hi += b
        if b - a > wmax:
            wmax = b - a
            smax = s
    return lo, hi, smax


@unrefcounted_kernel
def split_lazy(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, rows, ia, ib, row, mstat, cache):
    """Bounds at the split point ``t`` of the piece between rows ``ia`` and
    ``ib`` into ``row``, and the class of ``t``.

    Returns
    -------
    inside : bool
        ``F(t) >= 1``.
    nev : int
        Primitive evaluations done.
    """
    F, FH, FP = rows
    nev = 0
    for s in range(ns):
        k = mstat[s]
        if k == M_AMBIGUOUS:
            f, fp, ne = eval_dir(seg, hprim, hrec, sarr[s], ray, t, kp, scratch, cache)
            nev += ne
            F[row, s] = f
            FH[row, s] = f
            FP[row, s] = fp
        else:
            _carry(F, FH, FP, ia, ib, row, s, k)
    inside, ne = settle(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, rows, row, mstat, (ia, ib), True, cache)
    return inside, nev + ne


@unrefcounted_kernel
def settle(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, rows, row, mstat, stretch, keep_sign, cache):
    """The class ``F(t) >= 1`` of the point of ``row``, evaluating its
    unknown primitives widest bound first until the summed bound clears 1 by
    the pad (or every value is known: then the in-order sum decides).
    With ``keep_sign``, an evaluated monotone primitive (``mstat``) keeps the
    slope sign of its stretch (rows ``stretch = (ia, ib)``) if rounding
    flattened it. Returns ``(inside, evaluations)``."""
    ia, ib = stretch
    F, FH, FP = rows
    nev = 0
    while True:
        lo, hi, smax = _sums(F, FH, row, ns)
        if smax < 0:
            return lo >= 1.0, nev
        pad = PAD * (1.0 + abs(hi))
        if lo > 1.0 + pad:
            return True, nev
        if hi < 1.0 - pad:
            return False, nev
        f, fp, ne = eval_dir(seg, hprim, hrec, sarr[smax], ray, t, kp, scratch, cache)
        nev += ne
        F[row, smax] = f
        FH[row, smax] = f
        # a monotone primitive's slope at t, if it came out flat or of the
        # other sign by rounding, keeps the stretch's sign: the halves stay monotone
        if keep_sign and mstat[smax] == M_INC and not fp > 0.0:
            fp = FP[ib, smax]
        elif keep_sign and mstat[smax] == M_DEC and not fp < 0.0:
            fp = FP[ia, smax]
        FP[row, smax] = fp


@inline_kernel
def bound_at(hrec, r, t, cache):
    """Bound of hit ``r`` at ``t`` without evaluating it: exact outside its
    open support interval (0) and where it was last evaluated (tc); else,
    by unimodality along the ray, ``[0, f(tc)]`` where the slope at tc
    points down toward t (beyond a falling tc, before a rising one), and
    ``[0, fmax]`` (``H_FMAX``, a bound on the whole ray) otherwise.

    Returns
    -------
    lo, hi, fp : float
        ``fp`` is the slope where known; at an unknown end, -1 (+1) where
        the primitive is known to fall (rise) there, 0 where its direction is
        unknown (then :func:`slicer._kernels.rays.walk.piece_bounds_iv` never
        calls it monotone).
    """
    ct, cf, cfp = cache
    if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
        return 0.0, 0.0, 0.0
    tc = ct[r]
    if tc == t:
        return cf[r], cf[r], cfp[r]
    if t > tc and cfp[r] < 0.0:
        return 0.0, cf[r], -1.0
    if t < tc and cfp[r] > 0.0:
        return 0.0, cf[r], 1.0
    return 0.0, hrec[r, H_FMAX], 0.0


@unrefcounted_kernel
def lazy_ends(seg, hprim, hrec, sarr, ns, ray, ta, tb, kp, scratch, rows, ia, ib, mstat, cache):
    """Rows ``ia``/``ib`` at the ends of the piece ``[ta, tb]`` from
    :func:`bound_at`, then exact values for the primitives with the widest
    bounds, one primitive at a time, until the piece's bound
    (:func:`slicer._kernels.rays.walk.piece_bounds_iv`) clears 1 by the pad or
    every end value is known.

    Returns
    -------
    settled : bool
        The piece's bound clears 1: it holds no crossing.
    nev : int
        Evaluations done.
    """
    F, FH, FP = rows
    for s in range(ns):
        r = sarr[s]
        F[ia, s], FH[ia, s], FP[ia, s] = bound_at(hrec, r, ta, cache)
        F[ib, s], FH[ib, s], FP[ib, s] = bound_at(hrec, r, tb, cache)
    lo, hi, _ = piece_bounds_iv(hrec, sarr, ns, F, FH, FP, ia, ib, ta, tb, False, mstat)
    nev = 0
    while True:
        pad = PAD * (1.0 + abs(hi))
        if lo > 1.0 + pad or hi < 1.0 - pad:
            # the running sums only steer; the verdict is the full sum's
            lo, hi, _ = piece_bounds_iv(hrec, sarr, ns, F, FH, FP, ia, ib, ta, tb, False, mstat)
            pad = PAD * (1.0 + abs(hi))
            if lo > 1.0 + pad or hi < 1.0 - pad:
                return True, nev
        best = -1
        wbest = -1.0
        for s in range(ns):
            w = (FH[ia, s] - F[ia, s]) + (FH[ib, s] - F[ib, s])
            if (F[ia, s] != FH[ia, s] or F[ib, s] != FH[ib, s]) and w > wbest:
                wbest = w
                best = s
        if best < 0:
            return False, nev
        r = sarr[best]
        a0, b0, _ = prim_bound(hrec, r, F[ia, best], F[ib, best], FH[ia, best], FH[ib, best], FP[ia, best],
                               FP[ib, best], ta, tb, False)
        for row, t in ((ia, ta), (ib, tb)):
            if F[row, best] != FH[row, best]:
                f, fp, ne = eval_dir(seg, hprim, hrec, r, ray, t, kp, scratch, cache)
                F[row, best] = f
                FH[row, best] = f
                FP[row, best] = fp
                nev += ne
        a1, b1, _ = prim_bound(hrec, r, F[ia, best], F[ib, best], FH[ia, best], FH[ib, best], FP[ia, best],
                               FP[ib, best], ta, tb, False)
        lo += a1 - a0
        hi += b1 - b0


@unrefcounted_kernel
def complete_row(seg, hprim, hrec, sarr, ns, ray, t, kp, scratch, rows, row, cache):
    """Exact values in ``row`` at ``t`` for every primitive still bounded
    there (known ones are kept: an earlier evaluation at the same t gave
    them); returns ``(sum, evaluations)``, the sum in
    :func:`slicer._kernels.rays.walk.eval_along`'s order, so its value too."""
    F, FH, FP = rows
    tot = 0.0
    nev = 0
    for s in range(ns):
        if F[row, s] != FH[row, s]:
            f, fp, ne = eval_dir(seg, hprim, hrec, sarr[s], ray, t, kp, scratch, cache)
            nev += ne
            F[row, s] = f
            FH[row, s] = f
            FP[row, s] = fp
        tot += F[row, s]
    return tot, nev


__all__ = ["complete_row", "split_lazy", "settle", "bound_at", "lazy_ends", "eval_dir", "M_INC", "M_DEC", "M_ZERO", "M_AMBIGUOUS"]
