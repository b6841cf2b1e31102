"""Lazy split points of the slicing walk: evaluate only what can change the verdict.

When the tracer splits an ambiguous piece ``[ta, tb]`` at a voxel centre
``zm`` it needs the class of ``zm`` and, for the two halves, per-primitive
data at ``zm``. A primitive that :func:`slicer._kernels.rays.piece_bounds_iv`
found monotone on ``[ta, tb]`` (it is unimodal along the ray, and its slopes
at both ends have one sign) is bounded at ``zm`` by its known bounds at the
ends — ``[lo(ta), hi(tb)]`` when increasing, ``[lo(tb), hi(ta)]`` when
decreasing — and stays monotone, with the same slope sign, on both halves; a
primitive proven zero on the piece is zero at ``zm``. Only the ambiguous
primitives are evaluated at once; the others are evaluated, widest bound
first, only while the summed bound at ``zm`` still straddles 1 (with the
tracer's ``1e-10`` pad, :data:`slicer._kernels.rays.PAD`). When every
primitive ends up evaluated the class is ``sum >= 1`` with the sum taken in
the same order as :func:`slicer._kernels.rays.eval_along`, so verdicts are
those of the eager walk.

Rows of ``F`` (lower bounds), ``FH`` (upper bounds) and ``FP`` (slopes) are
the tracer's stack rows (:func:`slicer._kernels.rays.walk_buffers`).
"""
from __future__ import annotations

from .._jit import kernel
from .field import segment_eval
from .rays import PAD
from .raysupport import H_TIN, H_TOUT

#: kinds written by piece_bounds_iv into ``mstat``
M_INC, M_DEC, M_ZERO, M_AMBIGUOUS = 1, -1, 0, 2


@kernel
def eval_z(seg, hprim, hrec, r, px, py, t, m, inv_s2, norm, scratch, ct, cf, cfp):
    """Value and z-slope of hit ``r`` at ``(px, py, t)``, as
    :func:`slicer._kernels.rays.eval_along` computes them (same cache, zero
    outside the open support interval); returns ``(f, f', evaluations)``."""
    if not (t > hrec[r, H_TIN] and t < hrec[r, H_TOUT]):
        return 0.0, 0.0, 0
    if ct[r] == t:
        return cf[r], cfp[r], 0
    f, gx, gy, gz = segment_eval(seg, hprim[r], px, py, t, m, inv_s2, norm, True, scratch)
    fp = gx * 0.0 + gy * 0.0 + gz * 1.0
    ct[r] = t
    cf[r] = f
    cfp[r] = fp
    return f, fp, 1


@kernel
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


@kernel
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


@kernel
def split_lazy(seg, hprim, hrec, sarr, ns, px, py, t, m, inv_s2, norm, scratch, F, FH, FP, ia, ib, row, mstat,
               ct, cf, cfp):
    """Bounds at the split point ``t`` of the piece between rows ``ia`` and
    ``ib`` into ``row``, and the class of ``t``.

    Returns
    -------
    inside : bool
        ``F(t) >= 1``.
    nev : int
        Primitive evaluations done.
    """
    nev = 0
    for s in range(ns):
        k = mstat[s]
        if k == M_AMBIGUOUS:
            f, fp, ne = eval_z(seg, hprim, hrec, sarr[s], px, py, t, m, inv_s2, norm, scratch, ct, cf, cfp)
            nev += ne
            F[row, s] = f
            FH[row, s] = f
            FP[row, s] = fp
        else:
            _carry(F, FH, FP, ia, ib, row, s, k)
    while True:
        lo, hi, smax = _sums(F, FH, row, ns)
        if smax < 0:
            return lo >= 1.0, nev
        pad = PAD * (1.0 + abs(hi))
        if lo > 1.0 + pad:
            return True, nev
        if hi < 1.0 - pad:
            return False, nev
        f, fp, ne = eval_z(seg, hprim, hrec, sarr[smax], px, py, t, m, inv_s2, norm, scratch, ct, cf, cfp)
        nev += ne
        F[row, smax] = f
        FH[row, smax] = f
        # a monotone primitive's slope at t, if it came out flat or of the
        # other sign by rounding, keeps the stretch's sign: the halves stay monotone
        if mstat[smax] == M_INC and not fp > 0.0:
            fp = FP[ib, smax]
        elif mstat[smax] == M_DEC and not fp < 0.0:
            fp = FP[ia, smax]
        FP[row, smax] = fp


__all__ = ["split_lazy", "eval_z", "M_INC", "M_DEC", "M_ZERO", "M_AMBIGUOUS"]
