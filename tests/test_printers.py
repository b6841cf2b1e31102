"""Printer profiles, native orientation and placement on the plate.

References: PrusaSlicer's raster transform written out point by point
(docs/formats.md §1.2), the SL1S placement measured on a real PrusaSlicer export,
and models whose inside pixels have a known centre.
"""
from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest
from PIL import Image

from formats import WRITERS
from formats.printer_profiles import PRINTERS, get_printer
from helpers import assert_refused, run
from slicer import Skeleton
from slicer.errors import GridError, OptionError


@pytest.fixture(scope="module")
def post(tmp_path_factory):
    """A vertical strut of radius 0.4 mm, 3 mm tall: its footprint centre is its axis."""
    p = tmp_path_factory.mktemp("post") / "post.json"
    Skeleton([[5.0, -3.0, 10.0], [5.0, -3.0, 13.0]], [[0, 1]], [[0.4, 0.4]]).save(p)
    return p


@pytest.fixture(scope="module")
def ell(tmp_path_factory):
    """A chiral model: a post with a long arm toward +x and a short one toward +y."""
    p = tmp_path_factory.mktemp("ell") / "ell.json"
    Skeleton([[0, 0, 0], [0, 0, 3], [2.5, 0, 3], [0, 1.2, 3]], [[0, 1], [1, 2], [1, 3]],
             [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3]]).save(p)
    return p


# ---------------------------------------------------------------- the table
def test_table_has_the_required_printers():
    vendors = [p.vendor for p in PRINTERS.values()]
    assert vendors.count("Prusa") >= 2 and vendors.count("Elegoo") >= 2 and vendors.count("Anycubic") >= 2
    assert PRINTERS["prusa-sl1s"].pixel_size == pytest.approx((0.05, 0.05))
    assert PRINTERS["prusa-sl1"].pixel_size == pytest.approx((0.04725, 0.04725))
    assert PRINTERS["elegoo-saturn-3-ultra"].pixel_size == pytest.approx((0.019, 0.024))   # non-square
    for p in PRINTERS.values():
        assert p.format in WRITERS
        assert p.orientation in ("landscape", "portrait")
        assert 0 < p.exposure < p.bottom_exposure
        assert p.bottom_layers >= 1


def test_unknown_printer_lists_the_names():
    with pytest.raises(OptionError, match="prusa-sl1s"):
        get_printer("photon-9000")
    assert get_printer(" Prusa-SL1S ").name == "prusa-sl1s"


# ---------------------------------------------------------------- native layout
def _trafo_pixel(p, X, Y):
    """PrusaSlicer's raster transform of a plate point: (row, column) of the
    native image (SL1Archive::create_raster + RasterBase::Trafo)."""
    w, h = p.display
    pw, ph = p.pixels
    x, y = X, Y
    portrait = p.orientation == "portrait"
    if portrait:                                  # swap the display axes, then flipXY
        w, h, pw, ph = h, w, ph, pw
        x, y = Y, X
    mirror_x = (not p.mirror_x) if portrait else p.mirror_x
    mirror_y = not p.mirror_y
    if mirror_x:
        x = w - x
    if mirror_y:
        y = h - y
    return math.floor(y / (h / ph)), math.floor(x / (w / pw))


@pytest.mark.parametrize("name", sorted(PRINTERS))
def test_to_native_is_prusaslicers_raster_transform(name):
    """Plate pixel (j, i) goes to the native pixel PrusaSlicer rasterises its centre into."""
    p = PRINTERS[name]
    H, W = p.plate_shape
    rows = np.broadcast_to(np.arange(H)[:, None], (H, W))     # index maps as zero-copy views
    cols = np.broadcast_to(np.arange(W)[None, :], (H, W))
    nr, nc = p.to_native(rows), p.to_native(cols)
    assert nr.shape == p.native_shape
    px, py = p.pixel_size
    rng = np.random.default_rng(3)
    for j, i in [(0, 0), (H - 1, W - 1), (0, W - 1), (H - 1, 0)] + [
            (int(rng.integers(H)), int(rng.integers(W))) for _ in range(40)]:
        r, c = _trafo_pixel(p, (i + 0.5) * px, p.display[1] - (j + 0.5) * py)
        assert (nr[r, c], nc[r, c]) == (j, i)


