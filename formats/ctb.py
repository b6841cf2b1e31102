"""Chitubox CTB, versions 3 and 2 (``.ctb``): the plain layout Chitu firmware reads.

Not the *encrypted* CTB (magic ``0x12FD0107``) that newer Chitu firmware
requires: that needs a vendor's secret AES key, which skelslice does not
embed (docs/printers.md lists which printers read plain CTB).

Layout
------
Little-endian, offsets absolute (catibo's ``cbddlp-ctb.adoc``; UVtools
``ChituboxFile``; uv3dp ``ctb``). In file order:

* header, 112 bytes: magic ``0x12FD0086``, version (3 or 2), bed size (mm),
  model height, layer height, exposure and bottom exposure (s), light-off
  delay, bottom layers, resolution, the table offsets, print time (s),
  projector type (1: LCD, mirrored), anti-aliasing level 1 (always 1 in CTB;
  the grey depth is in the layer encoding), PWM 255, the layer key;
* print parameters, 60 bytes: bottom and normal lift distance and speed
  (mm, mm/min), retract speed, resin volume (ml), weight (g), cost, light-off
  delays, bottom layers;
* slicer information, 76 bytes, then the machine name (not NUL-terminated):
  anti-aliasing flag ``0x0F`` (grey layers) or ``0x07``, per-layer settings
  flag ``0x20`` (version 3), timestamp (minutes), anti-aliasing level,
  software version 1.6.3;
* the layer table, 36 bytes per layer: Z (mm, ``h (k + 1)``), exposure,
  light-off delay, data offset and size, record size (36, or 84 in v3);
* per layer (version 3 only) an 84-byte record repeating the table entry
  plus lift, retract and PWM, then the layer's RLE data;
* the two previews (400 x 300 and 200 x 125), each a 32-byte header and
  RGB15 run-length data (5-5-5 bits, bit 5 the run flag, run words
  ``0x3000 | (n - 1)``).

Layer encoding
--------------
Row-major over the ``ResolutionX x ResolutionY`` image, runs of one 7-bit
grey ``c``: one byte ``c`` for a single pixel, else ``0x80 | c`` and the run
length in 1-4 big-endian bytes (prefixes ``0``, ``10``, ``110``, ``1110``:
7, 14, 21, 28 bits). Readers widen ``c`` to 8 bits as ``0`` or ``2 c + 1``;
an 8-bit grey is stored as the nearest of those 128 levels (0 and 255
exactly). The data of layer ``k`` is XORed with the keystream of the layer
key and ``k`` (catibo's "86 cipher"; the key is in the header, so any reader
undoes it; UVtools and uv3dp write a non-zero key because some Chitu
firmware rejects 0; skelslice uses the fixed :data:`KEY` so files are
reproducible).

Images are the printer's native layout (:meth:`Printer.to_native`, the
layout UVtools' PrusaSlicer profiles for these printers produce; the header
records the LCD mirroring as projector type 1, as Chitubox writes for LCD
printers).

Layers stream to a temporary file after placeholder header and table; the
header, table and previews (which need the whole stack) are written last,
then the file is renamed over the target.
"""
from __future__ import annotations

import struct

import numpy as np

from formats.base import BinaryStackWriter, build_time
from formats.printer_profiles import plate_printer
from formats.rle import GreyLevels, runs, split_runs

MAGIC = 0x12FD0086
HEADER_SIZE = 112
PARAMS_SIZE = 60
SLICER_SIZE = 76
LAYER_DEF_SIZE = 36
LAYER_EX_SIZE = 84
PREVIEW_HEADER_SIZE = 32
#: large and small preview sizes, as Chitubox writes them
PREVIEWS = ((400, 300), (200, 125))
#: layer key written into every file (any non-zero value; fixed for reproducible output)
KEY = 0x5EED1E55
#: 7-bit greys: code c decodes to 0 or 2 c + 1
GREYS = GreyLevels([0] + [2 * c + 1 for c in range(1, 128)])
MAX_RUN = 0xFFFFFFF
#: largest RGB15 run (the run word holds n - 1 in 12 bits; Chitubox stops at 0xFFE)
MAX_PREVIEW_RUN = 0xFFF
SOFTWARE_VERSION = 0x01060300
U32 = 0xFFFFFFFF


