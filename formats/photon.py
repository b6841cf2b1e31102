"""Anycubic Photon Workshop files: ``.pws``, ``.pw0`` and the mono-LCD formats.

One writer, one table of machines (:data:`MACHINES`: file suffix, the
machine's display, file version, layer encoding) and one table of file
versions (:data:`LAYOUTS`). The layouts are the public ones (UVtools
``AnycubicFile``; PrusaSlicer ``AnycubicSLA``; uv3dp ``pws``; the Photon S
2.0 format notes; docs/printers.md).

Layout
------
Little-endian; every named table starts with a 12-byte NUL-padded name and a
``u32`` length. In file order:

* ``ANYCUBIC`` file mark: version, table count (4, 8, 9, 11 for versions 1,
  516, 517, 518) and the table offsets;
* ``HEADER`` (80 bytes in version 1, 84 / 92 / 96 after): pixel size (µm),
  layer height, exposure, wait before cure, bottom exposure, bottom layers
  (as f32), lift distance, lift and retract speeds (mm/s), resin volume
  (ml), anti-aliasing level, resolution, weight, price, currency ``$``,
  per-layer flag, print time (s), transition layers; then advanced mode
  (516+), grey and blur levels and resin type (517+), intelligent mode (518);
* ``PREVIEW``: 224 x 168 RGB565 (its length counts the 16-byte table head,
  as Photon Workshop writes it);
* (516+) the layer grey table: 16 greys for the anti-aliasing levels;
* ``LAYERDEF``: the layer count, then 32 bytes per layer: data offset and
  length, lift distance and speed, exposure, layer height (the layer's
  thickness), non-zero pixel count;
* (516+) ``EXTRA`` (two-stage lift, written as one stage), ``MACHINE``
  (machine name, ``pw0Img``/``pwsImg``, display size, height, file version;
  518: pixel width and height in µm and the resolution as ``u16``);
  (517+) the software table and ``MODEL`` (the model's bounding box, mm
  about the display centre); (518) ``SUBIMGS`` (the layer offsets again) and
  ``PREVIEW2`` (320 x 190);
* the layer data.

Layer encodings
---------------
* ``pw0`` (Photon Zero and every mono-LCD machine): runs of a 4-bit grey
  ``c``; ``c = 0`` or ``15``: two bytes ``c << 4 | n >> 8``, ``n & 0xFF``
  (runs up to 4095); other greys one byte ``c << 4 | n`` (up to 15).
  Readers decode ``c`` as ``17 c``; an 8-bit grey is stored as the nearest
  of those 16 levels. In version-1 ``.pw0`` files a CRC-16 of the run bytes
  follows them, big-endian (Anycubic's variant of CRC-16/ARC, as uv3dp
  reads Photon Workshop's files); UVtools and the mono-LCD formats have
  none, and decoders stop at the image's last pixel either way.
* ``pws`` (Photon S): ``N`` bit planes one after the other (``N = 1``, or
  8 with anti-aliasing), each runs of one bit, ``bit << 7 | n`` (up to 125
  pixels); a pixel set in ``c`` planes decodes as ``c (256 / N) - 1``.

Images are the printer's native layout (:meth:`Printer.to_native`: the
mirrored LCD image UVtools' PrusaSlicer profiles for these printers give).

Layers stream to a temporary file after placeholder tables of fixed size;
the tables, previews and bounding box are written last, then the file is
renamed over the target.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from slicer.errors import FormatError

from formats.base import BinaryStackWriter, fixed_string
from formats.printer_profiles import plate_printer
from formats.rle import Band, GreyLevels, runs, split_runs
from formats.thumbnails import rgb565
from slicer.constants import SQUARE_TOLERANCE

PREVIEW = (224, 168)
PREVIEW2 = (320, 190)
PW0_GREYS = GreyLevels([17 * c for c in range(16)])
PWS_RUN = 125


@dataclass(frozen=True)
class Machine:
    """A file suffix and the machine that reads it.

    Attributes
    ----------
    name : str
        Format name and file suffix.
    label : str
        Machine name in the file (UVtools' names).
    pixels : (2,) int
        Resolution of the machine's display (columns, rows of the stored image).
    version : int
        File version written (1, 516, 517 or 518: the one the machine's
        printer profile in UVtools names).
    encoding : {"pw0", "pws"}
    printer : str
        Default printer profile.
    """

    name: str
    label: str
    pixels: tuple[int, int]
    version: int
    encoding: str
    printer: str


@dataclass(frozen=True)
class Layout:
    """What a file version holds (sizes in bytes)."""

    tables: int
    filemark: int
    header: int
    machine: int
    property_fields: int


LAYOUTS = {1: Layout(4, 48, 80, 0, 0), 516: Layout(8, 52, 84, 156, 1), 517: Layout(9, 56, 92, 156, 7),
           518: Layout(11, 64, 96, 224, 15)}

MACHINES: dict[str, Machine] = {m.name: m for m in [
    Machine("pws", "Photon S", (1440, 2560), 1, "pws", "anycubic-photon-s"),
    Machine("pw0", "Photon Zero", (480, 854), 1, "pw0", "anycubic-photon-zero"),
    Machine("pwmo", "Photon Mono", (1620, 2560), 516, "pw0", "anycubic-photon-mono"),
    Machine("pwma", "Photon Mono 4K", (3840, 2400), 516, "pw0", "anycubic-photon-mono-4k"),
    Machine("pwmx", "Photon Mono X", (3840, 2400), 516, "pw0", "anycubic-photon-mono-x"),
    Machine("pwmb", "Photon Mono X 6K", (5760, 3600), 516, "pw0", "anycubic-photon-mono-x-6k"),
    Machine("pm5s", "Photon Mono M5s", (11520, 5120), 518, "pw0", "anycubic-photon-mono-m5s"),
]}


def pws_greys(planes: int) -> GreyLevels:
    """The greys ``N`` bit planes decode to: 0 and ``c (256 / N) - 1``."""
    return GreyLevels([0] + [c * (256 // planes) - 1 for c in range(1, planes + 1)])


def _crc_table() -> np.ndarray:
    table = np.zeros(256, np.int64)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
        table[i] = c
    return table


CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Anycubic's checksum of ``pw0`` layer data (CRC-16/ARC table, fed twice per byte)."""
    t = CRC_TABLE.tolist()
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ t[((crc >> 8) ^ t[b]) & 0xFF]) & 0xFFFF
    return (t[crc & 0xFF] * 0x100 + t[(crc >> 8) & 0xFF]) & 0xFFFF


