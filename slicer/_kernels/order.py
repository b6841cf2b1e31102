"""Stable ordering of small non-negative integer keys in linear time.

Runs of a slab are ordered by layer (to make layers) and by pixel (to merge
tiles); with tens of millions of runs a comparison sort costs seconds per
slab. These kernels are least-significant-digit radix sorts with 16-bit
digits: one counting pass per digit, each stable, so the result is exactly
``np.argsort(keys, kind="stable")``.
"""
from __future__ import annotations

import numpy as np

from .._jit import kernel

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
