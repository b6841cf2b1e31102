"""Numba decorator presets: the single place where JIT flags are chosen.

Every kernel in :mod:`slicer._kernels` is decorated with one of these presets.
Interval and root-finding code relies on IEEE semantics (``inf``, ``nan``,
correctly rounded ``+ - * / sqrt``), so **no preset enables fastmath**; a test
walks the kernels and enforces it.

Environment switches
--------------------
SKELSLICE_NUMBA_CACHE
    ``0`` disables Numba's on-disk cache (default: enabled).
"""
from __future__ import annotations

import os

from numba import njit

CACHE: bool = os.environ.get("SKELSLICE_NUMBA_CACHE", "1") not in ("0", "false", "no")

_COMMON = dict(cache=CACHE, error_model="numpy", fastmath=False)

#: serial, GIL-free kernel (inner functions, per-tile work, Dask tasks)
kernel = njit(nogil=True, **_COMMON)

#: parallel kernel (``prange`` over points, tiles or buckets)
parallel_kernel = njit(parallel=True, nogil=True, **_COMMON)

__all__ = ["CACHE", "kernel", "parallel_kernel"]
