"""NanoDLP archives (``.nanodlp``) read back three ways.

* Python (zipfile + PIL): member names, 1-based layers, RGB-packed mono PNGs
  (every byte one display pixel), every layer equal to the PNG stack (or,
  with ``--printer``, to the zip's plate images in the printer's native
  layout), manifest values equal to the options.
* ``info.json``'s islands and boxes against a slow breadth-first flood fill.
* The ``msla_format`` crate (``tests/readers``, the ``checker`` fixture): it
  parses every manifest with its serde structs and decodes every layer; its
  per-layer counts and position-weighted sums equal ours, and it rejects
  broken archives.
* Atomicity (an exception or SIGKILL mid-stack leaves nothing at the target)
  and byte-identical output whatever the thread count.
"""
from __future__ import annotations

import json
import math
import struct
import subprocess
import sys
import zipfile
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from formats.nanodlp import NanoDlpWriter, island_sizes, layer_info, pack_rgb, unpack_rgb
from formats.printer_profiles import PRINTERS
from helpers import run
from slicer.errors import OutputError
from slicer.tracer.grid import SliceGrid

#: X0 Y0 Z0 X1 Y1 Z1 of the plain job: 58 x 38 px at 0.05 mm (58 = 3 x 19 + 1:
#: the display is padded to 60 columns), 13 layers of 0.2 mm
BOUNDS = (-0.5, -0.5, -0.5, 2.4, 1.4, 2.1)
JSONS = ("meta.json", "info.json", "plate.json", "profile.json", "options.json", "slicer.json")


@pytest.fixture(scope="module")
def jobs(ell, tmp_path_factory):
    """The same model as a plain job (nanodlp + PNG stack) and on the SL1S
    plate (nanodlp + zip of plate images)."""
    d = tmp_path_factory.mktemp("nanodlp")
    plain = ["--pixel-size", "0.05", "--layer-height", "0.2", "--bounds", *BOUNDS, "--aa", "2",
             "--exposure", "3.5", "--bottom-exposure", "30", "--bottom-layers", "4"]
    sl1s = ["--printer", "prusa-sl1s", "--layer-height", "0.4"]
    outs = {}
    for name, args in [("p.nanodlp", plain), ("stack", plain), ("s.nanodlp", sl1s), ("s.zip", sl1s)]:
        out = d / name
        r = run("slice", ell, "-o", out, "-q", *args)
        assert r.exit_code == 0, r.output
        outs[name] = out
    return outs


def read_nanodlp(path):
    """(manifests dict, list of display images (PHeight, PWidth) uint8, member names)."""
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None
        docs = {n: json.loads(z.read(n)) for n in JSONS}
        n = docs["plate.json"]["LayersCount"]
        layers = []
        for k in range(1, n + 1):
            raw = z.read(f"{k}.png")
            assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR"
            w, h, depth, ctype = struct.unpack(">IIBB", raw[16:26])
            assert (depth, ctype) == (8, 2), "8-bit RGB"
            img = np.asarray(Image.open(z.open(f"{k}.png")))
            assert img.shape == (h, w, 3)
            layers.append(img.reshape(h, 3 * w))                    # R, G, B = display columns 3i, 3i+1, 3i+2
        return docs, layers, z.namelist()


def islands_reference(mask: np.ndarray) -> list[int]:
    """Sizes of the 8-connected components of ``mask`` by breadth-first flood
    fill, in the row-major order of each component's first pixel."""
    h, w = mask.shape
    seen = np.zeros(mask.shape, bool)
    sizes = []
    for r in range(h):
        for c in range(w):
            if not mask[r, c] or seen[r, c]:
                continue
            seen[r, c] = True
            todo, n = deque([(r, c)]), 0
            while todo:
                y, x = todo.popleft()
                n += 1
                for yy in (y - 1, y, y + 1):
                    for xx in (x - 1, x, x + 1):
                        if 0 <= yy < h and 0 <= xx < w and mask[yy, xx] and not seen[yy, xx]:
                            seen[yy, xx] = True
                            todo.append((yy, xx))
            sizes.append(n)
    return sizes