def encode_rle(codes) -> bytes:
    """CTB run-length data of an image of 7-bit codes.

    Parameters
    ----------
    codes : (rows, columns) uint8, values 0-127, or its :class:`formats.rle.Band`

    Returns
    -------
    bytes
        Unencrypted layer data (see the module docstring).
    """
    vals, lens = runs(codes)
    vals, lens = split_runs(vals, lens, MAX_RUN)
    run = lens > 1
    nlen = np.where(~run, 0, np.where(lens <= 0x7F, 1, np.where(lens <= 0x3FFF, 2, np.where(lens <= 0x1FFFFF, 3, 4))))
    size = 1 + nlen
    pos = np.concatenate([[0], np.cumsum(size)[:-1]])
    out = np.zeros(int(size.sum()), np.uint8)
    out[pos] = vals | (run.astype(np.uint8) << 7)
    prefix = np.array([0, 0x00, 0x80, 0xC0, 0xE0], np.int64)
    for e in range(4):                                       # e-th length byte, most significant first
        has = nlen > e
        shift = 8 * (nlen[has] - 1 - e)
        byte = (lens[has] >> shift) & 0xFF
        if e == 0:
            byte = byte | prefix[nlen[has]]
        out[pos[has] + 1 + e] = byte
    return out.tobytes()


