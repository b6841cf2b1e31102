"""Anycubic Photon Workshop files (pws, pw0 and the mono-LCD versions) read back.

* Our own reader (``tests/format_readers.py``), written from the public layout (UVtools
  ``AnycubicFile``, PrusaSlicer ``AnycubicSLA``; docs/printers.md), for every
  machine of :data:`formats.photon.MACHINES`: the file mark, every named table
  (name, length, fields), and every layer decoded here equal to the job's zip
  of plate images in the printer's native layout.
* uv3dp v1.2.12 reads the version-1 files (``.pws``, ``.pw0``); no
  independent reader of the mono-LCD versions (516-518) exists here, so those
  share the container and ``pw0`` layer code that uv3dp checks on ``.pw0``,
  and the rest is checked field by field by our reader. uv3dp's command line
  returns empty pws/pw0 layers (its reader's decoder is ``Print.Image``, not
  the ``LayerImage`` the converter calls): ``uv3dp-layers`` calls uv3dp's
  decoder directly.
"""
from __future__ import annotations

import dataclasses
import json
import struct
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from format_readers import decode_pw0, decode_pws, layer_images, read_photon, reference_crc
from formats.photon import MACHINES, PHOTON_WRITERS, PW0_GREYS, encode_pw0, encode_pws, pws_greys
from formats.printer_profiles import PRINTERS, PrintSettings
from slicer.errors import FormatError
from helpers import run
from uv3dp_checks import sha256, uv3dp_convert, uv3dp_layers

SETTINGS = ["--layer-height", "0.2", "--exposure", "2.4", "--bottom-exposure", "33", "--bottom-layers", "2", "-q"]
JOBS = [(name, []) for name in MACHINES] + [(name, ["--aa", "2"]) for name in ("pws", "pw0", "pwmx")]
#: per suffix: file version, display (columns, rows) and machine name, as UVtools' printer profiles
#: (FILEFORMAT_*, FILEVERSION_*, display_pixels_*) and AnycubicFile name them
UVTOOLS = {"pws": (1, (1440, 2560), "Photon S"), "pw0": (1, (480, 854), "Photon Zero"),
           "pwmo": (516, (1620, 2560), "Photon Mono"), "pwma": (516, (3840, 2400), "Photon Mono 4K"),
           "pwmx": (516, (3840, 2400), "Photon Mono X"), "pwmb": (516, (5760, 3600), "Photon Mono X 6K"),
           "pm5s": (518, (11520, 5120), "Photon Mono M5s")}


@pytest.fixture(scope="module")
def jobs(ell, tmp_path_factory):
    """Every machine's file (its default printer) and a zip of the same plate images."""
    d = tmp_path_factory.mktemp("photon")
    outs = {}
    for name, extra in JOBS:
        key = name + ("-aa" if extra else "")
        f, z = d / f"{key}.{name}", d / f"{key}.zip"
        assert run("slice", ell, "-o", f, *SETTINGS, *extra).exit_code == 0
        r = run("slice", ell, "-o", z, "--printer", MACHINES[name].printer, *SETTINGS, *extra)
        assert r.exit_code == 0, r.output
        outs[key] = (f, z)
    return outs


def plate_layers(path):
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("slices.json"))
        return meta, [np.asarray(Image.open(z.open(f))) for f in meta["files"]]


