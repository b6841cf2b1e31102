"""Meshes: checks with counts, exact predicates, self-intersections, repair, reading, placing."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from slicer.errors import SceneError
from slicer.parts.mesh_intersect import orient2d, orient3d, self_intersections
from slicer.parts.meshes import make_mesh, merge_coincident, read_mesh_file

BOX = trimesh.creation.box(extents=(2.0, 2.0, 2.0))


def refused(v, f, *needles, **kw):
    with pytest.raises(SceneError) as e:
        make_mesh(v, f, "m.stl", **kw)
    msg = str(e.value)
    assert msg.startswith("m.stl: not a closed solid"), msg
    for n in needles:
        assert n in msg, msg
    return msg


# ----------------------------------------------------------------------------- exact predicates
def _exact3(a, b, c, d):
    m = [[Fraction(float(x)) - Fraction(float(y)) for x, y in zip(p, a)] for p in (b, c, d)]
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    return (det > 0) - (det < 0)


coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(coord, min_size=9, max_size=9), st.floats(-1, 1), st.floats(-1, 1), st.integers(0, 40))
def test_orient3d_is_exact_near_coplanar(abc, s, t, ulps):
    """d nudged a few ulps off the plane of a, b, c: the float determinant is noise, the predicate exact."""
    a, b, c = (np.array(abc[3 * i:3 * i + 3]) for i in range(3))
    d = a + s * (b - a) + t * (c - a)
    d = np.nextafter(d, d + 1.0) if ulps % 2 else d
    for _ in range(ulps // 4):
        d = np.nextafter(d, np.inf)
    got = orient3d(a[None], b[None], c[None], d[None])[0]
    assert got == _exact3(a, b, c, d)


@settings(max_examples=200, deadline=None)
@given(st.lists(coord, min_size=4, max_size=4), st.floats(-2, 2), st.integers(0, 8))
def test_orient2d_is_exact_near_collinear(ab, s, ulps):
    a, b = np.array(ab[:2]), np.array(ab[2:])
    c = a + s * (b - a)
    for _ in range(ulps):
        c = np.nextafter(c, np.inf)
    m = [[Fraction(float(x)) - Fraction(float(y)) for x, y in zip(p, a)] for p in (b, c)]
    det = m[0][0] * m[1][1] - m[0][1] * m[1][0]
    assert orient2d(a[None], b[None], c[None])[0] == (det > 0) - (det < 0)


# ----------------------------------------------------------------------------- self-intersections
def test_valid_meshes_have_no_self_intersection():
    for tm in (BOX, BOX.subdivide().subdivide(), trimesh.creation.icosphere(3),
               trimesh.creation.annulus(r_min=1, r_max=2, height=1, sections=48), trimesh.creation.torus(2, 0.5)):
        assert self_intersections(tm.vertices, tm.faces)[0] == 0


@pytest.mark.parametrize("shift, crossing", [((1.0, 1.0, 1.0), True), ((2.0, 0.0, 0.0), True),
                                             ((2.0, 2.0, 2.0), True), ((2.5, 0.0, 0.0), False)])
def test_two_shells_crossing_touching_or_apart(shift, crossing):
    """Overlapping or touching (a face, a vertex) shells intersect; apart they do not."""
    other = BOX.copy()
    other.apply_translation(shift)
    u = trimesh.util.concatenate([BOX, other])
    n, ex = self_intersections(u.vertices, u.faces)
    assert (n > 0) == crossing
    assert all(a < 12 <= b for a, b in ex)           # every pair has one face of each shell


def test_nested_shells_do_not_intersect():
    inner = BOX.copy()
    inner.apply_scale(0.5)
    u = trimesh.util.concatenate([BOX, inner])
    assert self_intersections(u.vertices, u.faces)[0] == 0


def test_pushed_vertex_is_caught_and_named():
    s = trimesh.creation.icosphere(2)
    v = s.vertices.copy()
    v[0] = -1.5 * v[0]                                   # through the far side
    msg = refused(v, s.faces, "pairs of faces intersect or touch", "e.g. faces")
    assert self_intersections(v, s.faces)[0] > 0 and "fix the mesh" in msg


def test_folded_coplanar_faces_intersect():
    """Two faces sharing an edge, folded flat onto each other."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.9, 0]], float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    assert self_intersections(v, f)[0] == 1
    v[3, 2] = 0.1                                        # lifted off the plane: only the edge is shared
    assert self_intersections(v, f)[0] == 0


