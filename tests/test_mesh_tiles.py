"""Meshes made tile by tile (slicer.meshing.tiles, docs/mesh.md, "Tiles").

* A tile's closed mesh (its cubes' faces and the caps on its box, widened by the overlap) is
  watertight, its caps lie on the box's faces, and it holds exactly the one-piece uniform
  mesh's solid cut by that box (manifold3d's intersection); cut by the tile's own box, the
  tiles' volumes add up to the whole's. Random struts and tile sizes (hypothesis) as well as a
  fixed scene.
* Tiled meshes a few cubes wide (many seams) pass the acceptance check of tests/mesh_checks.py.
* The same job gives the same mesh on one thread or two; mesh_scene tiles by itself when the
  band would not fit (MAX_BAND lowered) and not otherwise; the command line's --tile, and its
  refusals.
"""
from __future__ import annotations


import manifold3d
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from mesh_checks import assert_certified_mesh
from slicer import Skeleton
from slicer._kernels.runtime.launch import numba_threads
from slicer.cli.app import main
from slicer.errors import OptionError
from slicer.meshing import mesh_part, mesh_scene, tiles
from slicer.meshing.certificate import MeshField
from slicer.meshing.cubes import _band, _grid, _triangles
from slicer.meshing.surface import first_cell
from slicer.parts.meshes import make_mesh
from slicer.parts.part import Part, PartMesh


def struts():
    rng = np.random.default_rng(11)
    nodes = rng.uniform(0, 3, (5, 3))
    return Skeleton(nodes, [[0, 1], [1, 2], [2, 3], [1, 4]], rng.uniform(0.25, 0.6, (4, 2)))


def solid(v, f):
    m = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v, np.float64),
                                              tri_verts=np.ascontiguousarray(f, np.uint64)))
    assert m.status() == manifold3d.Error.NoError
    return m


