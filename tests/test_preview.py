"""``skelslice preview``: the page's content, read with an independent parser.

The data block of the page is parsed back and every stored layer decoded
(PIL) and pasted at its corner: it must equal the layer of the output it
was made from (PNG folder, zip, and, in plate orientation, SL1S, GOO and
NanoDLP against the zip of plate images of the same job). The page must be
self-contained (no URL but data: URIs), carry the check's findings, the
contours (computed or from a ``--contours`` file) and the renders.
"""
from __future__ import annotations

import base64
import io
import json
import re
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from formats.goo import HEADER_SIZE, encode_layer
from slicer import Skeleton
from slicer._kernels.formats.goo_rle import OK, decode_goo
from slicer.cli.app import main
from slicer.viewer.page import decode_ring, layer_png


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def page_data(html_path) -> dict:
    html = html_path.read_text("utf-8")
    m = re.search(r'<script type="application/json" id="skelslice-data">(.*?)</script>', html, re.S)
    assert m, "no data block"
    return json.loads(m.group(1))


def page_layers(doc) -> list[np.ndarray]:
    """Every layer of the page, decoded and pasted into the window."""
    out = []
    for item in doc["layers"]:
        img = np.zeros((doc["height"], doc["width"]), np.uint8)
        if item is not None:
            c0, r0, w, h, b64 = item
            crop = np.asarray(Image.open(io.BytesIO(base64.b64decode(b64))).convert("L"))
            assert crop.shape == (h, w)
            img[r0:r0 + h, c0:c0 + w] = crop
        out.append(img)
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.integers(0, 2**32 - 1), st.booleans())
def test_layer_png_round_trip(h, w, seed, grey):
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((h, w)) < 0.3, 255, 0).astype(np.uint8)
    if grey:
        img[rng.random((h, w)) < 0.2] = rng.integers(1, 255)
    item = layer_png(img)
    if not img.any():
        assert item is None
        return
    c0, r0, cw, ch, b64 = item
    data = base64.b64decode(b64)
    assert data[25] == 0 and data[24] == (8 if np.any((img > 0) & (img < 255)) else 1)   # grey; bit depth
    back = np.zeros_like(img)
    back[r0:r0 + ch, c0:c0 + cw] = np.asarray(Image.open(io.BytesIO(data)).convert("L"))
    assert np.array_equal(back, img)


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    d = tmp_path_factory.mktemp("preview")
    scene = d / "hang.json"
    r = 0.3
    Skeleton([[0, 0, 0], [0, 0, 3], [2, 0, 3], [2, 0, 1.5], [4, 0, 2], [5, 0, 2]],
             [[0, 1], [1, 2], [2, 3], [4, 5]], [[r, r]] * 4).save(scene)
    return d, scene


def assert_self_contained(html_path):
    html = html_path.read_text("utf-8")
    assert not re.search(r"https?://|//cdn|<link\b|<script[^>]+src=|@import", html), "the page refers to the network"
    assert "default-src 'none'" in html                 # the browser refuses any request the page would make
    for uri in re.findall(r'"(data:[^"]{0,40})', html):
        assert uri.startswith("data:image/png;base64,")


def test_preview_of_a_png_stack(job, tmp_path):
    d, scene = job
    stack = tmp_path / "stack"
    contours = tmp_path / "c.geojson"
    assert run("slice", scene, "-o", stack, "--pixel-size", "0.05", "--contours", contours, "-q").exit_code == 0
    html = tmp_path / "v.html"
    r = run("preview", stack, "-o", html, "--contours", contours, "--scene", scene)
    assert r.exit_code == 0, r.output
    assert "MB" in r.output and "2 islands" in r.output
    assert_self_contained(html)
    doc = page_data(html)
    meta = json.loads((stack / "slices.json").read_text())
    layers = page_layers(doc)
    assert len(layers) == meta["layers"]
    for k, f in enumerate(meta["files"]):
        assert np.array_equal(layers[k], np.asarray(Image.open(stack / f))), k
    assert [(f["kind"], f["layer"]) for f in doc["findings"]] == [("island", 31), ("island", 37)]
    assert doc["findings"][0]["col"] == pytest.approx((2.0 - meta["origin"][0]) / 0.05, abs=0.5)
    assert doc["check"]["ok"] is False
    assert doc["areas"][31] == pytest.approx(np.count_nonzero(layers[31]) * 0.05 ** 2)
    # the contours of the file, in pixels: the ring of layer 31's island passes between its
    # pixel centres and the outside ones (within a pixel of its extreme pixels)
    ring = decode_ring(doc["contours"]["31"][-1])
    rows, cols = np.nonzero(layers[31][:, 35:])
    cols = cols + 35
    assert cols.min() - 1 < ring[:, 0].min() <= cols.min() and cols.max() <= ring[:, 0].max() < cols.max() + 1
    assert rows.min() - 1 < ring[:, 1].min() <= rows.min() and rows.max() <= ring[:, 1].max() < rows.max() + 1
    assert [r["caption"].split(" (")[0] for r in doc["renders"]][:1] == ["transparent render of the scene"]
    assert doc["frame"] == "scene"


