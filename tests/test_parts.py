"""Parts: lattice + meshes sliced, checked voxel by voxel; every plan and output; the CLI."""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from PIL import Image

from parts_helpers import centres, inside_mesh, rotated, tmesh
from slicer.cli.app import main
from slicer.errors import SceneError
from slicer.model.field import evaluate
from slicer.parts.slicing import PartResult, PartStreamedResult, slice_part, slice_part_planned
from slicer.parts.part import Part, PartMesh, load_part
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import slice_skeleton

#: a small lattice: four struts through a node, and a strut beside them
LATTICE = Skeleton([[-2.5, 0, 0], [2.5, 0, 0], [0, -2.5, 0], [0, 2.5, 0], [0, 0, -2.5], [0, 0, 2.5],
                    [-2, -2, -2], [2, 2, 2]],
                   [[0, 1], [2, 3], [4, 5], [6, 7]], np.full((4, 2), 0.45))
SPHERE = trimesh.creation.icosphere(2, radius=1.6)
BOX = trimesh.creation.box(extents=(3.0, 3.0, 3.0))


def voxels(res) -> np.ndarray:
    return res.volume().reshape(-1)


def expected(part: Part, grid, margin: float = 1e-3):
    """Independent classification of every centre: the field (F >= 1) and the winding
    number of each role's meshes; ``sure`` leaves out centres near a surface."""
    p = centres(grid)
    f = evaluate(part.skeleton, p)[0] if part.skeleton is not None else np.zeros(len(p))
    lat, sure = f >= 1.0, np.abs(f - 1.0) > 1e-6
    for role in ("clip-inside", "clip-outside", "solid"):
        ms = part.of_role(role)
        if not ms:
            continue
        ins, ok = inside_mesh(ms, p, margin)
        sure &= ok
        if role == "clip-inside":
            lat &= ins
        elif role == "clip-outside":
            lat &= ~ins
        else:
            solid = ins
    out = lat | solid if part.of_role("solid") else lat
    return out, sure


# ----------------------------------------------------------------------------- every voxel
SMALL_CUBE = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).apply_translation((2.2, 2.2, 0.0))

PARTS = {
    "solid": lambda: Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 1)), "solid")]),
    "clip-inside": lambda: Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 2)), "clip-inside")]),
    "clip-outside": lambda: Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 3)), "clip-outside")]),
    "clip-and-solid": lambda: Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 2)), "clip-inside"),
                                             PartMesh(tmesh(SMALL_CUBE), "solid")]),
}


@pytest.mark.parametrize("kind", sorted(PARTS))
def test_every_voxel_against_the_field_and_the_winding_number(kind):
    """((lattice ∩ CI) − CO) ∪ S at every centre, against F >= 1 and winding numbers."""
    part = PARTS[kind]()
    res = slice_part(part, 0.12, layer_height=0.15)
    assert isinstance(res, PartResult)
    want, sure = expected(part, res.grid)
    got = voxels(res)
    assert sure.mean() > 0.97 and want.sum() > 200
    assert np.array_equal(got[sure], want[sure])
    # the grid is trimmed to what is printed, plus one voxel
    j, i = np.divmod(res.pix, res.grid.width)
    assert i.min() == j.min() == res.k0.min() == 1
    assert i.max() == res.grid.width - 2 and j.max() == res.grid.height - 2 and res.k1.max() == res.grid.layers - 1


def test_mesh_only_part():
    part = Part(None, [PartMesh(tmesh(rotated(SPHERE, 5)), "solid")])
    res = slice_part(part, 0.1)
    want, sure = expected(part, res.grid)
    assert np.array_equal(voxels(res)[sure], want[sure]) and res.lattice.n_runs == 0
    assert (res.k1 - res.k0).sum() * 1e-3 == pytest.approx(tmesh(SPHERE).volume(), rel=0.02)


def test_part_without_meshes_is_the_lattice():
    a = slice_part(Part(LATTICE), 0.1)
    b = slice_skeleton(LATTICE, 0.1)
    assert a.grid == b.grid and np.array_equal(a.pix, b.pix) and np.array_equal(a.k0, b.k0)


def test_clipping_needs_a_lattice():
    with pytest.raises(SceneError, match="clipping meshes but no lattice"):
        Part(None, [PartMesh(tmesh(BOX), "clip-inside")])
    with pytest.raises(SceneError, match="nothing to print"):
        Part(None, [])