def check_tiles_cut_the_uniform_mesh(skel, tol, per_tile):
    """Each tile's closed mesh is the one-piece uniform mesh cut by its box widened by the overlap."""
    fld = MeshField(skel)
    grid = _grid(skel, first_cell(skel, tol, None))
    verts, faces, _, _ = _triangles(fld, grid, _band(fld, grid)[0])
    whole = solid(verts, faces)
    total, n_tiles = 0.0, 0
    m = tiles.overlap(grid.h, tol)
    for lo, hi in tiles.tile_boxes(grid, per_tile):
        closed, planes, _ = tiles.tile_mesh(fld, grid, lo, hi, tol, {})
        elo, ehi = np.maximum(lo - m, 0), np.minimum(hi + m, grid.coarse << grid.levels)
        lo_mm, hi_mm = grid.points(np.stack([elo, ehi]))
        box = manifold3d.Manifold.cube(hi_mm - lo_mm).translate(lo_mm)
        want = (whole ^ box).volume()
        if closed is None:
            assert want <= 1e-12 * whole.volume()
            continue
        own = grid.points(np.stack([lo, hi]))
        t = trimesh.Trimesh(closed.vertices, closed.faces, process=False)
        assert t.is_watertight and t.is_winding_consistent
        got = solid(closed.vertices, closed.faces).volume()
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12 * whole.volume())
        v, f = tiles.cut(*own)(closed.vertices, closed.faces)
        n_tiles += len(f) > 0
        total += solid(v, f).volume() if len(f) else 0.0
        # the caps lie on the faces of the box, each on the one it is numbered for
        cap = closed.vertices[closed.faces[planes > 0]]
        face = planes[planes > 0] - 1
        plane = np.where(face % 2 == 0, lo_mm[face // 2], hi_mm[face // 2])
        assert np.array_equal(cap[np.arange(len(cap)), :, face // 2], np.repeat(plane[:, None], 3, 1))
        # bounds on the tile's own faces (inside its box) alone: the caps and the overlap's serve nothing here
        c = closed.vertices[closed.faces].mean(axis=1)
        inside = ((c > own[0]) & (c < own[1])).all(axis=1)
        outside = ((c < own[0]) | (c > own[1])).any(axis=1)
        assert np.isnan(closed.face_bounds[planes > 0]).all() and np.isnan(closed.face_bounds[outside]).all()
        assert not np.isnan(closed.face_bounds[(planes == 0) & inside]).any()
    assert n_tiles > 1 and total == pytest.approx(whole.volume(), rel=1e-9)


def test_tiles_cut_the_uniform_mesh():
    check_tiles_cut_the_uniform_mesh(struts(), 0.06, 2)


@settings(max_examples=2, deadline=None)
@given(seed=st.integers(0, 10_000), per_tile=st.integers(1, 3))
def test_tiles_cut_the_uniform_mesh_of_random_struts(seed, per_tile):
    rng = np.random.default_rng(seed)
    nodes = rng.uniform(0, 2.0, (4, 3))
    skel = Skeleton(nodes, [[0, 1], [1, 2], [1, 3]], rng.uniform(0.25, 0.5, (3, 2)))
    check_tiles_cut_the_uniform_mesh(skel, 0.1, per_tile)


@pytest.fixture(scope="module")
def tiled():
    """The random struts at 0.08 mm in tiles of one coarse cube (half a millimetre): many seams."""
    skel = struts()
    with numba_threads(1):
        one = mesh_scene(skel, tol=0.08, tile=0.5)
    return skel, one


def test_a_tiled_mesh_passes_the_acceptance_check(tiled):
    skel, m = tiled
    assert len(m.stats["tiles"]) > 8 and m.stats["coarse_per_tile"] == 1
    # margins measured to the union (the seams' faces are held, so the union adds few triangles of its own)
    assert m.stats["margin_faces"] > 0
    assert_certified_mesh(skel, m, 0.08)


def test_tiles_are_simplified_and_meet_along_their_seams(tiled):
    """Each tile is simplified within its own share of the tolerance (pieces split until certified
    within it, the uniform faces' distances aimed below it), and holds its seam's faces: the
    tiles' cuts meet, so the union adds almost no triangles of its own, and no tile falls back to
    its uniform mesh (certifying at the job's tolerance, or with slivers of caps between the
    tiles, thousands of the union's triangles here were its own, and tiles kept their uniform mesh)."""
    _, m = tiled
    simplified = [tile["simplify"] for tile in m.stats["tiles"] if tile["simplify"]]
    assert len(simplified) > 8
    assert all(rows[-1]["kept"] and rows[-1]["eps"] > 0 and rows[-1]["seam"] > 0 for rows in simplified)
    assert m.stats["fresh_triangles"] < 0.01 * len(m.faces)
    # a bound is within the tile's share or not certified (inf): none falls between it and the tolerance
    inner = (1.0 - tiles.SEAM_SHARE) * 0.08
    assert not any(inner < row.get("mesh_to_surface", 0.0) <= 0.08 for rows in simplified for row in rows)


def test_seam_faces_touch_the_box():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [2, 1, 0], [0.5, 2, 0], [1.5, 2, 0]])
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 2]])
    lo, hi = np.array([1.0, -5, -5]), np.array([5.0, 5, 5])
    # a vertex on the plane x = 1, one well inside the box, one crossing x = 1
    assert tiles.seam_faces(v, f, lo, hi, 0.1).tolist() == [True, False, True]
    # a face that stops short of the plane by more than SEAM_REACH of a cube
    assert tiles.seam_faces(v - [0.002, 0, 0], f, lo, hi, 0.1).tolist() == [False, False, True]
    # the same on the box's upper planes, along each axis
    for axis in range(3):
        turn = np.roll(np.eye(3), axis, axis=1)
        w = (np.array([6.0, 0, 0]) - v) @ turn
        top, bottom = np.roll([1.0, 5, 5], axis) + 5.0, np.roll([-5.0, -5, -5], axis)
        assert tiles.seam_faces(w, f, bottom, top, 0.1).tolist() == [True, False, True]


@pytest.mark.parametrize("split", ["tiles at once", "threads in a tile"])
def test_tiles_give_the_same_mesh_on_any_thread_count(tiled, monkeypatch, split):
    skel, one = tiled
    if split == "threads in a tile":
        monkeypatch.setattr(tiles, "tile_threads", lambda n: (1, 2))
    with numba_threads(2):
        two = mesh_scene(skel, tol=0.08, tile=0.5)
    assert np.array_equal(one.vertices, two.vertices) and np.array_equal(one.faces, two.faces)
    assert one.bound == two.bound


def test_a_refused_tile_raises_in_its_turn(monkeypatch):
    """A tile refused on a worker thread raises its error where it comes in the tiles' order; the
    tiles before it are reported done, and those after it stop."""
    real, calls = tiles._tile_simplified, []

    def refuse_the_third(fld, closed, planes, lo_mm, hi_mm, tol, reach):
        calls.append(lo_mm)
        if len(calls) == 3:
            return None
        return real(fld, closed, planes, lo_mm, hi_mm, tol, reach)

    monkeypatch.setattr(tiles, "_tile_simplified", refuse_the_third)
    monkeypatch.setattr(tiles, "tile_threads", lambda n: (1, 1))
    lines = []
    with pytest.raises(OptionError, match="no simplification of its mesh could be certified within 0.0582 mm"):
        mesh_scene(struts(), tol=0.06, tile=1.5, progress=lines.append)
    assert len(calls) == 3 and len(lines) >= 2 and all(line.startswith("tile ") for line in lines)
    monkeypatch.setattr(tiles, "tile_threads", lambda n: (2, 1))
    calls.clear()
    with pytest.raises(OptionError, match="no simplification"):
        mesh_scene(struts(), tol=0.06, tile=1.5)
    # the tiles after the refused one stopped: far fewer simplified than the 15 of the whole job
    assert len(calls) <= 5