# ---------------------------------------------------------------- our reader (tests/format_readers.py)
@pytest.mark.parametrize("key", [name + ("-aa" if extra else "") for name, extra in JOBS])
def test_our_reader_checks_every_field(jobs, key):
    name = key.split("-")[0]
    m, aa = MACHINES[name], key.endswith("-aa")
    p = PRINTERS[m.printer]
    path, zp = jobs[key]
    meta, plate = plate_layers(zp)
    n = meta["layers"]
    f = read_photon(path, n)
    version, pixels, label = UVTOOLS[name]
    assert f["version"] == version and f["tables"] == {1: 4, 516: 8, 517: 9, 518: 11}[version]
    rows, cols = p.native_shape
    assert (f["res_x"], f["res_y"]) == (cols, rows) == pixels
    assert f["pixel_um"] == pytest.approx(max(p.pixel_size) * 1000)
    assert f["layer_height"] == pytest.approx(0.2) and f["exposure"] == pytest.approx(2.4)
    assert f["bottom_exposure"] == pytest.approx(33) and f["bottom_layers"] == 2.0
    lift_d, lift_v, _, retract_v = p.lift
    assert (f["lift"], f["lift_speed"], f["retract_speed"]) == pytest.approx((lift_d, lift_v / 60, retract_v / 60))
    assert f["wait"] == pytest.approx(2.5) and f["currency"] == ord("$")
    planes = (8 if aa else 1) if m.encoding == "pws" else 1
    assert f["aa"] == ((8 if m.encoding == "pws" else 16) if aa else 1)
    assert f["per_layer"] == f["transition"] == f["transition_type"] == 0 and not any(f["rest"])
    # print time and volume: the estimate of the plate images
    grey = sum(int(i.sum(dtype=np.uint64)) for i in plate)
    px, py = p.pixel_size
    assert f["volume"] == pytest.approx(grey / 255 * px * py * 0.2 / 1000, rel=1e-6)
    assert f["weight"] == pytest.approx(1.1 * f["volume"], rel=1e-6)
    seconds = 2 * 33 + (n - 2) * 2.4 + n * (2.5 + 60 * (lift_d / lift_v + lift_d / retract_v))
    assert f["print_time"] == round(seconds)
    assert f["preview"] == (224, 42 if version == 1 else ord("x"), 168)
    # layer table, then every layer: the plate image in the native layout at the nearest stored grey
    greys = pws_greys(planes) if m.encoding == "pws" else PW0_GREYS
    images = layer_images(f, m.encoding, planes)
    at = f["addr"]["image"]
    for k, ((addr, size, lift, speed, exposure, height, lit, pad), img, ref) in \
            enumerate(zip(f["layers"], images, plate)):
        assert addr == at and (lift, speed) == pytest.approx((lift_d, lift_v / 60))
        assert exposure == pytest.approx(33 if k < 2 else 2.4) and height == pytest.approx(0.2) and pad == 0
        want = greys.level[p.to_native(ref)]
        assert np.array_equal(img, want), f"layer {k}"
        assert lit == np.count_nonzero(p.to_native(ref))
        at += size
    assert at == len(f["raw"])
    if not aa:
        assert all(np.array_equal(img, p.to_native(ref)) for img, ref in zip(images, plate))   # binary: exact
    if version >= 516:
        use_full, count, table_greys, unknown = f["colours"]
        assert (use_full, count, unknown) == (0, 16, 0)
        assert table_greys == ([15 + 16 * i for i in range(16)] if aa else [255] * 16)
        assert f["extra"] == pytest.approx((2, lift_d, lift_v / 60, retract_v / 60, 0, lift_v / 60, retract_v / 60,
                                            2, lift_d, lift_v / 60, retract_v / 60, 0, lift_v / 60, retract_v / 60))
        assert f["machine"] == label and f["image_format"] == "pw0Img"
        max_aa, fields, w, h, z, maxver, bg = f["machine_fields"]
        assert (max_aa, fields, maxver, bg) == (16, {516: 1, 517: 7, 518: 15}[version], version, 6506241)
        assert (w, h, z) == pytest.approx((p.display[0], p.display[1], p.max_height))
    if version >= 518:
        pw, ph, *pad, count, pad9, res_x, res_y, p10, p11, p12, p13 = f["machine_518"]
        assert (pw, ph) == pytest.approx((px * 1000, py * 1000)) and (res_x, res_y) == pixels and count == 1
        assert f["sublayers"] == [(a, s, lit) for a, s, *_, lit, _ in f["layers"]]
        assert f["preview2"] == (320, 4293, 0, 190)
    if version >= 517:
        x0, y0, z0, x1, y1, z1, supports, density = f["model"]
        rows_any = np.flatnonzero(np.any([p.to_native(i).any(axis=1) for i in plate], axis=0))
        cols_any = np.flatnonzero(np.any([p.to_native(i).any(axis=0) for i in plate], axis=0))
        assert x0 == pytest.approx(cols_any[0] * px - p.display[0] / 2, abs=1e-4)
        assert x1 == pytest.approx((cols_any[-1] + 1) * px - p.display[0] / 2, abs=1e-4)
        assert y0 == pytest.approx(rows_any[0] * py - p.display[1] / 2, abs=1e-4)
        assert (z0, z1) == pytest.approx((0, 0.2 * n)) and supports == 0


