"""Image-stack formats read back by independent readers: zip, SL1/SL1S, GOO.

* GOO: a decoder written here from Elegoo's spec (formats.md §2.1), checking
  every header offset, record, checksum and pixel; plus the ``goo`` crate
  checker (``tests/readers``, built by the ``checker`` fixture where cargo exists).
* SL1/SL1S: every reader rule of formats.md §1.3 (PrusaSlicer importer,
  Prusa firmware, UVtools) checked on our archives; and, when the Debian
  ``prusa-slicer`` package is installed, ``prusa-slicer --load
  prusaslicer.ini`` accepts our profile (and rejects a corrupted one).
* zip: ``slices.json`` keys and the images equal the PNG stack's.
* Atomicity: a signalled process leaves nothing at the target.
"""
from __future__ import annotations

import configparser
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from formats.goo import HEADER_SIZE, encode_layer
from interrupting import interrupt_and_check, start_slice, wait_mid_write
from formats.printers import PRINTERS
from slicer import Skeleton
from slicer.cli import main



def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def ell(tmp_path_factory):
    """A small chiral model: a post with a long +x arm and a short +y arm."""
    p = tmp_path_factory.mktemp("ell") / "ell.json"
    Skeleton([[0, 0, 0], [0, 0, 1.6], [2.0, 0, 1.6], [0, 1.0, 1.6]], [[0, 1], [1, 2], [1, 3]],
             [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3]]).save(p)
    return p


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


# ---------------------------------------------------------------- GOO reader (from the spec)
def goo_decode_rle(data: bytes, n_pixels: int) -> np.ndarray:
    """Decode a GOO layer payload (all four chunk types) to a flat uint8 array."""
    out = np.zeros(n_pixels, np.uint8)
    pos, i, colour = 0, 0, 0
    while i < len(data):
        b0 = data[i]
        kind, width, low = b0 >> 6, (b0 >> 4) & 3, b0 & 0xF
        i += 1
        if kind == 2:                                  # diff from the previous pixel
            diff = low if not (b0 & 0x20) else -low
            colour += diff
            if b0 & 0x10:
                length = data[i]
                i += 1
            else:
                length = 1
        else:
            if kind == 1:
                colour = data[i]
                i += 1
            else:
                colour = 0 if kind == 0 else 255
            length = low
            for e in range(width):                     # big-endian extra bytes, most significant first
                length += data[i] << (4 + 8 * (width - 1 - e))
                i += 1
        assert length > 0, "zero-length run"
        assert pos + length <= n_pixels, "runs overflow the image"
        out[pos:pos + length] = colour
        pos += length
    assert pos == n_pixels, f"runs cover {pos} of {n_pixels} pixels"
    return out


def read_goo(path):
    """Parse a whole GOO file; returns (header dict, list of (record dict, image))."""
    h, layers = read_goo_lazy(path)
    return h, list(layers)


def read_goo_lazy(path):
    """Parse a GOO file: (header dict, iterator of (record dict, image)), one layer at a time."""
    raw = Path(path).read_bytes()
    h = {}
    assert raw[0:4] == b"V3.0"
    assert raw[4:12] == bytes([7, 0, 0, 0, 0x44, 0x4C, 0x50, 0])
    assert raw[27106:27108] == b"\r\n" and raw[195308:195310] == b"\r\n"
    h["printer_name"] = raw[92:124].split(b"\0")[0].decode()
    h["aa"], h["grey"], h["blur"] = struct.unpack_from(">3H", raw, 188)
    h["layers"], h["x_res"], h["y_res"] = struct.unpack_from(">IHH", raw, 195310)
    h["x_mirror"], h["y_mirror"] = struct.unpack_from(">??", raw, 195318)
    h["x_size"], h["y_size"], h["z_size"], h["layer_h"], h["exposure"] = struct.unpack_from(">5f", raw, 195320)
    h["delay_mode"] = raw[195340]
    h["bottom_exposure"], h["bottom_layers"] = struct.unpack_from(">fI", raw, 195369)
    h["lift"] = struct.unpack_from(">16f", raw, 195377)
    h["pwm"] = struct.unpack_from(">HH", raw, 195441)
    h["time"], h["volume"] = struct.unpack_from(">If", raw, 195446)
    assert struct.unpack_from(">I", raw, 195470)[0] == HEADER_SIZE
    h["grey_scale_level"] = raw[195474]
    h["transition"] = struct.unpack_from(">H", raw, 195475)[0]
    return h, _goo_layers(raw, h)


