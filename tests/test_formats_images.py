"""Image-stack formats read back by independent readers: zip, SL1/SL1S, GOO.

* GOO: a decoder written from Elegoo's spec (docs/formats.md §2.1;
  ``tests/format_readers.py``), checking every header offset, record, checksum
  and pixel; plus the ``goo`` crate checker (``tests/readers``, built by the
  ``checker`` fixture where cargo exists).
* SL1/SL1S: every reader rule of docs/formats.md §1.3 (PrusaSlicer importer,
  Prusa firmware, UVtools) checked on our archives; uv3dp (the ``uv3dp``
  fixture) reads them as a second SL1 reader, every layer pixel for pixel;
  and, when the Debian ``prusa-slicer`` package is installed, ``prusa-slicer
  --load prusaslicer.ini`` accepts our profile (and rejects a corrupted one).
* zip: ``slices.json`` keys and the images equal the PNG stack's.
* Atomicity: a signalled process leaves nothing at the target (every printer
  format, CTB and Anycubic included).
"""
from __future__ import annotations

import configparser
import dataclasses
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from format_readers import goo_decode_rle, read_goo, read_goo_lazy
from formats.goo import HEADER_SIZE, GooWriter, encode_layer
from formats.printer_profiles import PRINTERS, PrintSettings
from helpers import missing_tool, run
from interrupting import interrupt_and_check, start_slice, wait_mid_write
from slicer import Skeleton
from slicer.tracer.grid import SliceGrid


@pytest.fixture(scope="module")
def jobs(ell, tmp_path_factory):
    """One job written as zip (plate images), sl1s and sl1 (native images)."""
    d = tmp_path_factory.mktemp("jobs")
    outs = {}
    for name, args in [("e.zip", ["--printer", "prusa-sl1s"]), ("e.sl1s", []),
                       ("e.sl1", []), ("aa.sl1s", ["--aa", "2"]), ("az.sl1s", ["--aa", "2", "--aa-z"])]:
        out = d / name
        r = run("slice", ell, "-o", out, "--layer-height", "0.2", "-q", *args)
        assert r.exit_code == 0, r.output
        outs[name] = out
    return outs


def _zip_plate_layers(path):
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("slices.json"))
        return meta, [np.asarray(Image.open(z.open(f))) for f in meta["files"]]


# ---------------------------------------------------------------- GOO (reader: tests/format_readers.py)
@settings(max_examples=120, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.3, 0.9]))
def test_goo_rle_round_trip(H, W, seed, grey_share):
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((H, W)) < 0.5, 0, 255).astype(np.uint8)
    img = np.repeat(img, rng.integers(1, 4), axis=1)[:, :W]
    m = rng.random(img.shape) < grey_share
    img[m] = rng.integers(0, 256, m.sum())
    payload, checksum = encode_layer(img)
    assert checksum == (~sum(payload)) & 0xFF
    assert np.array_equal(goo_decode_rle(payload, img.size).reshape(img.shape), img)


@pytest.mark.parametrize("length", [1, 15, 16, 4095, 4096, 0xFFFFF, 0xFFFFF + 1, 3 * 0xFFFFF])
def test_goo_run_length_widths(length):
    for v in (0, 255, 77):
        img = np.full((1, length), v, np.uint8)
        payload, _ = encode_layer(img)
        width = 0 if length <= 0xF else 1 if length <= 0xFFF else 2 if length <= 0xFFFFF else 3
        assert len(payload) == 1 + (v not in (0, 255)) + width
        assert np.array_equal(goo_decode_rle(payload, length), img.ravel())


def test_goo_file_read_back(ell, tmp_path):
    out = tmp_path / "e.goo"
    zp = tmp_path / "e.zip"
    common = ["--printer", "elegoo-saturn-3-ultra", "--layer-height", "0.4", "--exposure", "2.2",
              "--bottom-exposure", "28", "--bottom-layers", "3", "-q"]
    assert run("slice", ell, "-o", out, *common).exit_code == 0
    assert run("slice", ell, "-o", zp, *common).exit_code == 0
    p = PRINTERS["elegoo-saturn-3-ultra"]
    h, layers = read_goo_lazy(out)
    z = zipfile.ZipFile(zp)
    meta = json.loads(z.read("slices.json"))
    assert h["layers"] == meta["layers"]
    assert (h["x_res"], h["y_res"]) == (11520, 5120)
    assert (h["x_mirror"], h["y_mirror"]) == (True, False)
    assert (h["x_size"], h["y_size"]) == pytest.approx((218.88, 122.88))
    assert h["layer_h"] == pytest.approx(0.4) and h["exposure"] == pytest.approx(2.2)
    assert h["bottom_exposure"] == pytest.approx(28) and h["bottom_layers"] == 3
    assert h["grey_scale_level"] == 1 and h["printer_name"] == "ELEGOO Saturn 3 Ultra"
    ld, lv, rd, rv = p.lift                                             # the profile's motion
    assert h["lift"] == pytest.approx((ld, lv, ld, lv, rd, rv, rd, rv) + (0.0,) * 8)
    solid, n = 0, 0
    for k, (rec, img) in enumerate(layers):                            # one layer at a time (59 Mpx each)
        assert rec["z"] == pytest.approx(0.4 * (k + 1))
        assert rec["exposure"] == pytest.approx(28 if k < 3 else 2.2)
        assert (rec["lift"], rec["lift_speed"], rec["retract"], rec["retract_speed"]) == pytest.approx(p.lift)
        plate = np.asarray(Image.open(z.open(meta["files"][k])))
        assert np.array_equal(img, p.to_native(plate))
        solid += int(np.count_nonzero(img))
        n += 1
    assert n == meta["layers"] and solid > 0
    assert h["volume"] == pytest.approx(solid * 0.019 * 0.024 * 0.4, rel=1e-5)


