"""Bundled samples ("examples are tests"): committed JSON == build(), and a surface exists."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sample_lattices
from sample_lattices import SAMPLES, load_sample, sample_path
from slicer import SceneError, save_scene

#: (min, max) number of segments of each sample
SIZES = {
    "jellyfish": (140, 170),          # the paper's artistic model has 154
    "microstructure": (2800, 3000),   # the paper's microstructure has 2,895
    "cubic_2x2x2": (54, 54),
    "bcc_3x3x3_graded": (216, 216),
    "octet_2x2x2": (240, 240),
    "kelvin_2x2x2": (240, 240),
}


@pytest.fixture(scope="module", params=sorted(SAMPLES))
def sample(request):
    name = request.param
    return name, load_sample(name), SAMPLES[name]()


def test_registry_matches_files():
    assert set(SIZES) == set(SAMPLES)
    committed = {p.stem for p in Path(sample_lattices.__file__).parent.glob("*.json")}
    assert committed == set(SAMPLES)
    with pytest.raises(SceneError, match="unknown sample 'nope'.*jellyfish"):
        sample_path("nope")


def test_committed_json_equals_fresh_build(sample, tmp_path):
    name, committed, built = sample
    np.testing.assert_array_equal(committed.nodes, built.nodes)
    np.testing.assert_array_equal(committed.segments, built.segments)
    np.testing.assert_array_equal(committed.radii, built.radii)
    assert (committed.degree, committed.sigma) == (built.degree, built.sigma)
    # regeneration (python -m sample_lattices) is byte-for-byte deterministic
    fresh = tmp_path / f"{name}.json"
    save_scene(SAMPLES[name](), fresh)
    assert fresh.read_bytes() == sample_path(name).read_bytes()


def test_size_and_radii(sample):
    name, skel, _ = sample
    lo, hi = SIZES[name]
    assert lo <= skel.n_segments <= hi
    assert np.all(skel.radii > 0.05 * 4)     # several 0.05 mm pixels thick
    extent = np.ptp(skel.nodes, axis=0)
    assert 5.0 <= extent.max() <= 45.0


def test_connected_and_compact(sample):
    name, skel, _ = sample
    assert np.array_equal(np.unique(skel.segments), np.arange(skel.n_nodes))  # no orphan nodes
    parent = np.arange(skel.n_nodes)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in skel.segments.tolist():
        parent[find(a)] = find(b)
    assert len({find(i) for i in range(skel.n_nodes)}) == 1, f"{name} is not one piece"


def test_surface_exists(sample):
    name, skel, _ = sample
    # an isolated strut shorter than 0.688 tau has no surface (docs/math.md §1.5): keep a wide margin
    a, b = skel.endpoints()
    assert np.all(np.linalg.norm(b - a, axis=1) > 2.0 * skel.radii.max(axis=1))
    # the skeleton lies inside the solid: F >= 1 at every node and strut midpoint
    assert np.all(skel.field(skel.nodes) >= 1.0)
    assert np.all(skel.field(0.5 * (a + b)) >= 1.0)


def test_jellyfish_shape():
    skel = SAMPLES["jellyfish"]()
    assert skel.n_segments == 154
    z = skel.nodes[:, 2]
    assert 35.0 <= np.ptp(z) <= 45.0
    r = skel.radii
    assert r.min() == pytest.approx(0.3) and r.max() == pytest.approx(0.7)
    assert np.count_nonzero(r[:, 0] != r[:, 1]) > 72        # tentacles (at least) are tapered


def test_microstructure_is_graded_along_z():
    skel = SAMPLES["microstructure"]()
    a, b = skel.endpoints()
    z = np.concatenate([a[:, 2], b[:, 2]])
    r = np.concatenate([skel.radii[:, 0], skel.radii[:, 1]])
    np.testing.assert_allclose(r, 0.3 + 0.3 * (z - z.min()) / np.ptp(z), rtol=1e-12)
