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
file (say ``field/segment.py`` under ``trace/summed.py``) would silently reuse
stale machine code. The kernels are therefore cached per *group* (a subfolder of
:mod:`slicer._kernels`): a group's functions live in a folder named after a hash
of this file and :mod:`slicer.constants`, the group's sources and the sources of every group it imports,
directly or not (:func:`group_keys`). Editing the renderer starts a fresh cache
for the renderer alone; editing the field starts one for every group built on it.
The folders sit under ``NUMBA_CACHE_DIR`` when it is set, else under
``~/.cache/skelslice/numba`` (``$XDG_CACHE_HOME/skelslice/numba``).
"""
from __future__ import annotations

import hashlib
import os
import re

try:
    import fcntl
except ImportError:                 # pragma: no cover - not POSIX: Numba's own cache writes
    fcntl = None
from pathlib import Path

from numba import config, njit
from numba.core import caching

CACHE: bool = os.environ.get("SKELSLICE_NUMBA_CACHE", "1") not in ("0", "false", "no")

_KERNELS = Path(__file__).parent / "_kernels"
_SHARED = (Path(__file__), Path(__file__).parent / "constants.py")
_GROUP_IMPORT = re.compile(r"\bslicer\._kernels\.(\w+)")


def _group_sources(kernels: Path) -> dict[str, list[Path]]:
    return {d.name: sorted(d.rglob("*.py")) for d in sorted(kernels.iterdir())
            if d.is_dir() and (d / "__init__.py").exists()}


def group_keys(kernels: Path = _KERNELS, shared: tuple[Path, ...] = _SHARED) -> dict[str, str]:
    """The cache key of every kernel group.

    Parameters
    ----------
    kernels : Path
        The kernel package (``slicer/_kernels``); each subfolder with an ``__init__.py`` is a group.
    shared : tuple of Path
        Files part of every key: the decorator presets (this file) and the tolerances
        (:mod:`slicer.constants`), whose values are frozen into the compiled code.

    Returns
    -------
    dict
        Group name -> 16 hex digits: a hash of the ``shared`` files, the group's sources and the sources of
        every group it imports (``slicer._kernels.<group>``), directly or through other groups.
    """
    sources = _group_sources(kernels)
    texts = {g: [f.read_bytes() for f in files] for g, files in sources.items()}
    deps = {g: {m for t in texts[g] for m in _GROUP_IMPORT.findall(t.decode()) if m in sources and m != g}
            for g in sources}
    keys = {}
    for g in sources:
        closure, todo = {g}, [g]
        while todo:
            for d in deps[todo.pop()]:
                if d not in closure:
                    closure.add(d)
                    todo.append(d)
        h = hashlib.sha256()
        for f in shared:
            h.update(f.read_bytes())
        for d in sorted(closure):
            for f, t in zip(sources[d], texts[d]):
                h.update(f"{d}/{f.relative_to(kernels / d).as_posix()}".encode())
                h.update(t)
        keys[g] = h.hexdigest()[:16]
    return keys


def cache_root() -> Path:
    """Where the compiled kernels are cached: ``NUMBA_CACHE_DIR`` or ``~/.cache/skelslice/numba``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "skelslice" / "numba"


_KEYS: dict[str, str] = group_keys() if CACHE else {}

# numba >= 0.61 names these without the leading underscore
_CacheImpl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")
_UserLocator = getattr(caching, "UserProvidedCacheLocator", None) or getattr(caching, "_UserProvidedCacheLocator")


class GroupCacheLocator(_UserLocator):
    """Numba cache locator of the kernels: one folder per kernel group and group key."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        group = Path(py_file).resolve().relative_to(_KERNELS.resolve()).parts[0]
        self._cache_path = str(cache_root() / f"{group}-{_KEYS[group]}" / self.get_suitable_cache_subpath(py_file))

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            group = Path(py_file).resolve().relative_to(_KERNELS.resolve()).parts[0]
        except ValueError:
            return None
        if group not in _KEYS:
            return None
        return super(_UserLocator, cls).from_function(py_func, py_file)


if CACHE and GroupCacheLocator not in _CacheImpl._locator_classes:
    _CacheImpl._locator_classes.insert(0, GroupCacheLocator)


def _locked_save(save):
    """``IndexDataCacheFile.save`` under an exclusive lock of the cache folder, across processes.

    Numba names a new entry's data file after the first number free in the index it has just read, so two
    processes compiling different versions of one function at once (test workers, process and Dask
    workers, ``skelslice warmup``) could both write ``name.1.nbc`` and leave an index that points at the
    other's machine code (numba/numba#4807). Under the lock, reading the index, choosing the name and
    writing both files is one step.
    """
    def locked(self, key, data):
        os.makedirs(self._cache_path, exist_ok=True)
        with open(os.path.join(self._cache_path, ".skelslice.lock"), "a+b") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                return save(self, key, data)
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
    locked._skelslice_locked = True
    return locked


if CACHE and fcntl is not None and not getattr(caching.IndexDataCacheFile.save, "_skelslice_locked", False):
    caching.IndexDataCacheFile.save = _locked_save(caching.IndexDataCacheFile.save)

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

__all__ = ["CACHE", "group_keys", "cache_root", "GroupCacheLocator", "kernel", "inline_kernel", "unrefcounted_kernel", "parallel_kernel"]