# ----------------------------------------------------------------------------- refusals, with counts
def test_open_mesh_counts_open_edges():
    refused(BOX.vertices, BOX.faces[1:], "3 open edges (used by one face only)", "between vertices")


def test_non_manifold_edge():
    f = np.vstack([BOX.faces, BOX.faces[:1]])
    refused(BOX.vertices, f, "non-manifold edges (shared by more than two faces)")


def test_inconsistent_orientation():
    f = BOX.faces.copy()
    f[0] = f[0][::-1]
    refused(BOX.vertices, f, "3 edges where the faces' orientations disagree", "try --repair")


def test_inside_out():
    refused(BOX.vertices, BOX.faces[:, ::-1], "the volume is -8.0 mm^3: the mesh is inside out")


def test_degenerate_faces():
    f = BOX.faces.copy()
    f[0, 1] = f[0, 0]
    refused(BOX.vertices, f, "1 degenerate face with a repeated corner")
    v = np.vstack([BOX.vertices, [[0.0, 0.0, 1.0]]])     # the middle of an edge of the top face
    tri = trimesh.Trimesh(v, BOX.faces, process=False)
    top = np.flatnonzero(np.all(np.isclose(tri.vertices[BOX.faces][:, :, 2], 1.0), axis=1))
    assert top.size == 2
    # a sliver: three collinear corners (exactly, in float: -1, 0, 1 on a line)
    v2 = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0]], float)
    f2 = np.array([[0, 4, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3], [0, 2, 1]])
    refused(v2, f2, "degenerate face of zero area (three corners on a line")


def test_non_finite_and_out_of_range():
    v = BOX.vertices.copy()
    v[3, 1] = np.inf
    refused(v, BOX.faces, "non-finite coordinates (e.g. vertex 3")
    f = BOX.faces.copy()
    f[5, 2] = 99
    refused(BOX.vertices, f, "refer to vertices that do not exist (e.g. face 5 corner 2 = 99")


def test_pinched_vertex():
    other = BOX.copy()
    other.apply_translation((2.0, 2.0, 2.0))            # the boxes share one corner
    v, f = merge_coincident(np.vstack([BOX.vertices, other.vertices]), np.vstack([BOX.faces, other.faces + 8]))
    refused(v, f, "1 non-manifold vertex where the surface touches itself")


def test_self_intersections_skipped_for_positive_fill():
    other = BOX.copy()
    other.apply_translation((1.0, 0.0, 0.0))
    u = trimesh.util.concatenate([BOX, other])
    refused(u.vertices, u.faces, "pairs of faces intersect")
    m = make_mesh(u.vertices, u.faces, "overlap.3mf", check_self_intersections=False)
    assert m.n_faces == 24


# ----------------------------------------------------------------------------- repair
def test_repair_reorients_and_says_so():
    f = BOX.faces.copy()
    f[[0, 5]] = f[[0, 5]][:, ::-1]
    m = make_mesh(BOX.vertices, f, "m.stl", repair=True)
    assert m.volume() == pytest.approx(8.0)
    assert any("reversed 2 faces" in n for n in m.notes)
    m = make_mesh(BOX.vertices, BOX.faces[:, ::-1], "m.stl", repair=True)
    assert m.volume() == pytest.approx(8.0) and any("reversed all 12 faces (the mesh was inside out)" in n
                                                    for n in m.notes)
    f = np.vstack([BOX.faces, [[0, 0, 1]]])
    m = make_mesh(BOX.vertices, f, "m.stl", repair=True)
    assert m.n_faces == 12 and any("dropped 1 face with a repeated corner" in n for n in m.notes)


def test_repair_does_not_close_holes():
    msg = refused(BOX.vertices, BOX.faces[1:], "open edges", repair=True)
    assert "--repair does not fix these" in msg


