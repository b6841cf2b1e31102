"""The compiled cache is kept per kernel group (slicer/_jit.py): editing one group's sources leaves every
group that does not import it on its cached machine code, and recompiles the edited group."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from slicer import _jit

ROOT = Path(__file__).resolve().parent.parent
KERNELS = ROOT / "slicer" / "_kernels"
SHARED = (ROOT / "slicer" / "_jit.py", ROOT / "slicer" / "constants.py")


def _copy_kernels(tmp_path: Path) -> tuple[Path, tuple[Path, ...]]:
    kernels = tmp_path / "_kernels"
    shutil.copytree(KERNELS, kernels, ignore=shutil.ignore_patterns("__pycache__"))
    shared = tuple(Path(shutil.copy(f, tmp_path / f.name)) for f in SHARED)
    return kernels, shared


def _touch(path: Path) -> None:
    path.write_text(path.read_text() + "\n# edited\n")


def _importers(group: str) -> set[str]:
    """Groups whose sources import ``group`` directly or through others (a plain reading of the imports)."""
    direct = {g.name: {m for f in g.rglob("*.py") for m in _jit._GROUP_IMPORT.findall(f.read_text())}
              for g in KERNELS.iterdir() if (g / "__init__.py").exists()}
    found = {group}
    while True:
        more = {g for g, deps in direct.items() if deps & found} - found
        if not more:
            return found
        found |= more


def test_every_kernel_lives_in_a_group():
    """Each kernel module sits in a group folder, so the per-group locator finds it."""
    assert sorted(p.name for p in KERNELS.glob("*.py")) == ["__init__.py"]
    assert set(_jit.group_keys()) == {g.name for g in KERNELS.iterdir() if (g / "__init__.py").exists()}


def test_editing_a_group_changes_its_key_and_its_importers_only(tmp_path):
    kernels, shared = _copy_kernels(tmp_path)
    before = _jit.group_keys(kernels, shared)
    assert before == _jit.group_keys(KERNELS, SHARED)           # the key depends on contents, not on paths
    _touch(kernels / "render" / "walk.py")
    after = _jit.group_keys(kernels, shared)
    assert {g for g in before if before[g] != after[g]} == {"render"}
    _touch(kernels / "field" / "segment.py")
    again = _jit.group_keys(kernels, shared)
    changed = {g for g in after if after[g] != again[g]}
    assert changed == _importers("field")
    assert {"field", "rays", "trace", "render", "contours"} <= changed and "raster" not in changed
    _touch(shared[1])                                            # a tolerance: every group
    last = _jit.group_keys(kernels, shared)
    assert all(last[g] != again[g] for g in last)


PROBE = """
import json, sys
import numpy as np
from slicer._kernels.raster.counting_sort import stable_order
order = stable_order(np.array([3, 1, 2, 1], np.int64), 1)
assert order.tolist() == [1, 3, 2, 0], order
print(json.dumps({"hits": sum(stable_order.stats.cache_hits.values()),
                  "misses": sum(stable_order.stats.cache_misses.values())}))
"""


def _probe(tree: Path, cache: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("SKELSLICE_NUMBA_CACHE", "NUMBA_DISABLE_JIT")}
    env.update(PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=tree, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_editing_another_group_keeps_a_compiled_kernel(tmp_path):
    """Through Numba itself, in fresh processes: a raster kernel compiled once is loaded from the cache after
    the renderer's sources change, and compiled again after its own group's sources change."""
    tree = tmp_path / "tree"
    shutil.copytree(ROOT / "slicer", tree / "slicer", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "formats", tree / "formats", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    first = _probe(tree, cache)
    assert first == {"hits": 0, "misses": 1}
    _touch(tree / "slicer" / "_kernels" / "render" / "walk.py")
    assert _probe(tree, cache) == {"hits": 1, "misses": 0}
    _touch(tree / "slicer" / "_kernels" / "raster" / "counting_sort.py")
    assert _probe(tree, cache) == {"hits": 0, "misses": 1}
    assert len([d for d in cache.iterdir() if d.name.startswith("raster-")]) == 2


SAVER = """
import sys
import slicer._jit  # noqa: F401  (puts the lock around Numba's cache writes)
from numba.core import caching
f = caching.IndexDataCacheFile(cache_path=sys.argv[1], filename_base="probe", source_stamp="stamp")
who = sys.argv[2]
for i in range(int(sys.argv[3])):
    f.save((who, i), f"{who}:{i}")
"""


def test_processes_writing_one_cache_at_once_keep_every_entry(tmp_path):
    """Several processes saving versions of one function into one cache folder at the same time: every
    version is in the index, and each index entry leads to its own data (Numba alone may give two versions
    one data file)."""
    env = {k: v for k, v in os.environ.items() if k != "SKELSLICE_NUMBA_CACHE"}
    procs = [subprocess.Popen([sys.executable, "-c", SAVER, str(tmp_path), f"p{w}", "40"], env=env)
             for w in range(4)]
    assert [p.wait(timeout=300) for p in procs] == [0, 0, 0, 0]
    from numba.core import caching
    f = caching.IndexDataCacheFile(cache_path=str(tmp_path), filename_base="probe", source_stamp="stamp")
    for w in range(4):
        for i in range(40):
            assert f.load((f"p{w}", i)) == f"p{w}:{i}"