# ----------------------------------------------------------------------------- plans, executors, spans
def _same(a, b):
    assert a.grid == b.grid
    la = list(a.iter_layers())
    lb = list(b.iter_layers())
    assert len(la) == len(lb) and all(np.array_equal(x, y) for x, y in zip(la, lb))


@pytest.mark.parametrize("plan", [dict(tile=16), dict(tile=16, slab=7), dict(slab=5, executor="threads", workers=2)])
def test_every_plan_gives_the_same_layers(plan):
    part = Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 2)), "clip-inside"),
                          PartMesh(tmesh(trimesh.creation.box(extents=(1, 1, 4))), "solid")])
    ref = slice_part(part, 0.1)
    got = slice_part_planned(part, 0.1, **plan)
    if "slab" in plan:
        assert isinstance(got, PartStreamedResult)
    _same(ref, got)


def test_sub_layer_coverage_of_a_mesh_is_exact():
    """A box from z = 0.03 to 0.97 on layers of 0.1 (centres at multiples of 0.1): the
    partial layers' coverage is the part of the voxel inside, exactly (vertical spans)."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.94))
    box.apply_translation((0.0, 0.0, 0.5))
    part = Part(None, [PartMesh(tmesh(box), "solid")])
    res = slice_part(part, 0.1, bounds=(-0.7, -0.7, -0.05, 0.7, 0.7, 1.05), spans=True)
    cov = np.stack(list(res.iter_coverage()))
    col = cov[:, 7, 7]                     # a column through the box
    assert col[0] == pytest.approx(0.2) and col[1:10] == pytest.approx(1.0) and col[10] == pytest.approx(0.2)
    assert cov.sum() * 0.01 * 0.1 == pytest.approx(1.0 * 1.0 * 0.94, rel=1e-9)


def test_spans_of_lattice_and_clip_combine():
    part = PARTS["clip-inside"]()
    res = slice_part(part, 0.1, spans=True)
    cov = np.stack(list(res.iter_coverage()))
    img = np.stack(list(res.iter_layers(1))).astype(bool)
    assert cov.max() <= 1.0 and np.all(cov[~img & (cov > 0)] < 0.5 + 1e-9)     # centres out: at most half
    assert np.all(cov[img] > 0)


# ----------------------------------------------------------------------------- the command line
def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r


@pytest.fixture
def part_files(tmp_path):
    shell = trimesh.util.concatenate([BOX, trimesh.Trimesh(BOX.vertices * 0.8, BOX.faces[:, ::-1])])
    shell.export(tmp_path / "shell.stl")
    inner = BOX.copy()
    inner.apply_scale(0.8)
    inner.export(tmp_path / "inner.stl")
    scene = {"skelslice": 2, "units": "mm", "nodes": LATTICE.nodes.tolist(), "segments": LATTICE.segments.tolist(),
             "segment_radii": LATTICE.radii.tolist(),
             "meshes": [{"path": "shell.stl", "role": "solid"}, {"path": "inner.stl", "role": "clip-inside"}]}
    (tmp_path / "part.json").write_text(json.dumps(scene))
    return tmp_path


def test_json_scene_with_meshes_slices_through_the_cli(part_files):
    out = part_files / "stack"
    r = run("slice", part_files / "part.json", "-o", out, "--pixel-size", "0.1", "-q")
    assert r.exit_code == 0, r.output
    meta = json.loads((out / "slices.json").read_text())
    layers = sorted(out.glob("*.png"))
    # 30 layers of 0.1 mm (centres half a layer off the shell's faces), plus one empty layer each side
    assert meta["layers"] == len(layers) == 32
    mid = np.asarray(Image.open(layers[16])) > 0
    part = load_part(part_files / "part.json")
    res = slice_part(part, 0.1)
    assert np.array_equal(mid, list(res.iter_layers())[16] > 0)
    assert mid[0].sum() == 0 and mid[1, 1:-1].all() and mid[mid.shape[0] // 2].sum() > 2 * 3 + 4   # wall, struts


def test_meshes_on_the_command_line(part_files):
    scene = part_files / "lat.json"
    scene.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": LATTICE.nodes.tolist(),
                                 "segments": LATTICE.segments.tolist(), "segment_radii": LATTICE.radii.tolist()}))
    a, b = part_files / "a.zip", part_files / "b.zip"
    assert run("slice", scene, "-o", a, "--pixel-size", "0.1", "--solid", part_files / "shell.stl",
               "--clip-inside", part_files / "inner.stl", "-q").exit_code == 0
    assert run("slice", part_files / "part.json", "-o", b, "--pixel-size", "0.1", "-q").exit_code == 0
    la = {n: zipfile.ZipFile(a).read(n) for n in zipfile.ZipFile(a).namelist() if n.endswith(".png")}
    lb = {n: zipfile.ZipFile(b).read(n) for n in zipfile.ZipFile(b).namelist() if n.endswith(".png")}
    assert la == lb and len(la) == 32


@pytest.mark.parametrize("aa, plans", [
    (["--aa", "2", "--aa-z"], [["--tile", "16"], ["--executor", "processes", "--workers", "2", "--tile", "16"]]),
    (["--aa", "2"], [["--slab", "6"], ["--slab", "5", "--tile", "16", "--executor", "threads", "--workers", "2"]]),
])
def test_plans_and_executors_give_the_same_bytes(part_files, aa, plans):
    """(Sub-layer coverage across slabs is left out: the lattice's own spans depend on the
    slab boundaries, to within their tolerance, with or without meshes.)"""
    outs = []
    for k, extra in enumerate([[], *plans]):
        out = part_files / f"o{k}.zip"
        r = run("slice", part_files / "part.json", "-o", out, "--pixel-size", "0.1", "-q", *aa, *extra)
        assert r.exit_code == 0, r.output
        outs.append(out.read_bytes())
    assert all(o == outs[0] for o in outs[1:])


def test_mesh_coverage_is_the_same_across_slabs():
    """The meshes' sub-layer coverage does not depend on the slabs (it is computed in the
    job grid's layer units)."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.33))
    box.apply_translation((2.2, -2.2, 0.61))                     # away from the struts
    part = Part(LATTICE, [PartMesh(tmesh(box), "solid")])
    ref = slice_part(part, 0.1, spans=True)
    g = ref.grid
    i, j = int(round((2.2 - g.origin[0]) / 0.1)), int(round((g.origin[1] + 2.2) / 0.1))
    a = np.stack(list(ref.iter_coverage()))[:, j - 4:j + 5, i - 4:i + 5]
    assert a.max() == 1.0 and ((a > 0) & (a < 1)).any()
    for slab in (3, 4, 7):
        got = slice_part_planned(part, 0.1, spans=True, slab=slab)
        b = np.stack(list(got.iter_coverage()))[:, j - 4:j + 5, i - 4:i + 5]
        assert got.grid == g and np.array_equal(a, b)


