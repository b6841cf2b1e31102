"""Elegoo GOO (``.goo``): big-endian header, RLE layers with checksums.

Layout (Elegoo's open spec V1.2; formats.md §2.1; every multi-byte field
big-endian):

* header, 195 477 bytes: version ``V3.0``, magic, software/printer strings,
  116 x 116 and 290 x 290 RGB565 previews, resolution, mirror flags, display
  size, exposure and motion settings, volume, the layer-content offset
  (195 477) and ``grey_scale_level = 1`` (8-bit pixels);
* one record per layer: pause flag, ``position_z`` (= h (k + 1)), exposure,
  waits and motion (f32), light PWM, ``0D 0A``, ``u32`` data length
  (= payload + 2), ``0x55``, the RLE payload, the checksum
  ``~sum(payload) & 0xFF``, ``0D 0A``;
* the ending string ``00 00 00 07 00 00 00 44 4C 50 00``.

The RLE covers every pixel of the x_resolution x y_resolution image, row by
row. Runs of 0x00 and 0xFF are chunk types 00 and 11, other greys type 01
with the grey byte; the run length takes 4, 12, 20 or 28 bits (the low 4
in byte 0, the rest in 0-3 following bytes, most significant first). Diff
chunks (type 10) are optional and never written.

Layers stream to a temporary file after a placeholder header; the header
(with the previews, which need the whole stack) is written last, then the
file is renamed over the target.
"""
from __future__ import annotations

import struct

import numpy as np

from slicer.atomic import AtomicFile
from slicer.errors import OutputError

from .base import StackWriter, build_time
from .estimate import LayerMeter
from .printers import plate_printer
from .rle import runs
from .thumbnails import TopView, rgb565

HEADER_SIZE = 195_477
MAGIC = bytes([0x07, 0x00, 0x00, 0x00, 0x44, 0x4C, 0x50, 0x00])
DELIMITER = b"\r\n"
ENDING = bytes([0x00, 0x00, 0x00]) + MAGIC
LAYER_MAGIC = 0x55
SMALL_PREVIEW = (116, 116)
BIG_PREVIEW = (290, 290)
MAX_RUN = 0xFFFFFFF


def _fixed(text: str, n: int) -> bytes:
    """NUL-padded fixed-width string field."""
    b = text.encode("ascii", "replace")[:n - 1]
    return b + b"\0" * (n - len(b))


