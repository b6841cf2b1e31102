"""Output formats: one module per format, one table mapping names to writers.

A writer is a class with the protocol of :class:`formats.base.StackWriter`:
``open`` a destination, ``write_layer`` one layer at a time (never the whole
stack), then ``close`` (publishes the output atomically) or ``abort``
(removes everything it wrote).
"""
from __future__ import annotations

from pathlib import Path

from slicer.errors import OutputError

from formats.base import AtomicDir, AtomicFile, StackWriter
from formats.common_layer import CliAsciiWriter, CliShortWriter, CliWriter
from formats.contour_base import ContourWriter
from formats.ctb import CtbV2Writer, CtbWriter
from formats.goo import GooWriter
from formats.nanodlp import NanoDlpWriter
from formats.photon import PHOTON_WRITERS
from formats.png_stack import PngStackWriter
from formats.sl1 import Sl1sWriter, Sl1Writer
from formats.svg import SvgWriter
from formats.threemf_slices import ThreeMFSliceWriter
from formats.zip_stack import ZipStackWriter

#: format name -> writer class
WRITERS: dict[str, type[StackWriter]] = {
    "png": PngStackWriter,
    # image formats (StackWriter: write_layer(k, image (H, W) uint8))
    "zip": ZipStackWriter,
    "sl1": Sl1Writer,
    "sl1s": Sl1sWriter,
    "goo": GooWriter,
    "nanodlp": NanoDlpWriter,
    "ctb": CtbWriter,
    "ctb-v2": CtbV2Writer,
    **PHOTON_WRITERS,                  # pws, pw0, pwmo, pwma, pwmx, pwmb, pm5s
    # contour formats (ContourWriter: write_layer(k, z, polygons))
    "cli": CliWriter,
    "cli-ascii": CliAsciiWriter,
    "cli-short": CliShortWriter,
    "3mf": ThreeMFSliceWriter,
    "svg": SvgWriter,
}

#: output suffix -> format name (a path without a known suffix is a PNG folder)
SUFFIXES: dict[str, str] = {".zip": "zip", ".sl1": "sl1", ".sl1s": "sl1s", ".goo": "goo", ".nanodlp": "nanodlp",
                            ".ctb": "ctb", **{f".{name}": name for name in PHOTON_WRITERS},
                            ".cli": "cli", ".3mf": "3mf", ".svg": "svg"}


def format_for(name: str | None, path, default: str = "png") -> str:
    """The format name: ``name`` if given, else from ``path``'s suffix, else ``default``."""
    if name is not None:
        return str(name).lower()
    return SUFFIXES.get(Path(path).suffix.lower(), default)


def writer_for(name: str | None, path, default: str = "png") -> type[StackWriter]:
    """The writer class for a format name, or inferred from ``path``'s suffix
    (``default`` when the suffix is not a known one)."""
    name = format_for(name, path, default)
    try:
        return WRITERS[name]
    except KeyError:
        raise OutputError(f"unknown output format {name!r}; choose one of {sorted(WRITERS)}") from None


__all__ = ["WRITERS", "SUFFIXES", "writer_for", "format_for", "StackWriter", "ContourWriter", "AtomicDir", "AtomicFile"]
