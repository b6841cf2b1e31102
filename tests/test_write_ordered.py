"""Layers encoded on a thread pool, stored in order: the same bytes as a serial run, errors by name."""
from __future__ import annotations

import dataclasses
import hashlib
import threading
from pathlib import Path

import numpy as np
import pytest

from formats import writer_for
from formats.base import StackWriter, write_ordered
from formats.nanodlp import NanoDlpWriter
from formats.png_stack import PngStackWriter
from formats.zip_stack import ZipStackWriter
from formats.printer_profiles import PRINTERS, PrintSettings
from formats.rle import Band, occupied, runs
from slicer.errors import OutputError
from slicer.tracer.grid import SliceGrid


def _layers(n=40, h=37, w=53, seed=3):
    rng = np.random.default_rng(seed)
    for k in range(n):
        img = (rng.random((h, w)) < 0.3 + 0.01 * k).astype(np.uint8) * 255
        img[k % h, :] = k            # every layer differs
        yield img


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for p in files:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


GRID = SliceGrid((0.0, 0.0, 0.0), (0.1, 0.1), 0.1, 53, 37, 40)


@pytest.mark.parametrize("cls,name", [(PngStackWriter, "stack"), (ZipStackWriter, "stack.zip"),
                                      (NanoDlpWriter, "stack.nanodlp")])
def test_parallel_encoding_is_byte_identical(tmp_path, cls, name):
    digests = []
    for workers in (1, 2, 5):
        out = tmp_path / f"w{workers}" / name
        out.parent.mkdir()
        with cls(out, GRID, {"method": "interval"}) as wr:
            assert wr.parallel_encode
            assert write_ordered(wr, _layers(), workers) == 40
        digests.append(_digest(out))
    assert digests[0] == digests[1] == digests[2]


def _small(name, orientation, mirror_x, mirror_y, pixels=(53, 37)):
    """A real printer profile shrunk to ``pixels``, in any orientation and mirroring."""
    p = PRINTERS[name]
    px, py = p.pixel_size
    return dataclasses.replace(p, pixels=pixels, display=(pixels[0] * px, pixels[1] * py),
                               orientation=orientation, mirror_x=mirror_x, mirror_y=mirror_y)


def _plates(n, shape, seed):
    """Plate images with the model in a box that moves, greys, and empty layers."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        img = np.zeros(shape, np.uint8)
        if k % 7 != 3:
            r0, c0 = rng.integers(0, shape[0] - 8), rng.integers(0, shape[1] - 10)
            img[r0:r0 + 8, c0:c0 + 10] = np.where(rng.random((8, 10)) < 0.6, rng.integers(1, 256, (8, 10)), 0)
            img[r0, c0] = 255
        yield img


@pytest.mark.parametrize("fmt,printer", [("ctb", "elegoo-saturn"), ("ctb-v2", "elegoo-saturn"),
                                         ("goo", "elegoo-mars-4-ultra"), ("pws", "anycubic-photon-s"),
                                         ("pw0", "anycubic-photon-zero"), ("pwmx", "anycubic-photon-mono-x")])
@pytest.mark.parametrize("orientation", ["landscape", "portrait"])
def test_printer_files_encoded_in_parallel_are_byte_identical(tmp_path, fmt, printer, orientation):
    """The same bytes from the serial write_layer path and from 2 and 5 encoding
    threads, whatever the plate's orientation and mirroring."""
    photon = fmt.startswith("pw")          # Anycubic files hold only their machine's display size
    n = 6 if photon else 23
    for mirror_x, mirror_y in ((True, False), (False, True)):
        real = PRINTERS[printer].pixels
        p = _small(printer, orientation, mirror_x, mirror_y,
                   (real if orientation == "landscape" else real[::-1]) if photon else (53, 37))
        s = PrintSettings(p, 0.05, exposure=2.0, bottom_exposure=20.0, bottom_layers=2)
        grid = SliceGrid((0.5 * p.pixel_size[0], p.display[1] - 0.5 * p.pixel_size[1], 0.025), p.pixel_size, 0.05,
                         p.pixels[0], p.pixels[1], n)
        cls = writer_for(fmt, f"x.{fmt}")
        digests = []
        for workers in (0, 2, 5):
            out = tmp_path / f"{mirror_x}{mirror_y}w{workers}" / f"stack.{fmt}"
            out.parent.mkdir()
            with cls(out, grid, {"generator": "skelslice 9.9"}, settings=s) as wr:
                assert wr.parallel_encode
                if workers == 0:
                    for k, img in enumerate(_plates(n, p.plate_shape, 5)):
                        wr.write_layer(k, img)
                else:
                    assert write_ordered(wr, _plates(n, p.plate_shape, 5), workers) == n
            digests.append(_digest(out))
        assert digests[0] == digests[1] == digests[2]


@pytest.mark.parametrize("name", ["prusa-sl1", "elegoo-saturn", "anycubic-photon-s"])
@pytest.mark.parametrize("orientation", ["landscape", "portrait"])
@pytest.mark.parametrize("mirror_x,mirror_y", [(False, False), (True, False), (False, True), (True, True)])
def test_the_native_box_and_band_are_those_of_the_native_image(name, orientation, mirror_x, mirror_y):
    """Printer.native_box maps the plate's occupied box to the native image's,
    and runs of the band read from that box alone are the image's runs."""
    p = _small(name, orientation, mirror_x, mirror_y, pixels=(31, 19))
    for img in _plates(14, p.plate_shape, 11):
        native = p.to_native(img)
        box = p.native_box(occupied(img))
        assert box == occupied(native)
        v0, n0 = runs(np.ascontiguousarray(native))
        v1, n1 = runs(Band.of(native, box))
        assert np.array_equal(v0, v1) and np.array_equal(n0, n1)
        assert int(n1.sum()) == native.size


