"""Layers encoded on a thread pool, stored in order: the same bytes as a serial run, errors by name."""
from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import numpy as np
import pytest

from formats.base import StackWriter, write_ordered
from formats.nanodlp import NanoDlpWriter
from formats.png_stack import PngStackWriter
from formats.zip_stack import ZipStackWriter
from slicer.errors import OutputError
from slicer.grid import SliceGrid


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