# ---------------------------------------------------------------- uv3dp (version 1)
@pytest.mark.slow
@pytest.mark.parametrize("key", ["pws", "pws-aa", "pw0", "pw0-aa"])
def test_uv3dp_reads_pws_and_pw0(uv3dp, jobs, key):
    m = MACHINES[key.split("-")[0]]
    p = PRINTERS[m.printer]
    path, zp = jobs[key]
    meta, plate = plate_layers(zp)
    doc = uv3dp_layers(uv3dp, path)
    assert doc["decoder"] == "Image"                       # uv3dp's own pws/pw0 decoder
    size = doc["size"]
    assert (size["X"], size["Y"], size["Layers"]) == (*UVTOOLS[m.name][1], meta["layers"])
    assert (size["Millimeter"]["X"], size["Millimeter"]["Y"]) == pytest.approx(p.display, rel=1e-2)
    assert size["LayerHeight"] == pytest.approx(0.2)
    assert doc["exposure"]["LightOnTime"] == pytest.approx(2.4) and doc["exposure"]["LightOffTime"] == 2.5
    assert doc["bottom"]["Count"] == 2 and doc["bottom"]["LightOnTime"] == pytest.approx(33)
    assert doc["exposure"]["LiftHeight"] == pytest.approx(p.lift[0])
    assert doc["exposure"]["LiftSpeed"] == pytest.approx(p.lift[1]) and doc["exposure"]["RetractSpeed"] == \
        pytest.approx(p.lift[3])
    assert doc["previews"] == {"tiny": {"width": 224, "height": 168}}
    planes = 8 if key == "pws-aa" else 1
    greys = pws_greys(planes) if m.encoding == "pws" else PW0_GREYS
    assert [lay["sha256"] for lay in doc["layers"]] == [sha256(greys.level[p.to_native(i)]) for i in plate]
    for k, lay in enumerate(doc["layers"]):
        assert lay["exposure"]["LightOnTime"] == pytest.approx(33 if k < 2 else 2.4)
        assert lay["z"] == pytest.approx(0.2 * (k + 1))
    assert sum(lay["lit"] > 0 for lay in doc["layers"]) >= len(plate) - 2


@pytest.mark.slow
def test_uv3dp_checks_the_pw0_checksum(uv3dp, jobs, tmp_path):
    path, _ = jobs["pw0"]
    f = read_photon(path, len(plate_layers(jobs["pw0"][1])[1]))
    addr, size, *_ = f["layers"][3]
    data = bytearray(path.read_bytes())
    data[addr + size - 1] ^= 0xFF                           # the CRC's low byte
    bad = tmp_path / "bad.pw0"
    bad.write_bytes(bytes(data))
    assert "checksum" in uv3dp_layers(uv3dp, bad, ok=False)["error"]


@pytest.mark.slow
def test_uv3dp_command_line_returns_empty_pws_layers(uv3dp, jobs, tmp_path):
    """Why uv3dp-layers exists: the command line's converter gets empty pws layers
    (uv3dp's pws reader has Image, not LayerImage), though the file holds the model."""
    _, layers = uv3dp_convert(uv3dp, jobs["pws"][0], tmp_path / "s.uvj")
    assert all(img.max() == 0 for img in layers)
    assert max(lay["lit"] for lay in uv3dp_layers(uv3dp, jobs["pws"][0])["layers"]) > 0


# ---------------------------------------------------------------- encoders
@settings(max_examples=150, deadline=None)
@given(st.integers(1, 30), st.integers(1, 40), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.3, 0.9]),
       st.booleans())
def test_pw0_round_trip(H, W, seed, grey_share, crc):
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((H, W)) < 0.5, 0, 15).astype(np.uint8)
    img = np.repeat(img, rng.integers(1, 40), axis=1)[:, :W]
    m = rng.random(img.shape) < grey_share
    img[m] = rng.integers(0, 16, m.sum())
    data = encode_pw0(img, crc=crc)
    dec, used = decode_pw0(data, img.size)
    assert np.array_equal(dec.reshape(img.shape), 17 * img)
    assert used == len(data) - 2 * crc
    if crc:
        assert struct.unpack(">H", data[used:])[0] == reference_crc(data[:used])