def info_reference(img: np.ndarray, pitch) -> dict:
    sizes = islands_reference(img > 0)
    rows, cols = np.nonzero(img)
    a = pitch[0] * pitch[1]
    if not sizes:
        return {"TotalSolidArea": 0.0, "LargestArea": 0.0, "SmallestArea": 0.0,
                "MinX": 0, "MinY": 0, "MaxX": 0, "MaxY": 0, "AreaCount": 0}
    return {"TotalSolidArea": sum(sizes) * a, "LargestArea": max(sizes) * a, "SmallestArea": min(sizes) * a,
            "MinX": int(cols.min()), "MinY": int(rows.min()), "MaxX": int(cols.max()) + 1,
            "MaxY": int(rows.max()) + 1, "AreaCount": len(sizes)}


def weighted_sum(img: np.ndarray) -> int:
    """sum(value x (row-major index + 1)) mod 2**64, as the checker computes it."""
    flat = img.ravel().astype(np.uint64)
    return int((flat * np.arange(1, flat.size + 1, dtype=np.uint64)).sum(dtype=np.uint64))


# ---------------------------------------------------------------- islands
@settings(max_examples=150, deadline=None)
@given(st.integers(1, 14), st.integers(1, 14), st.integers(0, 2**32 - 1), st.sampled_from([0.2, 0.45, 0.6]))
def test_island_sizes_equal_a_flood_fill(h, w, seed, share):
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((h, w)) < share, rng.integers(1, 256, (h, w)), 0).astype(np.uint8)
    assert island_sizes(img).tolist() == islands_reference(img > 0)


def test_island_sizes_diagonals_join_and_gaps_split():
    diag = np.eye(5, dtype=np.uint8) * 255                      # touching corners only: one island
    assert island_sizes(diag).tolist() == [5]
    assert island_sizes(diag[:, ::-1]).tolist() == [5]
    gap = np.array([[1, 0, 1, 0, 0],
                    [1, 0, 1, 0, 1],
                    [0, 0, 0, 0, 1]], np.uint8)                    # a one-pixel gap separates
    assert island_sizes(gap).tolist() == [2, 2, 2]
    u = np.array([[9, 0, 9],
                  [9, 0, 9],
                  [9, 9, 9]], np.uint8)                            # two arms joined below: one island
    assert island_sizes(u).tolist() == [7]
    assert island_sizes(np.zeros((3, 4), np.uint8)).tolist() == []


def test_layer_info_of_a_known_image():
    img = np.zeros((6, 9), np.uint8)
    img[1:3, 2:5] = 255                                          # 6 px
    img[4, 7] = 40                                               # 1 px, grey still counts
    info = layer_info(img, (0.05, 0.1))
    assert info == {"TotalSolidArea": pytest.approx(7 * 0.005), "LargestArea": pytest.approx(6 * 0.005),
                    "SmallestArea": pytest.approx(0.005), "MinX": 2, "MinY": 1, "MaxX": 8, "MaxY": 5,
                    "AreaCount": 2}
    assert layer_info(np.zeros((2, 3), np.uint8), (1, 1))["AreaCount"] == 0


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.integers(0, 2**32 - 1), st.booleans())
def test_layer_info_from_a_box_equals_the_full_scan(h, w, seed, loose):
    """With the box of its pixels (tight, or any box holding them), the info
    record is that of the whole image; with None, that of an empty one."""
    from formats.rle import occupied

    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.uint8)
    r0, c0 = int(rng.integers(0, h)), int(rng.integers(0, w))
    img[r0:r0 + 5, c0:c0 + 4] = np.where(rng.random(img[r0:r0 + 5, c0:c0 + 4].shape) < 0.6, 255, 0)
    box = occupied(img)
    if box is not None and loose:
        box = (max(box[0] - 2, 0), min(box[1] + 1, h), max(box[2] - 1, 0), min(box[3] + 3, w))
    assert layer_info(img, (0.05, 0.1), box=box) == layer_info(img, (0.05, 0.1))
    assert layer_info(img, (0.05, 0.1), box=None)["AreaCount"] == 0


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 9), st.integers(1, 7), st.integers(0, 2**32 - 1))
def test_pack_rgb_round_trip(h, w3, seed):
    img = np.random.default_rng(seed).integers(0, 256, (h, 3 * w3)).astype(np.uint8)
    rgb = pack_rgb(img)
    assert rgb.shape == (h, w3, 3)
    assert np.array_equal(rgb[:, 0, :], img[:, :3]) and np.array_equal(rgb[:, -1, :], img[:, -3:])
    assert np.array_equal(unpack_rgb(rgb), img)
    with pytest.raises(OutputError):
        pack_rgb(img[:, :-1])


