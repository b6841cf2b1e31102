"""Elegoo GOO (``.goo``): big-endian header, RLE layers with checksums.

Layout (Elegoo's open spec V1.2; docs/formats.md §2.1; every multi-byte field
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

from slicer.errors import OutputError

from formats.base import BinaryStackWriter, build_time, fixed_string
from formats.printer_profiles import plate_printer
from formats.rle import runs
from formats.thumbnails import rgb565

HEADER_SIZE = 195_477
MAGIC = bytes([0x07, 0x00, 0x00, 0x00, 0x44, 0x4C, 0x50, 0x00])
DELIMITER = b"\r\n"
ENDING = bytes([0x00, 0x00, 0x00]) + MAGIC
LAYER_MAGIC = 0x55
SMALL_PREVIEW = (116, 116)
BIG_PREVIEW = (290, 290)
MAX_RUN = 0xFFFFFFF


def encode_layer(image) -> tuple[bytes, int]:
    """GOO RLE payload of an 8-bit image and its checksum byte.

    Parameters
    ----------
    image : (y_resolution, x_resolution) uint8, or its :class:`formats.rle.Band`

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


class GooWriter(BinaryStackWriter):
    """Elegoo GOO file for an Elegoo printer profile."""

    name = "goo"
    needs_printer = True

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        self.printer = plate_printer(self.name, path, grid, settings)
        if max(self.printer.native_shape) > 0xFFFF:
            raise OutputError(f"{path}: GOO stores at most 65535 px per side")
        super().__init__(path, grid, meta, force, settings, placeholder=HEADER_SIZE)

    #: layers are encoded on a thread pool (formats.base.write_ordered)
    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """RLE payload, checksum and plate box of plate image ``k`` (thread-safe)."""
        band, box = self.native_band(image)
        return encode_layer(band) + (box,)

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, encoded) -> None:
        self.next_layer(k)
        s = self.settings
        payload, checksum, box = encoded
        lift_d, lift_v, retract_d, retract_v = self.printer.lift
        rec = struct.pack(">H15fH", 0, self.printer.max_height, s.layer_height * (k + 1), s.exposure_of(k),
                          0.0, 0.0, 0.0, 0.0, lift_d, lift_v, 0.0, 0.0, retract_d, retract_v, 0.0, 0.0, 255)
        self.write(rec + DELIMITER + struct.pack(">IB", len(payload) + 2, LAYER_MAGIC) + payload
                   + bytes([checksum]) + DELIMITER, f"layer {k}")
        self.layer_done(k, image, box)

    def header(self) -> bytes:
        """The 195 477-byte header (after :meth:`close` has set :attr:`estimate`:
        print time and volume, mm³ as Elegoo's spec gives it)."""
        s, p, est = self.settings, self.printer, self.estimate
        rows, cols = p.native_shape
        volume = est.volume_ml * 1000.0                               # mm^3
        lift_d, lift_v, retract_d, retract_v = p.lift
        gen = self.meta.get("generator", "skelslice")
        parts = [
            b"V3.0", MAGIC, fixed_string("skelslice", 32), fixed_string(gen.split()[-1], 24),
            fixed_string(build_time().strftime("%Y-%m-%d %H:%M:%S"), 24), fixed_string(p.model, 32),
            fixed_string("DLP", 32), fixed_string(f"skelslice {s.layer_height:g} mm", 32),
            struct.pack(">HHH", max(s.aa, 1), 0, 0),
            rgb565(self._top.render(SMALL_PREVIEW)), DELIMITER,
            rgb565(self._top.render(BIG_PREVIEW)), DELIMITER,
            struct.pack(">IHH??", self._k, cols, rows, p.mirror_x, p.mirror_y),
            struct.pack(">5f", p.display[0], p.display[1], p.max_height, s.layer_height, s.exposure),
            struct.pack(">?7f", True, 0, 0, 0, 0, 0, 0, 0),
            struct.pack(">fI", s.bottom_exposure, s.bottom_layers),
            struct.pack(">16f", lift_d, lift_v, lift_d, lift_v, retract_d, retract_v, retract_d, retract_v,
                        *([0.0] * 8)),
            struct.pack(">HH?I3f", 255, 255, False, int(round(est.seconds)), volume, est.weight_g, 0.0),
            fixed_string("$", 8), struct.pack(">I?H", HEADER_SIZE, True, 0),
        ]
        head = b"".join(parts)
        assert len(head) == HEADER_SIZE, len(head)
        return head

    def finish(self) -> dict[int, bytes]:
        self.write(ENDING, "the ending string")
        return {0: self.header()}


__all__ = ["GooWriter", "encode_layer", "runs", "HEADER_SIZE"]