def test_goo_read_by_the_goo_crate(checker, ell, tmp_path):
    out = tmp_path / "c.goo"
    assert run("slice", ell, "-o", out, "--printer", "elegoo-mars-4-ultra", "--layer-height", "0.25", "--aa", "2",
               "-q").exit_code == 0
    rep = subprocess.run([str(checker), "goo", str(out)], capture_output=True, text=True, timeout=300)
    assert rep.returncode == 0, rep.stdout + rep.stderr
    doc = json.loads(rep.stdout)
    h, layers = read_goo(out)
    assert doc["x_resolution"] == h["x_res"] and doc["layer_count"] == len(layers)
    for mine, theirs in zip(layers, doc["layers"]):
        img = mine[1]
        assert theirs["ok"] and theirs["checksum_ok"]
        assert theirs["pixels"] == img.size
        assert theirs["solid"] == int(np.count_nonzero(img >= 128))
        assert theirs["grey_sum"] == int(img.sum(dtype=np.uint64))


def _tiny_goo_printer():
    """A 30 x 20 px Elegoo-like display whose lift and retract values all differ."""
    return dataclasses.replace(PRINTERS["elegoo-mars-4-ultra"], name="tiny-goo", label="tiny", pixels=(30, 20),
                               display=(0.6, 0.5), max_height=40.0, lift=(6.5, 75.0, 4.5, 190.0))


def test_goo_header_and_layer_records_hold_the_settings(tmp_path):
    """Every motion and exposure field lands where the spec puts it (distinct
    values, so a swap of any two fails), the per-layer records agree with the
    header, and the header's print time and volume are what the records and
    images add up to."""
    p = _tiny_goo_printer()
    s = PrintSettings(p, 0.05, exposure=2.25, bottom_exposure=31.5, bottom_layers=3)
    grid = SliceGrid((0.01, 0.4875, 0.025), p.pixel_size, 0.05, 30, 20, 7)
    rng = np.random.default_rng(3)
    imgs = [np.where(rng.random((20, 30)) < 0.3, rng.integers(1, 256, (20, 30)), 0).astype(np.uint8)
            for _ in range(7)]
    out = tmp_path / "t.goo"
    with GooWriter(out, grid, {"generator": "skelslice 9.9"}, settings=s) as w:
        for k, img in enumerate(imgs):
            w.write_layer(k, img)
    h, layers = read_goo(out)
    assert h["layers"] == 7 and (h["x_res"], h["y_res"]) == (30, 20)
    assert h["exposure"] == 2.25 and h["bottom_exposure"] == 31.5 and h["bottom_layers"] == 3
    assert h["layer_h"] == pytest.approx(0.05) and h["z_size"] == 40.0
    assert (h["x_size"], h["y_size"]) == pytest.approx((0.6, 0.5))
    # bottom lift d, v; lift d, v; bottom retract d, v; retract d, v; then the unused second stage
    assert h["lift"] == (6.5, 75.0, 6.5, 75.0, 4.5, 190.0, 4.5, 190.0) + (0.0,) * 8
    assert h["pwm"] == (255, 255) and h["delay_mode"] == 1 and h["waits"] == (0.0,) * 7
    assert h["transition"] == 0 and h["grey_scale_level"] == 1 and h["aa"] == 1
    seconds = 0.0
    for k, ((rec, img), plate) in enumerate(zip(layers, imgs)):
        assert np.array_equal(img, p.to_native(plate))
        exp = 31.5 if k < 3 else 2.25
        assert rec == {"pause": 0, "pause_z": 40.0, "z": pytest.approx(0.05 * (k + 1)), "exposure": exp,
                       "off_time": 0.0, "before_lift": 0.0, "after_lift": 0.0, "after_retract": 0.0,
                       "lift": 6.5, "lift_speed": 75.0, "lift2": 0.0, "lift2_speed": 0.0,
                       "retract": 4.5, "retract_speed": 190.0, "retract2": 0.0, "retract2_speed": 0.0,
                       "pwm": 255}
        # what a reader adds up: exposure plus lift and retract moves at mm/min
        seconds += rec["exposure"] + 60 * (rec["lift"] / rec["lift_speed"] + rec["retract"] / rec["retract_speed"])
    assert h["time"] == round(seconds)
    grey = sum(float(i.sum()) / 255 for i in imgs)
    assert h["volume"] == pytest.approx(grey * 0.02 * 0.025 * 0.05, rel=1e-6)