# ---------------------------------------------------------------- plain job against the PNG stack
def test_layers_equal_the_png_stack(jobs):
    docs, layers, names = read_nanodlp(jobs["p.nanodlp"])
    ref = json.loads((jobs["stack"] / "slices.json").read_text())
    W, H, n = ref["width"], ref["height"], ref["layers"]
    assert (W, H, n) == (58, 38, 13)
    assert sorted(names) == sorted([*JSONS, "3d.png", *(f"{k}.png" for k in range(1, n + 1))])
    assert names[:n] == [f"{k}.png" for k in range(1, n + 1)]          # layers first: UVtools probes 1.png
    o = docs["options.json"]
    assert (o["PWidth"], o["PHeight"]) == (60, 38)                      # padded to a multiple of 3
    lit = 0
    for f, img in zip(ref["files"], layers):
        stack = np.asarray(Image.open(jobs["stack"] / f))
        assert img.shape == (38, 60)
        assert np.array_equal(img[:, :W], stack)
        assert not img[:, W:].any()
        lit += int(np.count_nonzero(stack))
    assert lit > 0
    greys = set(np.unique(np.concatenate([i.ravel() for i in layers])).tolist())
    assert len(greys) > 3                                               # --aa 2: real grey edges


def test_manifests_record_the_options(jobs):
    docs, layers, _ = read_nanodlp(jobs["p.nanodlp"])
    meta, o, prof, plate = docs["meta.json"], docs["options.json"], docs["profile.json"], docs["plate.json"]
    with zipfile.ZipFile(jobs["p.nanodlp"]) as z:
        assert z.read("options.json") == z.read("slicer.json")
        preview = Image.open(z.open("3d.png"))
        assert preview.size == (200, 100) and np.asarray(preview)[..., 3].max() == 255
    assert meta["FormatVersion"] == 2 and meta["Program"] == "skelslice" and meta["Profile"] is False
    assert o["Thickness"] == pytest.approx(200.0) and o["SupportDepth"] == 200
    assert o["XPixelSize"] == o["YPixelSize"] == pytest.approx(0.05)
    assert o["XRes"] == o["YRes"] == pytest.approx(50.0)
    assert o["SupportLayerNumber"] == 4 and o["AntiAlias"] == 2 and o["LayerCount"] == 13
    assert o["ImageMirror"] == 0 and o["DisplayController"] == 1
    assert prof["Depth"] == prof["SupportDepth"] == pytest.approx(200.0)
    assert prof["CureTime"] == pytest.approx(3.5) and prof["SupportCureTime"] == pytest.approx(30.0)
    assert prof["SupportLayerNumber"] == 4 and prof["Title"] == "skelslice"
    assert plate["LayersCount"] == 13 and plate["Processed"] is True
    assert plate["PrintEst"] == round(4 * 30 + 9 * 3.5)
    ml = sum(float(i.sum()) / 255 for i in layers) * 0.05 * 0.05 * 0.2 / 1000
    assert plate["TotalSolidArea"] == pytest.approx(ml, rel=1e-12)
    # the readers' number types: lengths and times are JSON floats, counts integers
    for doc, floats, ints in [(o, ("Thickness", "XPixelSize", "YPixelSize", "XRes", "YRes"),
                               ("PWidth", "PHeight", "SupportDepth", "LayerCount", "XOffset")),
                              (prof, ("Depth", "SupportDepth", "CureTime", "SupportCureTime"),
                               ("SupportLayerNumber", "AntiAlias")),
                              (plate, ("TotalSolidArea", "XMin", "XMax", "YMin", "YMax", "ZMin", "ZMax"),
                               ("LayersCount", "CreatedDate"))]:
        assert all(isinstance(doc[k], float) for k in floats), [k for k in floats if not isinstance(doc[k], float)]
        assert all(type(doc[k]) is int for k in ints)
    # bounding box, mm about the display centre (x right, y down), z over the stack
    rows = np.flatnonzero(np.any([i.any(axis=1) for i in layers], axis=0))
    cols = np.flatnonzero(np.any([i.any(axis=0) for i in layers], axis=0))
    assert plate["XMin"] == pytest.approx((cols[0] - 30) * 0.05) and plate["XMax"] == pytest.approx((cols[-1] - 29) * 0.05)
    assert plate["YMin"] == pytest.approx((rows[0] - 19) * 0.05) and plate["YMax"] == pytest.approx((rows[-1] - 18) * 0.05)
    assert (plate["ZMin"], plate["ZMax"]) == (0.0, pytest.approx(13 * 0.2))
    assert o["Boundary"] == {k: plate[k] for k in ("XMin", "XMax", "YMin", "YMax", "ZMin", "ZMax")}