def encode_layer(image: np.ndarray) -> tuple[bytes, int]:
    """GOO RLE payload of an 8-bit image and its checksum byte.

    Parameters
    ----------
    image : (y_resolution, x_resolution) uint8

    Returns
    -------
    payload : bytes
    checksum : int
        ``~sum(payload) & 0xFF``.
    """
    vals, lens = runs(image)
    if np.any(lens > MAX_RUN):                       # only for images above 268 Mpx
        reps = -(-lens // MAX_RUN)
        vals = np.repeat(vals, reps)
        lens = np.concatenate([[MAX_RUN] * (r - 1) + [L - MAX_RUN * (r - 1)] for L, r in zip(lens, reps)])
    kind = np.where(vals == 0, 0, np.where(vals == 255, 3, 1)).astype(np.int64)
    width = np.where(lens <= 0xF, 0, np.where(lens <= 0xFFF, 1, np.where(lens <= 0xFFFFF, 2, 3)))
    grey = kind == 1
    size = 1 + grey + width
    pos = np.concatenate([[0], np.cumsum(size)[:-1]])
    out = np.zeros(int(size.sum()), np.uint8)
    out[pos] = (kind << 6) | (width << 4) | (lens & 0xF)
    out[pos[grey] + 1] = vals[grey]
    first = pos + 1 + grey                           # first length byte
    for e in range(3):                               # e-th extra byte, most significant first
        has = width > e
        shift = 4 + 8 * (width[has] - 1 - e)
        out[first[has] + e] = (lens[has] >> shift) & 0xFF
    checksum = (~int(out.sum(dtype=np.uint64))) & 0xFF
    return out.tobytes(), checksum


class GooWriter(StackWriter):
    """Elegoo GOO file for an Elegoo printer profile."""

    name = "goo"
    needs_printer = True

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        self.printer = plate_printer(self.name, path, grid, settings)
        super().__init__(path, grid, meta, force, settings)
        if max(self.printer.native_shape) > 0xFFFF:
            raise OutputError(f"{self.path}: GOO stores at most 65535 px per side")
        self._out = AtomicFile(self.path)
        self._out.fh.write(b"\0" * HEADER_SIZE)
        self._top = TopView(self.printer.plate_shape)
        self._k = 0
        self._meter = LayerMeter()

    def write_layer(self, k: int, image: np.ndarray) -> None:
        if k != self._k:
            raise ValueError(f"layers must be written in order: expected {self._k}, got {k}")
        s = self.settings
        payload, checksum = encode_layer(self.printer.to_native(image))
        lift_d, lift_v, retract_d, retract_v = self.printer.lift
        exposure = s.exposure_of(k)
        rec = struct.pack(">H15fH", 0, self.printer.max_height, s.layer_height * (k + 1), exposure,
                          0.0, 0.0, 0.0, 0.0, lift_d, lift_v, 0.0, 0.0, retract_d, retract_v, 0.0, 0.0, 255)
        try:
            fh = self._out.fh
            fh.write(rec + DELIMITER + struct.pack(">IB", len(payload) + 2, LAYER_MAGIC))
            fh.write(payload)
            fh.write(bytes([checksum]) + DELIMITER)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot write layer {k} ({exc})") from None
        self._meter.add(image)
        self._top.add(k, image)
        self._k += 1

    def header(self) -> bytes:
        """The 195 477-byte header (needs every layer written); print time and
        volume (mm³, as Elegoo's spec gives it) from :mod:`formats.estimate`."""
        s, p = self.settings, self.printer
        rows, cols = p.native_shape
        est = self._meter.estimate(s)
        volume = est.volume_ml * 1000.0                               # mm^3
        lift_d, lift_v, retract_d, retract_v = p.lift
        gen = self.meta.get("generator", "skelslice")
        parts = [
            b"V3.0", MAGIC, _fixed("skelslice", 32), _fixed(gen.split()[-1], 24),
            _fixed(build_time().strftime("%Y-%m-%d %H:%M:%S"), 24), _fixed(p.model, 32), _fixed("DLP", 32),
            _fixed(f"skelslice {s.layer_height:g} mm", 32),
            struct.pack(">HHH", max(s.aa, 1), 0, 0),
            rgb565(self._top.render(SMALL_PREVIEW)), DELIMITER,
            rgb565(self._top.render(BIG_PREVIEW)), DELIMITER,
            struct.pack(">IHH??", self._k, cols, rows, p.mirror_x, p.mirror_y),
            struct.pack(">5f", p.display[0], p.display[1], p.max_height, s.layer_height, s.exposure),
            struct.pack(">?7f", True, 0, 0, 0, 0, 0, 0, 0),
            struct.pack(">fI", s.bottom_exposure, s.bottom_layers),
            struct.pack(">16f", lift_d, lift_v, lift_d, lift_v, retract_d, retract_v, retract_d, retract_v,
                        *([0.0] * 8)),
            struct.pack(">HH?I3f", 255, 255, False, int(round(est.seconds)), volume, volume * 1.1e-3, 0.0),
            _fixed("$", 8), struct.pack(">I?H", HEADER_SIZE, True, 0),
        ]
        head = b"".join(parts)
        assert len(head) == HEADER_SIZE, len(head)
        return head

    def close(self) -> None:
        if self._k != self.grid.layers:
            self.abort()
            raise OutputError(f"{self.path}: {self._k} of {self.grid.layers} layers were written")
        self.estimate = self._meter.estimate(self.settings)
        try:
            fh = self._out.fh
            fh.write(ENDING)
            fh.seek(0)
            fh.write(self.header())
            fh.seek(0, 2)
            self._out.publish(self.force)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot finish the output ({exc})") from None

    def abort(self) -> None:
        self._out.discard()


__all__ = ["GooWriter", "encode_layer", "runs", "HEADER_SIZE"]