def test_to_native_small_printers_fully():
    for name in ("prusa-sl1", "prusa-sl1s"):
        p = PRINTERS[name]
        img = np.arange(p.plate_shape[0] * p.plate_shape[1], dtype=np.int64).reshape(p.plate_shape)
        nat = p.to_native(img)
        assert nat.shape == p.native_shape
        assert np.array_equal(p.from_native(nat), img)
        px, py = p.pixel_size
        for j, i in [(0, 0), (5, 2000), (1619 if name == "prusa-sl1s" else 1439, 2559), (700, 1234)]:
            r, c = _trafo_pixel(p, (i + 0.5) * px, p.display[1] - (j + 0.5) * py)
            assert nat[r, c] == img[j, i]


def test_sl1s_matches_the_measured_prusaslicer_export():
    """docs/formats.md §1.2: bed X 20.013..34.013, Y 10.021..27.021 mm landed at rows
    1879..2159, columns 200..540 of the 1620 x 2560 SL1S PNG."""
    p = PRINTERS["prusa-sl1s"]
    px, py = p.pixel_size
    X = (np.arange(p.pixels[0]) + 0.5) * px
    Y = p.display[1] - (np.arange(p.pixels[1]) + 0.5) * py
    plate = ((Y[:, None] >= 10.021) & (Y[:, None] <= 27.021) & (X >= 20.013) & (X <= 34.013)).astype(np.uint8)
    nat = p.to_native(plate)
    assert nat.shape == (2560, 1620)
    rows, cols = np.nonzero(nat)
    assert 1879 <= rows.min() and rows.max() <= 2159 and rows.max() - rows.min() >= 278
    assert 200 <= cols.min() and cols.max() <= 540 and cols.max() - cols.min() >= 338


@pytest.mark.parametrize("name", sorted(PRINTERS))
def test_native_round_trip(name):
    p = PRINTERS[name]
    small = type(p)(**{**p.__dict__, "pixels": (7, 5), "display": (0.7, 0.5)})
    img = np.random.default_rng(0).integers(0, 256, small.plate_shape, dtype=np.uint8)
    assert np.array_equal(small.from_native(small.to_native(img)), img)


# ---------------------------------------------------------------- placement through the CLI
def _plate_layers(path):
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("slices.json"))
        imgs = [np.asarray(Image.open(z.open(f))) for f in meta["files"]]
    return meta, imgs


def _centroid_mm(meta, img):
    rows, cols = np.nonzero(img >= 128)
    px, py = meta["pixel_size"]
    x0, y0 = meta["origin"][:2]
    return x0 + cols.mean() * px, y0 - rows.mean() * py


