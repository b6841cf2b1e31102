"""Reading back the image stacks skelslice writes: PNG folders, zip, SL1/SL1S, GOO, NanoDLP.

For consumers of finished outputs (``skelslice check OUT``, ``skelslice
preview OUT``). :func:`open_stack` recognises the output and returns a
:class:`ReadStack`: the grid of its layers and a generator of the layers,
one 8-bit image at a time, bottom first.

* PNG folder and zip: ``slices.json`` gives the grid (scene mm; plate mm
  when the job had a printer, whose name is in ``print.printer``).
* SL1/SL1S (``config.ini``, ``prusaslicer.ini``), GOO (the header) and
  NanoDLP with a printer profile store the printer's native images; they
  are turned back into plate images (columns +X, rows -Y of the plate,
  :meth:`formats.printer_profiles.Printer.from_native`) with the built-in profile
  the file names, or one built from the file's own display settings.
* NanoDLP without a profile stores the grid's image padded on the right;
  its coordinates are the display's, about its centre (``frame ==
  "display"``).

Contour formats (CLI, SVG, 3MF slices) hold no images and are refused by
name.
"""
from __future__ import annotations

import configparser
import io
import json
import mmap
import re
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from PIL import Image

from slicer._kernels.formats.goo_rle import OK, decode_goo
from slicer.errors import ReadError
from slicer.input_limits import check_allocation, check_file_size, check_members, read_member
from slicer.tracer.grid import SliceGrid

from formats.goo import HEADER_SIZE, MAGIC
from formats.nanodlp import unpack_rgb
from formats.printer_profiles import PRINTERS, Printer, PrintSettings

#: suffixes of image outputs this module reads
IMAGE_SUFFIXES = (".zip", ".sl1", ".sl1s", ".goo", ".nanodlp")
#: contour outputs (no images)
CONTOUR_SUFFIXES = (".cli", ".svg", ".3mf")
#: memory :meth:`ReadStack.cropped` may keep to read a stack once instead of twice
KEEP_BYTES = 256 * 2**20


@dataclass
class ReadStack:
    """An output's layers, read one at a time.

    Attributes
    ----------
    path : Path
    format : str
        ``png``, ``zip``, ``sl1``, ``sl1s``, ``goo`` or ``nanodlp``.
    grid : slicer.tracer.grid.SliceGrid
        Grid of the (plate) images.
    frame : {"scene", "plate", "display"}
    printer : Printer or None
    settings : PrintSettings or None
        Exposure settings the file records.
    meta : dict
        The file's own metadata (``slices.json``, ``config.ini`` ...).
    """

    path: Path
    format: str
    grid: SliceGrid
    frame: str
    printer: Printer | None
    settings: PrintSettings | None
    meta: dict
    _read: Callable[[int], np.ndarray] = field(repr=False, default=None)
    _iter: Callable[[], Iterator[np.ndarray]] | None = field(repr=False, default=None)

    def layers(self, window=None) -> Iterator[np.ndarray]:
        """Each layer, bottom first, as a (h, w) uint8 plate image, or its
        ``window`` = (r0, c0, r1, c1) cut."""
        src = self._iter() if self._iter is not None else (self._read(k) for k in range(self.grid.layers))
        for k, img in enumerate(_guarded(src, self.path, self.format)):
            img = np.asarray(img)
            if img.shape != (self.grid.height, self.grid.width):
                raise ReadError(f"{self.path}: layer {k} is {img.shape[1]} x {img.shape[0]} px, expected "
                                f"{self.grid.width} x {self.grid.height}")
            if window is not None:
                r0, c0, r1, c1 = window
                img = img[r0:r1, c0:c1]
            yield np.ascontiguousarray(img, dtype=np.uint8)

    def solid_window(self, margin: int = 1) -> tuple[int, int, int, int]:
        """(r0, c0, r1, c1): the box of every layer's non-zero pixels plus
        ``margin`` (a pass over the whole stack); the whole image if empty."""
        return self.cropped(margin, keep=0)[0]

    def cropped(self, margin: int = 1, keep: int = KEEP_BYTES) -> tuple[tuple[int, int, int, int], Iterator[np.ndarray]]:
        """The box of every layer's non-zero pixels plus ``margin``, and the layers cut to it.

        One pass reads every layer and keeps the box of its own non-zero
        pixels while those boxes fit in ``keep`` bytes; the cut layers are then
        made from them, without reading the file again. Past the budget, the
        layers are read a second time.

        Parameters
        ----------
        margin : int, px
        keep : int, bytes
            Memory for the layers' own boxes; 0 always reads twice.

        Returns
        -------
        window : (r0, c0, r1, c1)
            As :meth:`solid_window`; the whole image if every layer is empty.
        layers : iterator of (r1 - r0, c1 - c0) uint8
        """
        H, W = self.grid.height, self.grid.width
        r0, c0, r1, c1 = H, W, 0, 0
        kept, used = [], 0
        for img in self.layers():
            rows = np.flatnonzero(img.any(axis=1))
            box = None
            if rows.size:
                cols = np.flatnonzero(img[rows[0]:rows[-1] + 1].any(axis=0))
                box = (int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1)
                r0, c0 = min(r0, box[0]), min(c0, box[1])
                r1, c1 = max(r1, box[2]), max(c1, box[3])
            if kept is not None:
                cut = None if box is None else img[box[0]:box[2], box[1]:box[3]].copy()
                used += 0 if cut is None else cut.nbytes
                kept.append((box, cut))
                if used > keep:
                    kept = None
        if r1 == 0:
            window = (0, 0, H, W)
        else:
            window = (max(r0 - margin, 0), max(c0 - margin, 0), min(r1 + margin, H), min(c1 + margin, W))
        return window, (self.layers(window) if kept is None else _pasted(kept, window))


