"""Stable ordering of small non-negative integer keys in linear time.

Runs of a slab are ordered by layer (to make layers) and by pixel (to merge
tiles); with tens of millions of runs a comparison sort costs seconds per
slab. These kernels are least-significant-digit radix sorts with 16-bit
digits: one counting pass per digit, each stable, so the result is exactly
``np.argsort(keys, kind="stable")``.
"""
from __future__ import annotations

import numpy as np

from slicer._jit import kernel

#: bits per radix digit (one counting pass each)
DIGIT_BITS = 16
_DIGITS = 1 << DIGIT_BITS
_MASK = _DIGITS - 1


@kernel
def _digit_offsets(keys, shift):
    """Start of each digit's block in the output of one counting pass:
    ``(2**DIGIT_BITS,) int64``."""
    counts = np.zeros(_DIGITS + 1, np.int64)
    for i in range(keys.shape[0]):
        counts[((keys[i] >> shift) & _MASK) + 1] += 1
    for d in range(_DIGITS):
        counts[d + 1] += counts[d]
    return counts[:_DIGITS]


@kernel
def stable_order(keys, passes):
    """The stable ascending order of ``keys``.

    Parameters
    ----------
    keys : (n,) int64
        Non-negative, below ``2 ** (DIGIT_BITS * passes)``.
    passes : int
        Radix digits to sort on, >= 1.

    Returns
    -------
    (n,) int64
        ``keys[order]`` is ascending; equal keys keep their input order.
    """
    n = keys.shape[0]
    # first digit: scatter indices straight from the keys
    pos = _digit_offsets(keys, 0)
    order = np.empty(n, np.int64)
    ksorted = np.empty(n if passes > 1 else 0, np.int64)
    for i in range(n):
        d = keys[i] & _MASK
        order[pos[d]] = i
        if passes > 1:
            ksorted[pos[d]] = keys[i]
        pos[d] += 1
    # higher digits: the keys travel with the indices (sequential reads)
    if passes > 1:
        korder = np.empty(n, np.int64)
        otmp = np.empty(n, np.int64)
        for p in range(1, passes):
            shift = p * DIGIT_BITS
            pos = _digit_offsets(ksorted, shift)
            for i in range(n):
                k = ksorted[i]
                d = (k >> shift) & _MASK
                korder[pos[d]] = k
                otmp[pos[d]] = order[i]
                pos[d] += 1
            ksorted, korder = korder, ksorted
            order, otmp = otmp, order
    return order


@kernel
def run_events_by_layer(pix, k0, k1, layers, value):
    """The set and clear events of inside runs, grouped by layer: the kernel of
    :func:`slicer.raster.ordering.layer_events` (same arguments and results; the runs
    must lie in ``[0, layers]``, which the wrapper checks).

    Each run ``[k0, k1)`` of pixel ``pix`` sets the pixel to ``value`` at layer
    k0 and clears it at layer k1. Two counting passes place every event: the
    sets of a layer first, then its clears, each in run order -- the stable
    order of ``concatenate([k0, k1])`` by layer, without sorting or gathering.
    """
    n = pix.shape[0]
    pos = np.zeros(layers + 2, np.int64)
    for i in range(n):
        pos[k0[i] + 1] += 1
        pos[k1[i] + 1] += 1
    for k in range(layers + 1):
        pos[k + 1] += pos[k]
    starts = pos[:layers + 1].copy()
    ev_pix = np.empty(2 * n, np.int64)
    ev_val = np.empty(2 * n, np.uint8)
    for i in range(n):
        d = k0[i]
        ev_pix[pos[d]] = pix[i]
        ev_val[pos[d]] = value
        pos[d] += 1
    for i in range(n):
        d = k1[i]
        ev_pix[pos[d]] = pix[i]
        ev_val[pos[d]] = 0
        pos[d] += 1
    return starts, ev_pix, ev_val


@kernel
def rect_parts_order(local, starts, i0, j0, tw, tr, visit, width, minor):
    """The order by plate pixel of items held by non-overlapping rectangles.

    Part ``p`` holds items ``starts[p] .. starts[p + 1] - 1`` of ``local``:
    indices ``jl * tw[p] + il`` in its own rectangle of ``tr[p]`` rows whose
    corner is plate column ``i0[p]``, row ``j0[p]``, sorted ascending (items
    of one index, when ``minor`` is not empty, with ``minor`` ascending).
    Row by row of the plate, the parts crossing the row from left to right
    each give their stretch of that row: one pass, no sort.

    Parameters
    ----------
    local : (n,) int64
    starts : (P + 1,) int64
    i0, j0, tw, tr : (P,) int64
    visit : (P,) int64
        The parts in order of ``i0`` (left to right).
    width : int
        Plate width: plate pixel = ``(j0 + jl) * width + i0 + il``.
    minor : (n,) int64 or (0,) int64
        A secondary key that must ascend within each index (not checked when empty).

    Returns
    -------
    ok : bool
        False if a part is not sorted or an item lies outside its rectangle
        or the plate (then ``order`` is meaningless).
    order : (n,) int64
        ``pix[order]`` ascending, ties in input order (the stable order).
    pix : (n,) int64
        Each item's plate pixel, in input order.
    """
    n = local.shape[0]
    P = i0.shape[0]
    order = np.empty(n, np.int64)
    pix = np.empty(n, np.int64)
    rows = 0
    for p in range(P):
        last = -1
        w = tw[p]
        for q in range(starts[p], starts[p + 1]):
            v = local[q]
            if v < last or v < 0 or v >= w * tr[p] or i0[p] + v % w >= width:
                return False, order, pix
            if v == last and minor.shape[0] > 0 and minor[q] <= minor[q - 1]:
                return False, order, pix
            last = v
            pix[q] = (j0[p] + v // w) * width + i0[p] + v % w
        rows = max(rows, j0[p] + tr[p])
    cursor = starts[:P].copy()
    out = 0
    for j in range(rows):
        for t in range(P):
            p = visit[t]
            jl = j - j0[p]
            if jl < 0 or jl >= tr[p]:
                continue
            end = starts[p + 1]
            c = cursor[p]
            limit = (jl + 1) * tw[p]
            while c < end and local[c] < limit:
                order[out] = c
                out += 1
                c += 1
            cursor[p] = c
    return out == n, order, pix