def test_centred_on_the_plate_bottom_at_zero(post, tmp_path):
    out = tmp_path / "c.zip"
    r = run("slice", post, "-o", out, "--printer", "prusa-sl1s", "--layer-height", "0.1", "-q")
    assert r.exit_code == 0, r.output
    meta, imgs = _plate_layers(out)
    assert (meta["width"], meta["height"]) == (2560, 1620)
    assert meta["origin"] == pytest.approx([0.025, 80.975, 0.05])
    assert meta["print"]["printer"] == "prusa-sl1s"
    x, y = _centroid_mm(meta, imgs[len(imgs) // 2])
    assert abs(x - 64.0) <= 0.5 * 0.05 + 1e-6 and abs(y - 40.5) <= 0.5 * 0.05 + 1e-6
    assert imgs[0].max() == 255 and imgs[-1].max() == 255          # no empty layer at either end
    assert abs(len(imgs) * 0.1 - 3.0) < 1.2                        # ~ the strut plus its caps


def test_at_places_the_axis_and_the_sl1s_pixel(post, tmp_path):
    """--at 30 20: the post's axis lands at plate (30, 20) mm, i.e. native SL1S
    column Y/0.05 - 1/2 = 399.5 and row 2560 - X/0.05 - 1/2 = 1959.5."""
    zp, sp = tmp_path / "a.zip", tmp_path / "a.sl1s"
    for out in (zp, sp):
        r = run("slice", post, "-o", out, "--printer", "prusa-sl1s", "--at", "30", "20", "--layer-height", "0.1",
                "-q")
        assert r.exit_code == 0, r.output
    meta, imgs = _plate_layers(zp)
    k = len(imgs) // 2
    x, y = _centroid_mm(meta, imgs[k])
    assert abs(x - 30) <= 0.026 and abs(y - 20) <= 0.026
    with zipfile.ZipFile(sp) as z:
        nat = np.asarray(Image.open(z.open(f"a{k:05d}.png")))
    rows, cols = np.nonzero(nat >= 128)
    assert abs(cols.mean() - 399.5) <= 0.52 and abs(rows.mean() - 1959.5) <= 0.52
    assert np.array_equal(nat, PRINTERS["prusa-sl1s"].to_native(imgs[k]))


def test_chirality_survives_placement(ell, tmp_path):
    """The +x arm points toward plate +X (columns), the +y arm toward plate +Y
    (rows up): no mirror in plate images; the printer's mirror is in to_native."""
    out = tmp_path / "e.zip"
    assert run("slice", ell, "-o", out, "--printer", "elegoo-mars-4-ultra", "--layer-height", "0.25",
               "-q").exit_code == 0
    meta, imgs = _plate_layers(out)
    post_x, post_y = _centroid_mm(meta, imgs[2])
    top = max(range(len(imgs)), key=lambda k: np.count_nonzero(imgs[k]))
    rows, cols = np.nonzero(imgs[top] >= 128)
    px, py = meta["pixel_size"]
    X = meta["origin"][0] + cols * px
    Y = meta["origin"][1] - rows * py
    assert X.max() - post_x == pytest.approx(2.5, abs=0.35)      # long arm toward +X (SIIS free ends are short)
    assert Y.max() - post_y == pytest.approx(1.2, abs=0.35)      # short arm toward +Y
    assert post_x - X.min() == pytest.approx(0.3, abs=0.1) and post_y - Y.min() == pytest.approx(0.3, abs=0.1)


def test_contours_are_placed_like_the_images(ell, tmp_path):
    """With --printer, a --contours side file and a CLI file hold plate mm and
    plate layers: filled at the plate's pixel centres they give the plate
    images, and the CLI box is the plate (its origin the plate's corner)."""
    import shapely

    from formats.common_layer import read_cli

    zp, cj, cl = tmp_path / "e.zip", tmp_path / "e.json", tmp_path / "e.cli"
    common = ["--printer", "prusa-sl1s", "--at", "30", "20", "--layer-height", "0.25", "-q"]
    r = run("slice", ell, "-o", zp, "--contours", cj, *common)
    assert r.exit_code == 0, r.output
    r = run("slice", ell, "-o", cl, *common)
    assert r.exit_code == 0, r.output
    meta, imgs = _plate_layers(zp)
    doc = json.loads(cj.read_text())
    cli = read_cli(cl)
    assert doc["skelslice"]["grid"]["origin"] == meta["origin"]
    assert len(doc["layers"]) == len(cli.layers) == len(imgs) == meta["layers"]
    assert np.allclose(cli.origin, 0.0)
    px, py = meta["pixel_size"]
    x0, y0 = meta["origin"][:2]
    rows, cols = np.nonzero(np.any(np.stack(imgs) >= 128, axis=0))
    r0, r1, c0, c1 = rows.min() - 3, rows.max() + 4, cols.min() - 3, cols.max() + 4
    X, Y = np.meshgrid(x0 + np.arange(c0, c1) * px, y0 - np.arange(r0, r1) * py)
    pts = shapely.points(X, Y)
    inside_total = 0
    for k, (lay, cli_lay, img) in enumerate(zip(doc["layers"], cli.layers, imgs)):
        assert lay["layer"] == k and lay["z"] == pytest.approx((k + 0.5) * 0.25)
        mp = shapely.MultiPolygon([shapely.Polygon(p[0], p[1:]) for p in lay["polygons"]])
        want = img[r0:r1, c0:c1] >= 128
        got = shapely.contains_xy(mp, X, Y)
        near = shapely.dwithin(mp.boundary, pts, 3e-3) if not mp.is_empty else np.zeros_like(want)
        assert np.array_equal(got[~near], want[~near]), k
        # the CLI (1 um units) holds the same region, on the plate too
        cm = cli_lay.multipolygon()
        assert shapely.symmetric_difference(cm, mp).area <= 2e-3 * max(mp.length, 1e-9)
        inside_total += int(want.sum())
    assert inside_total > 500
    # --at 30 20 centres the footprint there: so does the contours' box (to a pixel)
    allp = shapely.union_all([shapely.Polygon(p[0], p[1:]) for lay in doc["layers"] for p in lay["polygons"]])
    bx0, by0, bx1, by1 = allp.bounds
    assert abs(0.5 * (bx0 + bx1) - 30) <= px and abs(0.5 * (by0 + by1) - 20) <= py


def test_model_too_big_for_the_plate(tmp_path):
    scene = tmp_path / "long.json"
    Skeleton([[0, 0, 0], [150, 0, 0]], [[0, 1]], [[0.5, 0.5]]).save(scene)
    r = run("slice", scene, "-o", tmp_path / "x.sl1s", "--printer", "prusa-sl1s", "--layer-height", "0.5")
    assert_refused(r, "does not fit", "Original Prusa SL1S SPEED", "128 x 81 mm", "150.2")
    assert not (tmp_path / "x.sl1s").exists()


def test_at_off_the_plate(post, tmp_path):
    r = run("slice", post, "-o", tmp_path / "x.sl1s", "--printer", "prusa-sl1s", "--at", "0.1", "40",
            "--layer-height", "0.5")
    assert_refused(r, "outside the Original Prusa SL1S SPEED plate", "X 0..128, Y 0..81 mm")


def test_model_too_tall(tmp_path):
    scene = tmp_path / "tall.json"
    Skeleton([[0, 0, 0], [0, 0, 170]], [[0, 1]], [[0.5, 0.5]]).save(scene)
    r = run("slice", scene, "-o", tmp_path / "x.goo", "--printer", "elegoo-mars-4-ultra", "--layer-height", "2")
    assert_refused(r, "tall", "165 mm")


@pytest.mark.parametrize("args, needles", [
    (["--printer", "prusa-sl1s", "--pixel-size", "0.05"], ["--pixel-size cannot be combined"]),
    (["--printer", "prusa-sl1s", "--bounds", "0", "0", "0", "1", "1", "1"], ["--bounds cannot be combined"]),
    (["--pixel-size", "0.1", "--at", "1", "2"], ["--at needs --printer"]),
    (["--printer", "nope"], ["unknown printer", "prusa-sl1s", "elegoo-saturn-3-ultra"]),
    (["--format", "goo", "--pixel-size", "0.1"], ["goo format needs --printer"]),
    ([], ["--pixel-size is required without --printer"]),
    (["--printer", "prusa-sl1s", "--exposure", "90"], ["exposure 90 s", "0.1-60 s"]),
    (["--printer", "prusa-sl1s", "--bottom-layers", "1"], ["2-200"]),
    (["--pixel-size", "0.1", "--aa", "0"], ["--aa must be an integer from 1 to 16"]),
    (["--pixel-size", "0.1", "--aa", "2", "--gamma", "-1"], ["--gamma"]),
])
def test_option_errors(post, tmp_path, args, needles):
    out = tmp_path / ("x.sl1s" if "prusa-sl1s" in args else "x")
    r = run("slice", post, "-o", out, *args)
    assert_refused(r, *needles)
    assert not out.exists()


def test_printers_command_lists_the_table():
    r = run("printers")
    assert r.exit_code == 0
    for name in PRINTERS:
        assert name in r.output
    doc = json.loads(run("printers", "--json").output)
    assert doc["elegoo-saturn-3-ultra"]["pixel_size"] == pytest.approx([0.019, 0.024])
