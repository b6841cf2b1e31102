"""PNG stack: a folder of 8-bit greyscale layers plus ``slices.json``.

``slices.json`` (a public interface; keys are only ever added):

========================  ==================================================
key                       meaning
========================  ==================================================
width, height, layers     image size in pixels and number of layers
pixel_size                [px, py], mm
layer_height              mm
origin                    [x, y, z] mm, centre of voxel (column 0, row 0, layer 0)
files                     layer file names, bottom layer first
units                     "mm"
axes                      columns toward +x, rows toward -y, layers toward +z
inside_value              grey level of inside pixels (255)
generator, method, ...    provenance (skelslice version, tracing method, scene)
========================  ==================================================

Voxel (i, j, k) has its centre at ``(x0 + i px, y0 - j py, z0 + k h)``.
"""
from __future__ import annotations

import json

import numpy as np

from slicer.atomic import AtomicDir
from slicer.errors import OutputError

from formats.base import StackWriter, png_bytes

LAYER_NAME = "layer_{:05d}.png"


def slices_doc(grid, files: list[str], meta: dict, settings=None) -> dict:
    """The ``slices.json`` document of a stack (also the zip format's)."""
    doc = {
        **grid.to_dict(),
        "files": files,
        "units": "mm",
        "axes": {"columns": "+x", "rows": "-y", "layers": "+z"},
        "inside_value": 255,
        **meta,
    }
    if settings is not None:
        doc["print"] = settings.to_dict()
    return doc


class PngStackWriter(StackWriter):
    """Folder of ``layer_00000.png`` ... plus ``slices.json``, published atomically."""

    name = "png"

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        super().__init__(path, grid, meta, force, settings)
        self._dir = AtomicDir(self.path)
        self._files: list[str] = []

    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """The layer's PNG bytes, or the OSError that encoding raised."""
        try:
            return png_bytes(image)
        except OSError as exc:
            return exc

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        if k != len(self._files):
            raise OutputError(f"layers must be written in order: expected {len(self._files)}, got {k}")
        name = LAYER_NAME.format(k)
        if isinstance(payload, OSError):
            self.abort()
            raise OutputError(f"{self.path}: cannot encode {name} ({payload.strerror or payload})") from None
        self._dir.write_file(name, payload)
        self._files.append(name)

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def close(self) -> None:
        g = self.grid
        if len(self._files) != g.layers:
            self.abort()
            raise OutputError(f"{self.path}: {len(self._files)} of {g.layers} layers were written")
        doc = slices_doc(g, self._files, self.meta, self.settings)
        self._dir.write_file("slices.json", (json.dumps(doc, indent=1) + "\n").encode())
        self._dir.publish(self.force)

    def abort(self) -> None:
        self._dir.discard()