def encode_pw0(codes: np.ndarray, crc: bool = False) -> bytes:
    """``pw0`` run-length data of an image of 4-bit greys (0-15), with the
    CRC-16 appended when ``crc``."""
    vals, lens = runs(codes)
    two = (vals == 0) | (vals == 15)
    vals, lens = split_runs(vals, lens, np.where(two, 0xFFF, 0xF))
    two = (vals == 0) | (vals == 15)
    size = 1 + two
    pos = np.concatenate([[0], np.cumsum(size)[:-1]])
    out = np.zeros(int(size.sum()), np.uint8)
    out[pos] = (vals.astype(np.int64) << 4) | np.where(two, lens >> 8, lens)
    out[pos[two] + 1] = lens[two] & 0xFF
    data = out.tobytes()
    return data + struct.pack(">H", crc16(data)) if crc else data


def encode_pws(counts: np.ndarray, planes: int) -> bytes:
    """``pws`` bit-plane data: plane ``p`` (1..planes) sets the pixels with ``counts >= p``."""
    out = []
    for p in range(1, planes + 1):
        vals, lens = runs(counts.where_at_least(p) if isinstance(counts, Band) else (counts >= p).astype(np.uint8))
        vals, lens = split_runs(vals, lens, PWS_RUN)
        out.append(((vals.astype(np.int64) << 7) | lens).astype(np.uint8).tobytes())
    return b"".join(out)


def _table(name: str, payload: bytes, with_head: bool) -> bytes:
    """A named table: name, length (counting the 16-byte head when ``with_head``), payload."""
    return fixed_string(name, 12) + struct.pack("<I", len(payload) + (16 if with_head else 0)) + payload


