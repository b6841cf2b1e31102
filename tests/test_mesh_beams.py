"""The skeleton written as a 3MF Beam Lattice (slicer.meshing.beams3mf), read back by our
3MF reader and, independently, by lib3mf's own API: same nodes, segments and radii (to
float32, as lib3mf keeps coordinates and radii); parts keep their clipping and solid meshes."""
from __future__ import annotations

import zipfile

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from parts_helpers import tmesh
from slicer import Skeleton
from slicer.errors import OutputError
from slicer.meshing.beams3mf import write_beam_lattice
from slicer.parts.part import Part, PartMesh, load_part
from slicer.scene.threemf import load_3mf
from slicer.scene.read import load_scene

lib3mf = pytest.importorskip("lib3mf")


def read_with_lib3mf(path):
    """Nodes (n, 3), beams (m, 2), radii (m, 2) and the clipping mode of the one lattice, through
    lib3mf's API only (nothing of slicer.scene.threemf)."""
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    model.QueryReader("3mf").ReadFromFile(str(path))
    objs = model.GetMeshObjects()
    found = []
    while objs.MoveNext():
        mesh = objs.GetCurrentMeshObject()
        lat = mesh.BeamLattice()
        if lat.GetBeamCount():
            verts = np.array([[v.Coordinates[k] for k in range(3)] for v in mesh.GetVertices()])
            beams = lat.GetBeams()
            idx = np.array([[b.Indices[0], b.Indices[1]] for b in beams])
            rad = np.array([[b.Radii[0], b.Radii[1]] for b in beams])
            found.append((verts, idx, rad, int(lat.GetClipping()[0])))
    assert len(found) == 1
    return found[0]


def f32(a):
    """What lib3mf keeps of float64 values."""
    return np.asarray(a).astype(np.float32).astype(np.float64)


def random_skeleton(seed, n_nodes, n_segs):
    rng = np.random.default_rng(seed)
    nodes = rng.uniform(-20, 20, (n_nodes, 3))
    segs = np.array([rng.choice(n_nodes, 2, replace=False) for _ in range(n_segs)])
    radii = rng.uniform(0.05, 2.0, (n_segs, 2))
    return Skeleton(nodes, segs, radii)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_nodes=st.integers(2, 30), n_segs=st.integers(1, 40))
def test_reads_back_to_the_same_lattice(tmp_path_factory, seed, n_nodes, n_segs):
    s = random_skeleton(seed, n_nodes, n_segs)
    path = tmp_path_factory.mktemp("b") / "l.3mf"
    write_beam_lattice(s, path)
    used = np.unique(s.segments)
    want_nodes = f32(s.nodes[used])
    want_segs = np.searchsorted(used, s.segments)
    back = load_3mf(path)
    assert np.array_equal(back.nodes, want_nodes)
    assert np.array_equal(back.segments, want_segs)
    assert np.array_equal(back.radii, f32(s.radii))
    verts, idx, rad, clip = read_with_lib3mf(path)
    assert np.array_equal(verts, want_nodes) and np.array_equal(idx, want_segs) and clip == 0
    assert np.array_equal(rad, f32(s.radii))


def test_samples_read_back_and_files_are_byte_identical(tmp_path):
    s = load_scene("sample_lattices/bcc_3x3x3_graded.json")
    a, b = tmp_path / "a.3mf", tmp_path / "b.3mf"
    st_ = write_beam_lattice(s, a)
    write_beam_lattice(s, b)
    assert a.read_bytes() == b.read_bytes()
    assert st_["beams"] == s.n_segments and st_["clipping"] is None
    back = load_3mf(a)
    assert back.n_segments == s.n_segments and not np.array_equal(s.radii[:, 0], s.radii[:, 1])
    assert np.array_equal(back.radii, f32(s.radii))
    assert np.abs(back.nodes - s.nodes[np.unique(s.segments)]).max() <= 1e-6 * np.abs(s.nodes).max()
    with zipfile.ZipFile(a) as zf:
        assert 'requiredextensions="b"' in zf.read("3D/3dmodel.model").decode()


@pytest.mark.parametrize("role", ["clip-inside", "clip-outside"])
def test_part_keeps_its_clipping_mesh_and_solids(tmp_path, role):
    s = Skeleton([[-3, 0, 0], [3, 0, 0], [0, -3, 0], [0, 3, 0]], [[0, 1], [2, 3]], [[0.5, 0.4], [0.5, 0.5]])
    ball = tmesh(trimesh.creation.icosphere(2, radius=2.0), "ball")
    box = tmesh(trimesh.creation.box((1, 1, 1), trimesh.transformations.translation_matrix((0, 0, 5))), "box")
    part = Part(s, (PartMesh(ball, role), PartMesh(box, "solid")))
    path = tmp_path / "part.3mf"
    got = write_beam_lattice(part, path)
    assert got["clipping"] == role[5:] and got["solids"] == 1
    back = load_part(path)
    assert np.array_equal(back.skeleton.radii, f32(s.radii))
    (clip,) = back.of_role(role)
    (solid,) = back.solids()
    assert np.allclose(clip.vertices, ball.vertices, atol=1e-6) and np.array_equal(clip.faces, ball.faces)
    assert np.allclose(solid.vertices, box.vertices, atol=1e-6) and np.array_equal(solid.faces, box.faces)
    assert read_with_lib3mf(path)[3] == (1 if role == "clip-inside" else 2)


def test_refusals_write_nothing(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 1.0]], degree=8)
    with pytest.raises(OutputError, match="degree 8"):
        write_beam_lattice(s, tmp_path / "k.3mf")
    s6 = Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 1.0]])
    ball = tmesh(trimesh.creation.icosphere(1, radius=2.0), "ball")
    part = Part(s6, (PartMesh(ball, "clip-inside"), PartMesh(ball, "clip-outside")))
    with pytest.raises(OutputError, match="one clipping mode"):
        write_beam_lattice(part, tmp_path / "c.3mf")
    assert list(tmp_path.iterdir()) == []