def test_goo_settings_read_back_by_the_goo_crate(checker, tmp_path):
    """The goo crate's header and layer structs hold the same motion, exposure,
    time and volume values as our spec reader."""
    p = _tiny_goo_printer()
    s = PrintSettings(p, 0.05, exposure=2.25, bottom_exposure=31.5, bottom_layers=3)
    grid = SliceGrid((0.01, 0.4875, 0.025), p.pixel_size, 0.05, 30, 20, 5)
    out = tmp_path / "t.goo"
    with GooWriter(out, grid, {"generator": "skelslice 9.9"}, settings=s) as w:
        for k in range(5):
            w.write_layer(k, np.full((20, 30), 40 * k, np.uint8))
    rep = subprocess.run([str(checker), "goo", str(out)], capture_output=True, text=True, timeout=300)
    assert rep.returncode == 0, rep.stdout + rep.stderr
    doc = json.loads(rep.stdout)
    h, layers = read_goo(out)
    assert doc["layers_ok"] and doc["offset_ok"] and doc["size_ok"]
    assert (doc["exposure_time"], doc["bottom_exposure_time"], doc["bottom_layers"]) == (2.25, 31.5, 3)
    assert [doc[k] for k in ("bottom_lift_distance", "bottom_lift_speed", "lift_distance", "lift_speed",
                             "bottom_retract_distance", "bottom_retract_speed", "retract_distance",
                             "retract_speed")] == list(h["lift"][:8]) == [6.5, 75.0, 6.5, 75.0, 4.5, 190.0, 4.5, 190.0]
    assert doc["printing_time"] == h["time"] > 0
    assert doc["total_volume"] == pytest.approx(h["volume"], rel=1e-7)
    assert (doc["bottom_light_pwm"], doc["light_pwm"]) == h["pwm"]
    for (rec, _), theirs in zip(layers, doc["layers"]):
        assert theirs["exposure"] == rec["exposure"] and theirs["position_z"] == pytest.approx(rec["z"])
        assert (theirs["lift_distance"], theirs["lift_speed"], theirs["retract_distance"],
                theirs["retract_speed"]) == (rec["lift"], rec["lift_speed"], rec["retract"], rec["retract_speed"])


# ---------------------------------------------------------------- SL1 / SL1S reader rules
def _ini(text: str) -> dict:
    lines = text.splitlines()
    assert all(re.fullmatch(r"[A-Za-z_0-9]+ = .*", ln) for ln in lines), "key = value lines"
    keys = [ln.split(" = ", 1)[0] for ln in lines]
    assert keys == sorted(keys), "keys sorted"
    return dict(ln.split(" = ", 1) for ln in lines)


@pytest.mark.parametrize("name, model, printer", [("e.sl1s", "SL1S", "prusa-sl1s"), ("e.sl1", "SL1", "prusa-sl1"),
                                                  ("aa.sl1s", "SL1S", "prusa-sl1s")])
