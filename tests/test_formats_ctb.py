"""Chitubox CTB v3 and v2 read back by two independent readers.

* Our own reader (``tests/format_readers.py``), written from the public layout (catibo's
  ``cbddlp-ctb.adoc``; docs/printers.md): every header, print-parameter,
  slicer and layer-table field, the v3 per-layer records, the previews, and
  every layer (decrypted with the keystream recurrence written out here,
  RLE-decoded here) equal to the job's zip of plate images in the printer's
  native layout.
* uv3dp v1.2.12 (``uv3dp`` fixture): its command line converts our CTB to
  its ``.uvj`` (PNG layers plus JSON); every layer equals our PNG stack pixel
  for pixel and its header values equal what we set. uv3dp does not report
  the header's print time and volume: those are checked by our reader
  against :mod:`formats.estimate`.
"""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from format_readers import decode_rgb15, decode_rle7, read_ctb, reference_keystream
from formats.ctb import GREYS, KEY, cipher, encode_preview, encode_rle, keystream
from formats.estimate import print_estimate
from formats.printer_profiles import PRINTERS, PrintSettings
from helpers import run
from uv3dp_checks import uv3dp_convert, uv3dp_layers

COMMON = ["--printer", "elegoo-saturn", "--layer-height", "0.2", "--exposure", "2.2", "--bottom-exposure", "28",
          "--bottom-layers", "3", "-q"]


@pytest.fixture(scope="module")
def jobs(ell, tmp_path_factory):
    """One job as CTB v3, CTB v2 and a zip of plate images; and an anti-aliased one."""
    d = tmp_path_factory.mktemp("ctb")
    outs = {}
    for name, args in [("v3.ctb", []), ("v2.ctb", ["--format", "ctb-v2"]), ("plate.zip", []),
                       ("aa.ctb", ["--aa", "2", "--aa-z"]), ("aa.zip", ["--aa", "2", "--aa-z"])]:
        out = d / name
        r = run("slice", ell, "-o", out, *COMMON, *args)
        assert r.exit_code == 0, r.output
        outs[name] = out
    return outs


def plate_layers(path):
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("slices.json"))
        return meta, [np.asarray(Image.open(z.open(f))) for f in meta["files"]]


# ---------------------------------------------------------------- our reader (tests/format_readers.py)
@pytest.mark.parametrize("name, version", [("v3.ctb", 3), ("v2.ctb", 2), ("aa.ctb", 3)])
def test_our_reader_checks_every_field(jobs, name, version):
    p = PRINTERS["elegoo-saturn"]
    f = read_ctb(jobs[name])
    meta, plate = plate_layers(jobs["aa.zip" if name == "aa.ctb" else "plate.zip"])
    n = meta["layers"]
    assert f["magic"] == 0x12FD0086 and f["version"] == version
    assert f["bed"] == pytest.approx([192, 120, 200]) and (f["res_x"], f["res_y"]) == (3840, 2400)
    assert f["layers"] == n and f["layer_height"] == pytest.approx(0.2) and f["height"] == pytest.approx(0.2 * n)
    assert f["exposure"] == pytest.approx(2.2) and f["bottom_exposure"] == pytest.approx(28)
    assert f["bottom_layers"] == f["params"]["bottom_layers"] == 3
    assert f["projector"] == 1 and f["aa"] == 1 and (f["pwm"], f["bottom_pwm"]) == (255, 255)
    assert f["key"] == KEY != 0 and f["machine"] == "ELEGOO SATURN"
    assert f["aa_flag"] == (0x0F if name == "aa.ctb" else 0x07) and f["per_layer"] == (0x20 if version == 3 else 0)
    assert f["aa_level"] == (2 if name == "aa.ctb" else 1) and f["software"] == 0x01060300
    pr = f["params"]
    assert (pr["lift"], pr["lift_speed"], pr["retract_speed"]) == pytest.approx((7, 70, 210))
    assert (pr["bottom_lift"], pr["bottom_lift_speed"]) == pytest.approx((7, 70))
    assert pr["light_off"] == pr["bottom_light_off"] == f["light_off"] == 0
    assert pr["padding"] == ((0, 0, 0, 0x1234) if version == 2 else (0, 0, 0, 0))
    # print time and volume: the estimate of the plate images
    grey = sum(int(i.sum(dtype=np.uint64)) for i in plate)
    s = PrintSettings(p, 0.2, exposure=2.2, bottom_exposure=28, bottom_layers=3)
    est = print_estimate(s, n, grey)
    assert f["print_time"] == round(3 * 28 + (n - 3) * 2.2 + n * 60 * (7 / 70 + 7 / 210)) == round(est.seconds)
    assert pr["volume"] == pytest.approx(grey / 255 * 0.05 * 0.05 * 0.2 / 1000, rel=1e-6)
    assert pr["weight"] == pytest.approx(1.1 * pr["volume"], rel=1e-6)
    # the layer table and the v3 records
    for k, d in enumerate(f["layer_defs"]):
        assert d["z"] == pytest.approx(0.2 * (k + 1)) and d["exposure"] == pytest.approx(28 if k < 3 else 2.2)
        assert d["light_off"] == 0 and d["zeros"] == (0, 0, 0) and d["size"] == (84 if version == 3 else 36)
    if version == 3:
        for lift, speed, lift2, speed2, retract, *rest, pwm in f["ex"]:
            assert (lift, speed, retract, pwm) == pytest.approx((7, 70, 210, 255))
            assert lift2 == speed2 == 0 and not any(rest)
    else:
        assert f["ex"] == []
    # every layer: the plate image, in the native layout, at the nearest 7-bit grey
    for img, ref in zip(f["images"], plate):
        assert np.array_equal(img, GREYS.level[p.to_native(ref)])
    if name != "aa.ctb":
        assert all(np.array_equal(img, p.to_native(ref)) for img, ref in zip(f["images"], plate))   # binary: exact
    assert sorted(f["previews"]) == [(200, 125), (400, 300)]
    assert all(prev.max() > 0 for prev in f["previews"].values())                # the model is drawn