def test_info_json_equals_a_flood_fill_reference(jobs):
    docs, layers, _ = read_nanodlp(jobs["p.nanodlp"])
    info = docs["info.json"]
    assert len(info) == len(layers)
    counts = set()
    for entry, img in zip(info, layers):
        ref = info_reference(img, (0.05, 0.05))
        assert entry == {k: (pytest.approx(v, rel=1e-12) if isinstance(v, float) else v) for k, v in ref.items()}
        counts.add(entry["AreaCount"])
    assert 1 in counts and max(counts) >= 1


# ---------------------------------------------------------------- printer job: native layout
def test_printer_job_stores_the_native_display(jobs):
    p = PRINTERS["prusa-sl1s"]
    docs, layers, _ = read_nanodlp(jobs["s.nanodlp"])
    with zipfile.ZipFile(jobs["s.zip"]) as z:
        meta = json.loads(z.read("slices.json"))
        plates = [np.asarray(Image.open(z.open(f))) for f in meta["files"]]
    assert len(layers) == len(plates) == meta["layers"] > 0
    for img, plate in zip(layers, plates):
        assert img.shape == p.native_shape == (2560, 1620)
        assert np.array_equal(p.from_native(img), plate)
    o, prof = docs["options.json"], docs["profile.json"]
    assert (o["PWidth"], o["PHeight"]) == (1620, 2560) and o["ImageMirror"] == 1
    assert o["XPixelSize"] == o["YPixelSize"] == pytest.approx(0.05) and o["Thickness"] == pytest.approx(400.0)
    assert prof["Title"] == p.label and prof["CureTime"] == pytest.approx(p.exposure)
    assert prof["SupportCureTime"] == pytest.approx(p.bottom_exposure)
    assert prof["SupportLayerNumber"] == p.bottom_layers
    for entry, img in zip(docs["info.json"], layers):
        rows, cols = np.nonzero(img)
        if rows.size == 0:
            assert entry["AreaCount"] == 0
            continue
        r0, c0 = rows.min(), cols.min()
        crop = img[r0:rows.max() + 1, c0:cols.max() + 1]                # the flood fill is slow: crop first
        ref = info_reference(crop, (0.05, 0.05))
        ref.update(MinX=ref["MinX"] + c0, MaxX=ref["MaxX"] + c0, MinY=ref["MinY"] + r0, MaxY=ref["MaxY"] + r0)
        assert entry == {k: (pytest.approx(v, rel=1e-12) if isinstance(v, float) else v) for k, v in ref.items()}