def test_printer_placement_and_contours(part_files):
    out = part_files / "p.sl1s"
    r = run("slice", part_files / "part.json", "-o", out, "--printer", "prusa-sl1s", "-q",
            "--contours", part_files / "c.geojson")
    assert r.exit_code == 0, r.output
    z = zipfile.ZipFile(out)
    pngs = sorted(n for n in z.namelist() if n.endswith(".png") and not n.startswith("thumbnail"))
    assert len(pngs) == 60                                             # 3 mm in 0.05 mm layers
    img = np.asarray(Image.open(io.BytesIO(z.read(pngs[30]))))
    assert (img > 0).sum() > 0.8 * (3.0 / 0.05) ** 2 * (1 - 0.64)      # at least the shell's wall
    feats = json.loads((part_files / "c.geojson").read_text())["features"]
    assert len(feats) == 60
    import shapely.geometry

    mid = shapely.geometry.shape(feats[30]["geometry"])
    assert mid.is_valid and 9.0 - 5.76 < mid.area < 9.0                  # the wall plus the struts inside


@pytest.mark.parametrize("fmt", ["cli", "svg", "3mf"])
def test_contour_formats(part_files, fmt):
    out = part_files / f"p.{fmt}"
    r = run("slice", part_files / "part.json", "-o", out, "--pixel-size", "0.1", "-q")
    assert r.exit_code == 0, r.output
    assert out.stat().st_size > 1000


