"""The mesh of a part: the lattice's certified mesh with solid and clipping meshes
(slicer.meshing.composite), checked independently (tests/mesh_checks.py, convex meshes decided
by their face planes).

* Each role (clip-inside, clip-outside, solid) and a mix: the mesh is watertight and consistently
  wound, its certified bound is at most --tol, sampled mesh points have the part's surface
  ``((S ∩ CI) − CO) ∪ M`` within the bound, and surface points found on random lines have the
  mesh within it.
* The certificate is not a formality: a lattice mesh moved off the surface near a clipping mesh
  is refused by it.
* Winding numbers against the face-plane test, and nested shells.
* Unions: a supported scene (model, supports) and the union blend, checked against the scene's
  own union field (which tells the union from the sum); the classes of struts that unite have
  disjoint supports (their sum is their largest field).
* The command line meshes a lattice with a clipping mesh, a mesh-only part and a supported
  scene.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from mesh_checks import (convex_inside, part_mesh_points_off_surface, part_surface_points_on_lines,
                         point_triangle_distance)
from slicer import Skeleton
from slicer._kernels.meshing.winding import winding_numbers
from slicer.cli import main
from slicer.errors import SceneError
from slicer.meshing import composite, mesh_part, mesh_scene
from slicer.meshing.unions import disjoint_classes
from slicer.model.field import evaluate
from slicer.parts.meshes import make_mesh
from slicer.parts.part import Part, PartMesh
from slicer.scene.write import write_scene
from slicer.supports.build import write_supported
from slicer.supports.groups import GroupedSkeleton


def _box(size, centre=(0, 0, 0), turn=None):
    m = trimesh.creation.box(size)
    if turn is not None:
        m.apply_transform(trimesh.transformations.rotation_matrix(turn, [1, 1, 0]))
    m.apply_translation(centre)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _ico(radius, centre):
    m = trimesh.creation.icosphere(subdivisions=1, radius=radius)
    m.apply_translation(centre)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _struts():
    return Skeleton([[-1.2, 0, -0.6], [1.2, 0.2, 0.6], [0, -1.2, 0.3], [0.1, 1.2, -0.2]], [[0, 1], [2, 3]],
                    [[0.45, 0.35], [0.4, 0.4]])


CASES = {
    "clip-inside": [("clip-inside", _box((1.6, 1.8, 1.4), (0.1, 0, 0), turn=0.4))],
    "clip-outside": [("clip-outside", _ico(0.6, (0.3, 0.2, 0.1)))],
    "solid": [("solid", _box((0.8, 0.8, 0.8), (-0.5, 0.1, 0.0), turn=0.7))],
    "mixed": [("clip-inside", _ico(1.1, (0, 0, 0))), ("clip-outside", _box((0.5, 3, 0.5), (0.2, 0, 0))),
              ("solid", _ico(0.35, (0.9, 0.0, 0.2)))],
}


def _part(skel, meshes):
    return Part(skel, tuple(PartMesh(make_mesh(v, f, f"{role} {i}"), role) for i, (role, (v, f)) in
                            enumerate(meshes)))


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_part_is_meshed_within_the_tolerance(case):
    skel, tol = _struts(), 0.1
    m = mesh_part(_part(skel, CASES[case]), tol=tol)
    t = m.trimesh()
    assert m.certified and 0 < m.bound <= tol
    assert t.is_watertight and t.is_winding_consistent and t.volume > 0
    roles = {}
    for role, mesh in CASES[case]:
        roles.setdefault(role, []).append(mesh)
    assert not len(part_mesh_points_off_surface(skel, roles, m.vertices, m.faces, m.bound))
    pts = part_surface_points_on_lines(skel, roles, [-1.5, -1.5, -1.2], [1.5, 1.5, 1.2], n_lines=60)
    assert len(pts) > 15
    assert point_triangle_distance(pts, m.vertices[m.faces]).max() <= m.bound


def test_a_lattice_mesh_off_its_surface_is_not_certified():
    """The part's certificate checks the lattice's mesh where the meshes cut it: a lattice mesh
    pushed outward by 2.5 tol (its own bounds kept, as a wrong lattice mesher would report them)
    gives caps wider than the true solid's, which the probes find."""
    skel = Skeleton([[0, 0, -2], [0, 0, 2]], [[0, 1]], [[0.6, 0.6]])
    tol = 0.05
    part = _part(skel, [("clip-inside", _box((3, 3, 2)))])
    lattices = composite._Lattices([skel])
    lattices.mesh(tol, None, 6)
    meshes = composite._Meshes(part)
    good = composite._combine(lattices.meshes, meshes)
    a, s, _ = composite._certify(lattices, meshes, *good, tol)
    assert max(a, s) <= tol
    lattice = lattices.meshes[0]
    moved = lattice.vertices.copy()
    radial = np.linalg.norm(moved[:, :2], axis=1)
    side = np.abs(moved[:, 2]) < 1.5                 # the cylinder's side, not its round ends
    moved[side, :2] *= ((radial[side] + 2.5 * tol) / radial[side])[:, None]
    bad = composite._combine([dataclasses.replace(lattice, vertices=moved)], meshes)
    a, s, _ = composite._certify(lattices, meshes, *bad, tol)
    assert not a <= tol
    # not to be simplified: the wide cap triangles are first probed along their normals alone
    a, s, _ = composite._certify(lattices, meshes, *bad, tol, compact=False)
    assert not a <= tol
    # a wide triangle 0.45 tol above the cap: along its normal alone it is not certified within
    # the tolerance, so it is halved, and its pieces' bounds hold its true distance
    tri = np.array([[0.03, 0, 0], [-0.015, 0.026, 0], [-0.015, -0.026, 0]]) + [0.0, 0.0, 1.0 + 0.45 * tol]
    d, _ = composite._mesh_to_surface(lattices, meshes, tri, np.array([[0, 1, 2]]), tol, of_lattices=False)
    assert 0.45 * tol <= d[0] <= tol


