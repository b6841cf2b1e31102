"""Borrowed array views (slicer._kernels.runtime.borrow): same memory, any layout, tuples."""
from __future__ import annotations

import numpy as np
from numba import njit

from slicer._kernels.runtime.borrow import borrow, keep_alive


@njit(cache=False)
def _write_through(a, b):
    va, vb = borrow((a, b))
    for i in range(va.shape[0]):
        va[i] = i
        vb[i] = 2.0 * i
    return va.shape[0], vb.strides[0]


@njit(cache=False)
def _allocated_then_kept(n):
    own = (np.zeros(n), np.ones((n, 3)))
    w, m = borrow(own)
    for i in range(n):
        w[i] = m[i, 0] + m[i, 2] + i
    total = 0.0
    for i in range(n):
        total += w[i]
    keep_alive(own)
    return total


@njit(cache=False)
def _single(a):
    v = borrow(a)
    v[0, 1] = 7.5
    return v.shape[0] * 10 + v.shape[1]


def test_a_borrowed_view_writes_into_the_array_it_borrows():
    a = np.zeros(5)
    b2 = np.zeros((5, 3))
    n, stride = _write_through(a, b2[:, 1])        # a strided column view
    assert n == 5 and stride == 3 * 8
    np.testing.assert_array_equal(a, np.arange(5.0))
    np.testing.assert_array_equal(b2[:, 1], 2.0 * np.arange(5.0))
    assert not b2[:, [0, 2]].any()                 # only the borrowed column was written


def test_a_single_array_keeps_its_shape():
    a = np.zeros((3, 4))
    assert _single(a) == 34
    assert a[0, 1] == 7.5 and a.sum() == 7.5


def test_views_of_allocated_arrays_live_until_keep_alive():
    n = 1000
    assert _allocated_then_kept(n) == n * 2.0 + n * (n - 1) / 2