def test_mesh_only_scene_file(tmp_path):
    BOX.export(tmp_path / "box.stl")
    out = tmp_path / "s"
    r = run("slice", tmp_path / "box.stl", "-o", out, "--pixel-size", "0.25", "-q")
    assert r.exit_code == 0, r.output
    layers = sorted(out.glob("*.png"))
    assert len(layers) == 14 and (np.asarray(Image.open(layers[7])) > 0).sum() == 12 * 12


def test_info_lists_meshes(part_files):
    r = run("info", part_files / "part.json", "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.output)
    assert [m["role"] for m in d["meshes"]] == ["solid", "clip-inside"]
    assert d["meshes"][0]["faces"] == 24 and d["meshes"][0]["volume"] == pytest.approx(27 - 27 * 0.512)
    assert d["segments"] == 4
    r = run("info", part_files / "part.json")
    assert "mesh (solid):" in r.output and "mesh (clip-inside):" in r.output


def test_validate_part(part_files):
    r = run("validate", part_files / "part.json", "--pixel-size", "0.11", "--layers-checked", "3", "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["passed"] and rep["summary"]["min_iou"] > 0.99 and "lattice of 4 segments" in rep["settings"]["part"]


def test_render_part_and_mesh(part_files):
    out = part_files / "r.png"
    r = run("render", part_files / "part.json", "-o", out, "--size", "60", "60", "--roots-out", part_files / "r.npz")
    assert r.exit_code == 0, r.output
    img = np.asarray(Image.open(out))
    assert (img.min(axis=2) < 250).mean() > 0.2
    BOX.export(part_files / "box.stl")
    out2 = part_files / "b.png"
    r = run("render", part_files / "box.stl", "-o", out2, "--size", "40", "40", "--view", "front",
            "--roots-out", part_files / "b.npz")
    assert r.exit_code == 0, r.output
    roots = np.load(part_files / "b.npz")
    count = roots["count"]
    assert set(np.unique(count)) <= {0, 2} and (count == 2).mean() > 0.5   # in and out of the box, once each


# ----------------------------------------------------------------------------- refusals through the CLI
def _refused(r, *needles):
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    for n in needles:
        assert n in r.output, r.output


@pytest.mark.parametrize("case, needles", [
    ("open", ("not a closed solid", "3 open edges")),
    ("inverted", ("inside out", "try --repair")),
    ("crossing", ("pairs of faces intersect",)),
    ("nonfinite", ("non-finite", "vertex 3")),
])
def test_bad_meshes_refused(tmp_path, case, needles):
    tm = BOX.copy()
    if case == "open":
        tm = trimesh.Trimesh(BOX.vertices, BOX.faces[1:], process=False)
    elif case == "inverted":
        tm = trimesh.Trimesh(BOX.vertices, BOX.faces[:, ::-1], process=False)
    elif case == "crossing":
        b = BOX.copy()
        b.apply_translation((1, 1, 1))
        tm = trimesh.util.concatenate([BOX, b])
    path = tmp_path / "bad.stl"
    if case == "nonfinite":
        path = tmp_path / "bad.ply"
        path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                        "property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
                        "0 0 0\n1 0 0\n0 1 0\n0 0 nan\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n")
    else:
        tm.export(path)
    for cmd in (["slice", path, "-o", tmp_path / "o", "--pixel-size", "0.1"], ["info", path]):
        _refused(run(*cmd), str(path), *needles)


def test_repair_option(tmp_path):
    path = tmp_path / "inv.stl"
    trimesh.Trimesh(BOX.vertices, BOX.faces[:, ::-1], process=False).export(path)
    r = run("slice", path, "-o", tmp_path / "o", "--pixel-size", "0.5", "--repair")
    assert r.exit_code == 0 and "note:" in r.stderr and "reversed all 12 faces" in r.stderr


@pytest.mark.parametrize("entry, needles", [
    ({"path": "x.stl", "role": "hole"}, ('meshes[0].role = "hole" is not a mesh role',)),
    ({"path": "x.3mf", "units": "cm"}, ("meshes[0].units: a 3MF file carries its own unit",)),
    ({"path": "x.stl", "transform": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0]]}, ("transform is singular",)),
    ({"path": "x.stl", "transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]},
     ("4th row must be [0, 0, 0, 1]",)),
    ({"path": "missing.stl"}, ("missing.stl", "No such file")),
    ({"path": "x.off"}, ("unknown mesh file type '.off'",)),
    ({"role": "solid"}, ('meshes[0]: missing key "path"',)),
    ({"path": "x.stl", "colour": 1}, ('meshes[0]: unknown key "colour"',)),
])
def test_bad_mesh_entries_refused(tmp_path, entry, needles):
    BOX.export(tmp_path / "x.stl")
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps({"skelslice": 2, "units": "mm", "meshes": [entry]}))
    _refused(run("info", scene), *needles)