class PhotonWriter(BinaryStackWriter):
    """Anycubic Photon Workshop file for :attr:`machine` (set by each subclass)."""

    machine: Machine
    needs_printer = True
    max_size = 0xFFFFFFFF
    max_bottom_layers = 2**24                    # the header stores the count as a 32-bit float

    @classmethod
    def check_settings(cls, settings) -> None:
        """Refuse a printer whose display the machine's file cannot hold, and
        values its fields cannot hold (FormatError)."""
        super().check_settings(settings)
        m, p = cls.machine, settings.printer
        if p is None:
            raise FormatError(f"{m.name}: the format needs a printer profile (--printer)")
        rows, cols = p.native_shape
        if (cols, rows) != m.pixels:
            raise FormatError(f"{m.name}: files for the Anycubic {m.label} hold a {m.pixels[0]} x {m.pixels[1]} px "
                              f"display; the {p.label} has {cols} x {rows} px")
        px, py = p.pixel_size
        if m.version == 1 and abs(px - py) > SQUARE_TOLERANCE * max(px, py):
            raise FormatError(f"{m.name}: version-1 files store one pixel size; the {p.label} pixels are "
                              f"{px * 1000:.4g} x {py * 1000:.4g} um")

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        self.printer = plate_printer(self.name, path, grid, settings)
        m = self.machine
        self.layout = LAYOUTS[m.version]
        self.planes = 8 if settings.antialiased else 1
        self.greys = pws_greys(self.planes) if m.encoding == "pws" else PW0_GREYS
        self.addresses = self.plan(grid.layers)
        super().__init__(path, grid, meta, force, settings, placeholder=self.addresses["image"])
        self._layers: list[tuple[int, int, int]] = []           # (address, length, non-zero pixels)
        self._box = None                                         # native row0, row1, col0, col1 of the model

    def plan(self, n: int) -> dict:
        """Offsets of every table for ``n`` layers (all but the layer data have fixed sizes)."""
        v, lay = self.machine.version, self.layout
        a = {"header": lay.filemark}
        a["preview"] = a["header"] + 16 + lay.header
        at = a["preview"] + 16 + 12 + PREVIEW[0] * PREVIEW[1] * 2
        if v >= 516:
            a["colours"], at = at, at + 28
        a["layerdef"], at = at, at + 16 + 4 + 32 * n
        if v >= 516:
            a["extra"], at = at, at + 16 + 56
            a["machine"], at = at, at + lay.machine
        if v >= 517:
            a["software"], at = at, at + 164
            a["model"], at = at, at + 48
        if v >= 518:
            a["sublayers"], at = at, at + 16 + 8 + 44 * n
            a["preview2"], at = at, at + 16 + 12 + PREVIEW2[0] * PREVIEW2[1] * 2
        a["image"] = at
        return a

    def encode(self, native) -> bytes:
        """Layer data of a native image (8-bit greys, stored at the nearest
        level), or of its :class:`formats.rle.Band`."""
        codes = native.map(self.greys.code) if isinstance(native, Band) else self.greys.code[native]
        if self.machine.encoding == "pws":
            return encode_pws(codes, self.planes)
        return encode_pw0(codes, crc=self.machine.version == 1)

    #: layers are encoded on a thread pool (formats.base.write_ordered)
    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """Layer data, lit pixels and plate box of plate image ``k`` (thread-safe)."""
        band, box = self.native_band(image)
        return self.encode(band), int(np.count_nonzero(band.rows)), box

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        self.next_layer(k)
        data, lit, box = payload
        self._layers.append((self.tell(), len(data), lit))
        self.write(data, f"layer {k}")
        nbox = self.printer.native_box(box)
        if nbox is not None:
            old = self._box or nbox
            self._box = (min(old[0], nbox[0]), max(old[1], nbox[1]), min(old[2], nbox[2]), max(old[3], nbox[3]))
        self.layer_done(k, image, box)

    # ------------------------------------------------------------------ tables
    def filemark(self) -> bytes:
        v, a = self.machine.version, self.addresses
        fields = [a["header"], a.get("software", 0), a["preview"], a.get("colours", 0), a["layerdef"],
                  a.get("extra", 0)]
        if v >= 516:
            fields.append(a["machine"])
        fields.append(a["image"])
        if v >= 517:
            fields.append(a["model"])
        if v >= 518:
            fields += [a["sublayers"], a["preview2"]]
        return fixed_string("ANYCUBIC", 12) + struct.pack(f"<2I{len(fields)}I", v, self.layout.tables, *fields)

    def header(self) -> bytes:
        s, p, est, v = self.settings, self.printer, self.estimate, self.machine.version
        rows, cols = p.native_shape
        lift_d, lift_v, _, retract_v = p.lift
        aa = (self.planes if self.machine.encoding == "pws" else 16) if s.antialiased else 1
        body = struct.pack("<10f3I2f5I", max(p.pixel_size) * 1000.0, s.layer_height, s.exposure, p.layer_overhead,
                           s.bottom_exposure, float(s.bottom_layers), lift_d, lift_v / 60.0, retract_v / 60.0,
                           est.volume_ml, aa, cols, rows, est.weight_g, 0.0, ord("$"), 0,
                           int(round(est.seconds)), 0, 0)
        if v >= 516:
            body += struct.pack("<I", 0)                           # advanced mode off: one-stage lift
        if v >= 517:
            body += struct.pack("<2HI", 0, 0, 0)
        if v >= 518:
            body += struct.pack("<I", 0)
        assert len(body) == self.layout.header
        return _table("HEADER", body, with_head=False)

    def preview(self) -> bytes:
        w, h = PREVIEW
        mark = struct.pack("<I", 42) if self.machine.version == 1 else b"x\0\0\0"
        return _table("PREVIEW", struct.pack("<I", w) + mark + struct.pack("<I", h)
                      + rgb565(self._top.render(PREVIEW), big_endian=False), with_head=True)

    def colours(self) -> bytes:
        aa = 16 if self.settings.antialiased else 1
        greys = [min(int((i + 1) * 255.0 / aa), 255) for i in range(16)]
        return struct.pack("<2I16BI", 0, 16, *greys, 0)

    def layerdef(self) -> bytes:
        s, (lift_d, lift_v, _, _) = self.settings, self.printer.lift
        recs = [struct.pack("<2I4f2I", addr, size, lift_d, lift_v / 60.0, s.exposure_of(k), s.layer_height, lit, 0)
                for k, (addr, size, lit) in enumerate(self._layers)]
        return _table("LAYERDEF", struct.pack("<I", len(recs)) + b"".join(recs), with_head=False)

    def extra(self) -> bytes:
        lift_d, lift_v, _, retract_v = self.printer.lift
        up, down = lift_v / 60.0, retract_v / 60.0
        stage = (lift_d, up, down, 0.0, up, down)
        body = struct.pack("<I6fI6f", 2, *stage, 2, *stage)
        return fixed_string("EXTRA", 12) + struct.pack("<I", 24) + body

    def machine_table(self) -> bytes:
        p, m = self.printer, self.machine
        rows, cols = p.native_shape
        size = p.native_size
        body = (fixed_string(m.label, 96) + fixed_string(f"{m.encoding}Img", 16)
                + struct.pack("<2I3f2I", 16, self.layout.property_fields, size[0], size[1], p.max_height,
                              m.version, 6506241))
        if m.version >= 518:
            px, py = p.pixel_size
            body += struct.pack("<2f8I2I2H4I", px * 1000.0, py * 1000.0, *([0] * 8), 1, 0, cols, rows, 0, 0, 0, 0)
        assert len(body) + 16 == self.layout.machine
        return _table("MACHINE", body, with_head=True)

    def software(self) -> bytes:
        gen = self.meta.get("generator", "skelslice")
        return (fixed_string("skelslice", 32) + struct.pack("<I", 164) + fixed_string(gen.split()[-1], 32)
                + fixed_string("any", 64) + fixed_string("", 32))

    def model(self) -> bytes:
        p, s = self.printer, self.settings
        rows, cols = p.native_shape
        size = p.native_size
        cw, rh = size[0] / cols, size[1] / rows
        r0, r1, c0, c1 = self._box or (0, 0, 0, 0)
        box = (c0 * cw - size[0] / 2, r0 * rh - size[1] / 2, 0.0, c1 * cw - size[0] / 2, r1 * rh - size[1] / 2,
               s.layer_height * self._k)
        return _table("MODEL", struct.pack("<6fIf", *box, 0, 0.0), with_head=True)

    def sublayers(self) -> bytes:
        recs = [struct.pack("<3I8f", addr, size, lit, *([0.0] * 8)) for addr, size, lit in self._layers]
        return _table("SUBIMGS", struct.pack("<2I", len(recs), 1) + b"".join(recs), with_head=True)

    def preview2(self) -> bytes:
        w, h = PREVIEW2
        image = rgb565(self._top.render(PREVIEW2), big_endian=False)
        return _table("PREVIEW2", struct.pack("<I2HI", w, 4293, 0, h) + image, with_head=True)

    def tables(self) -> dict[int, bytes]:
        """Offset -> bytes of every table (needs every layer written)."""
        a = self.addresses
        out = {0: self.filemark(), a["header"]: self.header(), a["preview"]: self.preview(),
               a["layerdef"]: self.layerdef()}
        parts = {"colours": self.colours, "extra": self.extra, "machine": self.machine_table,
                 "software": self.software, "model": self.model, "sublayers": self.sublayers,
                 "preview2": self.preview2}
        out.update({a[key]: make() for key, make in parts.items() if key in a})
        return out

    def finish(self) -> dict[int, bytes]:
        return self.tables()


def _writer(m: Machine) -> type[PhotonWriter]:
    doc = f"Anycubic {m.label} file (``.{m.name}``, version {m.version}, {m.encoding} layers)."
    return type(f"{m.name.capitalize()}Writer", (PhotonWriter,),
                {"name": m.name, "machine": m, "default_printer": m.printer, "__doc__": doc, "__module__": __name__})


#: format name -> writer class, one per machine
PHOTON_WRITERS: dict[str, type[PhotonWriter]] = {name: _writer(m) for name, m in MACHINES.items()}

__all__ = ["PhotonWriter", "PHOTON_WRITERS", "MACHINES", "LAYOUTS", "Machine", "Layout", "encode_pw0", "encode_pws",
           "crc16", "pws_greys", "PW0_GREYS"]