def test_winding_numbers():
    v, f = _box((1, 2, 3), (0.5, 0, 0), turn=0.3)
    rng = np.random.default_rng(3)
    p = rng.uniform(-2, 2, size=(400, 3))
    w = winding_numbers(p, v, f)
    assert np.allclose(w, convex_inside(v, f, p).astype(float), atol=1e-9)
    v2, f2 = _box((0.5, 0.5, 0.5), (0.5, 0, 0))
    both = composite._joined([(v, f), (v2, f2)])
    assert math.isclose(winding_numbers(np.array([[0.5, 0, 0]]), *both)[0], 2.0, abs_tol=1e-9)


def test_membership_shared_by_cells_is_each_points_own(monkeypatch):
    """A union of many triangles decides points far from its surface by their cells' centres
    (composite._Meshes._members): the same answer as each point's own winding number, at
    distances from 1e-6 mm to 1 mm on both sides of a non-convex mesh (two overlapping
    polyhedral spheres, a groove where they meet), with far fewer winding numbers taken for
    clustered points."""
    spheres = []
    for centre in ((0.0, 0.0, 0.0), (1.3, 0.2, 0.1)):
        m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        m.apply_translation(centre)
        spheres.append((np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)))
    meshes = composite._Meshes(_part(None, [("solid", spheres[0]), ("solid", spheres[1])]))
    meshes.index(0.3)
    v, f = meshes.roles["solid"]
    assert len(f) >= composite.MEMBER_FACES
    rng = np.random.default_rng(7)
    n_points = 4000
    on = v[f[rng.integers(0, len(f), n_points)]]
    base = (on * rng.dirichlet(np.ones(3), n_points)[:, :, None]).sum(axis=1)      # points of the surface
    normal = np.cross(on[:, 1] - on[:, 0], on[:, 2] - on[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    dist = np.exp(rng.uniform(math.log(1e-6), 0.0, n_points)) * rng.choice([-1.0, 1.0], n_points)
    pts = base + dist[:, None] * normal
    # probes come in clusters: five points within a hundredth of their distance
    pts = (pts[:, None] + 0.01 * np.abs(dist)[:, None, None] * rng.uniform(-1, 1, (n_points, 5, 3))).reshape(-1, 3)
    taken = []

    def counted(points, *mesh):
        taken.append(len(points))
        return winding_numbers(points, *mesh)

    monkeypatch.setattr(composite, "winding_numbers", counted)
    known, inside = meshes.inside(pts)
    assert known.mean() > 0.95
    assert sum(taken) < 0.5 * known.sum()
    own = winding_numbers(pts[known], v, f) > 0.5
    assert np.array_equal(inside["solid"][known], own)
    assert 0.3 < own.mean() < 0.7


def test_united_lattice_meshes_keep_their_triangles():
    """The booleans keep each lattice triangle's edges (composite._combine): two overlapping
    struts along a grid axis (rows of a pad) have coplanar strips of triangles, which manifold3d
    would merge into slivers millimetres long (each then certified piece by piece)."""
    along_x = Skeleton([[-2.35, -2.7, -1.075], [7.35, -2.7, -1.075]], [[0, 1]], [[0.5, 0.5]])
    lat = composite._Lattices([along_x, Skeleton([[-2.35, -2.25, -1.075], [7.35, -2.25, -1.075]], [[0, 1]],
                                                 [[0.5, 0.5]])])
    lat.mesh(0.2, None, 6)

    def largest(v, f):
        tri = v[f]
        return np.linalg.norm(tri - tri.mean(axis=1)[:, None], axis=2).max()

    v, f = composite._combine(lat.meshes, composite._Meshes(_part(along_x, [])))
    assert largest(v, f) <= max(largest(m.vertices, m.faces) for m in lat.meshes) * (1 + 1e-9)
    assert trimesh.Trimesh(v, f, process=False).is_watertight


def test_cli_meshes_a_clipped_lattice_and_a_mesh_only_part(tmp_path):
    scene = tmp_path / "s.json"
    _struts().save(scene)
    v, f = CASES["clip-inside"][0][1]
    trimesh.Trimesh(v, f).export(tmp_path / "clip.stl")
    out = tmp_path / "m.stl"
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--tol", "0.1",
                                    "--clip-inside", str(tmp_path / "clip.stl")])
    assert res.exit_code == 0, res.output
    bound = float(res.output.split("certified Hausdorff bound ")[1].split()[0])
    assert 0 < bound <= 0.1 and "where the lattice meets the part's meshes" in res.output
    t = trimesh.load(out, force="mesh")
    assert t.is_watertight and t.is_winding_consistent
    # inside the clip box's bounds
    assert (t.bounds[0] >= v.min(axis=0) - 1e-6).all() and (t.bounds[1] <= v.max(axis=0) + 1e-6).all()
    solid = tmp_path / "solid.stl"
    trimesh.creation.box((1, 1, 1)).export(solid)
    res = CliRunner().invoke(main, ["mesh", str(solid), "-o", str(tmp_path / "b.ply")])
    assert res.exit_code == 0, res.output
    assert abs(trimesh.load(tmp_path / "b.ply").volume - 1.0) < 1e-9


