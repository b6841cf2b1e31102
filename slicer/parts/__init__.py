"""Parts: a lattice with the triangle meshes it fills or is trimmed by (:mod:`slicer.parts.part`),
the meshes themselves, their exact cuts at the voxel centres, and the slicing of a whole part.

The names of :mod:`slicer.parts.part` are importable from here too (``from slicer.parts import ...``),
loaded on first use.
"""
from __future__ import annotations

import importlib


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("slicer.parts.part"), name)