# ---------------------------------------------------------------- uv3dp
@pytest.mark.slow
@pytest.mark.parametrize("name", ["v3.ctb", "v2.ctb", "aa.ctb"])
def test_uv3dp_converts_our_ctb(uv3dp, jobs, tmp_path, name):
    """The uv3dp command line reads our CTB; its PNG layers equal our plate images in
    the native layout (at the nearest 7-bit grey) pixel for pixel."""
    p = PRINTERS["elegoo-saturn"]
    config, layers = uv3dp_convert(uv3dp, jobs[name], tmp_path / "out.uvj")
    meta, plate = plate_layers(jobs["aa.zip" if name == "aa.ctb" else "plate.zip"])
    prop = config["Properties"]
    size = prop["Size"]
    assert (size["X"], size["Y"], size["Layers"]) == (3840, 2400, meta["layers"])
    assert (size["Millimeter"]["X"], size["Millimeter"]["Y"]) == pytest.approx((192, 120))
    assert size["LayerHeight"] == pytest.approx(0.2)
    assert prop["Exposure"]["LightOnTime"] == pytest.approx(2.2)
    assert prop["Bottom"]["Count"] == 3 and prop["Bottom"]["LightOnTime"] == pytest.approx(28)
    assert (prop["Exposure"]["LiftHeight"], prop["Exposure"]["LiftSpeed"]) == pytest.approx((7, 70))
    assert prop["Exposure"]["RetractSpeed"] == pytest.approx(210)
    assert len(layers) == len(plate)
    for k, (theirs, ref, lay) in enumerate(zip(layers, plate, config["Layers"])):
        assert np.array_equal(theirs, GREYS.level[p.to_native(ref)]), f"layer {k}"
        assert lay["Z"] == pytest.approx(0.2 * (k + 1))
        assert lay["Exposure"]["LightOnTime"] == pytest.approx(28 if k < 3 else 2.2)
    assert sum(int(i.max() > 0) for i in layers) >= len(layers) - 2          # the model is there


@pytest.mark.slow
def test_uv3dp_layer_decoder_agrees(uv3dp, jobs):
    """uv3dp's decoders through uv3dp-layers: one SHA-256 per layer, the machine name."""
    from uv3dp_checks import sha256

    p = PRINTERS["elegoo-saturn"]
    doc = uv3dp_layers(uv3dp, jobs["aa.ctb"])
    _, plate = plate_layers(jobs["aa.zip"])
    assert doc["metadata"]["Machine"] == "ELEGOO SATURN" and set(doc["previews"]) == {"tiny", "huge"}
    assert doc["previews"]["huge"] == {"width": 400, "height": 300}
    assert [lay["sha256"] for lay in doc["layers"]] == [sha256(GREYS.level[p.to_native(i)]) for i in plate]