# ---------------------------------------------------------------- ImageMirror as a reader applies it
def reader_view(docs, layer):
    """A stored layer as UVtools presents it: its NanoDLP reader maps
    ``ImageMirror != 0`` to ``DisplayMirror = FlipDirection.Horizontally``
    (NanoDLPFile.cs), layer images are kept as stored (the LCD's own layout)
    and the layer preview flips them left-right back to the plate seen from
    above (LayerPreview.AutoFlipLayerIfMirrored). A file whose PNGs are
    already mirrored *and* that says ImageMirror = 1 is therefore consistent;
    mirroring the PNGs once more, or dropping the flag, shows a mirrored part."""
    return layer[:, ::-1] if docs["options.json"]["ImageMirror"] else layer


def _footprint_centre(images, pitch, height_mm):
    """Centre (X, Y) mm of the bounding box of every lit pixel, columns toward
    +X from X = 0 and rows toward -Y from Y = height_mm (the plate seen from above)."""
    rows = np.flatnonzero(np.any([i.any(axis=1) for i in images], axis=0))
    cols = np.flatnonzero(np.any([i.any(axis=0) for i in images], axis=0))
    x = 0.5 * (cols[0] + cols[-1] + 1) * pitch[0]
    y = height_mm - 0.5 * (rows[0] + rows[-1] + 1) * pitch[1]
    return x, y


@pytest.fixture(scope="module")
def landscape_jobs(ell, tmp_path_factory):
    """The chiral model off-centre on a landscape, X-mirrored display
    (Anycubic Photon Mono X, 3840 x 2400 px), as NanoDLP and as a PNG stack
    of plate images."""
    d = tmp_path_factory.mktemp("mirror")
    outs = {}
    for name, fmt in (("m.nanodlp", "nanodlp"), ("stack", "png")):
        out = d / name
        r = run("slice", ell, "-o", out, "-q", "--printer", "anycubic-photon-mono-x", "--at", "40", "30",
                "--layer-height", "0.4", "--format", fmt)
        assert r.exit_code == 0, r.output
        outs[name] = out
    return outs


def test_mirrored_display_is_not_mirrored_twice(landscape_jobs):
    """Read as UVtools reads it, every NanoDLP layer is the PNG stack's plate
    image, and the part's footprint is centred where --at put it (X 40, Y 30
    mm on a 192 x 120 mm plate; mirrored, it would be at X 152)."""
    p = PRINTERS["anycubic-photon-mono-x"]
    assert p.orientation == "landscape" and p.mirror_x
    docs, layers, _ = read_nanodlp(landscape_jobs["m.nanodlp"])
    assert docs["options.json"]["ImageMirror"] == 1
    stack = landscape_jobs["stack"]
    meta = json.loads((stack / "slices.json").read_text())
    plates = [np.asarray(Image.open(stack / f)) for f in meta["files"]]
    assert meta["pixel_size"] == pytest.approx(p.pixel_size) and len(layers) == len(plates) > 2
    assert meta["origin"][:2] == pytest.approx([0.5 * p.pixel_size[0], p.display[1] - 0.5 * p.pixel_size[1]])
    for img, plate in zip(layers, plates):
        assert img.shape == plate.shape == (2400, 3840)
        assert np.array_equal(reader_view(docs, img), plate)
    for images in ([reader_view(docs, i) for i in layers], plates):
        x, y = _footprint_centre(images, p.pixel_size, p.display[1])
        assert abs(x - 40) <= 0.5 * p.pixel_size[0] + 1e-9 and abs(y - 30) <= 0.5 * p.pixel_size[1] + 1e-9, (x, y)


def test_portrait_display_shows_a_rotation_not_a_mirror_image(jobs):
    """SL1S (portrait, X-mirrored): the reader's view of each layer is the
    plate image turned by a multiple of 90 degrees (a portrait display swaps
    the axes), never its mirror image."""
    docs, layers, _ = read_nanodlp(jobs["s.nanodlp"])
    with zipfile.ZipFile(jobs["s.zip"]) as z:
        meta = json.loads(z.read("slices.json"))
        plates = [np.asarray(Image.open(z.open(f))) for f in meta["files"]]
    assert docs["options.json"]["ImageMirror"] == 1
    turns = []
    for img, plate in zip(layers, plates):
        if not plate.any():
            continue
        view = reader_view(docs, img)
        assert not any(np.array_equal(view, np.rot90(plate[:, ::-1], k)) for k in range(4)), \
            "the reader sees the part mirrored"
        turns.append([k for k in range(4) if np.array_equal(view, np.rot90(plate, k))])
    assert len(turns) > 2 and all(t == turns[0] and len(t) == 1 for t in turns), turns