def _pasted(kept: list, window: tuple[int, int, int, int]) -> Iterator[np.ndarray]:
    """Layers of ``window`` made from each layer's (box, pixels) of :meth:`ReadStack.cropped`."""
    r0, c0, r1, c1 = window
    for box, cut in kept:
        out = np.zeros((r1 - r0, c1 - c0), np.uint8)
        if box is not None:
            out[box[0] - r0:box[2] - r0, box[1] - c0:box[3] - c0] = cut
        yield out


#: what a malformed member, record or table raises while a stack is read
_MALFORMED = (zipfile.BadZipFile, KeyError, ValueError, TypeError, AttributeError, struct.error, OSError, IndexError,
              EOFError, zlib.error)
#: smallest GOO layer record, bytes: 66-byte definition, 4-byte size, 0x55, checksum, delimiter
GOO_MIN_RECORD = 66 + 4 + 2 + 2


def _guarded(src: Iterator, path, kind: str) -> Iterator:
    """``src``'s items; a malformed member or record met while reading becomes one :class:`ReadError`."""
    try:
        yield from src
    except _MALFORMED as exc:
        if isinstance(exc, ReadError):
            raise
        raise ReadError(f"{path}: cannot read the {kind} file ({type(exc).__name__}: {exc})") from None


def _check_stack(rs: "ReadStack", p: Path) -> "ReadStack":
    """Refuse a stack whose declared image size passes the input limit (before any layer is read)."""
    g = rs.grid
    if g.width < 1 or g.height < 1 or g.layers < 0:
        raise ReadError(f"{p}: the file declares {g.width} x {g.height} px and {g.layers} layers")
    check_allocation(g.width * g.height, 4, f"layer images of {g.width:,} x {g.height:,} px", p, ReadError)
    return rs


def kind_of(path) -> str | None:
    """The output format of ``path`` (``png`` for a folder with ``slices.json``), or None."""
    p = Path(path)
    if p.is_dir():
        return "png" if (p / "slices.json").is_file() else None
    suffix = p.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return suffix[1:]
    return None


def open_stack(path) -> ReadStack:
    """Open an image output of skelslice.

    Raises
    ------
    ReadError
        Not an image output (a contour format, a folder without
        ``slices.json``, an unknown suffix), or a malformed file (naming the
        member and the value).
    """
    p = Path(path)
    if not p.exists():
        raise ReadError(f"{p}: no such file or folder")
    kind = kind_of(p)
    if kind is None:
        if p.is_dir():
            raise ReadError(f"{p}: a folder without slices.json is not a skelslice PNG stack")
        if p.suffix.lower() in CONTOUR_SUFFIXES:
            raise ReadError(f"{p}: {p.suffix[1:].upper()} files hold contours, not layer images; "
                            "preview and check read png folders, zip, sl1, sl1s, goo and nanodlp")
        raise ReadError(f"{p}: not a layer stack skelslice reads (a png folder with slices.json, "
                        ".zip, .sl1, .sl1s, .goo or .nanodlp)")
    try:
        return _check_stack(_OPENERS[kind](p), p)
    except _MALFORMED as exc:
        if isinstance(exc, ReadError):
            raise
        raise ReadError(f"{p}: cannot read the {kind} file ({type(exc).__name__}: {exc})") from None