@pytest.mark.slow
def test_uv3dp_rejects_a_broken_ctb(uv3dp, jobs, tmp_path):
    data = bytearray(jobs["v3.ctb"].read_bytes())
    data[:4] = b"\0\0\0\0"
    (tmp_path / "magic.ctb").write_bytes(bytes(data))
    assert "magic" in uv3dp_layers(uv3dp, tmp_path / "magic.ctb", ok=False)["error"]


# ---------------------------------------------------------------- encoders
@settings(max_examples=150, deadline=None)
@given(st.integers(1, 30), st.integers(1, 40), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.2, 0.9]))
def test_rle_round_trip(H, W, seed, grey_share):
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((H, W)) < 0.5, 0, 127).astype(np.uint8)
    img = np.repeat(img, rng.integers(1, 5), axis=1)[:, :W]
    m = rng.random(img.shape) < grey_share
    img[m] = rng.integers(0, 128, m.sum())
    dec = decode_rle7(encode_rle(img), img.size).reshape(img.shape)
    assert np.array_equal(dec, np.where(img == 0, 0, 2 * img.astype(np.int64) + 1))


@pytest.mark.parametrize("length", [1, 2, 0x7F, 0x80, 0x3FFF, 0x4000, 0x1FFFFF, 0x200000])
def test_run_length_widths(length):
    img = np.full((1, length), 127, np.uint8)
    data = encode_rle(img)
    width = 0 if length == 1 else 1 if length <= 0x7F else 2 if length <= 0x3FFF else 3 if length <= 0x1FFFFF else 4
    assert len(data) == 1 + width
    assert np.array_equal(decode_rle7(data, length), np.full(length, 255, np.uint8))


@pytest.mark.parametrize("key, index", [(KEY, 0), (KEY, 7), (1, 123456), (0xFFFFFFFF, 3)])
def test_keystream_is_the_published_recurrence(key, index):
    assert keystream(key, index, 37).tobytes() == reference_keystream(key, index, 37)
    data = bytes(range(200))
    assert cipher(cipher(data, key, index), key, index) == data != cipher(data, key, index)
    assert cipher(data, 0, index) == data


def test_grey_levels_are_the_nearest_7_bit_ones():
    stored = {0} | {2 * c + 1 for c in range(1, 128)}
    for g in range(256):
        lv = int(GREYS.level[g])
        assert lv in stored and lv == (0 if GREYS.code[g] == 0 else 2 * GREYS.code[g] + 1)
        assert abs(lv - g) == min(abs(s - g) for s in stored)
        assert (lv >= 128) == (g >= 128)                     # the 50 % threshold is kept
    assert GREYS.level[0] == 0 and GREYS.level[255] == 255


def test_preview_round_trip():
    rng = np.random.default_rng(1)
    img = np.repeat(rng.integers(0, 256, (30, 12, 4)), 40, axis=1).astype(np.uint8)   # runs across rows
    img[3, :] = [255, 255, 255, 255]
    dec = decode_rgb15(encode_preview(img), img.shape[1], img.shape[0])
    assert np.array_equal(dec, img[..., :3] >> 3)


# ---------------------------------------------------------------- CLI
def test_ctb_needs_a_printer(ell, tmp_path):
    r = run("slice", ell, "-o", tmp_path / "x.ctb", "--pixel-size", "0.05")
    assert r.exit_code == 2 and "needs --printer" in r.output and not (tmp_path / "x.ctb").exists()


@pytest.mark.parametrize("args, needle", [
    # beyond float32 is beyond the magnitude every option is held to (slicer.arguments), refused first
    (["--exposure", "1e39"], "--exposure = 1e+39 s is beyond the supported magnitude 1e+09 s"),
    (["--bottom-layers", "5000000000"],
     "ctb: --bottom-layers must be an integer from 0 to 4294967295, got 5,000,000,000")])
def test_values_the_fields_cannot_hold_are_refused_before_work(ell, tmp_path, args, needle):
    r = run("slice", ell, "-o", tmp_path / "x.ctb", "--printer", "elegoo-saturn", *args)
    assert r.exit_code == 2 and needle in r.output
    assert not list(tmp_path.iterdir())


def test_same_bytes_whatever_the_thread_count(ell, tmp_path):
    outs = []
    for t in (1, 2):
        (tmp_path / f"t{t}").mkdir()
        out = tmp_path / f"t{t}" / "job.ctb"
        assert run("slice", ell, "-o", out, *COMMON, "--aa", "2", "--threads", t).exit_code == 0
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]