def test_sl1_reader_rules(jobs, name, model, printer):
    """docs/formats.md §1.3, rule by rule."""
    p = PRINTERS[printer]
    with zipfile.ZipFile(jobs[name]) as z:
        assert z.testzip() is None                                      # firmware CRC check
        names = z.namelist()
        cfg = _ini(z.read("config.ini").decode())                      # exact names
        prof = _ini(z.read("prusaslicer.ini").decode())                # UVtools needs both
        n = int(cfg["numFast"]) + int(cfg["numSlow"])
        # PrusaSlicer importer: every entry containing "png" but not "thumbnail" is a layer, sorted by name
        pz_layers = sorted(x for x in names if "png" in x.lower() and "thumbnail" not in x.lower())
        # firmware: entries ending .png that start with jobDir
        fw_layers = sorted(x for x in names if x.endswith(".png") and x.startswith(cfg["jobDir"]))
        assert pz_layers == fw_layers and len(fw_layers) == n > 0
        # UVtools: ([0-9]{5})[.]png$ and every index 0..N-1 present
        idx = sorted(int(m.group(1)) for x in names if (m := re.search(r"([0-9]{5})[.]png$", x))
                     and "thumbnail" not in x)
        assert idx == list(range(n))
        assert fw_layers == [f"{cfg['jobDir']}{k:05d}.png" for k in range(n)]
        # firmware: model and ranges
        assert cfg["printerModel"] == model and cfg["printerModel"] in ("SL1", "SL1S", "M1")
        assert 0.1 <= float(cfg["expTime"]) <= 60 and 0.1 <= float(cfg["expTimeFirst"]) <= 120
        assert 2 <= int(cfg["numFade"]) <= 200 and float(cfg["layerHeight"]) > 0.0099
        for key in ("action", "expUserProfile", "fileCreationTimestamp", "hollow", "printTime", "printerProfile",
                    "printerVariant", "prusaSlicerVersion", "usedMaterial", "materialName", "printProfile"):
            assert key in cfg
        assert re.fullmatch(r"\d{4}-\d\d-\d\d at \d\d:\d\d:\d\d UTC", cfg["fileCreationTimestamp"])
        # PrusaSlicer importer: profile keys (MissingProfileError otherwise) and slice parameters
        assert int(prof["display_pixels_x"]) == p.pixels[0] and int(prof["display_pixels_y"]) == p.pixels[1]
        assert float(prof["display_width"]) == pytest.approx(p.display[0])
        assert float(prof["display_height"]) == pytest.approx(p.display[1])
        assert prof["display_orientation"] == "portrait"
        assert prof["display_mirror_x"] == "1" and prof["display_mirror_y"] == "0"
        assert float(prof["layer_height"]) == float(prof["initial_layer_height"]) == pytest.approx(0.2)
        assert prof["printer_technology"] == "SLA" and prof["printer_model"] == model
        # layer PNGs: 8-bit greyscale (colour type 0, depth 8) of the rotated display
        for x in fw_layers[:3] + fw_layers[-2:]:
            raw = z.read(x)
            assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR"
            w, h, depth, ctype = struct.unpack(">IIBB", raw[16:26])
            assert (depth, ctype) == (8, 0)
            assert (h, w) == p.native_shape == (p.pixels[0], p.pixels[1])
        thumbs = [x for x in names if x.startswith("thumbnail/")]
        assert sorted(thumbs) == sorted(f"thumbnail/thumbnail{w}x{h}.png" for w, h in p.thumbnails)
        for t in thumbs:
            im = Image.open(z.open(t))
            assert im.mode == "RGBA" and f"{im.size[0]}x{im.size[1]}" in t
            assert np.asarray(im)[..., 3].max() == 255                 # the model is drawn


def test_sl1s_layers_round_trip_to_the_plate_images(jobs):
    p = PRINTERS["prusa-sl1s"]
    meta, plate = _zip_plate_layers(jobs["e.zip"])
    with zipfile.ZipFile(jobs["e.sl1s"]) as z:
        cfg = _ini(z.read("config.ini").decode())
        assert cfg["jobDir"] == "e"
        for k, img in enumerate(plate):
            nat = np.asarray(Image.open(z.open(f"e{k:05d}.png")))
            assert np.array_equal(p.from_native(nat), img)
    ml = sum(float(np.count_nonzero(i)) for i in plate) * 0.05 * 0.05 * 0.2 / 1000
    assert float(cfg["usedMaterial"]) == pytest.approx(ml, abs=5e-7)            # printed as %.6f ml
    assert int(cfg["numSlow"]) == 0                                     # a tiny model never fills 50 %


@pytest.fixture(scope="module")
def exposure_jobs(ell, tmp_path_factory):
    """SL1S jobs with distinct exposure options: the base, +1 s normal
    exposure, +10 s bottom exposure; and the base as a zip (layer count)."""
    d = tmp_path_factory.mktemp("exposure")
    base = {"--exposure": 3.5, "--bottom-exposure": 27.0, "--bottom-layers": 4}
    outs = {}
    for name, change in [("base.sl1s", {}), ("exp.sl1s", {"--exposure": 4.5}),
                         ("bottom.sl1s", {"--bottom-exposure": 37.0}), ("base.zip", {})]:
        opts = {**base, **change}
        out = d / name
        args = [a for kv in opts.items() for a in kv] + (["--printer", "prusa-sl1s"] if name.endswith(".zip") else [])
        r = run("slice", ell, "-o", out, "--layer-height", "0.05", "-q", *args)
        assert r.exit_code == 0, r.output
        outs[name] = out
    return outs


def _sl1(path):
    with zipfile.ZipFile(path) as z:
        cfg = _ini(z.read("config.ini").decode())
        prof = _ini(z.read("prusaslicer.ini").decode())
        layers = [np.asarray(Image.open(z.open(x))) for x in sorted(z.namelist())
                  if re.fullmatch(r"[A-Za-z0-9_-]+\d{5}\.png", x)]
    return cfg, prof, layers


def test_sl1_config_records_the_exposure_options(exposure_jobs):
    """--exposure, --bottom-exposure and --bottom-layers land in the firmware's
    (config.ini) and PrusaSlicer's (prusaslicer.ini) fields; the layer count,
    layer height and resin volume are those of the images."""
    cfg, prof, layers = _sl1(exposure_jobs["base.sl1s"])
    assert (float(cfg["expTime"]), float(cfg["expTimeFirst"]), int(cfg["numFade"])) == (3.5, 27.0, 4)
    assert (float(prof["exposure_time"]), float(prof["initial_exposure_time"]), int(prof["faded_layers"])) == \
        (3.5, 27.0, 4)
    with zipfile.ZipFile(exposure_jobs["base.zip"]) as z:
        n = json.loads(z.read("slices.json"))["layers"]
    assert len(layers) == n == int(cfg["numFast"]) + int(cfg["numSlow"]) > 8
    assert float(cfg["layerHeight"]) == float(prof["layer_height"]) == 0.05
    ml = sum(float(i.sum()) / 255 for i in layers) * 0.05 * 0.05 * 0.05 / 1000
    assert float(cfg["usedMaterial"]) == pytest.approx(ml, abs=5e-7)
    assert ml > 1e-3


