"""Limits on what the readers take from an input file, checked before the work.

A file sent by someone else must not stop the slicer: every reader takes its
input in time linear in the file's size, and refuses, with one line naming
the file, the member and the number, what would take more than the limits
below -- before anything large is allocated or decompressed.

* **Uncompressed bytes** (``max_bytes``, default 1 GiB; ``skelslice
  --max-input-bytes SIZE``): the most bytes a reader takes from one archive
  member (a 3MF model part, a zip stack's ``slices.json`` or layer, an SL1 or
  NanoDLP member) or from one plain scene file (JSON, OBJ; :func:`check_file_size`),
  and the largest array a count declared in a file may ask for (vertices,
  triangles, an image's width x height; :func:`check_allocation`).
* **Compression ratio** (``max_ratio``, default 200; ``skelslice
  --max-input-ratio N``): an archive member may expand to
  ``max(RATIO_FREE, max_ratio x its compressed size)`` bytes. XML and JSON
  compress 5 to 30 times; a member far past that is a decompression bomb.
* **XML tokens** (:data:`MAX_TOKEN`, 16 MiB, fixed): no comment, processing
  instruction or tag with its attributes in a 3MF model part may be longer
  (text is read in pieces and has no such bound). Expat
  re-scans an unfinished token each time it is fed; :func:`feed_xml` feeds
  the rest of a long token in one piece, so the scan stays linear, and a token
  past the bound is refused.

The limits of a command are set once by the command line (:func:`configure`);
library callers may use :func:`using` for a block.
"""
from __future__ import annotations

import contextlib
import os
import struct
import zipfile
from dataclasses import dataclass

from slicer.errors import SceneError

#: default most uncompressed bytes of one archive member, and of one declared allocation
DEFAULT_MAX_BYTES = 1 << 30
#: default most uncompressed / compressed size of an archive member
DEFAULT_MAX_RATIO = 200.0
#: an archive member may always expand to this many bytes, whatever its ratio
RATIO_FREE = 1 << 20
#: longest XML token (comment, tag with its attributes) of a 3MF model part, bytes
MAX_TOKEN = 16 << 20
#: bytes fed to expat at a time while no token is pending
FEED = 1 << 20


@dataclass(frozen=True)
class InputLimits:
    """What a reader may take from one input (see the module docstring).

    Attributes
    ----------
    max_bytes : int or None
        Bytes: most uncompressed bytes of one archive member and largest
        declared allocation; None: no limit.
    max_ratio : float or None
        Most uncompressed / compressed size of an archive member; None: no limit.
    """

    max_bytes: int | None = DEFAULT_MAX_BYTES
    max_ratio: float | None = DEFAULT_MAX_RATIO


_current = InputLimits()


def current() -> InputLimits:
    """The limits in force."""
    return _current


def configure(max_bytes="default", max_ratio="default") -> InputLimits:
    """Set the limits in force (``"default"`` keeps a default; ``None``: no limit); returns the old ones."""
    global _current
    old = _current
    _current = InputLimits(DEFAULT_MAX_BYTES if max_bytes == "default" else max_bytes,
                           DEFAULT_MAX_RATIO if max_ratio == "default" else max_ratio)
    return old


@contextlib.contextmanager
def using(max_bytes="default", max_ratio="default"):
    """Within the block, these limits are in force (as :func:`configure`).

    Examples
    --------
    >>> with using(max_bytes=1000):
    ...     current().max_bytes
    1000
    >>> current().max_bytes == DEFAULT_MAX_BYTES
    True
    """
    global _current
    old = configure(max_bytes, max_ratio)
    try:
        yield _current
    finally:
        _current = old


def _n(x) -> str:
    return f"{int(x):,}"


def _raise(error, message: str, src) -> None:
    if issubclass(error, SceneError):
        raise error(message, str(src))
    raise error(f"{src}: {message}")


def check_allocation(count, item_bytes: int, what: str, src, error=SceneError) -> int:
    """Refuse a count declared in a file whose array would pass ``max_bytes``.

    Parameters
    ----------
    count : int
        The declared count (vertices, triangles, pixels of an image ...).
    item_bytes : int
        Bytes per item of the array it sizes.
    what : str
        What is counted and where, for the message (``"layer 3: 4096 x 4096 pixels"``).

    Returns
    -------
    int
        ``count``.

    Examples
    --------
    >>> with using(max_bytes=1000):
    ...     check_allocation(10**6, 12, "vertices", "a.ply")
    Traceback (most recent call last):
    ...
    slicer.errors.SceneError: a.ply: vertices: 1,000,000 declared need 12,000,000 bytes, more than the input limit of 1,000 bytes (raise it with skelslice --max-input-bytes)
    """
    limit = _current.max_bytes
    if count < 0:
        _raise(error, f"{what}: the declared count {_n(count)} is negative", src)
    if limit is not None and count * item_bytes > limit:
        _raise(error, f"{what}: {_n(count)} declared need {_n(count * item_bytes)} bytes, more than the input "
                      f"limit of {_n(limit)} bytes (raise it with skelslice --max-input-bytes)", src)
    return int(count)