def _supported():
    """A model strut and two support struts at its end, one grazing its rounded cap."""
    return GroupedSkeleton([[0, 0, 0], [0, 0, 4], [3, 0, 0], [0, 0, -3]], [[0, 1], [0, 2], [0, 3]],
                           [[1, 1], [0.6, 0.6], [0.7, 0.5]], groups=(("model", 0, 1), ("support", 1, 3)))


def _star():
    """Three struts meeting at a node, where the sum bulges beyond the union."""
    return Skeleton([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]], [[0, 1], [0, 2], [0, 3]], [[0.5, 0.5]] * 3)


@pytest.mark.parametrize("case", ["supports", "union"])
def test_united_solids_are_meshed_within_the_tolerance(case):
    """A supported scene (the model's solid united with every support strut's) and the union
    blend are meshed as unions of summed lattices, checked against the scene's own union field."""
    skel, blend, box = (_supported(), "sum", ([-1.5, -1.5, -3.5], [3.5, 1.5, 4.5])) if case == "supports" else \
        (_star(), "union", ([-0.7, -0.7, -0.7], [2.7, 2.7, 2.7]))
    tol = 0.1
    m = mesh_part(skel, tol=tol, blend=blend)
    t = m.trimesh()
    assert m.certified and 0 < m.bound <= tol and m.stats["lattices"] == 3
    assert t.is_watertight and t.is_winding_consistent and t.volume > 0
    assert not len(part_mesh_points_off_surface(skel, {}, m.vertices, m.faces, m.bound, blend=blend))
    pts = part_surface_points_on_lines(skel, {}, *box, n_lines=40, blend=blend)
    assert len(pts) > 15
    assert point_triangle_distance(pts, m.vertices[m.faces]).max() <= m.bound
    if case == "union":     # the check tells the blends apart: the sum's mesh bulges at the node
        summed = mesh_part(skel, tol=tol)
        assert len(part_mesh_points_off_surface(skel, {}, summed.vertices, summed.faces, tol, blend=blend))