# ---------------------------------------------------------------- the msla_format crate
def _check(checker, path):
    r = subprocess.run([str(checker), "nanodlp", str(path)], capture_output=True, text=True, timeout=300)
    return r.returncode, json.loads(r.stdout)


@pytest.mark.parametrize("name", ["p.nanodlp", "s.nanodlp"])
def test_read_by_msla_format(checker, jobs, name):
    code, doc = _check(checker, jobs[name])
    assert code == 0, doc
    docs, layers, _ = read_nanodlp(jobs[name])
    o, prof, plate = docs["options.json"], docs["profile.json"], docs["plate.json"]
    assert doc["layer_count"] == len(layers) and doc["counts_ok"] and doc["layers_ok"]
    t = doc["options"]
    assert (t["p_width"], t["p_height"]) == (o["PWidth"], o["PHeight"])
    assert t["thickness_um"] == pytest.approx(o["Thickness"], rel=1e-6)
    assert t["x_pixel_size"] == pytest.approx(o["XPixelSize"], rel=1e-6)
    assert t["support_layer_number"] == o["SupportLayerNumber"] and t["layer_count"] == len(layers)
    assert t["image_mirror"] == o["ImageMirror"] and t["anti_alias"] == o["AntiAlias"]
    assert doc["meta"]["program"] == "skelslice" and doc["meta"]["format_version"] == 2
    p = doc["profile"]
    assert p["cure_time"] == pytest.approx(prof["CureTime"], rel=1e-6)
    assert p["support_cure_time"] == pytest.approx(prof["SupportCureTime"], rel=1e-6)
    assert p["support_layer_number"] == prof["SupportLayerNumber"] and p["title"] == prof["Title"]
    assert p["depth_um"] == pytest.approx(prof["Depth"], rel=1e-6)
    assert doc["plate"]["layers_count"] == len(layers)
    assert doc["plate"]["total_solid_area_ml"] == pytest.approx(plate["TotalSolidArea"], rel=1e-6)
    assert doc["preview"] == {"width": 200, "height": 100}
    for img, theirs, entry in zip(layers, doc["layers"], docs["info.json"]):
        assert theirs["ok"] and theirs["png_width"] * 3 == img.shape[1] and theirs["png_height"] == img.shape[0]
        assert theirs["pixels"] == img.size
        assert theirs["lit"] == int(np.count_nonzero(img))
        assert theirs["solid"] == int(np.count_nonzero(img >= 128))
        assert theirs["grey_sum"] == int(img.sum(dtype=np.uint64))
        assert int(theirs["weighted_sum"]) == weighted_sum(img)
        i = theirs["info"]
        assert (i["min_x"], i["min_y"], i["max_x"], i["max_y"], i["area_count"]) == \
            (entry["MinX"], entry["MinY"], entry["MaxX"], entry["MaxY"], entry["AreaCount"])
        assert i["total_solid_area"] == pytest.approx(entry["TotalSolidArea"], rel=1e-6)
        assert i["largest_area"] == pytest.approx(entry["LargestArea"], rel=1e-6)


def _rewrite(src, dst, drop=(), replace=None):
    replace = replace or {}
    with zipfile.ZipFile(src) as zi, zipfile.ZipFile(dst, "w") as zo:
        for info in zi.infolist():
            if info.filename not in drop:
                zo.writestr(info.filename, replace.get(info.filename, zi.read(info.filename)))


