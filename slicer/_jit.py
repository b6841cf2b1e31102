"""Numba decorator presets: the single place where JIT flags are chosen.

Every kernel in :mod:`slicer._kernels` is decorated with one of these presets.
Interval and root-finding code relies on IEEE semantics (``inf``, ``nan``,
correctly rounded ``+ - * / sqrt``), so **no preset enables fastmath**; a test
walks the kernels and enforces it.

Environment switches
--------------------
SKELSLICE_NUMBA_CACHE
    ``0`` disables Numba's on-disk cache (default: enabled).
NUMBA_CACHE_DIR
    If set, Numba's own cache location is used as is.

Cache invalidation
------------------
Numba keys a cached function on its own file only: editing a callee in another
file (say ``field.py`` under ``trace.py``) would silently reuse stale machine
code. Unless ``NUMBA_CACHE_DIR`` is set, the cache therefore lives in a folder
named after a hash of every kernel source file, so any change to any kernel
starts a fresh cache.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

from numba import config, njit

CACHE: bool = os.environ.get("SKELSLICE_NUMBA_CACHE", "1") not in ("0", "false", "no")


def _kernel_source_hash() -> str:
    here = Path(__file__).parent
    h = hashlib.sha256()
    for f in [here / "_jit.py", *sorted((here / "_kernels").glob("*.py"))]:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "skelslice" / "numba"


if CACHE and not os.environ.get("NUMBA_CACHE_DIR"):
    config.CACHE_DIR = str(_cache_root() / _kernel_source_hash())

# Threading layer: GNU OpenMP first. Kernels are launched from several Python
# threads at once (the `threads` executor); with the TBB layer such a process
# can spin forever in tbb::finalize at interpreter exit. NUMBA_THREADING_LAYER
# set by the user still wins.
if not os.environ.get("NUMBA_THREADING_LAYER"):
    config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

_COMMON = dict(cache=CACHE, error_model="numpy", fastmath=False)

#: serial, GIL-free kernel (inner functions, per-tile work, Dask tasks)
kernel = njit(nogil=True, **_COMMON)

#: small helper inlined into its callers at Numba IR level: no call, so no
#: atomic reference counting of the array arguments (in the innermost loops
#: that bookkeeping costs more than the arithmetic)
inline_kernel = njit(inline="always", nogil=True, **_COMMON)

#: serial kernel compiled without Numba's reference counting (``_nrt=False``):
#: for a kernel that allocates nothing and keeps no array beyond its call, as
#: its caller holds every array it is given. Helpers inlined into it (the ray
#: walks unpack tuples of work arrays in each) then cost no atomic or null-check
#: calls; kernels it calls count references as usual
unrefcounted_kernel = njit(nogil=True, _nrt=False, **_COMMON)

#: parallel kernel (``prange`` over points, tiles or buckets)
parallel_kernel = njit(parallel=True, nogil=True, **_COMMON)

__all__ = ["CACHE", "kernel", "inline_kernel", "unrefcounted_kernel", "parallel_kernel"]