# ---------------------------------------------------------------- png folder and zip
def _settings_of(doc: dict, h: float) -> tuple[Printer | None, PrintSettings | None]:
    pr = doc.get("print")
    if not isinstance(pr, dict):
        return None, None
    prn = PRINTERS.get(str(pr.get("printer", "")).lower()) if pr.get("printer") else None
    s = PrintSettings(prn, h, float(pr.get("exposure", 2.0)), float(pr.get("bottom_exposure", 25.0)),
                      int(pr.get("bottom_layers", 10)), int(pr.get("aa", 1)), bool(pr.get("aa_z", False)),
                      float(pr.get("gamma", 1.0)))
    return prn, s


def _grid_of(doc: dict, src) -> SliceGrid:
    try:
        g = SliceGrid(tuple(float(v) for v in doc["origin"]), tuple(float(v) for v in doc["pixel_size"]),
                      float(doc["layer_height"]), int(doc["width"]), int(doc["height"]), int(doc["layers"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ReadError(f"{src}: slices.json lacks or has a bad grid key ({exc})") from None
    files = doc.get("files")
    if not isinstance(files, list) or len(files) != g.layers:
        raise ReadError(f"{src}: slices.json lists {len(files) if isinstance(files, list) else 'no'} files "
                        f"for {g.layers} layers")
    return g


def _grey(data: bytes, name) -> np.ndarray:
    try:
        img = Image.open(io.BytesIO(data))
        img.load()
    except Exception as exc:                     # PIL raises many types for bad data
        raise ReadError(f"{name}: not a readable PNG ({exc})") from None
    if img.mode not in ("L", "1", "P"):
        raise ReadError(f"{name}: expected an 8-bit greyscale PNG, got mode {img.mode}")
    return np.asarray(img if img.mode == "L" else img.convert("L"))


def _open_png(p: Path) -> ReadStack:
    if (p / "slices.json").is_file():
        check_file_size(p / "slices.json", ReadError)
    try:
        doc = json.loads((p / "slices.json").read_text())
    except (OSError, ValueError) as exc:
        raise ReadError(f"{p / 'slices.json'}: cannot read ({exc})") from None
    g = _grid_of(doc, p / "slices.json")
    prn, s = _settings_of(doc, g.layer_height)
    files = doc["files"]
    return ReadStack(p, "png", g, "plate" if prn else "scene", prn, s, doc,
                     _read=lambda k: _grey((p / files[k]).read_bytes(), p / files[k]))


def _open_zip(p: Path) -> ReadStack:
    with zipfile.ZipFile(p) as z:
        check_members(z, p, ReadError)
        try:
            doc = json.loads(read_member(z, "slices.json", p, ReadError))
        except KeyError:
            raise ReadError(f"{p}: no slices.json: not a skelslice zip stack") from None
        names = set(z.namelist())
    g = _grid_of(doc, f"{p}:slices.json")
    prn, s = _settings_of(doc, g.layer_height)
    files = doc["files"]
    missing = next((f for f in files if not isinstance(f, str) or f not in names), None)
    if missing is not None:
        raise ReadError(f"{p}: slices.json lists {len(files):,} layer files, but the archive holds no {missing!r}")

    def layers():
        with zipfile.ZipFile(p) as z:
            for f in files:
                yield _grey(read_member(z, f, p, ReadError), f"{p}:{f}")

    return ReadStack(p, "zip", g, "plate" if prn else "scene", prn, s, doc, _iter=layers)


# ---------------------------------------------------------------- plate helpers
def _plate_grid(prn: Printer, h: float, n: int) -> SliceGrid:
    px, py = prn.pixel_size
    return SliceGrid((0.5 * px, prn.display[1] - 0.5 * py, 0.5 * h), (px, py), h, prn.pixels[0], prn.pixels[1], n)


def _printer_for(model: str, pixels, display, orientation, mirror_x, mirror_y, src) -> Printer:
    """The built-in profile with this machine code and display, else one made from the file's values."""
    pixels = (int(pixels[0]), int(pixels[1]))
    for prn in PRINTERS.values():
        if prn.model == model and prn.pixels == pixels and prn.orientation == orientation \
                and prn.mirror_x == mirror_x and prn.mirror_y == mirror_y \
                and np.allclose(prn.display, display, rtol=1e-6):
            return prn
    if orientation not in ("portrait", "landscape"):
        raise ReadError(f"{src}: unknown display orientation {orientation!r}")
    return Printer(f"file:{model or 'unknown'}", model or "printer of the file", "", pixels,
                   (float(display[0]), float(display[1])), orientation, bool(mirror_x), bool(mirror_y),
                   1e9, 0.05, 2.0, 25.0, 10, "zip", model)


# ---------------------------------------------------------------- SL1 / SL1S
def _ini(text: str) -> dict:
    cp = configparser.ConfigParser(interpolation=None, strict=False)
    cp.optionxform = str
    cp.read_string("[x]\n" + text)
    return dict(cp["x"])


def _open_sl1(p: Path) -> ReadStack:
    with zipfile.ZipFile(p) as z:
        check_members(z, p, ReadError)
        names = z.namelist()
        try:
            cfg = _ini(read_member(z, "config.ini", p, ReadError).decode())
        except KeyError:
            raise ReadError(f"{p}: no config.ini: not an SL1 archive") from None
        ps = _ini(read_member(z, "prusaslicer.ini", p, ReadError).decode()) if "prusaslicer.ini" in names else {}
    job = cfg.get("jobDir", "")
    pat = re.compile(re.escape(job) + r"(\d{5})\.png$")
    ks = sorted(int(m.group(1)) for m in map(pat.match, names) if m)
    if ks != list(range(len(ks))):
        raise ReadError(f"{p}: layer files {job}00000.png ... are not numbered 0 to {len(ks) - 1}")
    h = float(cfg.get("layerHeight", ps.get("layer_height", 0.05)))
    model = cfg.get("printerModel", "")
    try:
        pixels = (int(ps["display_pixels_x"]), int(ps["display_pixels_y"]))
        display = (float(ps["display_width"]), float(ps["display_height"]))
        prn = _printer_for(model, pixels, display, ps.get("display_orientation", "portrait"),
                           ps.get("display_mirror_x", "0") == "1", ps.get("display_mirror_y", "0") == "1", p)
    except KeyError:
        matches = [q for q in PRINTERS.values() if q.model == model and q.format.startswith("sl1")]
        if not matches:
            raise ReadError(f"{p}: no prusaslicer.ini and unknown printerModel {model!r}") from None
        prn = matches[0]
    s = PrintSettings(prn, h, float(cfg.get("expTime", prn.exposure)),
                      float(cfg.get("expTimeFirst", prn.bottom_exposure)), int(cfg.get("numFade", prn.bottom_layers)))

    def layers():
        with zipfile.ZipFile(p) as z:
            for k in ks:
                name = f"{job}{k:05d}.png"
                img = _grey(read_member(z, name, p, ReadError), f"{p}:{name}")
                if img.shape != prn.native_shape:
                    raise ReadError(f"{p}:{name}: {img.shape[1]} x {img.shape[0]} px, the display is "
                                    f"{prn.native_shape[1]} x {prn.native_shape[0]}")
                yield prn.from_native(img)

    fmt = "sl1s" if p.suffix.lower() == ".sl1s" else "sl1"
    return ReadStack(p, fmt, _plate_grid(prn, h, len(ks)), "plate", prn, s, {"config.ini": cfg, "prusaslicer.ini": ps},
                     _iter=layers)


# ---------------------------------------------------------------- GOO
def _open_goo(p: Path) -> ReadStack:
    with open(p, "rb") as fh:
        head = fh.read(HEADER_SIZE)
    if len(head) < HEADER_SIZE or head[0:4] != b"V3.0" or head[4:12] != MAGIC:
        raise ReadError(f"{p}: not a GOO V3.0 file (bad magic or a header shorter than {HEADER_SIZE} bytes)")
    model = head[92:124].split(b"\0")[0].decode("ascii", "replace")
    n, xres, yres = struct.unpack_from(">IHH", head, 195310)
    mx, my = struct.unpack_from(">??", head, 195318)
    xs, ys, _zs, h, exp = struct.unpack_from(">5f", head, 195320)
    bexp, blayers = struct.unpack_from(">fI", head, 195369)
    if struct.unpack_from(">I", head, 195470)[0] != HEADER_SIZE:
        raise ReadError(f"{p}: the layer content offset is not {HEADER_SIZE}")
    size = p.stat().st_size
    if HEADER_SIZE + n * GOO_MIN_RECORD > size:
        raise ReadError(f"{p}: the header says {n:,} layers, which need at least "
                        f"{HEADER_SIZE + n * GOO_MIN_RECORD:,} bytes; the file has {size:,}")
    check_allocation(xres * yres, 1, f"layer images of {xres:,} x {yres:,} px", p, ReadError)
    prn = _printer_for(model, (xres, yres), (xs, ys), "landscape", mx, my, p)
    h = float(np.float32(h))
    h = round(h, 6)
    s = PrintSettings(prn, h, round(float(exp), 6), round(float(bexp), 6), int(blayers))

    def layers():
        with open(p, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as raw:
            yield from _goo_layers(raw, p, n, xres, yres, prn)

    return ReadStack(p, "goo", _plate_grid(prn, h, n), "plate", prn, s, {"printer_name": model}, _iter=layers)


def _goo_layers(raw, p: Path, n: int, xres: int, yres: int, prn: Printer) -> Iterator[np.ndarray]:
    """The plate images of a GOO file's ``n`` layer records (``raw``: the whole file, bytes or mmap)."""
    off = HEADER_SIZE
    for k in range(n):
        off += 66
        if raw[off - 2:off] != b"\r\n":
            raise ReadError(f"{p}: layer {k}: no record delimiter at byte {off - 2}")
        (size,) = struct.unpack_from(">I", raw, off)
        if size < 2 or off + 5 + size + 1 > len(raw):
            raise ReadError(f"{p}: layer {k}: the record says {size:,} bytes of data at byte {off}; the file "
                            f"has {len(raw):,}")
        if raw[off + 4] != 0x55:
            raise ReadError(f"{p}: layer {k}: no 0x55 magic at byte {off + 4}")
        payload = np.frombuffer(bytes(raw[off + 5:off + 3 + size]), np.uint8)  # a copy: the mmap closes
        if raw[off + 5 + size - 2] != (~int(payload.sum(dtype=np.uint64))) & 0xFF:
            raise ReadError(f"{p}: layer {k}: bad checksum")
        img = np.zeros(xres * yres, np.uint8)
        status, where = decode_goo(payload, img)
        if status != OK:
            raise ReadError(f"{p}: layer {k}: bad run-length data (code {status} at {where})")
        end = off + 5 + size - 1                        # after the checksum
        if raw[end:end + 2] != b"\r\n":
            raise ReadError(f"{p}: layer {k}: no delimiter after the layer data at byte {end}")
        off = end + 2
        yield prn.from_native(img.reshape(yres, xres))


# ---------------------------------------------------------------- NanoDLP
def _open_nanodlp(p: Path) -> ReadStack:
    with zipfile.ZipFile(p) as z:
        check_members(z, p, ReadError)
        try:
            plate = json.loads(read_member(z, "plate.json", p, ReadError))
            opts = json.loads(read_member(z, "options.json", p, ReadError))
            prof = json.loads(read_member(z, "profile.json", p, ReadError))
            names = set(z.namelist())
        except KeyError as exc:
            raise ReadError(f"{p}: no {exc.args[0]}: not a NanoDLP archive") from None
    n = int(plate["LayersCount"])
    cols, rows = int(opts["PWidth"]), int(opts["PHeight"])
    missing = [f"{k}.png" for k in (1, n) if f"{k}.png" not in names] if n > 0 else []
    if missing:
        raise ReadError(f"{p}: plate.json says {n:,} layers, but there is no {missing[0]}")
    cw, rh = float(opts["XPixelSize"]), float(opts["YPixelSize"])
    h = float(prof["Depth"]) / 1000.0
    prn = next((q for q in PRINTERS.values() if q.label == prof.get("Title") and q.native_shape == (rows, cols)), None)
    exposure = (float(prof.get("CureTime", 2.0)), float(prof.get("SupportCureTime", 25.0)),
                int(prof.get("SupportLayerNumber", 10)))
    s = PrintSettings(prn, h, *exposure)
    if prn is not None:
        grid, frame = _plate_grid(prn, h, n), "plate"
    else:
        grid = SliceGrid(((0.5 - cols / 2) * cw, (rows / 2 - 0.5) * rh, 0.5 * h), (cw, rh), h, cols, rows, n)
        frame = "display"

    def layers():
        with zipfile.ZipFile(p) as z:
            for k in range(1, n + 1):
                img = np.asarray(Image.open(io.BytesIO(read_member(z, f"{k}.png", p, ReadError))).convert("RGB"))
                disp = unpack_rgb(img)
                if disp.shape != (rows, cols):
                    raise ReadError(f"{p}:{k}.png: {disp.shape[1]} x {disp.shape[0]} display px, expected "
                                    f"{cols} x {rows}")
                yield prn.from_native(disp) if prn is not None else disp

    return ReadStack(p, "nanodlp", grid, frame, prn, s, {"options.json": opts, "profile.json": prof}, _iter=layers)


_OPENERS = {"png": _open_png, "zip": _open_zip, "sl1": _open_sl1, "sl1s": _open_sl1, "goo": _open_goo,
            "nanodlp": _open_nanodlp}

__all__ = ["ReadStack", "open_stack", "kind_of", "IMAGE_SUFFIXES"]