def member_allowance(info: zipfile.ZipInfo) -> tuple[int | None, str]:
    """The most bytes a member may expand to under the limits in force, and the flag that raises it."""
    lim = _current
    by_ratio = None if lim.max_ratio is None else max(RATIO_FREE, int(lim.max_ratio * info.compress_size))
    if lim.max_bytes is not None and (by_ratio is None or lim.max_bytes <= by_ratio):
        return lim.max_bytes, "--max-input-bytes"
    return by_ratio, "--max-input-ratio"


def _too_big(info: zipfile.ZipInfo, size: int, src, error, declared: bool) -> None:
    allowed, flag = member_allowance(info)
    if allowed is None or size <= allowed:
        return
    how = "declares" if declared else "expands to more than"
    if flag == "--max-input-bytes":
        why = f"more than the input limit of {_n(allowed)} bytes"
    else:
        why = (f"a compression ratio of {size / max(info.compress_size, 1):,.0f} : 1, over the limit of "
               f"{current().max_ratio:g} : 1")
    _raise(error, f"archive member {info.filename} {how} {_n(size)} bytes from {_n(info.compress_size)} "
                  f"compressed: {why} (raise it with skelslice {flag})", src)


def check_members(zf: zipfile.ZipFile, src, error=SceneError) -> None:
    """Refuse an archive any of whose members declares more bytes than the limits allow.

    The declared sizes are cheap to check and :mod:`zipfile` never returns more
    than a member declares (a member that lies fails its CRC); readers that
    decompress with another library count the bytes too (:func:`read_member`).
    """
    for info in zf.infolist():
        _too_big(info, info.file_size, src, error, declared=True)


def read_member(zf: zipfile.ZipFile, name: str, src, error=SceneError) -> bytes:
    """The bytes of one archive member, refused past the limits (declared or actual size).

    Raises
    ------
    KeyError
        No such member (as :meth:`zipfile.ZipFile.read`).
    """
    info = zf.getinfo(name)
    _too_big(info, info.file_size, src, error, declared=True)
    with zf.open(info) as fh:
        return b"".join(stream_member(fh, info, src, error))


def stream_member(fh, info: zipfile.ZipInfo, src, error=SceneError, chunk: int | None = None):
    """Yield an open member's bytes in chunks of ``chunk`` bytes (default :data:`FEED`), refused as soon as
    they pass the limits.

    ``chunk`` may be changed between chunks by sending a new size (a generator ``send``).
    """
    allowed, _ = member_allowance(info)
    total, chunk = 0, chunk or FEED
    while True:
        data = fh.read(chunk if allowed is None else min(chunk, allowed + 1 - total))
        if not data:
            return
        total += len(data)
        _too_big(info, total, src, error, declared=False)
        got = yield data
        if got:
            chunk = got


class Restart(Exception):
    """Raised by a :func:`feed_xml` transform that cannot go on: the caller reads the member again without it."""


def feed_xml(parser, fh, info: zipfile.ZipInfo, part: str, src, error=SceneError, transform=None) -> None:
    """Feed an expat ``parser`` an archive member in time linear in its size, then finish the parse.

    Expat (before 2.6) scans an unfinished token again at each feed. While
    nothing is pending the member goes in :data:`FEED`-byte chunks; once a
    token is pending, the next chunk is as long as the pending bytes, so each
    byte is scanned a bounded number of times. A token longer than
    :data:`MAX_TOKEN` is refused.

    Parameters
    ----------
    transform : object, optional
        ``transform.feed(data) -> bytes`` and ``transform.finish() -> bytes``:
        what expat is given instead of the member's bytes (e.g. with runs of
        elements left out). A token past the bound then raises :class:`Restart`,
        so that the error is reported on the member's own bytes.

    Raises
    ------
    error
        Past the limits, or a token longer than :data:`MAX_TOKEN`.
    Restart
        From ``transform``, or a long token with a ``transform``.
    xml.parsers.expat.ExpatError
        Malformed XML (the caller names it).
    """
    fed = 0
    chunks = stream_member(fh, info, src, error)
    data = next(chunks, b"")
    while data:
        out = data if transform is None else transform.feed(data)
        parser.Parse(out, False)
        fed += len(out)
        pending = fed - parser.CurrentByteIndex
        if pending > MAX_TOKEN:
            if transform is not None:
                raise Restart()
            _raise(error, f"{part}: an XML token (a comment, or a tag with its attributes) at byte "
                          f"{_n(parser.CurrentByteIndex)} is longer than {_n(MAX_TOKEN)} bytes, which no 3MF "
                          f"model needs", src)
        try:
            data = chunks.send(max(FEED, pending))
        except StopIteration:
            break
    parser.Parse(transform.finish() if transform is not None else b"", True)