@pytest.mark.parametrize("seed", range(4))
def test_struts_of_a_class_have_disjoint_supports(seed):
    """Within each class of struts that unite, the summed field is the largest strut's field."""
    rng = np.random.default_rng(seed)
    n = 30
    nodes = rng.uniform(0, 12, size=(n, 3))
    seg = np.array([(i, j) for i, j in rng.integers(0, n, size=(40, 2)) if i != j])
    skel = Skeleton(nodes, seg, rng.uniform(0.2, 0.8, size=(len(seg), 2)))
    classes = disjoint_classes(skel, np.arange(len(seg)))
    assert sorted(np.concatenate(classes).tolist()) == list(range(len(seg)))
    assert len(classes) < len(seg)
    pts = np.concatenate([rng.uniform(-1, 13, size=(4000, 3)),
                          (nodes[seg[:, 0]] + rng.uniform(0, 1, (len(seg), 1)) * (nodes[seg[:, 1]] - nodes[seg[:, 0]])
                           + rng.normal(0, 0.5, (len(seg), 3)))])
    for c in classes:
        sub = Skeleton(nodes, seg[c], skel.radii[c])
        assert np.array_equal(evaluate(sub, pts)[0], evaluate(sub, pts, blend="union")[0])


def test_mesh_scene_points_unions_to_mesh_part():
    with pytest.raises(SceneError, match="groups that unite.*mesh_part"):
        mesh_scene(_supported())


def test_cli_meshes_a_supported_scene(tmp_path):
    scene = tmp_path / "supported.json"
    write_supported(_supported(), scene)
    out = tmp_path / "m.ply"
    # --blend union: the model's one strut is a solid of its own too (the same three)
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--tol", "0.1", "--blend", "union"])
    assert res.exit_code == 0, res.output
    assert "3 summed lattices united" in res.output and "where the united lattices meet" in res.output
    t = trimesh.load(out, force="mesh")
    assert t.is_watertight and t.is_winding_consistent
    # the supports reach below the model: the mesh spans the support strut's length
    assert t.bounds[0][2] < -3.0 and t.bounds[1][0] > 3.0


def test_cli_meshes_a_lattice_with_supports_auto(tmp_path):
    """``mesh --supports auto`` meshes the lattice with the supports ``skelslice supports``
    would add (found on a 0.05 mm grid): a bar lifted 1 mm (from z 1.5 - 2.5 to 2.5 - 3.5) stands
    on pillars reaching below it."""
    scene = tmp_path / "bar.json"
    write_scene(Skeleton([[0, 0, 2], [6, 0, 2]], [[0, 1]], [[0.5, 0.5]]), scene)
    out = tmp_path / "m.stl"
    args = ["mesh", str(scene), "-o", str(out), "--tol", "0.2", "--uniform", "--no-pad", "--elevation", "1"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 2 and "needs --supports auto" in res.output and not out.exists()
    res = CliRunner().invoke(main, [*args, "--supports", "auto"])
    assert res.exit_code == 0, res.output
    assert "summed lattices united" in res.output
    t = trimesh.load(out, force="mesh")
    assert t.is_watertight and t.is_winding_consistent
    assert t.bounds[0][2] < 2.0 and t.bounds[1][2] > 3.4