def test_preview_of_a_scene_has_findings_contours_and_render(job, tmp_path):
    d, scene = job
    html = tmp_path / "s.html"
    r = run("preview", scene, "-o", html, "--pixel-size", "0.05", "--min-feature", "0.7")
    assert r.exit_code == 0, r.output
    doc = page_data(html)
    kinds = {f["kind"] for f in doc["findings"]}
    assert kinds == {"island", "thin"}                     # every strut is 0.6 mm wide, under --min-feature 0.7
    assert sum(f["kind"] == "thin" for f in doc["findings"]) == 4
    assert set(doc["contours"]) >= {"31", "37"}
    assert len(doc["renders"]) == 3                       # the scene's render and two X-rays
    again = tmp_path / "s2.html"
    assert run("preview", scene, "-o", again, "--pixel-size", "0.05", "--min-feature", "0.7", "-q").exit_code == 0
    assert again.read_bytes() == html.read_bytes()          # same input and settings, same bytes


@pytest.mark.parametrize("fmt, printer", [("sl1s", "prusa-sl1s"), ("goo", "elegoo-mars-4-ultra"),
                                          ("nanodlp", "prusa-sl1s")])
def test_printer_archives_show_plate_images(job, tmp_path, fmt, printer):
    """Native images are turned back to the plate: the page's layers equal
    the plate images of a zip of the same job, in the page's window."""
    d, scene = job
    common = ["--printer", printer, "--layer-height", "0.1", "-q"]
    arch, zp = tmp_path / f"j.{fmt}", tmp_path / "j.zip"
    assert run("slice", scene, "-o", arch, *common).exit_code == 0
    assert run("slice", scene, "-o", zp, *common).exit_code == 0
    html = tmp_path / f"{fmt}.html"
    r = run("preview", arch, "-o", html, "--no-check")
    assert r.exit_code == 0, r.output
    doc = page_data(html)
    assert doc["frame"] == "plate" and doc["plate"] is True
    r0, c0 = doc["window"]
    with zipfile.ZipFile(zp) as z:
        meta = json.loads(z.read("slices.json"))
        plates = [np.asarray(Image.open(z.open(f))) for f in meta["files"]]
    assert doc["full_shape"] == list(plates[0].shape)
    layers = page_layers(doc)
    assert len(layers) == len(plates)
    for k, (a, b) in enumerate(zip(layers, plates)):
        win = b[r0:r0 + doc["height"], c0:c0 + doc["width"]]
        assert np.array_equal(a, win), k
        assert win.sum() == b.sum(), "the window holds every solid pixel"
    assert doc["check"] is None and doc["findings"] == []


def test_refusals(job, tmp_path):
    d, scene = job
    cli = tmp_path / "c.cli"
    assert run("slice", scene, "-o", cli, "--pixel-size", "0.1", "-q").exit_code == 0
    for args, needle in [((cli, "-o", tmp_path / "a.html"), "contours, not layer images"),
                         ((tmp_path / "none", "-o", tmp_path / "b.html"), "none"),
                         ((scene, "-o", tmp_path / "c.html"), "pixel"),
                         ((scene, "-o", scene, "--pixel-size", "0.1"), "input")]:
        r = run("preview", *args)
        assert r.exit_code == 2 and needle in r.output and "Traceback" not in r.output, (args, r.output)
    html = tmp_path / "d.html"
    assert run("preview", scene, "-o", html, "--pixel-size", "0.1", "-q").exit_code == 0
    r = run("preview", scene, "-o", html, "--pixel-size", "0.1")
    assert r.exit_code == 2 and "already exists" in r.output


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2**32 - 1), st.floats(0.0, 0.5))
def test_goo_decoder_inverts_the_writer(h, w, seed, grey_share):
    """The read-back decoder (a kernel) against the writer's encoder; cut
    payloads are reported, never decoded into a wrong image."""
    rng = np.random.default_rng(seed)
    img = np.where(rng.random((h, w)) < 0.5, 0, 255).astype(np.uint8)
    m = rng.random(img.shape) < grey_share
    img[m] = rng.integers(0, 256, int(m.sum()))
    payload, _ = encode_layer(img)
    out = np.zeros(img.size, np.uint8)
    status, _ = decode_goo(np.frombuffer(payload, np.uint8), out)
    assert status == OK and np.array_equal(out.reshape(img.shape), img)
    if len(payload) > 1:
        status, _ = decode_goo(np.frombuffer(payload[:-1], np.uint8), np.zeros(img.size, np.uint8))
        assert status != OK
    status, _ = decode_goo(np.frombuffer(payload, np.uint8), np.zeros(img.size - 1, np.uint8)) if img.size > 1 \
        else (1, 0)
    assert status != OK


def test_corrupt_archives_are_refused_by_name(job, tmp_path):
    d, scene = job
    goo = tmp_path / "j.goo"
    assert run("slice", scene, "-o", goo, "--printer", "elegoo-mars-4-ultra", "--layer-height", "0.2",
               "-q").exit_code == 0
    raw = bytearray(goo.read_bytes())
    off = HEADER_SIZE + 66 + 5                       # first layer's payload
    raw[off] ^= 0x01
    bad = tmp_path / "bad.goo"
    bad.write_bytes(bytes(raw))
    r = run("preview", bad, "-o", tmp_path / "v.html")
    assert r.exit_code == 2 and "layer 0: bad checksum" in r.output, r.output
    r = run("check", bad)
    assert r.exit_code == 2 and "bad checksum" in r.output
    empty = tmp_path / "x.sl1"
    with zipfile.ZipFile(empty, "w") as z:
        z.writestr("readme.txt", "no")
    r = run("check", empty)
    assert r.exit_code == 2 and "no config.ini" in r.output, r.output
