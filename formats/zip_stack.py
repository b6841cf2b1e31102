"""Zip of PNG layers plus ``slices.json``: the PNG stack in one file.

Members: ``layer_00000.png`` ... (8-bit greyscale, stored: PNG is already
compressed) and ``slices.json`` (deflated), with exactly the keys of the
PNG stack's ``slices.json`` (:mod:`formats.png_stack`), plus ``print`` (the
printer and exposure settings) when they were given. With ``--printer`` the
images are plate images (columns +X, rows -Y of the plate), not the
printer's mirrored native layout, so ``origin`` and ``axes`` stay true.

The archive is written to a hidden temporary file beside the target and
renamed over it when complete.
"""
from __future__ import annotations

import json
import zipfile

import numpy as np

from slicer.atomic import AtomicFile
from slicer.errors import OutputError

from formats.base import StackWriter, png_bytes, zip_entry
from formats.estimate import LayerMeter
from formats.png_stack import LAYER_NAME, slices_doc


class ZipArchiveWriter(StackWriter):
    """Common part of zip-based stacks: members stream into a hidden temporary
    zip beside the target; :meth:`close` adds the final members
    (:meth:`final_members`) and renames it over the target.

    Subclasses implement ``write_layer`` with :meth:`add` and
    :meth:`final_members`.
    """

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        super().__init__(path, grid, meta, force, settings)
        self._out = AtomicFile(self.path)
        self._zip = zipfile.ZipFile(self._out.fh, "w", allowZip64=True)

    def add(self, name: str, data, compress: bool) -> None:
        """Write one member (OutputError, and nothing left behind, on failure)."""
        try:
            self._zip.writestr(zip_entry(name, compress), data)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot write {name} ({exc})") from None

    def final_members(self):
        """(name, data, compress) of the members written at :meth:`close`."""
        return []

    def close(self) -> None:
        if self._k != self.grid.layers:
            self.abort()
            raise OutputError(f"{self.path}: {self._k} of {self.grid.layers} layers were written")
        for name, data, compress in self.final_members():
            self.add(name, data, compress)
        try:
            self._zip.close()
            self._out.publish(self.force)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.path}: cannot finish the output ({exc})") from None

    def abort(self) -> None:
        try:
            self._zip.close()
        except (OSError, ValueError):   # ValueError: zipfile already closed
            pass
        self._out.discard()


class ZipStackWriter(ZipArchiveWriter):
    """``layer_%05d.png`` + ``slices.json`` in one zip, published atomically."""

    name = "zip"

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        super().__init__(path, grid, meta, force, settings)
        printer = settings is not None and settings.printer is not None
        self._meter = LayerMeter() if printer else None          # for the print estimate

    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray) -> bytes:
        return png_bytes(image)

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, payload: bytes) -> None:
        self.next_layer(k)
        self.add(LAYER_NAME.format(k), payload, False)
        if self._meter is not None:
            self._meter.add(image)
        self._k += 1

    def final_members(self):
        if self._meter is not None:
            self.estimate = self._meter.estimate(self.settings)
        files = [LAYER_NAME.format(k) for k in range(self._k)]
        doc = slices_doc(self.grid, files, self.meta, self.settings)
        return [("slices.json", json.dumps(doc, indent=1) + "\n", True)]