def test_msla_format_rejects_broken_archives(checker, jobs, tmp_path):
    src = jobs["p.nanodlp"]
    same = tmp_path / "same.nanodlp"
    _rewrite(src, same)
    assert _check(checker, same)[0] == 0                                # the rewrite itself is harmless
    with zipfile.ZipFile(src) as z:
        opts = json.loads(z.read("options.json"))
        png = z.read("2.png")
    opts["Thickness"] = 200                                             # an integer where a float is due
    cases = {"no_plate": {"drop": ("plate.json",)},
             "no_layer": {"drop": ("13.png",)},
             "int_thickness": {"replace": {"options.json": json.dumps(opts)}},
             "cut_png": {"replace": {"2.png": png[: len(png) // 2]}}}
    for name, kw in cases.items():
        bad = tmp_path / f"{name}.nanodlp"
        _rewrite(src, bad, **kw)
        code, doc = _check(checker, bad)
        assert code == 1 and "error" in doc, (name, doc)
    assert "float" in _check(checker, tmp_path / "int_thickness.nanodlp")[1]["error"]


# ---------------------------------------------------------------- atomicity, determinism, CLI
def _grid(width=7, height=5, layers=3):
    return SliceGrid((0.0, 0.0, 0.05), (0.05, 0.05), 0.1, width, height, layers)


def test_direct_writer_pads_and_publishes(tmp_path):
    out = tmp_path / "d.nanodlp"
    imgs = [np.zeros((5, 7), np.uint8) for _ in range(3)]
    imgs[1][2, 6] = 255                                                 # the last real column
    with NanoDlpWriter(out, _grid()) as w:
        for k, img in enumerate(imgs):
            w.write_layer(k, img)
    docs, layers, _ = read_nanodlp(out)
    assert docs["options.json"]["PWidth"] == 9 and layers[1].shape == (5, 9)
    assert layers[1][2, 6] == 255 and layers[1].sum() == 255
    assert docs["info.json"][1] == {"TotalSolidArea": pytest.approx(0.0025), "LargestArea": pytest.approx(0.0025),
                                    "SmallestArea": pytest.approx(0.0025), "MinX": 6, "MinY": 2, "MaxX": 7,
                                    "MaxY": 3, "AreaCount": 1}
    assert docs["profile.json"]["CureTime"] == 2.0 and docs["profile.json"]["SupportLayerNumber"] == 10


def test_failure_mid_stack_leaves_nothing(tmp_path):
    out = tmp_path / "f.nanodlp"
    with pytest.raises(RuntimeError):
        with NanoDlpWriter(out, _grid()) as w:
            w.write_layer(0, np.full((5, 7), 255, np.uint8))
            raise RuntimeError("interrupted")
    w = NanoDlpWriter(out, _grid())
    w.write_layer(0, np.zeros((5, 7), np.uint8))
    with pytest.raises(OutputError, match="1 of 3 layers"):
        w.close()
    assert list(tmp_path.iterdir()) == []


def test_same_bytes_whatever_the_thread_count(ell, tmp_path):
    outs = []
    for t in (1, 2):
        (tmp_path / f"t{t}").mkdir()
        out = tmp_path / f"t{t}" / "job.nanodlp"                     # same name: plate.json's Path
        assert run("slice", ell, "-o", out, "--pixel-size", "0.04", "--layer-height", "0.3", "--aa", "2",
                   "--aa-z", "--threads", t, "-q").exit_code == 0
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_existing_output_needs_force(ell, jobs):
    out = jobs["p.nanodlp"]
    before = out.read_bytes()
    r = run("slice", ell, "-o", out, "--pixel-size", "0.05")
    assert r.exit_code == 2 and "already exists" in r.output
    assert out.read_bytes() == before


def test_python_m_slicer_writes_nanodlp(ell, tmp_path):
    out = tmp_path / "sub.nanodlp"
    r = subprocess.run([sys.executable, "-m", "slicer", "slice", str(ell), "-o", str(out), "--pixel-size", "0.05",
                        "--layer-height", "0.4"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "[nanodlp]" in r.stdout
    docs, layers, _ = read_nanodlp(out)
    W, H = (int(v) for v in r.stdout.split(" px")[0].split(" x "))
    assert docs["options.json"]["PWidth"] == math.ceil(W / 3) * 3 and docs["options.json"]["PHeight"] == H
    assert len(layers) == docs["options.json"]["LayerCount"] > 0