def _goo_layers(raw, h):
    off = HEADER_SIZE
    for k in range(h["layers"]):
        f = struct.unpack_from(">H15fH", raw, off)
        rec = {"pause": f[0], "pause_z": f[1], "z": f[2], "exposure": f[3], "lift": f[8], "pwm": f[16]}
        off += 2 + 60 + 2
        assert raw[off:off + 2] == b"\r\n"
        (n,) = struct.unpack_from(">I", raw, off + 2)
        assert raw[off + 6] == 0x55
        payload = raw[off + 7:off + 7 + n - 2]
        checksum = raw[off + 7 + n - 2]
        assert checksum == (~sum(payload)) & 0xFF, f"layer {k}: bad checksum"
        assert raw[off + 5 + n + 1:off + 5 + n + 3] == b"\r\n"
        off += 5 + n + 3
        yield rec, goo_decode_rle(payload, h["x_res"] * h["y_res"]).reshape(h["y_res"], h["x_res"])
    assert raw[off:] == bytes([0, 0, 0, 7, 0, 0, 0, 0x44, 0x4C, 0x50, 0]), "ending string"


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
    solid, n = 0, 0
    for k, (rec, img) in enumerate(layers):                            # one layer at a time (59 Mpx each)
        assert rec["z"] == pytest.approx(0.4 * (k + 1))
        assert rec["exposure"] == pytest.approx(28 if k < 3 else 2.2)
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
    """formats.md §1.3, rule by rule."""
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


def _stl_box(path):
    import trimesh

    trimesh.creation.box(extents=(6, 3, 2)).apply_translation((30, 20, 1)).export(path)   # X 27..33, Y 18.5..21.5


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("prusa-slicer") is None,
                    reason="prusa-slicer not installed (Debian: apt-get install --no-install-recommends prusa-slicer)")
def test_prusaslicer_loads_our_profile(jobs, tmp_path):
    """`prusa-slicer --config-compatibility disable --load prusaslicer.ini` accepts our
    profile and exports with it; a corrupted value is rejected (exit != 0); and
    PrusaSlicer rasterises a box exactly where Printer.to_native puts it."""
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


@pytest.mark.parametrize("ext, sig", [("sl1s", signal.SIGKILL), ("nanodlp", signal.SIGKILL),
                                      ("goo", signal.SIGKILL), ("goo", signal.SIGINT), ("goo", signal.SIGTERM)],
                         ids=["sl1s-kill", "nanodlp-kill", "goo-kill", "goo-int", "goo-term"])
def test_signal_mid_write_leaves_no_output(tmp_path, ext, sig):
    """A signal while the printer file's layers are written: nothing appears
    at the target (SIGINT/SIGTERM also remove the temporary; see
    interrupting.interrupt_and_check). The zip and PNG stack writers are
    interrupted in test_cli_scale."""
    scene = tmp_path / "tall.json"
    n = 30                                                  # a 60 mm post of 2 mm segments: 3000 layers
    Skeleton([[0, 0, 2.0 * i] for i in range(n + 1)], [[i, i + 1] for i in range(n)], [[0.5, 0.5]] * n).save(scene)
    out = tmp_path / f"out.{ext}"
    args = ["--printer", "elegoo-saturn-3-ultra"] if ext == "goo" else ["--printer", "prusa-sl1s"]
    proc = start_slice(scene, out, "-q", "--layer-height", "0.02", *args)
    wait_mid_write(proc, out, size=HEADER_SIZE + 500 if ext == "goo" else 50_000)
    interrupt_and_check(proc, out, sig)
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == ["tall.json"]
