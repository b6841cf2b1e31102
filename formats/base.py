"""Writer protocol and the helpers writers share (PNG bytes, zip entries, build
time, fixed-width strings, single-file binary formats).

Atomic publication is :mod:`slicer.atomic` (one implementation for every output)."""
from __future__ import annotations

import functools
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from slicer.atomic import AtomicDir, AtomicFile, check_destination
from slicer.arguments import integer, number
from slicer.errors import FormatError, OutputError
from slicer.scale.ordered_map import map_in_order

from formats.estimate import LayerMeter
from formats.rle import Band, occupied
from formats.thumbnails import TopView


class StackWriter:
    """Streams a layer stack to one output, published atomically.

    Parameters
    ----------
    path : path-like
        Final output location.
    grid : slicer.tracer.grid.SliceGrid
        Grid of the layers.
    meta : dict
        Extra metadata (method, scene, ...), written where the format allows.
    force : bool
        Replace an existing output.
    settings : formats.printer_profiles.PrintSettings, optional
        Printer, exposure and anti-aliasing settings (printer formats need a
        printer; others record them as metadata).
    """

    #: printer-format writers name the profile they imply without --printer
    default_printer: str | None = None
    #: True: the format cannot be written without a printer profile
    needs_printer: bool = False
    #: print time and resin volume of the written stack (formats.estimate.PrintEstimate),
    #: set by close() in the formats that know a printer; None otherwise
    estimate = None

    def __init__(self, path, grid, meta: dict | None = None, force: bool = False, settings=None):
        self.path = Path(path)
        self.grid = grid
        self.meta = dict(meta or {})
        self.force = force
        self.settings = settings
        self._k = 0                        # layers written
        check_destination(self.path, force)

    def next_layer(self, k: int) -> None:
        """Check that layer ``k`` is the next one."""
        if k != self._k:
            raise ValueError(f"layers must be written in order: expected {self._k}, got {k}")

    #: True when :meth:`encode_layer` does the costly part and is thread-safe
    #: (:func:`write_ordered` then runs it on a thread pool)
    parallel_encode: bool = False

    def write_layer(self, k: int, image: np.ndarray) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def encode_layer(self, k: int, image: np.ndarray):
        """The encoded payload of layer ``k`` (pure: no writer state is read
        or changed, so several layers may be encoded at once). Default: None,
        and :meth:`store_layer` does all the work."""
        return None

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        """Write layer ``k`` from its :meth:`encode_layer` payload (in order,
        one thread). Default: :meth:`write_layer`."""
        self.write_layer(k, image)

    def close(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def abort(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


#: largest 32-bit float
F32_MAX = float(np.finfo(np.float32).max)


class BinaryStackWriter(StackWriter):
    """A printer's single binary file, written through one seekable temporary file.

    ``__init__`` writes ``placeholder`` zero bytes (the fixed-size tables that
    come before the layers); ``write_layer`` appends each layer with
    :meth:`write` and ends with :meth:`layer_done`; :meth:`close` sets
    :attr:`estimate`, lets :meth:`finish` append what follows the layers and
    return the tables that need the whole stack (offset -> bytes), writes
    them over the placeholders and publishes the file. Subclasses set
    ``self.printer`` before calling ``__init__``.
    """

    #: largest file the format's offsets can address (None: no limit)
    max_size: int | None = None
    #: largest bottom-layer count the format's field holds (u32; an f32 field holds 2**24 exactly)
    max_bottom_layers: int = 0xFFFFFFFF

    @classmethod
    def check_settings(cls, settings) -> None:
        """Refuse times and counts the format's fields cannot hold (FormatError):
        exposures and layer height beyond a 32-bit float, bottom layers beyond
        :attr:`max_bottom_layers`."""
        for value, option in ((settings.exposure, "--exposure"), (settings.bottom_exposure, "--bottom-exposure"),
                              (settings.layer_height, "--layer-height")):
            number(value, f"{cls.name}: {option}", FormatError, lo=0.0, lo_open=True, hi=F32_MAX)
        integer(settings.bottom_layers, f"{cls.name}: --bottom-layers", FormatError, lo=0, hi=cls.max_bottom_layers)

    def __init__(self, path, grid, meta=None, force=False, settings=None, placeholder: int = 0):
        self.check_settings(settings)
        super().__init__(path, grid, meta, force, settings)
        self._out = AtomicFile(self.path)
        self._meter = LayerMeter()
        self._top = TopView(self.printer.plate_shape)
        self.write(b"\0" * placeholder, "the header")

    def tell(self) -> int:
        """Offset where the next :meth:`write` lands."""
        return self._out.fh.tell()

    def write(self, data: bytes, what: str) -> None:
        """Append ``data`` (``what`` names it in errors).

        Raises
        ------
        OutputError
            The write failed, or the file passes :attr:`max_size`; nothing is
            left at the target.
        """
        try:
            self._out.fh.write(data)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot write {what} ({exc})") from None
        if self.max_size is not None and self.tell() > self.max_size:
            self.abort()
            raise OutputError(f"{self.path}: the file passes {self.max_size + 1:,} bytes, beyond the "
                              f"{self.name} format's offsets")

    def layer_done(self, k: int, image: np.ndarray, box=False) -> None:
        """Record plate image ``k`` for the estimate and previews, after its data
        (``box``: its :func:`formats.rle.occupied` box if known)."""
        self._meter.add(image, box)
        self._top.add(k, image, box)
        self._k += 1

    def native_band(self, image: np.ndarray) -> tuple[Band, tuple | None]:
        """The printer's native image of plate image ``image`` as a
        :class:`formats.rle.Band` (only the model's box is read once the box is
        found), and the plate box (:func:`formats.rle.occupied`)."""
        box = occupied(image)
        return Band.of(self.printer.to_native(image), self.printer.native_box(box)), box

    def finish(self) -> dict[int, bytes]:  # pragma: no cover - protocol
        """Append what follows the layers; return offset -> bytes to write over the placeholders."""
        raise NotImplementedError

    def close(self) -> None:
        if self._k != self.grid.layers:
            self.abort()
            raise OutputError(f"{self.path}: {self._k} of {self.grid.layers} layers were written")
        self.estimate = self._meter.estimate(self.settings)
        parts = self.finish()
        try:
            fh = self._out.fh
            for at, data in sorted(parts.items()):
                fh.seek(at)
                fh.write(data)
            fh.seek(0, 2)
            self._out.publish(self.force)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot finish the output ({exc})") from None

    def abort(self) -> None:
        self._out.discard()


def fixed_string(text: str, n: int) -> bytes:
    """An ``n``-byte NUL-padded ASCII field holding at most ``n - 1`` characters of ``text``.

    Examples
    --------
    >>> fixed_string("ANYCUBIC", 12)
    b'ANYCUBIC\\x00\\x00\\x00\\x00'
    """
    b = text.encode("ascii", "replace")[:n - 1]
    return b + b"\0" * (n - len(b))


def encode_workers() -> int:
    """Threads for :func:`write_ordered` by default: the cores this process may use (at most 8)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 8))


def write_ordered(writer: StackWriter, layers, workers: int | None = None) -> int:
    """Write ``layers`` (an iterable of images, bottom first) to ``writer`` in order.

    With a writer whose :meth:`StackWriter.encode_layer` is thread-safe
    (``parallel_encode``) and ``workers > 1``, layers are encoded on a pool of
    ``workers`` threads (zlib and Pillow release the GIL), at most
    ``2 * workers`` in flight, while the next layers are produced
    (:func:`slicer.scale.ordered_map.map_in_order`); payloads
    are stored strictly in layer order, so the output is byte-identical to
    a serial run. Memory: ``2 * workers`` layers and their payloads.

    Returns
    -------
    int
        Layers written.
    """
    workers = encode_workers() if workers is None else int(workers)
    n = 0
    if workers <= 1 or not writer.parallel_encode:
        for k, img in enumerate(layers):
            writer.write_layer(k, img)
            n += 1
        return n
    for (k, img), payload in map_in_order(lambda item: writer.encode_layer(*item), enumerate(layers), workers,
                                          name="encode"):
        writer.store_layer(k, img, payload)
        n += 1
    return n


#: zlib level of layer PNGs (docs/formats.md, layer PNGs): 3 is the fastest level that
#: keeps the files no larger than Pillow's filtered level 3 made them
PNG_LEVEL = 3
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bytes(image: np.ndarray, level: int = PNG_LEVEL, box=False) -> bytes:
    """An 8-bit PNG of a (h, w) greyscale or (h, w, 3) RGB uint8 image.

    Written directly (PNG 1.2): one IHDR (depth 8, colour type 0 or 2, no
    interlace), one IDAT whose rows all use filter type 0 (None), IEND. On
    slice layers -- runs of 0 and 255 -- deflating the raw rows is several
    times faster than choosing a filter per row and compresses as well:
    the row above is a match at a fixed distance. zlib releases the GIL, so
    layers encode in parallel (:func:`write_ordered`).

    Parameters
    ----------
    image : (h, w) or (h, w, 3) uint8
    level : int
        zlib level, 0..9.
    box : (r0, r1, c0, c1), None or False
        Where the non-zero pixels are, if known (:func:`formats.rle.occupied`):
        only that box of ``image`` is read (a transposed plate is then not
        gathered whole), and the zero rows around it are not deflated again
        (:func:`png_bytes_sparse`). None: the image is all zero. False: read
        and deflate it all.

    Returns
    -------
    bytes

    Raises
    ------
    FormatError
        Not a 2-D or (h, w, 3) image, or an empty one.
    """
    image = np.asarray(image)
    colour, channels = _png_colour(image.shape, "")
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        raise FormatError(f"a PNG image needs at least one pixel, got {w} x {h}")
    if box is not False:
        if box is None:
            return png_bytes_sparse(h, w, np.zeros((0, 0) + image.shape[2:], np.uint8), (0, 0), level)
        r0, r1, c0, c1 = box
        return png_bytes_sparse(h, w, image[r0:r1, c0:c1], (r0, c0), level)
    rows = np.empty((h, 1 + w * channels), np.uint8)
    rows[:, 0] = 0                                 # filter type None on every row
    if channels == 1:
        rows[:, 1:] = image                        # one strided copy, whatever the layout
    else:
        rows[:, 1:] = image.reshape(h, w * channels)
    c = zlib.compressobj(level, zlib.DEFLATED, 15, 8, _strategy(rows, level))
    return _png_file(w, h, colour, c.compress(rows.data) + c.flush())


def png_bytes_sparse(height: int, width: int, block: np.ndarray, at: tuple[int, int],
                     level: int = PNG_LEVEL) -> bytes:
    """An 8-bit PNG of a ``height`` x ``width`` image that is zero except for
    ``block``, whose top-left pixel is at row and column ``at``.

    The image is never built whole. Its rows above and below the block are
    all zero bytes (filter type None, zero pixels); they are deflated as
    runs of cached pieces (each a power of two bytes long and ended by a
    full flush, so pieces join anywhere), and the zlib checksum of a zero
    run is computed, not summed. Only the rows of the block are deflated.
    The pixels are those of :func:`png_bytes` on the whole image; the
    deflate stream is another one (a few hundred bytes longer at most).

    Parameters
    ----------
    height, width : int, pixels
    block : (bh, bw) or (bh, bw, 3) uint8
        Greyscale or RGB; the PNG's colour type follows it.
    at : (row, col)
        Where ``block[0, 0]`` lies; the block must fit inside the image.
    level : int
        zlib level, 0..9.

    Returns
    -------
    bytes

    Raises
    ------
    FormatError
        An empty image, a block that is not greyscale or RGB, or one that does
        not fit.
    """
    block = np.asarray(block)
    colour, channels = _png_colour(block.shape, "a block of ")
    if height <= 0 or width <= 0:
        raise FormatError(f"a PNG image needs at least one pixel, got {width} x {height}")
    bh, bw = block.shape[:2]
    r0, c0 = (int(v) for v in at)
    if bh == 0 or bw == 0:
        bh = bw = r0 = c0 = 0
    elif not (0 <= r0 and r0 + bh <= height and 0 <= c0 and c0 + bw <= width):
        raise FormatError(f"a {bw} x {bh} px block at row {r0}, column {c0} does not fit a {width} x {height} "
                          f"px PNG")
    rowlen = 1 + width * channels
    band = np.zeros((bh, rowlen), np.uint8)       # filter type None; zero outside the block
    if bh:
        band[:, 1 + c0 * channels:1 + (c0 + bw) * channels] = block.reshape(bh, bw * channels)
    above = r0 * rowlen
    below = (height - r0 - bh) * rowlen
    adler = _adler32_zeros(1, above)
    adler = zlib.adler32(band.data, adler)
    adler = _adler32_zeros(adler, below)
    stream = b"".join((_zlib_header(level), _deflated_zeros(above, level),
                       _deflated(band.data, level, _strategy(band, level)),
                       _deflated_zeros(below, level), _FINAL_EMPTY_BLOCK, struct.pack(">I", adler)))
    return _png_file(width, height, colour, stream)


def _png_colour(shape: tuple, what: str) -> tuple[int, int]:
    """PNG colour type and channels of a (h, w) grey or (h, w, 3) RGB array."""
    if len(shape) == 2:
        return 0, 1
    if len(shape) == 3 and shape[2] == 3:
        return 2, 3
    raise FormatError(f"PNG layers are (h, w) greyscale or (h, w, 3) RGB images, not {what}shape {shape}")


def _png_file(w: int, h: int, colour: int, idat: bytes) -> bytes:
    header = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    return b"".join((_PNG_SIGNATURE, _png_chunk(b"IHDR", header), _png_chunk(b"IDAT", idat),
                     _png_chunk(b"IEND", b"")))


#: a raw deflate block that ends a stream: final, fixed codes, nothing but end-of-block
_FINAL_EMPTY_BLOCK = b"\x03\x00"
#: zero runs are deflated in cached pieces of 2^k bytes, k >= this
_ZERO_PIECE_BITS = 12
#: rows of a layer deflated both ways to choose its strategy (:func:`_strategy`)
_SAMPLE_ROWS = 32


@functools.lru_cache(maxsize=None)
def _zlib_header(level: int) -> bytes:
    """The two header bytes zlib writes at this level."""
    return zlib.compress(b"", level)[:2]


def _deflated(data, level: int, strategy: int = zlib.Z_DEFAULT_STRATEGY) -> bytes:
    """Raw deflate blocks of ``data``, ended by a full flush: byte-aligned,
    referring to nothing before them, not final."""
    c = zlib.compressobj(level, zlib.DEFLATED, -15, 8, strategy)
    return c.compress(data) + c.flush(zlib.Z_FULL_FLUSH)


def _strategy(rows: np.ndarray, level: int) -> int:
    """zlib's run-length strategy (matches at distance 1 only) or its default
    one, whichever deflates the middle :data:`_SAMPLE_ROWS` of ``rows``
    ((h, n) uint8, PNG rows) smaller; the default on a tie.

    Sparse plates (long empty stretches in every row) deflate several times
    smaller with runs; dense lattices, whose rows repeat the row above, with
    the default search (docs/formats.md, layer PNGs).
    """
    h = rows.shape[0]
    if h == 0:
        return zlib.Z_DEFAULT_STRATEGY
    a = max(0, h // 2 - _SAMPLE_ROWS // 2)
    sample = np.ascontiguousarray(rows[a:a + _SAMPLE_ROWS]).data
    rle = len(_deflated(sample, level, zlib.Z_RLE))
    default = len(_deflated(sample, level))
    return zlib.Z_RLE if rle < default else zlib.Z_DEFAULT_STRATEGY


@functools.lru_cache(maxsize=None)
def _deflated_zero_piece(n: int, level: int) -> bytes:
    return _deflated(bytes(n), level, zlib.Z_RLE)


def _deflated_zeros(n: int, level: int) -> bytes:
    """Raw deflate blocks of ``n`` zero bytes (see :func:`_deflated`), with
    the run-length strategy: 1 kB a MiB, where the default search makes 4.5 kB."""
    parts = []
    bit = n.bit_length() - 1
    while bit >= _ZERO_PIECE_BITS:
        if n >= 1 << bit:
            parts.append(_deflated_zero_piece(1 << bit, level))
            n -= 1 << bit
        bit -= 1
    if n:
        parts.append(_deflated(bytes(n), level, zlib.Z_RLE))
    return b"".join(parts)


def _adler32_zeros(adler: int, n: int) -> int:
    """zlib's Adler-32 of ``n`` zero bytes appended to data whose checksum is ``adler``:
    the low sum does not change and the high one grows by ``n`` times it."""
    a = adler & 0xFFFF
    b = adler >> 16
    return (((b + n * a) % 65521) << 16) | a


def build_time():
    """The creation time written into archives: ``SOURCE_DATE_EPOCH`` (UTC) if
    set, else 1980-01-01 00:00:00 UTC, so that the same input and settings
    give byte-identical files."""
    import datetime

    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    t = int(epoch) if epoch and epoch.strip().isdigit() else 315532800
    return datetime.datetime.fromtimestamp(max(t, 315532800), datetime.timezone.utc)


def zip_entry(name: str, compress: bool):
    """A ZipInfo with the fixed :func:`build_time`, deflated or stored."""
    import zipfile

    info = zipfile.ZipInfo(name, date_time=build_time().timetuple()[:6])
    info.compress_type = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    info.external_attr = 0o644 << 16
    return info


__all__ = ["StackWriter", "BinaryStackWriter", "fixed_string", "png_bytes", "png_bytes_sparse", "write_ordered", "encode_workers", "build_time", "zip_entry",
           "check_destination", "AtomicFile", "AtomicDir"]