def test_sl1_print_time_follows_the_exposures(exposure_jobs):
    """printTime (s) grows by 1 s per normal layer when the normal exposure
    grows by 1 s (by at least every layer after the faded ones, at most all
    of them), and by at most 10 s per faded layer when the bottom exposure
    grows by 10 s: a print time that ignored an exposure, or swapped the two,
    fails. It also covers at least the exposure of every layer."""
    cfg, _, layers = _sl1(exposure_jobs["base.sl1s"])
    n, fade = len(layers), int(cfg["numFade"])
    t = float(cfg["printTime"])
    t_exp = float(_sl1(exposure_jobs["exp.sl1s"])[0]["printTime"])
    t_bottom = float(_sl1(exposure_jobs["bottom.sl1s"])[0]["printTime"])
    assert (n - fade) * 1.0 - 1e-5 <= t_exp - t <= n * 1.0 + 1e-5
    assert 0.0 < t_bottom - t <= fade * 10.0 + 1e-5
    assert t >= (n - fade) * 3.5 + fade * 3.5


@pytest.mark.parametrize("name", ["aa.sl1s", "az.sl1s"])
def test_sl1s_aa_layers_are_grey_and_threshold_like_the_binary_job(jobs, name):
    with zipfile.ZipFile(jobs[name]) as z, zipfile.ZipFile(jobs["e.sl1s"]) as zb:
        prof = _ini(z.read("prusaslicer.ini").decode())
        assert prof["gamma_correction"] == "1"
        greys, diff, total = set(), 0, 0
        stem = name.split(".")[0]
        names = sorted(x for x in z.namelist() if re.fullmatch(stem + r"\d{5}\.png", x))
        assert len(names) == sum(1 for x in zb.namelist() if re.fullmatch(r"e\d{5}\.png", x))
        for x in names:
            a = np.asarray(Image.open(z.open(x)))
            greys |= set(np.unique(a).tolist())
            b = np.asarray(Image.open(zb.open("e" + x[len(stem):])))
            diff += int(np.count_nonzero((a >= 128) != (b >= 128)))
            total += int(np.count_nonzero(b))
        assert len(greys) > 3                                            # real grey edge pixels
        assert diff < 0.1 * total                                        # same shape at the 128 threshold


@pytest.mark.slow
@pytest.mark.parametrize("name, printer", [("e.sl1", "prusa-sl1"), ("e.sl1s", "prusa-sl1s"), ("az.sl1s", "prusa-sl1s")])
def test_sl1_read_by_uv3dp(uv3dp, jobs, tmp_path, name, printer):
    """uv3dp's SL1 reader (the ``uv3dp`` fixture) as a second SL1 reader: its command
    line converts our archive to its .uvj; every layer equals our PNG pixel for pixel
    and the sizes and exposures are ours. uv3dp takes the ``.sl1`` suffix only (an
    SL1S archive has the same layout) and reads SL1 as portrait (X = display_pixels_y);
    it counts numFast layers and takes numSlow as its bottom count, numFade as fade."""
    from uv3dp_checks import uv3dp_convert

    p = PRINTERS[printer]
    src = tmp_path / "job.sl1"
    shutil.copy(jobs[name], src)
    config, layers = uv3dp_convert(uv3dp, src, tmp_path / "job.uvj")
    with zipfile.ZipFile(jobs[name]) as z:
        cfg = _ini(z.read("config.ini").decode())
        ours = [np.asarray(Image.open(z.open(f"{cfg['jobDir']}{k:05d}.png")))
                for k in range(int(cfg["numFast"]) + int(cfg["numSlow"]))]
    prop = config["Properties"]
    size = prop["Size"]
    assert int(cfg["numSlow"]) == 0 and size["Layers"] == len(ours) > 3
    assert (size["X"], size["Y"]) == (p.pixels[1], p.pixels[0])
    assert (size["Millimeter"]["X"], size["Millimeter"]["Y"]) == pytest.approx((p.display[1], p.display[0]))
    assert size["LayerHeight"] == pytest.approx(0.2)
    assert prop["Exposure"]["LightOnTime"] == pytest.approx(p.exposure)
    assert prop["Bottom"]["LightOnTime"] == pytest.approx(p.bottom_exposure)
    assert prop["Bottom"]["Transition"] == p.bottom_layers
    for k, (theirs, mine) in enumerate(zip(layers, ours)):
        assert np.array_equal(theirs, mine), f"layer {k}"
    assert len({int(v) for img in layers for v in np.unique(img)}) > (3 if name.startswith("az") else 1)


