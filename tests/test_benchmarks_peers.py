"""The Fidget peer of ``benchmarks/peers.py`` counts exactly the voxels it should.

``benchmarks/peers/fidget`` is our small cargo project around the Fidget crate; the test
builds it as the benchmark does (``cargo build --release --locked`` into
``benchmarks/peers/fidget/target``: about a minute cold with the crates downloaded, 1 s
once built). Without cargo it is skipped with a message, failed instead under
``SKELSLICE_REQUIRE_READERS=1`` (set by ``.ci/run``), as the Rust checker's tests are.
"""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from helpers import missing_tool
from slicer.tracer.grid import SliceGrid

ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow


def _peers():
    spec = importlib.util.spec_from_file_location("peers_bench", ROOT / "benchmarks" / "peers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def peers():
    mod = _peers()
    if mod.cargo() is None:
        missing_tool("cargo is not installed: cannot build the Fidget program in benchmarks/peers/fidget")
    exe, _ = mod.build_fidget(log=lambda s: None)        # a failed build fails the test
    return mod, exe


@pytest.mark.parametrize("backend, options", [("jit", {}), ("vm", {}), ("jit", {"leaf": 2, "top": 4})])
def test_fidget_octree_counts_the_voxels_of_a_capsule_exactly(peers, tmp_path, backend, options):
    """One segment along z of constant radius r: inside are exactly the voxel centres
    closer than r to the segment. The grid is not a multiple of any cell (clipped cells),
    its layers are half its pixels (cells of 1 x 1 x 2 voxels' aspect), the top layer cuts the
    capsule, and the capsule is wide
    enough for cells settled inside, outside and split down to leaves: a cell dropped or
    counted twice, or a wrong settling, changes the count."""
    mod, exe = peers
    r, a, b = 0.6182, np.array([0.013, -0.021, 0.35]), np.array([0.013, -0.021, 1.9])
    scene = tmp_path / "capsule.json"
    scene.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": [a.tolist(), b.tolist()],
                                 "segments": [[0, 1]], "segment_radii": [[r, r]]}))
    grid = SliceGrid((-0.83, 0.77, -0.41), (0.03, 0.03), 0.015, 59, 55, 191)
    x, y, z = np.meshgrid(grid.centres_x(), grid.centres_y(), grid.centres_z(), indexing="ij")
    t = np.clip((z - a[2]) / (b[2] - a[2]), 0.0, 1.0)
    d = np.sqrt((x - a[0]) ** 2 + (y - a[1]) ** 2 + (z - (a[2] + t * (b[2] - a[2]))) ** 2)
    assert np.abs(d - r).min() > 1e-5            # no centre so near the surface that float32 could decide it
    want = int(np.count_nonzero(d < r))
    out = mod.run_fidget(exe, scene, grid, threads=2, backend=backend, **options)
    assert out["grid"] == [59, 55, 191] and out["voxels"] == grid.n_voxels and out["backend"] == backend
    # the octree did settle whole cells both ways and split others down to leaves
    assert out["settled_inside"] > 0 and out["settled_outside"] > 0 and out["leaves"] > 0
    assert out["points"] < grid.n_voxels // 2
    assert out["inside"] == want


def test_peers_quick_runs_every_method_and_writes_its_json(peers, tmp_path):
    """``benchmarks/peers.py --quick`` end to end: every method runs (the capsule route
    only where ``shared/tools`` is beside the repository, else it says why not), the
    two Fidget backends classify the same voxels, the JSON holds no local path."""
    import subprocess
    import sys

    mod, _ = peers
    out = tmp_path / "peers.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "peers.py"), "--quick", "--repeat", "2",
                        "--threads", "2", "--json", str(out)], capture_output=True, text=True, cwd=tmp_path,
                       timeout=1800)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["benchmark"] == "peers" and doc["quick"] is True and doc["repeat"] == 2 and doc["threads"] == 2
    assert str(tmp_path) not in json.dumps(doc) and str(ROOT) not in json.dumps(doc)
    assert doc["scene"]["segments"] == 36 and doc["voxels"] == 48 * 48 * 40
    rows = {r["method"]: r for r in doc["rows"]}
    want = {"skelslice", "fidget-jit", "fidget-vm"} | ({"capsules"} if mod.CAPSULE_ROUTE.is_file() else set())
    assert set(rows) == want
    if not mod.CAPSULE_ROUTE.is_file():
        assert "capsule_route.py is not beside" in doc["skipped"]["capsules"]
    for r in rows.values():
        assert len(r["runs_seconds"]) == 2 and r["min_seconds"] <= r["median_seconds"] <= r["max_seconds"]
    assert rows["skelslice"]["ratio_to_skelslice"] == 1.0
    assert rows["fidget-jit"]["inside"] == rows["fidget-vm"]["inside"] > 0
    assert 0.05 < rows["skelslice"]["inside_fraction"] < 0.5
    assert "| skelslice |" in p.stdout and "| fidget-jit |" in p.stdout
