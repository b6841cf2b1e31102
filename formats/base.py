"""Writer protocol and the helpers writers share (PNG bytes, zip entries, build time).

Atomic publication is :mod:`slicer.atomic` (one implementation for every output)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from slicer.atomic import AtomicDir, AtomicFile, check_destination


class StackWriter:
    """Streams a layer stack to one output, published atomically.

    Parameters
    ----------
    path : path-like
        Final output location.
    grid : slicer.grid.SliceGrid
        Grid of the layers.
    meta : dict
        Extra metadata (method, scene, ...), written where the format allows.
    force : bool
        Replace an existing output.
    settings : formats.printers.PrintSettings, optional
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
        check_destination(self.path, force)

    def write_layer(self, k: int, image: np.ndarray) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

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


def png_bytes(image: np.ndarray) -> bytes:
    """An 8-bit greyscale PNG (colour type 0, depth 8) of a (h, w) uint8 image."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(buf, format="PNG", compress_level=3)
    return buf.getvalue()


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


__all__ = ["StackWriter", "png_bytes", "build_time", "zip_entry", "check_destination", "AtomicFile", "AtomicDir"]