def test_a_band_is_the_image_it_stands_for():
    img = np.zeros((9, 12), np.uint8)
    img[3:5, 2:6] = [[0, 7, 9, 0], [4, 0, 0, 255]]
    band = Band.of(img)
    assert (band.r0, band.rows.shape, band.shape) == (3, (2, 12), (9, 12))
    full = np.zeros_like(img)
    full[band.r0:band.r0 + band.rows.shape[0]] = band.rows
    assert np.array_equal(full, img)
    table = np.arange(256, dtype=np.uint8) // 2
    assert np.array_equal(Band.of(img).map(table).rows, table[img[3:5]])
    assert np.array_equal(band.where_at_least(8).rows, (img[3:5] >= 8).astype(np.uint8))
    assert Band.of(np.zeros((4, 4), np.uint8)).rows.shape == (0, 4)
    with pytest.raises(ValueError):
        band.map(np.full(256, 1, np.uint8))          # would light the rows outside the band


class _Recorder(StackWriter):
    """Encodes on any thread, records where and in which order layers are stored."""

    parallel_encode = True

    def __init__(self, fail_at=None):
        self.stored, self.encoders, self.fail_at = [], set(), fail_at

    def encode_layer(self, k, image):
        self.encoders.add(threading.get_ident())
        if k == self.fail_at:
            raise OutputError(f"cannot encode layer {k}")
        return int(image[0, 0])

    def store_layer(self, k, image, payload):
        assert payload == int(image[0, 0])
        self.stored.append((k, threading.get_ident()))


def test_stored_in_order_on_the_calling_thread():
    wr = _Recorder()
    imgs = [np.full((2, 2), k, np.uint8) for k in range(25)]
    assert write_ordered(wr, iter(imgs), 3) == 25
    assert [k for k, _ in wr.stored] == list(range(25))
    assert {t for _, t in wr.stored} == {threading.get_ident()}
    assert threading.get_ident() not in wr.encoders


def test_an_encoding_error_stops_the_stack_by_name():
    wr = _Recorder(fail_at=7)
    with pytest.raises(OutputError, match="layer 7"):
        write_ordered(wr, (np.full((2, 2), k, np.uint8) for k in range(25)), 3)
    assert [k for k, _ in wr.stored] == list(range(7))


@pytest.mark.parametrize("seed", range(40))
def test_runs_of_a_band_read_from_its_box_are_the_image_runs(seed):
    """Boxes at the edges, one column wide or the full width, greys or 0/1, empty images."""
    rng = np.random.default_rng(seed)
    H, W = rng.integers(1, 9), rng.integers(1, 12)
    img = np.zeros((H, W), np.uint8)
    if seed % 9:
        r0, c0 = rng.integers(0, H), rng.integers(0, W)
        r1, c1 = rng.integers(r0 + 1, H + 1), rng.integers(c0 + 1, W + 1)
        img[r0:r1, c0:c1] = rng.integers(0, 3 if seed % 2 else 256, (r1 - r0, c1 - c0))
    flat = img.reshape(-1)
    cuts = np.flatnonzero(np.diff(flat)) + 1
    want_v = flat[np.concatenate([[0], cuts])]
    want_n = np.diff(np.concatenate([[0], cuts, [flat.size]]))
    band = Band.of(img)
    for b in (band, band.map(np.arange(256, dtype=np.uint8))):
        v, n = runs(b)
        assert v.tolist() == want_v.tolist() and n.tolist() == want_n.tolist()
    assert np.array_equal(runs(band.where_at_least(1))[1], runs((img >= 1).astype(np.uint8))[1])


def test_map_in_order_keeps_order_and_bounds_the_items_in_flight():
    """Uneven work finishes out of order; results come back in order, at most
    ``ahead * workers`` submitted ahead of the consumer."""
    import time

    from slicer.scale.ordered_map import map_in_order

    lock = threading.Lock()
    started, consumed = [], []

    def fn(x):
        with lock:
            started.append(x)
            ahead = len(started) - len(consumed)
        time.sleep(0.002 * ((7 * x) % 5))
        return x * x, ahead

    out = []
    for x, (sq, ahead) in map_in_order(fn, range(30), workers=3, ahead=2):
        out.append((x, sq))
        consumed.append(x)
        assert ahead <= 6
    assert out == [(x, x * x) for x in range(30)]


def test_map_in_order_raises_at_the_failing_item_and_stops_early():
    from slicer.scale.ordered_map import map_in_order

    calls = []

    def fn(x):
        calls.append(x)
        if x == 5:
            raise ValueError("item 5")
        return x

    got = []
    with pytest.raises(ValueError, match="item 5"):
        for x, r in map_in_order(fn, range(1000), workers=2):
            got.append(r)
    assert got == [0, 1, 2, 3, 4]
    assert len(calls) < 20                 # the rest of the 1000 items were never started


def test_map_in_order_does_not_wait_for_a_long_item_when_the_consumer_stops():
    """An error (or a signal) in the consumer while a long item runs: the generator
    closes at once, without waiting for that item, and nothing runs after it."""
    import time

    from slicer.scale.ordered_map import map_in_order

    release = threading.Event()
    started = []

    def fn(x):
        started.append(x)
        if x == 1:
            release.wait(30)               # a long item: minutes of contours at a fine tolerance
        return x

    t0 = time.perf_counter()
    with pytest.raises(KeyError):
        for x, _ in map_in_order(fn, range(100), workers=2, ahead=1):
            raise KeyError(x)              # the consumer fails on the first result
    assert time.perf_counter() - t0 < 5
    release.set()
    time.sleep(0.2)
    assert len(started) <= 3               # items queued behind the failure were cancelled