def test_mesh_scene_tiles_a_band_that_would_not_fit(monkeypatch):
    skel = struts()
    fld = MeshField(skel)
    band = tiles.estimated_band(fld, _grid(skel, first_cell(skel, 0.06, None)))
    assert "tiles" not in mesh_scene(skel, tol=0.06).stats
    # a memory for twice this band: above TILED_SHARE of it, so in tiles of a quarter of it
    monkeypatch.setattr(tiles, "MAX_BAND", int(2 * band))
    m = mesh_scene(skel, tol=0.06)
    assert len(m.stats["tiles"]) > 1 and m.certified
    assert_certified_mesh(skel, m, 0.06, n_lines=20)


def test_cli_meshes_in_tiles(tmp_path):
    scene = tmp_path / "s.json"
    struts().save(scene)
    out = tmp_path / "m.stl"
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--tol", "0.06", "--tile", "1.5"])
    assert res.exit_code == 0, res.output
    n = int(res.output.split(" tiles")[0].split(" in ")[-1])
    assert n > 1 and float(res.output.split("certified Hausdorff bound ")[1].split()[0]) <= 0.06
    # a line per tile as it is done (the boxes with none of the solid are passed over)
    assert sum(line.startswith("tile ") for line in res.output.splitlines()) == n
    t = trimesh.load(out, force="mesh")
    assert t.is_watertight and t.is_winding_consistent


@pytest.mark.parametrize("extra, message", [(["--uniform"], "--tile cannot go with --uniform"),
                                            (["--tile", "0"], "--tile"), (["--blend", "union"], "tiles mesh a summed")])
def test_cli_refuses_tiles_it_cannot_make(tmp_path, extra, message):
    scene = tmp_path / "s.json"
    struts().save(scene)
    out = tmp_path / "m.stl"
    args = ["mesh", str(scene), "-o", str(out), "--tol", "0.06"] + (["--tile", "1"] if "--tile" not in extra else [])
    res = CliRunner().invoke(main, args + extra)
    assert res.exit_code == 2 and message in res.output and not out.exists()


def test_a_part_with_meshes_is_not_tiled():
    box = trimesh.creation.box((2, 2, 2))
    part = Part(struts(), (PartMesh(make_mesh(box.vertices, box.faces, "box"), "clip-inside"),))
    with pytest.raises(OptionError, match="tiles mesh a summed lattice alone"):
        mesh_part(part, tol=0.06, tile=1.0)


def test_a_union_that_moves_the_tiles_triangles_is_not_certified(monkeypatch):
    """The tiles' distances hold for the union only where it keeps their triangles: a union that
    moves them (here, by twice the tolerance) leaves the bound infinite, not a wrong number."""
    real = manifold3d.Manifold.batch_boolean

    def moved(solids, op):
        return real(solids, op).translate([0.12, 0.0, 0.0])

    monkeypatch.setattr(manifold3d.Manifold, "batch_boolean", moved)
    m = mesh_scene(struts(), tol=0.06, tile=1.5)
    assert m.stats["certified_not_kept"] > 0 and not m.certified and m.surface_to_mesh > 0.1


def test_rows_name_a_triangle_however_numbered():
    v = np.random.default_rng(0).normal(size=(4, 3))
    rows = tiles._rows(v, np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [0, 1, 3]]))
    assert rows[0] == rows[1] == rows[2] and rows[3] != rows[0] and rows[4] != rows[0]


def test_margins_are_measured_to_the_mesh():
    """A margin face 0.01 mm above a flat mesh, with a bound of 0.02 mm: 0.03 (to within the
    distance bounds' splitting); none: 0; a mesh farther than the reach: still a bound."""
    box = trimesh.creation.box((2, 2, 2))
    tri = np.array([[-0.2, -0.2, 1.01], [0.2, -0.2, 1.01], [0.0, 0.2, 1.01]])
    got = tiles._margins_to([(tri, np.array([[0, 1, 2]]), np.array([0.02]))], box.vertices, box.faces, 0.06)
    assert 0.03 <= got <= 0.02 + 0.04        # the pieces are split while their distance is above reach - bound
    assert tiles._margins_to([], box.vertices, box.faces, 0.06) == 0.0
    assert tiles._margins_to([(tri + [0, 0, 1], np.array([[0, 1, 2]]), np.array([0.02]))], box.vertices, box.faces,
                             0.06) >= 1.03
