"""Writer protocol and atomic publication helpers."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from slicer.errors import OutputError


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


def check_destination(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing output unless ``force``; check the parent exists."""
    if path.exists() and not force:
        raise OutputError(f"{path}: already exists (use --force to replace it)")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{path}: the folder {parent} does not exist")


class atomic_dir:
    """A temporary folder beside ``path`` that becomes ``path`` on :meth:`publish`.

    Until then nothing exists at ``path``; :meth:`discard` removes the
    temporary folder. A crash leaves at most a hidden ``.<name>.tmp-*`` folder,
    never a half-written output at ``path``.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        parent = self.path.parent if str(self.path.parent) else Path(".")
        try:
            self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.tmp-", dir=parent))
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot create a temporary folder ({exc.strerror})") from None

    def publish(self, force: bool) -> None:
        if self.path.exists():
            if not force:
                self.discard()
                raise OutputError(f"{self.path}: already exists (use --force to replace it)")
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            os.replace(self.path, old)
            os.replace(self.tmp, self.path)
            if old.is_dir():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink(missing_ok=True)
        else:
            os.replace(self.tmp, self.path)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