@pytest.mark.parametrize("length", [1, 15, 16, 4095, 4096, 3 * 4095 + 7])
def test_pw0_run_lengths(length):
    for c in (0, 15, 7):
        data = encode_pw0(np.full((1, length), c, np.uint8))
        per = 4095 if c in (0, 15) else 15
        assert len(data) == -(-length // per) * (2 if c in (0, 15) else 1)
        assert np.array_equal(decode_pw0(data, length)[0], np.full(length, 17 * c, np.uint8))


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 20), st.integers(1, 300), st.sampled_from([1, 2, 4, 8]), st.integers(0, 2**32 - 1))
def test_pws_round_trip(H, W, planes, seed):
    rng = np.random.default_rng(seed)
    counts = np.repeat(rng.integers(0, planes + 1, (H, 1 + W // 50)), 50, axis=1)[:, :W].astype(np.uint8)
    dec = decode_pws(encode_pws(counts, planes), counts.size, planes).reshape(counts.shape)
    want = np.where(counts > 0, counts.astype(np.int64) * (256 // planes) - 1, 0)
    assert np.array_equal(dec, want)
    assert set(np.unique(want).tolist()) <= set(pws_greys(planes).level.tolist())


def test_crc_table_is_the_published_one():
    from formats.photon import CRC_TABLE, crc16

    assert CRC_TABLE[:8].tolist() == [0x0000, 0xC0C1, 0xC181, 0x0140, 0xC301, 0x03C0, 0x0280, 0xC241]
    assert CRC_TABLE[-1] == 0x4040
    data = bytes(range(256)) * 3
    assert crc16(data) == reference_crc(data)


# ---------------------------------------------------------------- refusals and profiles
def test_a_display_the_machine_cannot_hold_is_refused_before_work(ell, tmp_path):
    r = run("slice", ell, "-o", tmp_path / "x.pwmx", "--printer", "elegoo-saturn-3-ultra")
    assert r.exit_code == 2 and "3840 x 2400 px" in r.output and "11520 x 5120" in r.output
    assert not list(tmp_path.iterdir())
    r = run("slice", ell, "-o", tmp_path / "x.pws", "--printer", "anycubic-photon-mono-x")
    assert r.exit_code == 2 and "Photon S" in r.output


def test_bottom_layers_beyond_the_float_field_are_refused(ell, tmp_path):
    r = run("slice", ell, "-o", tmp_path / "x.pwmx", "--bottom-layers", "20000000")
    assert r.exit_code == 2 and "pwmx: --bottom-layers must be an integer from 0 to 16777216" in r.output
    assert not list(tmp_path.iterdir())


def test_version_1_refuses_non_square_pixels():
    p = dataclasses.replace(PRINTERS["anycubic-photon-s"], display=(68.04, 140.0))
    with pytest.raises(FormatError, match="one pixel size"):
        PHOTON_WRITERS["pws"].check_settings(PrintSettings(p, 0.05))
    square = dataclasses.replace(PRINTERS["anycubic-photon-mono-m5s"])
    PHOTON_WRITERS["pm5s"].check_settings(PrintSettings(square, 0.05))   # 19 x 24 um: version 518 holds both


@pytest.mark.parametrize("printer, fmt", [("anycubic-photon-mono-x", "pwmx"), ("anycubic-photon-mono-m5s", "pm5s")])
def test_existing_profiles_default_to_their_real_format(ell, tmp_path, printer, fmt):
    out = tmp_path / "job"
    r = run("slice", ell, "-o", out, "--printer", printer, "--layer-height", "0.4")
    assert r.exit_code == 0 and f"[{fmt}]" in r.output
    assert out.read_bytes()[:8] == b"ANYCUBIC"
    z = tmp_path / "job.zip"
    r = run("slice", ell, "-o", z, "--printer", printer, "--layer-height", "0.4", "--format", "zip")
    assert r.exit_code == 0 and "[zip]" in r.output and zipfile.is_zipfile(z)


def test_same_bytes_whatever_the_thread_count(ell, tmp_path):
    outs = []
    for t in (1, 2):
        (tmp_path / f"t{t}").mkdir()
        out = tmp_path / f"t{t}" / "job.pwmx"
        assert run("slice", ell, "-o", out, *SETTINGS, "--aa", "2", "--threads", t).exit_code == 0
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]