def _stl_box(path):
    import trimesh

    trimesh.creation.box(extents=(6, 3, 2)).apply_translation((30, 20, 1)).export(path)   # X 27..33, Y 18.5..21.5


@pytest.mark.slow
def test_prusaslicer_loads_our_profile(jobs, tmp_path):
    """`prusa-slicer --config-compatibility disable --load prusaslicer.ini` accepts our
    profile and exports with it; a corrupted value is rejected (exit != 0); and
    PrusaSlicer rasterises a box exactly where Printer.to_native puts it."""
    if shutil.which("prusa-slicer") is None:
        missing_tool("prusa-slicer not installed (Debian: apt-get install --no-install-recommends prusa-slicer)")
    with zipfile.ZipFile(jobs["e.sl1s"]) as z:
        ini = z.read("prusaslicer.ini").decode()
    good, bad, stl = tmp_path / "good.ini", tmp_path / "bad.ini", tmp_path / "box.stl"
    good.write_text(ini)
    bad.write_text(ini.replace("display_orientation = portrait", "display_orientation = sideways"))
    _stl_box(stl)
    env = {**os.environ, "HOME": str(tmp_path)}
    cmd = ["prusa-slicer", "--config-compatibility", "disable", "--export-sla", "--dont-arrange"]
    ok = subprocess.run(cmd + ["--load", str(good), str(stl), "--output", str(tmp_path / "ref.sl1s")],
                        capture_output=True, text=True, timeout=300, env=env)
    assert ok.returncode == 0, ok.stdout[-2000:] + ok.stderr[-2000:]
    with zipfile.ZipFile(tmp_path / "ref.sl1s") as z:
        ref = configparser.ConfigParser()
        ref.read_string("[p]\n" + z.read("prusaslicer.ini").decode())
        assert ref["p"]["display_pixels_x"] == "2560" and ref["p"]["display_orientation"] == "portrait"
        assert ref["p"]["layer_height"] == "0.2"
        layer = np.asarray(Image.open(z.open("ref00004.png")))
    p = PRINTERS["prusa-sl1s"]
    X = (np.arange(p.pixels[0]) + 0.5) * 0.05
    Y = 81 - (np.arange(p.pixels[1]) + 0.5) * 0.05
    plate = (X >= 27) & (X <= 33) & (Y[:, None] >= 18.5) & (Y[:, None] <= 21.5)
    assert layer.shape == p.native_shape
    assert np.array_equal(layer >= 128, p.to_native(plate))
    nok = subprocess.run(cmd + ["--load", str(bad), str(stl), "--output", str(tmp_path / "bad.sl1s")],
                         capture_output=True, text=True, timeout=300, env=env)
    assert nok.returncode != 0


# ---------------------------------------------------------------- zip
def test_zip_equals_the_png_stack(ell, tmp_path):
    zp, d = tmp_path / "s.zip", tmp_path / "stack"
    for out in (zp, d):
        assert run("slice", ell, "-o", out, "--pixel-size", "0.05", "--layer-height", "0.2", "-q").exit_code == 0
    meta, imgs = _zip_plate_layers(zp)
    ref = json.loads((d / "slices.json").read_text())
    assert meta == ref
    for f, img in zip(ref["files"], imgs):
        assert np.array_equal(np.asarray(Image.open(d / f)), img)
    with zipfile.ZipFile(zp) as z:
        assert z.testzip() is None
        for f in ref["files"]:
            assert (d / f).read_bytes() == z.read(f)


def test_format_inference_and_force(ell, tmp_path):
    out = tmp_path / "job.SL1S"
    r = run("slice", ell, "-o", out, "--layer-height", "0.4")
    assert r.exit_code == 0 and "[sl1s]" in r.output
    assert zipfile.is_zipfile(out)
    r = run("slice", ell, "-o", out, "--layer-height", "0.4")
    assert r.exit_code == 2 and "already exists" in r.output
    assert run("slice", ell, "-o", out, "--layer-height", "0.4", "--force", "-q").exit_code == 0
    other = tmp_path / "noext"
    r = run("slice", ell, "-o", other, "--printer", "elegoo-mars-4-ultra", "--layer-height", "0.4")
    assert r.exit_code == 0 and "[goo]" in r.output                     # the printer's default format
    assert other.read_bytes()[:4] == b"V3.0"


def test_same_bytes_whatever_the_thread_count(ell, tmp_path):
    for ext in ("sl1s", "goo"):
        outs = []
        for t in (1, 2):
            (tmp_path / f"t{t}").mkdir(exist_ok=True)
            out = tmp_path / f"t{t}" / f"job.{ext}"                     # same name: the SL1 jobDir
            args = ["--printer", "elegoo-mars-4-ultra"] if ext == "goo" else []
            assert run("slice", ell, "-o", out, "--layer-height", "0.4", "--threads", t, "--aa", "2", "-q",
                       *args).exit_code == 0
            outs.append(out.read_bytes())
        assert outs[0] == outs[1]