def check_file_size(src, error=SceneError) -> int:
    """Refuse a plain (not archived) input file larger than ``max_bytes``; return its size.

    Raises
    ------
    OSError
        The file cannot be examined (the caller names it).
    """
    size = os.stat(src).st_size
    limit = _current.max_bytes
    if limit is not None and size > limit and not os.path.isdir(src):
        _raise(error, f"the file has {_n(size)} bytes, more than the input limit of {_n(limit)} bytes "
                      f"(raise it with skelslice --max-input-bytes)", src)
    return size


#: bytes of each PLY property type
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
#: longest PLY header read, bytes
PLY_HEADER = 1 << 16


def check_mesh_header(src, suffix: str) -> None:
    """Cheap checks of a mesh file before it is parsed: the counts its header declares.

    A binary STL declares its triangle count: the file must hold them
    (84 + 50 per triangle bytes) and a closed surface needs at least 4. A PLY
    header declares its element counts: the file must be long enough for them
    (binary: their sizes; ASCII: two bytes per value at least), and the
    arrays they size must fit ``max_bytes``. OBJ declares nothing.

    Raises
    ------
    SceneError
        Naming the file, the count and the size.
    """
    if suffix == ".stl":
        _check_stl(src)
    elif suffix == ".ply":
        _check_ply(src)


def _check_stl(src) -> None:
    size = os.stat(src).st_size
    with open(src, "rb") as fh:
        head = fh.read(84)
    if len(head) < 84:
        if head.lstrip().lower().startswith(b"solid"):
            return                                   # a short ASCII STL: trimesh reads or refuses it
        raise SceneError(f"not an STL file: {len(head)} bytes, shorter than a binary STL header (84)", str(src))
    (n,) = struct.unpack_from("<I", head, 80)
    if head.lstrip().lower().startswith(b"solid") and size != 84 + 50 * n:
        return                                       # ASCII (a binary file may start with "solid" too)
    if 84 + 50 * n > size:
        raise SceneError(f"the binary STL header declares {_n(n)} triangles, which need {_n(84 + 50 * n)} "
                         f"bytes; the file has {_n(size)}", str(src))
    if n < 4:
        raise SceneError(f"not a closed solid: the binary STL has {n} triangles; a closed surface needs at least 4",
                         str(src))
    check_allocation(n, 3 * 3 * 8, "binary STL triangles", src)


def _check_ply(src) -> None:
    size = os.stat(src).st_size
    with open(src, "rb") as fh:
        head = fh.read(PLY_HEADER)
    if not head.startswith(b"ply"):
        return                                       # trimesh names what is wrong
    end = head.find(b"end_header")
    if end < 0:
        raise SceneError(f"PLY header: no end_header in the first {_n(PLY_HEADER)} bytes", str(src))
    fmt, elements = "ascii", []
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            fmt = words[1]
        elif len(words) >= 3 and words[0] == "element":
            try:
                elements.append([words[1], int(words[2]), 0, 0])   # name, count, least bytes, least values
            except ValueError:
                raise SceneError(f"PLY header: element {words[1]!r} has count {words[2]!r}, not an integer",
                                 str(src)) from None
        elif len(words) >= 3 and words[0] == "property" and elements:
            if words[1] == "list" and len(words) >= 5:          # a face lists 3 indices at least
                elements[-1][2] += _PLY_SIZES.get(words[2], 1) + 3 * _PLY_SIZES.get(words[3], 1)
                elements[-1][3] += 4
            else:
                elements[-1][2] += _PLY_SIZES.get(words[1], 1)
                elements[-1][3] += 1
    need = 0
    for name, count, nbytes, values in elements:
        if count < 0:
            raise SceneError(f"PLY header: element {name!r} has a negative count {count}", str(src))
        need += count * (nbytes if fmt.startswith("binary") else 2 * values)   # ASCII: a digit and a space
    if need > size:
        what = ", ".join(f"{c:,} {n}" for n, c, _, _ in elements)
        raise SceneError(f"the PLY header declares {what}, which need at least {_n(need)} bytes; the file has "
                         f"{_n(size)}", str(src))
    for name, count, _, _ in elements:
        check_allocation(count, 3 * 8, f"PLY element {name!r}", src)
        if name == "face" and 0 < count < 4:
            raise SceneError(f"not a closed solid: the PLY has {count} faces; a closed surface needs at least 4",
                             str(src))


__all__ = ["InputLimits", "current", "configure", "using", "check_allocation", "check_members", "read_member",
           "stream_member", "feed_xml", "Restart", "check_file_size",
           "check_mesh_header", "member_allowance", "DEFAULT_MAX_BYTES", "DEFAULT_MAX_RATIO", "RATIO_FREE",
           "MAX_TOKEN"]
