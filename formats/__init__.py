"""Output formats: one module per format, one table mapping names to writers.

A writer is a class with the protocol of :class:`formats.base.StackWriter`:
``open`` a destination, ``write_layer`` one layer at a time (never the whole
stack), then ``close`` (publishes the output atomically) or ``abort``
(removes everything it wrote).
"""
from __future__ import annotations

from .base import StackWriter, atomic_dir
from .png_stack import PngStackWriter

#: format name -> writer class
WRITERS: dict[str, type[StackWriter]] = {
    "png": PngStackWriter,
}

#: output suffix -> format name (a path without a known suffix is a PNG folder)
SUFFIXES: dict[str, str] = {}


def writer_for(name: str | None, path) -> type[StackWriter]:
    """The writer class for a format name, or inferred from ``path``'s suffix."""
    from pathlib import Path

    from slicer.errors import OutputError

    if name is None:
        name = SUFFIXES.get(Path(path).suffix.lower(), "png")
    try:
        return WRITERS[name]
    except KeyError:
        raise OutputError(f"unknown output format {name!r}; choose one of {sorted(WRITERS)}") from None


__all__ = ["WRITERS", "SUFFIXES", "writer_for", "StackWriter", "atomic_dir"]
