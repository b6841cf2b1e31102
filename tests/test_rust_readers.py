"""Our binary CLI and GOO files read by independent Rust parsers.

``tests/readers`` is a small cargo project (our code) around two crates from
crates.io: ``colain`` (binary CLI) and ``goo`` (Elegoo GOO). It is built once
per session (``cargo build --release --locked``, about 5 s cold with the
crates downloaded) into ``tests/readers/target``. Without cargo the tests are
skipped with a message; CI has cargo.
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from contour_checks import GRID, as_multipolygon, sample_layers, write_all
from formats.common_layer import CliAsciiWriter, CliShortWriter, CliWriter, read_cli
from slicer import Skeleton
from slicer.tracer.grid import SliceGrid

pytestmark = pytest.mark.slow

def check(exe: Path, kind: str, path: Path, ok: bool = True) -> dict:
    r = subprocess.run([str(exe), kind, str(path)], capture_output=True, text=True, timeout=120)
    doc = json.loads(r.stdout)
    assert (r.returncode == 0) == ok, (r.returncode, r.stdout[:500], r.stderr[:500])
    return doc


# ============================================================================= CLI via colain
@pytest.mark.parametrize("cls,variant", [(CliWriter, "long"), (CliShortWriter, "short")])
def test_colain_reads_our_binary_cli(checker, tmp_path, cls, variant):
    out = tmp_path / "s.cli"
    w = write_all(cls, out)
    doc = check(checker, "cli", out)
    ours = read_cli(out)
    assert doc["variant"] == variant and doc["binary"] and doc["version"] == 2.0 and not doc["aligned"]
    assert doc["units"] == w.units and doc["header_layers"] == doc["layer_count"] == GRID.layers
    for k, (layer, mine, want) in enumerate(zip(doc["layers"], ours.layers, sample_layers())):
        want = as_multipolygon(want)
        assert layer["z"] == pytest.approx((k + 1) * GRID.layer_height, abs=w.units)
        assert layer["outer"] == len(want.geoms)
        assert layer["holes"] == sum(len(p.interiors) for p in want.geoms) and layer["open"] == 0
        assert layer["vertex_counts"] == [len(p) for _, p in mine.polylines]
        assert layer["dirs"] == [d for d, _ in mine.polylines]
        assert layer["closed"] and layer["dir_mismatch"] == 0 and layer["hatches"] == 0
        # signed shoelace sum of colain's points = outer area minus holes
        assert layer["area"] == pytest.approx(want.area, abs=want.length * w.units + 1e-9)


def test_colain_rejects_what_it_should(checker, tmp_path):
    write_all(CliWriter, tmp_path / "b.cli")
    data = (tmp_path / "b.cli").read_bytes()
    (tmp_path / "cut.cli").write_bytes(data[:-3])
    (tmp_path / "nover.cli").write_bytes(data.replace(b"$$VERSION/200\n", b""))
    write_all(CliAsciiWriter, tmp_path / "a.cli")
    assert "UnexpectedEOF" in check(checker, "cli", tmp_path / "cut.cli", ok=False)["error"]
    assert "HeaderIncomplete(2)" in check(checker, "cli", tmp_path / "nover.cli", ok=False)["error"]
    assert "UnsupportedGeometryFormat" in check(checker, "cli", tmp_path / "a.cli", ok=False)["error"]


def test_python_m_slicer_cli_output_checked_by_colain(checker, tmp_path):
    """The real entry point in a subprocess, its CLI file parsed by colain."""
    scene = tmp_path / "y.json"
    Skeleton([[0, 0, 0], [0, 0, 2], [1, 0, 3], [-1, 0, 3]], [[0, 1], [1, 2], [1, 3]],
             [[0.5, 0.3], [0.3, 0.25], [0.3, 0.25]]).save(scene)
    out = tmp_path / "y.cli"
    r = subprocess.run([sys.executable, "-m", "slicer", "slice", str(scene), "-o", str(out),
                        "--pixel-size", "0.05", "--layer-height", "0.1"], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert "[cli]" in r.stdout or str(out) in r.stdout
    doc = check(checker, "cli", out)
    ours = read_cli(out)
    assert doc["layer_count"] == len(ours.layers) > 30
    areas = [lay.multipolygon().area for lay in ours.layers]
    assert [lay["area"] for lay in doc["layers"]] == pytest.approx(areas, abs=1e-6)
    assert all(lay["dir_mismatch"] == 0 and lay["closed"] for lay in doc["layers"])
    assert sum(lay["holes"] for lay in doc["layers"]) == 0 and max(areas) > 0.5   # struts: discs, no holes


# ============================================================================= GOO via the goo crate
def fnv1a64(data: np.ndarray) -> str:
    h = 0xcbf29ce484222325
    for b in np.ascontiguousarray(data, np.uint8).ravel().tolist():
        h = ((h ^ b) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


@pytest.fixture
def goo_job():
    goo = pytest.importorskip("formats.goo")
    from formats.printer_profiles import PrintSettings, get_printer

    base = get_printer("elegoo-mars-4-ultra")
    printer = dataclasses.replace(base, pixels=(48, 32), display=(48 * 0.018, 32 * 0.018))
    grid = SliceGrid(origin=(0.009, 0.567, 0.025), pixel_size=printer.pixel_size, layer_height=0.05,
                     width=48, height=32, layers=4)
    rng = np.random.default_rng(5)
    solid = np.zeros((32, 48), np.uint8)
    solid[5:20, 10:40] = 255
    grey = np.repeat(rng.integers(0, 256, (32, 6)), 8, axis=1).astype(np.uint8)   # runs of 8, all levels
    images = [np.zeros((32, 48), np.uint8), solid, grey, np.full((32, 48), 255, np.uint8)]
    settings = PrintSettings(printer, 0.05, bottom_layers=1)
    return goo, printer, grid, settings, images


def test_goo_reader_reads_our_goo(checker, tmp_path, goo_job):
    goo, printer, grid, settings, images = goo_job
    out = tmp_path / "s.goo"
    with goo.GooWriter(out, grid, {"generator": "skelslice test"}, settings=settings) as w:
        for k, img in enumerate(images):
            w.write_layer(k, img)
    doc = check(checker, "goo", out)
    rows, cols = printer.native_shape
    assert (doc["x_resolution"], doc["y_resolution"]) == (cols, rows)
    assert doc["version"] == "V3.0" and doc["layer_count"] == 4 and doc["grey_scale_level"]
    assert doc["offset_ok"] and doc["size_ok"] and doc["layers_ok"]
    assert doc["layer_thickness"] == pytest.approx(0.05) and doc["bottom_layers"] == 1
    for k, (layer, img) in enumerate(zip(doc["layers"], images)):
        native = printer.to_native(img)
        assert layer["checksum_ok"] and layer["pixels"] == rows * cols
        assert layer["lit"] == int((img > 0).sum()) and layer["solid"] == int((img >= 128).sum())
        assert layer["grey_sum"] == int(img.sum(dtype=np.int64))
        assert layer["fnv1a64"] == fnv1a64(native)
        assert layer["position_z"] == pytest.approx(0.05 * (k + 1))


def test_goo_reader_catches_corruption(checker, tmp_path, goo_job):
    goo, printer, grid, settings, images = goo_job
    out = tmp_path / "c.goo"
    with goo.GooWriter(out, grid, settings=settings) as w:
        for k, img in enumerate(images):
            w.write_layer(k, img)
    data = bytearray(out.read_bytes())
    first = goo.HEADER_SIZE + 2 + 15 * 4 + 2 + 2 + 4 + 1       # payload of layer 0
    data[first] ^= 0x01                                        # a run length changes by one
    (tmp_path / "bad.goo").write_bytes(bytes(data))
    doc = check(checker, "goo", tmp_path / "bad.goo")
    assert not doc["layers_ok"] and not doc["layers"][0]["ok"]
    (tmp_path / "cut.goo").write_bytes(bytes(data[:-20]))
    assert "error" in check(checker, "goo", tmp_path / "cut.goo", ok=False)
