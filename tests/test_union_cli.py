"""``--blend union`` through the commands: every image and printer format, placement,
anti-aliasing, tiles and executors, parts, ``info``."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
import trimesh
from PIL import Image

from formats import WRITERS
from helpers import run
from slicer import Skeleton
from slicer.model.field import evaluate
from slicer.parts.part import Part, PartMesh
from slicer.printability import printed_widths
from slicer.parts.meshes import make_mesh
from slicer.parts.slicing import slice_part, slice_part_planned
from validation.bulge import node

PRINTER_FOR = {"goo": "elegoo-mars-4-ultra", "ctb": "elegoo-saturn", "ctb-v2": "creality-ld-002h"}
#: one format per writer family (the writers only see layers, never the blend)
IMAGE_FORMATS = [k for k in ("png", "zip", "goo", "ctb", "pwmo", "sl1", "nanodlp")
                 if getattr(WRITERS[k], "kind", "image") == "image"]


@pytest.fixture(scope="module")
def elbow(tmp_path_factory):
    """Three struts meeting at a node: the sum bulges there, the union does not."""
    p = tmp_path_factory.mktemp("elbow") / "elbow.obj"
    p.write_text("v 0 0 0.6 0.5\nv 0 0 3 0.5\nv 2 0 3 0.5\nv 0 2 3 0.4\nl 1 2\nl 2 3\nl 2 4\n")
    return p


def _png_stack(out):
    meta = json.loads((out / "slices.json").read_text())
    return meta, np.stack([np.asarray(Image.open(out / f)) for f in meta["files"]])


def test_png_stack_is_the_union_field_at_every_voxel_centre(elbow, tmp_path):
    out = tmp_path / "u"
    r = run("slice", elbow, "-o", out, "--pixel-size", "0.1", "--blend", "union")
    assert r.exit_code == 0, r.output
    meta, vol = _png_stack(out)
    assert meta["blend"] == "union"
    (x0, y0), (px, py), h, z0 = meta["origin"][:2], meta["pixel_size"], meta["layer_height"], meta["origin"][2]
    K, H, W = vol.shape
    k, j, i = np.meshgrid(np.arange(K), np.arange(H), np.arange(W), indexing="ij")
    P = np.stack([x0 + i * px, y0 - j * py, z0 + k * h], -1).reshape(-1, 3)
    skel = Skeleton([[0, 0, 0.6], [0, 0, 3], [2, 0, 3], [0, 2, 3]], [[0, 1], [1, 2], [1, 3]],
                    [[0.5, 0.5], [0.5, 0.5], [0.5, 0.4]])
    f = evaluate(skel, P, blend="union")[0].reshape(K, H, W)
    assert np.array_equal(vol == 255, f >= 1.0) and (vol == 255).sum() > 1000
    summed = tmp_path / "s"
    assert run("slice", elbow, "-o", summed, "--pixel-size", "0.1").exit_code == 0
    smeta, svol = _png_stack(summed)
    assert "blend" not in smeta and (svol == 255).sum() > (vol == 255).sum()


def _write(elbow, out, fmt, blend):
    args = ["slice", elbow, "-o", out, "--format", fmt, "--blend", blend]
    if fmt in PRINTER_FOR:
        args += ["--printer", PRINTER_FOR[fmt]]
    elif fmt in ("png", "zip", "nanodlp"):
        args += ["--pixel-size", "0.1"]
    r = run(*args)
    assert r.exit_code == 0, r.output
    files = sorted(p for p in out.rglob("*") if p.is_file()) if out.is_dir() else [out]
    return b"".join(p.read_bytes() for p in files)


@pytest.mark.parametrize("fmt", IMAGE_FORMATS)
def test_every_image_format_writes_the_union(elbow, tmp_path, fmt):
    """Every image format writes a union job; a few (one per writer family) differ from the sum's
    file, which they would not if the blend were lost on the way (the writers only see layers)."""
    ext = {"nanodlp": "zip", "ctb-v2": "ctb"}.get(fmt, fmt)
    union = _write(elbow, tmp_path / f"union.{ext}", fmt, "union")
    assert len(union) > 1000
    if fmt in ("png", "zip", "goo", "ctb", "pwmo", "sl1"):
        assert _write(elbow, tmp_path / f"sum.{ext}", fmt, "sum") != union


def _plate_images(path):
    with zipfile.ZipFile(path) as z:
        return [np.asarray(Image.open(z.open(f))).astype(np.int64) for f in sorted(z.namelist())
                if f.endswith(".png") and not f.startswith("thumbnail")]


def test_placement_antialiasing_tiles_and_executors(elbow, tmp_path):
    """sl1s on the plate at --at with --aa 2: the same bytes in memory, in tiles and on a process
    pool; with --aa-z too, greys within 1 (coverage agrees to 1e-9 across tiles, and a coverage on a
    grey's rounding tie may round either way, as for the sum). The union's plate has fewer lit
    pixels than the sum's. (Several slabs with a printer are refused by the placement for either
    blend; slabs are tested in test_union_trace.)"""
    base = ["slice", elbow, "--printer", "prusa-sl1s", "--at", "60", "40", "--aa", "2", "--blend", "union"]
    outs = {}
    for name, extra in (("ref", []), ("tiles", ["--tile", "64"]),
                        ("pool", ["--executor", "processes", "--workers", "2", "--tile", "96"]),
                        ("z", ["--aa-z"]), ("ztiles", ["--aa-z", "--tile", "64"])):
        out = tmp_path / name / "part.sl1s"      # the job's name (and so the bytes) comes from the file name
        out.parent.mkdir()
        r = run(*base, "-o", out, *extra)
        assert r.exit_code == 0, r.output
        outs[name] = out
    assert outs["tiles"].read_bytes() == outs["ref"].read_bytes()
    assert outs["pool"].read_bytes() == outs["ref"].read_bytes()
    for a, b in zip(_plate_images(outs["z"]), _plate_images(outs["ztiles"])):
        assert np.abs(a - b).max() <= 1
    summed = tmp_path / "sum.sl1s"
    assert run(*[a if a != "union" else "sum" for a in base], "-o", summed).exit_code == 0
    lit = {name: sum(int(im.sum()) for im in _plate_images(p)) for name, p in (("union", outs["ref"]),
                                                                                ("sum", summed))}
    assert 0 < lit["union"] < lit["sum"]


def test_part_with_a_mesh_traces_the_union():
    """A lattice node unioned with a box: the lattice part is the union of the struts."""
    skel = node(12, 0.4, 2.0)
    box = trimesh.creation.box(extents=(1, 1, 1))
    box.apply_translation((0, 0, -2.5))
    part = Part(skel, [PartMesh(make_mesh(box.vertices, box.faces, "box"), "solid")])
    bounds = (-2.3, -2.3, -3.1, 2.3, 2.3, 2.3)
    res = slice_part(part, 0.1, bounds=bounds, blend="union")
    g = res.grid
    z, y, x = np.meshgrid(g.centres_z(), g.centres_y(), g.centres_x(), indexing="ij")
    P = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    lattice = evaluate(skel, P, blend="union")[0] >= 1.0
    inbox = np.all(np.abs(P - (0, 0, -2.5)) < 0.5 - 1e-9, axis=1)
    onface = np.any(np.abs(np.abs(P - (0, 0, -2.5)) - 0.5) < 1e-9, axis=1)
    got = res.volume().reshape(-1)
    assert np.array_equal(got[~onface], (lattice | inbox)[~onface])
    for kw in ({"tile": 16}, {"tile": 24, "executor": "threads", "workers": 2}):
        planned = slice_part_planned(part, 0.1, bounds=bounds, blend="union", progress=False, **kw)
        assert np.array_equal(planned.volume(), res.volume()), kw


def test_info_reports_the_blend(elbow):
    r = run("info", elbow, "--blend", "union")
    assert r.exit_code == 0 and "blend union" in r.output


def test_check_measures_thin_struts_on_the_union(tmp_path):
    """Two parallel struts 0.07 mm apart (radius 0.05 mm): the sum widens each one's thinnest
    diameter, the union does not (it is the strut's own, 2 r); check measures on the blend it
    sliced with."""
    s = Skeleton([[0, 0, 0], [0, 0, 1], [0.07, 0, 0], [0.07, 0, 1]], [[0, 1], [2, 3]], [[0.05, 0.05]] * 2)
    ws, wu = printed_widths(s, blend="sum"), printed_widths(s, blend="union")
    assert np.all(wu < ws - 5e-4) and np.allclose(wu, 0.1, atol=1e-6)
    scene = tmp_path / "x.json"
    s.save(scene)
    for blend, n in (("union", 2), ("sum", 0)):
        out = tmp_path / f"{blend}.json"
        r = run("check", scene, "--pixel-size", "0.01", "--blend", blend, "--min-feature", "0.1005", "--json", out)
        assert r.exit_code in (0, 1), r.output
        assert len(json.loads(out.read_text())["thin_segments"]) == n, blend


def test_preview_refuses_what_sums(elbow, tmp_path):
    r = run("preview", elbow, "-o", tmp_path / "p.html", "--pixel-size", "0.1", "--blend", "union")
    assert r.exit_code == 2 and "--no-contours" in r.output and not (tmp_path / "p.html").exists()
    r = run("preview", elbow, "-o", tmp_path / "p.html", "--pixel-size", "0.1", "--blend", "union", "--no-contours")
    assert r.exit_code == 2 and "--no-render" in r.output
    r = run("preview", elbow, "-o", tmp_path / "p.html", "--pixel-size", "0.1", "--blend", "union", "--no-contours",
            "--no-render")
    assert r.exit_code == 0 and (tmp_path / "p.html").exists()