def keystream(key: int, index: int, n: int) -> np.ndarray:
    """The first ``n`` keystream bytes of layer ``index`` under ``key``.

    ``c = key * 0x2D83CDAC + 0xD8A83423``, word 0 is ``(index * 0x1E1530CD +
    0xEC3D47CD) * c``, each next word adds ``c`` (all mod 2^32); the words'
    little-endian bytes follow each other.

    Returns
    -------
    (n,) uint8
    """
    c = (key * 0x2D83CDAC + 0xD8A83423) & U32
    w0 = (((index * 0x1E1530CD) & U32) + 0xEC3D47CD) * c & U32
    words = (w0 + c * np.arange(-(-n // 4), dtype=np.uint64)) & U32
    return words.astype("<u4").view(np.uint8)[:n]


def cipher(data: bytes, key: int, index: int) -> bytes:
    """XOR layer data with its keystream (encrypts and decrypts); key 0 leaves it as is."""
    if key == 0 or not data:
        return data
    buf = np.frombuffer(data, np.uint8)
    return (buf ^ keystream(key, index, buf.size)).tobytes()


def encode_preview(rgba: np.ndarray) -> bytes:
    """RGB15 run-length data of a (h, w, 3+) uint8 preview (see the module docstring)."""
    rgb = rgba[..., :3].astype(np.uint16).reshape(-1, 3)
    word = ((rgb[:, 0] >> 3) << 11) | ((rgb[:, 1] >> 3) << 6) | (rgb[:, 2] >> 3)
    starts = np.concatenate([[0], np.flatnonzero(word[1:] != word[:-1]) + 1])
    lens = np.diff(np.concatenate([starts, [word.size]])).astype(np.int64)
    vals, lens = split_runs(word[starts], lens, MAX_PREVIEW_RUN)
    run = lens > 1
    out = []
    for v, n, r in zip(vals.tolist(), lens.tolist(), run.tolist()):
        out.append(v | 0x20 if r else v)
        if r:
            out.append(0x3000 | (n - 1))
    return np.asarray(out, "<u2").tobytes()


class CtbWriter(BinaryStackWriter):
    """Chitubox CTB version 3 (per-layer lift and PWM records)."""

    name = "ctb"
    version = 3
    needs_printer = True
    max_size = U32

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        self.printer = plate_printer(self.name, path, grid, settings)
        self.machine = self.printer.model.encode("ascii", "replace")
        self.table_at = HEADER_SIZE + PARAMS_SIZE + SLICER_SIZE + len(self.machine)
        self.ex_size = LAYER_EX_SIZE if self.version >= 3 else 0
        super().__init__(path, grid, meta, force, settings, placeholder=self.table_at + LAYER_DEF_SIZE * grid.layers)
        self._table: list[bytes] = []

    def layer_def(self, k: int, address: int, size: int) -> bytes:
        """The 36-byte layer table entry of layer ``k``."""
        s = self.settings
        return struct.pack("<3f6I", s.layer_height * (k + 1), s.exposure_of(k), self.printer.layer_overhead,
                           address, size, 0, self.ex_size or LAYER_DEF_SIZE, 0, 0)

    #: layers are encoded on a thread pool (formats.base.write_ordered)
    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """Encrypted layer data of plate image ``k`` and its plate box (thread-safe)."""
        band, box = self.native_band(image)
        return cipher(encode_rle(band.map(GREYS.code)), KEY, k), box

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        self.next_layer(k)
        data, box = payload
        entry = self.layer_def(k, self.tell() + self.ex_size, len(data))
        if self.ex_size:
            lift_d, lift_v, _, retract_v = self.printer.lift
            data = entry + struct.pack("<I11f", self.ex_size + len(data), lift_d, lift_v, 0.0, 0.0, retract_v,
                                       0.0, 0.0, 0.0, 0.0, 0.0, 255.0) + data
        self.write(data, f"layer {k}")
        self._table.append(entry)
        self.layer_done(k, image, box)

    # ------------------------------------------------------------------ header
    def header(self, previews: tuple[int, int]) -> bytes:
        """The 112-byte header (needs every layer written)."""
        s, p, est = self.settings, self.printer, self.estimate
        rows, cols = p.native_shape
        bed = p.native_size
        return struct.pack(
            "<2I3f2I5fI3I3I5I2H3I",
            MAGIC, self.version, bed[0], bed[1], p.max_height, 0, 0,
            s.layer_height * self._k, s.layer_height, s.exposure, s.bottom_exposure, p.layer_overhead,
            s.bottom_layers, cols, rows,
            previews[0], self.table_at, self._k, previews[1],
            int(round(est.seconds)), int(p.mirror_x or p.mirror_y), HEADER_SIZE, PARAMS_SIZE,
            1, 255, 255, KEY, HEADER_SIZE + PARAMS_SIZE, SLICER_SIZE)

    def print_parameters(self) -> bytes:
        """The 60-byte print parameters (lift, resin, light-off delays)."""
        s, p, est = self.settings, self.printer, self.estimate
        lift_d, lift_v, _, retract_v = p.lift
        pad = 0x1234 if self.version <= 2 else 0              # as UVtools writes v2 files
        return struct.pack("<10f5I", lift_d, lift_v, lift_d, lift_v, retract_v, est.volume_ml,
                           est.weight_g, 0.0, p.layer_overhead, p.layer_overhead, s.bottom_layers,
                           0, 0, 0, pad)

    def slicer_info(self) -> bytes:
        """The 76-byte slicer information; the machine name follows it."""
        s = self.settings
        flag = 0x0F if s.antialiased else 0x07
        per_layer = 0x20 if self.version >= 3 else 0
        minutes = int(build_time().timestamp()) // 60
        return struct.pack("<7f2IBHB3I2f4I", *([0.0] * 7), HEADER_SIZE + PARAMS_SIZE + SLICER_SIZE,
                           len(self.machine), flag, 0, per_layer, minutes, max(s.aa, 1), SOFTWARE_VERSION,
                           0.0, 0.0, 0, 0, 0, 0)

    def finish(self) -> dict[int, bytes]:
        previews = []
        for w, h in PREVIEWS:
            data = encode_preview(self._top.render((w, h)))
            at = self.tell()
            self.write(struct.pack("<8I", w, h, at + PREVIEW_HEADER_SIZE, len(data), 0, 0, 0, 0) + data,
                       "the previews")
            previews.append(at)
        head = self.header(tuple(previews)) + self.print_parameters() + self.slicer_info() + self.machine
        return {0: head + b"".join(self._table)}


class CtbV2Writer(CtbWriter):
    """Chitubox CTB version 2 (no per-layer records), for older Chitu firmware."""

    name = "ctb-v2"
    version = 2


__all__ = ["CtbWriter", "CtbV2Writer", "encode_rle", "encode_preview", "keystream", "cipher", "GREYS", "KEY",
           "MAGIC", "HEADER_SIZE"]