# ----------------------------------------------------------------------------- reading and placing
@pytest.mark.parametrize("ext", ["stl", "obj", "ply"])
def test_read_mesh_files(tmp_path, ext):
    p = tmp_path / f"box.{ext}"
    BOX.export(p)
    m = read_mesh_file(p, scale=10.0)
    assert m.n_faces == 12 and m.vertices.shape == (8, 3)         # STL's 36 corners merged exactly
    assert m.volume() == pytest.approx(8000.0) and np.allclose(m.bounds(), [[-10] * 3, [10] * 3])


def test_read_mesh_file_errors(tmp_path):
    with pytest.raises(SceneError, match="No such file"):
        read_mesh_file(tmp_path / "nope.stl")
    (tmp_path / "x.off").write_text("OFF\n")
    with pytest.raises(SceneError, match="unknown mesh file type '.off'"):
        read_mesh_file(tmp_path / "x.off")
    (tmp_path / "bad.stl").write_bytes(b"\x00" * 10)
    with pytest.raises(SceneError, match="bad.stl"):
        read_mesh_file(tmp_path / "bad.stl")
    (tmp_path / "lines.obj").write_text("v 0 0 0\nv 1 0 0\nl 1 2\n")
    with pytest.raises(SceneError, match="no triangles"):
        read_mesh_file(tmp_path / "lines.obj")


def test_transform_mirror_keeps_outward_faces():
    m = make_mesh(BOX.vertices + [1.0, 0.0, 0.0], BOX.faces, "box")
    mirrored = m.transformed(np.diag([-1.0, 1.0, 1.0, 1.0]))
    assert mirrored.volume() == pytest.approx(8.0)
    assert np.allclose(mirrored.bounds(), [[-2, -1, -1], [0, 1, 1]])
    sheared = m.transformed([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3]])
    assert sheared.volume() == pytest.approx(8.0) and sheared.bounds()[0, 2] == pytest.approx(2.0)
    with pytest.raises(SceneError, match="singular"):
        m.transformed(np.diag([1.0, 0.0, 1.0, 1.0]))


def _fans_reference(faces: np.ndarray) -> np.ndarray:
    """Vertices whose faces form more than one fan, the slow obvious way: for each vertex, join
    two of its faces when they share an edge at it, and count the groups (union-find)."""
    out = []
    for v in range(int(faces.max()) + 1):
        around = [k for k in range(len(faces)) if v in faces[k]]
        group = {k: k for k in around}

        def root(k):
            while group[k] != k:
                k = group[k]
            return k

        for i in around:
            for j in around:
                if i < j and len((set(faces[i]) & set(faces[j])) - {v}) > 0:
                    group[root(i)] = root(j)
        if len({root(k) for k in around}) > 1:
            out.append(v)
    return np.array(out, dtype=np.int64)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(1, 5), st.data())
def test_pinched_vertices_match_the_slow_reference(k, data):
    """Tetrahedra glued at single vertices (no edge shared): each glued vertex has one fan per
    tetrahedron that meets it, as the union-find reference counts."""
    from slicer.parts.meshes import _pinched

    tet = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    faces = np.concatenate([tet + 4 * i for i in range(k)])
    label = np.arange(4 * k)
    for i in range(1, k):                                # glue one corner of tetrahedron i to an earlier one
        corner = data.draw(st.integers(0, 3), label="corner")
        onto = data.draw(st.integers(0, 4 * i - 1), label="onto")
        label[4 * i + corner] = label[onto]
    _, inv = np.unique(label, return_inverse=True)
    faces = inv[faces]
    want = _fans_reference(faces)
    assert np.array_equal(_pinched(faces), want)
    m = len(faces)                                       # directed edge c m + f: faces[f, c] -> next corner
    start = {(int(faces[f, c]), int(faces[f, (c + 1) % 3])): c * m + f for f in range(m) for c in range(3)}
    twin = np.array([start[(int(faces[k % m, (k // m + 1) % 3]), int(faces[k % m, k // m]))]
                     for k in range(3 * m)])
    assert np.array_equal(_pinched(faces, twin), want)