def test_python_m_slicer_writes_sl1s(ell, tmp_path):
    out = tmp_path / "sub.sl1s"
    r = subprocess.run([sys.executable, "-m", "slicer", "slice", str(ell), "-o", str(out), "--printer",
                        "prusa-sl1s", "--layer-height", "0.4", "--aa", "2"], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert "2560 x 1620 px" in r.stdout and "[sl1s]" in r.stdout
    with zipfile.ZipFile(out) as z:
        assert z.testzip() is None and "config.ini" in z.namelist()


#: printer of each format in the signal test, and the temporary-file size that means layers are being written
#: (past the placeholder header and layer table the format writes first)
KILL_JOBS = {"sl1s": ("prusa-sl1s", 50_000), "goo": ("elegoo-saturn-3-ultra", HEADER_SIZE + 500),
             "zip": ("prusa-sl1s", 50_000), "nanodlp": ("prusa-sl1s", 50_000),
             "ctb": ("elegoo-saturn", 248 + 13 + 36 * 3000 + 20_000), "pwmx": ("anycubic-photon-mono-x", 250_000),
             "pws": ("anycubic-photon-s", 250_000)}
SIGNAL_CASES = [(ext, signal.SIGKILL) for ext in sorted(KILL_JOBS)] + \
    [(ext, sig) for ext in ("goo", "ctb", "pwmx") for sig in (signal.SIGINT, signal.SIGTERM)]


@pytest.mark.parametrize("ext, sig", SIGNAL_CASES, ids=[f"{e}-{s.name}" for e, s in SIGNAL_CASES])
def test_signal_mid_write_leaves_no_output(tmp_path, ext, sig):
    """A signal while the printer file's layers are written: nothing appears
    at the target (SIGINT/SIGTERM also remove the temporary; see
    interrupting.interrupt_and_check). The PNG stack is interrupted in
    test_cli_scale."""
    scene = tmp_path / "tall.json"
    n = 30                                                  # a 60 mm post of 2 mm segments: 3000 layers
    Skeleton([[0, 0, 2.0 * i] for i in range(n + 1)], [[i, i + 1] for i in range(n)], [[0.5, 0.5]] * n).save(scene)
    out = tmp_path / f"out.{ext}"
    printer, started = KILL_JOBS[ext]
    proc = start_slice(scene, out, "-q", "--layer-height", "0.02", "--printer", printer)
    wait_mid_write(proc, out, size=started)
    interrupt_and_check(proc, out, sig)
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == ["tall.json"]


# ----------------------------------------------------------------------------- layer PNGs
def _png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """Chunks of a PNG, each CRC checked (PNG 1.2 §5)."""
    import zlib

    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, out = 8, []
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(kind + body), kind
        out.append((kind, body))
        pos += 12 + n
    return out


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 70), st.integers(1, 70), st.booleans(), st.integers(0, 2**32 - 1))
def test_layer_pngs_decode_to_the_image(h, w, rgb, seed):
    import io
    import zlib

    from formats.base import png_bytes

    rng = np.random.default_rng(seed)
    shape = (h, w, 3) if rgb else (h, w)
    img = np.where(rng.random(shape) < 0.5, 0, 255).astype(np.uint8)
    img[rng.random(shape) < 0.1] = rng.integers(1, 255)           # some grey too
    data = png_bytes(img)
    decoded = Image.open(io.BytesIO(data))
    assert decoded.mode == ("RGB" if rgb else "L")
    assert np.array_equal(np.asarray(decoded), img)
    chunks = _png_chunks(data)
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    assert struct.unpack(">IIBBBBB", chunks[0][1]) == (w, h, 8, 2 if rgb else 0, 0, 0, 0)
    rows = np.frombuffer(zlib.decompress(chunks[1][1]), np.uint8).reshape(h, -1)
    assert np.all(rows[:, 0] == 0) and np.array_equal(rows[:, 1:].reshape(shape), img)


@pytest.mark.parametrize("bad", [np.zeros((2, 3, 4), np.uint8), np.zeros(5, np.uint8), np.zeros((0, 4), np.uint8)])
def test_layer_png_refuses_what_it_cannot_hold(bad):
    from formats.base import png_bytes
    from slicer.errors import FormatError

    with pytest.raises(FormatError, match="PNG"):
        png_bytes(bad)