def test_mesh_units_and_transform(tmp_path):
    """A mesh in cm, moved by a transform whose translation is in the scene's unit (um)."""
    b = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    b.apply_translation((0.5, 0.5, 0.5))
    b.export(tmp_path / "cube_cm.stl")
    scene = {"skelslice": 2, "units": "um", "nodes": [[0, 0, 0], [0, 0, 5000]], "segments": [[0, 1]],
             "radii": [500, 500],
             "meshes": [{"path": "cube_cm.stl", "units": "cm",
                         "transform": [[0, -1, 0, 20000], [1, 0, 0, 0], [0, 0, 1, 1000]]}]}
    (tmp_path / "s.json").write_text(json.dumps(scene))
    part = load_part(tmp_path / "s.json")
    assert np.allclose(part.skeleton.nodes[1], [0, 0, 5]) and np.allclose(part.skeleton.radii, 0.5)
    (m,) = part.solids()
    assert np.allclose(m.bounds(), [[10, 0, 1], [20, 10, 11]]) and m.volume() == pytest.approx(1000.0)


def test_clip_outside_scene_without_lattice_refused(tmp_path):
    BOX.export(tmp_path / "box.stl")
    _refused(run("slice", tmp_path / "box.stl", "-o", tmp_path / "o", "--pixel-size", "0.1",
                 "--clip-outside", tmp_path / "box.stl"), "clipping meshes but no lattice")


def test_version_1_scene_keeps_working(tmp_path):
    s = tmp_path / "v1.json"
    s.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 4]], "segments": [[0, 1]],
                             "radii": [1, 1]}))
    r = run("slice", s, "-o", tmp_path / "o", "--pixel-size", "0.25", "-q")
    assert r.exit_code == 0 and len(list((tmp_path / "o").glob("*.png"))) == 21


def test_part_contours_hold_the_independent_classification_on_any_thread_count():
    """The part's contours, layer planes on 1 or 2 threads and one layer at a time,
    are the same polygons; they hold exactly the voxel centres the field and the
    winding numbers put inside (those clear of every surface by 0.01 mm)."""
    import shapely

    from slicer.contours import iter_part_contours, part_layer_contours

    part = PARTS["clip-and-solid"]()
    res = slice_part(part, 0.12, layer_height=0.15)
    g = res.grid
    want, sure = expected(part, g, margin=1e-2)
    want = want.reshape(g.layers, g.height * g.width)
    sure = sure.reshape(g.layers, g.height * g.width)
    p = centres(g).reshape(g.layers, g.height * g.width, 3)
    runs = [[(k, z, mp.wkb) for k, z, mp in iter_part_contours(res, workers=w)] for w in (1, 2)]
    assert runs[0] == runs[1] and [k for k, _, _ in runs[0]] == list(range(g.layers))
    checked = 0
    for k, z, wkb in runs[0]:
        mp = shapely.from_wkb(wkb)
        assert wkb == part_layer_contours(res, k).wkb
        clear = sure[k] & (shapely.distance(mp.boundary, shapely.points(p[k, :, :2])) > 0.01)
        got = shapely.contains_xy(mp, p[k, clear, 0], p[k, clear, 1])
        assert np.array_equal(got, want[k, clear]), k
        checked += int(clear.sum())
    assert checked > 0.5 * want.size and want.sum() > 200


def test_contours_of_a_streamed_part_on_a_plate_ask_for_more_memory():
    """A part sliced in slabs (not held in memory) cannot have its contours put on a
    printer's plate: a clear error naming the option, not a crash."""
    from slicer.contours import iter_part_contours
    from slicer.errors import GridError

    part = Part(LATTICE, [PartMesh(tmesh(rotated(SPHERE, 2)), "clip-inside")])
    got = slice_part_planned(part, 0.1, slab=5)
    assert isinstance(got, PartStreamedResult)
    with pytest.raises(GridError, match="max-memory"):
        next(iter_part_contours(got, 1e-3, placement=object()))