def _decoded_png(data):
    """Pixels of a layer PNG, by Pillow and by inflating its IDAT here (with
    the zlib checksum and the chunk CRCs checked); the two must agree."""
    import io
    import zlib

    chunks = _png_chunks(data)
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    w, h, depth, colour = struct.unpack(">IIBB", chunks[0][1][:10])
    raw = zlib.decompress(chunks[1][1])          # raises on a bad stream or Adler-32
    rows = np.frombuffer(raw, np.uint8).reshape(h, -1)
    assert np.all(rows[:, 0] == 0)
    mine = rows[:, 1:].reshape((h, w, 3) if colour == 2 else (h, w))
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(data))), mine)
    return mine


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.booleans(), st.integers(0, 2**32 - 1))
def test_a_layer_png_from_its_box_has_the_same_pixels(h, w, rgb, seed):
    """Only the box that holds the model is read (transposed, flipped views
    too), and the zero rows around it are not deflated again: other deflate
    bytes, the same pixels."""
    from formats.base import png_bytes
    from formats.rle import occupied

    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3) if rgb else (h, w), np.uint8)
    r0, c0 = int(rng.integers(0, h)), int(rng.integers(0, w))
    img[r0:r0 + 4, c0:c0 + 6] = rng.integers(0, 256, img[r0:r0 + 4, c0:c0 + 6].shape)
    views = [img, img[::-1, ::-1]] + ([] if rgb else [img.T])
    for v in views:
        box = occupied(v.any(axis=2) if rgb else v)
        assert np.array_equal(_decoded_png(png_bytes(v, box=box)), v)
        assert np.array_equal(_decoded_png(png_bytes(v)), v)
    assert not _decoded_png(png_bytes(np.zeros_like(img), box=None)).any()


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3000), st.integers(1, 300), st.integers(0, 40), st.integers(0, 40), st.booleans(),
       st.integers(0, 2**32 - 1))
def test_sparse_png_rows_of_zeros_are_spliced_in_correctly(h, w, bh, bw, rgb, seed):
    """``png_bytes_sparse``: the zero rows are cached deflate pieces joined
    at full flushes and their Adler-32 is computed, not summed; tall images
    cross several piece sizes. The PNG decodes to the image with the block
    pasted in, and a block that does not fit is refused."""
    from formats.base import png_bytes_sparse
    from slicer.errors import FormatError

    rng = np.random.default_rng(seed)
    bh, bw = min(bh, h), min(bw, w)
    block = rng.integers(0, 256, (bh, bw, 3) if rgb else (bh, bw)).astype(np.uint8)
    r0, c0 = int(rng.integers(0, h - bh + 1)), int(rng.integers(0, w - bw + 1))
    want = np.zeros((h, w, 3) if rgb else (h, w), np.uint8)
    want[r0:r0 + bh, c0:c0 + bw] = block
    assert np.array_equal(_decoded_png(png_bytes_sparse(h, w, block, (r0, c0))), want)
    if bh and bw:
        with pytest.raises(FormatError, match="does not fit"):
            png_bytes_sparse(h, w, block, (h - bh + 1, c0))
        with pytest.raises(FormatError, match="does not fit"):
            png_bytes_sparse(h, w, block, (r0, -1))


def test_each_layer_png_takes_the_smaller_deflate_strategy():
    """A sparse plate row (a short part in a long empty row) deflates several
    times smaller with runs; a dense lattice, whose rows repeat rows above
    it, smaller with zlib's default search. Each layer gets the better one
    (sampled on its middle rows), and both decode to the image."""
    import zlib

    from formats.base import PNG_LEVEL, _strategy, png_bytes

    rng = np.random.default_rng(3)
    sparse = np.zeros((400, 6000), np.uint8)
    for r in range(150, 250):
        c = 2900 + int(rng.integers(0, 40))
        sparse[r, c:c + 60 + int(rng.integers(0, 40))] = 255
    cell = (rng.random((7, 43)) < 0.4).astype(np.uint8) * 255
    dense = np.tile(cell, (60, 100))
    sizes = {}
    for name, img in (("sparse", sparse), ("dense", dense)):
        rows = np.zeros((img.shape[0], 1 + img.shape[1]), np.uint8)
        rows[:, 1:] = img
        sizes[name] = {}
        for strategy in (zlib.Z_RLE, zlib.Z_DEFAULT_STRATEGY):
            c = zlib.compressobj(PNG_LEVEL, zlib.DEFLATED, 15, 8, strategy)
            sizes[name][strategy] = len(c.compress(rows.data) + c.flush())
        data = png_bytes(img)
        assert np.array_equal(_decoded_png(data), img)
        assert len(data) < 1.1 * min(sizes[name].values()) + 100
        sizes[name]["chosen"] = _strategy(rows, PNG_LEVEL)
    assert sizes["sparse"][zlib.Z_RLE] * 2 < sizes["sparse"][zlib.Z_DEFAULT_STRATEGY]
    assert sizes["sparse"]["chosen"] == zlib.Z_RLE
    assert sizes["dense"][zlib.Z_DEFAULT_STRATEGY] * 2 < sizes["dense"][zlib.Z_RLE]
    assert sizes["dense"]["chosen"] == zlib.Z_DEFAULT_STRATEGY


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 200_000))
def test_adler32_of_appended_zeros_matches_zlib(data, n):
    import zlib

    from formats.base import _adler32_zeros

    assert _adler32_zeros(zlib.adler32(data), n) == zlib.adler32(data + bytes(n))
