"""skelslice: slicing of skeleton-based scale-invariant integral surfaces.

The main entry points, importable from ``slicer`` itself:

======================  ====================================================
``Skeleton``            the scene model: nodes, segments, end radii, kernel
``load_scene``          read a ``.json`` scene, ``.obj`` polylines or a
                        ``.3mf`` beam lattice
``save_scene``          write a scene (JSON v1 or OBJ), atomically
``generate_lattice``    unit-cell lattices and microstructures
``slice_skeleton``      inside runs per pixel column (every voxel centre exact)
``render``              transparent rendering of the surface (ray tracing)
``run_slice``           the ``slice`` command's job: slice and write a format
``SliceJob``            a job's settings as data (grid, tracing, printer, scale)
``Part``, ``load_part`` a lattice with solid and clipping meshes (docs/parts.md)
``slice_part``          :func:`slice_skeleton` for a part
======================  ====================================================

Examples
--------
>>> import slicer
>>> s = slicer.Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 1.0]])
>>> res = slicer.slice_skeleton(s, 0.25)
>>> res.grid.width, res.grid.height, res.grid.layers
(9, 9, 21)
>>> float(s.field([[0.0, 0.0, 2.0]])[0]) > 1       # on the axis: inside
True

The job-level names (``run_slice``, ``SliceJob``) and the parts' are loaded on first use:
they sit above the output formats (:mod:`formats`), which themselves use
this package's core modules, so importing them here eagerly would make
``import formats`` circular.
"""
from __future__ import annotations

import importlib

from slicer import _aliases

_aliases.install()
from slicer._version import __version__
from slicer.errors import (FormatError, GridError, MissingDependencyError, OptionError, OutputError, SceneError,
                     SkelsliceError, UsageError)
from slicer.model.siis_kernel import kernel_normalisation
from slicer.scene.lattice import generate_lattice
from slicer.render.rendering import RenderResult, render
from slicer.scene.read import load_scene, save_scene
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult, slice_skeleton

#: name -> module of the names loaded on first use (see the module docstring)
_LAZY = {"run_slice": "slicer.job.run", "SliceJob": "slicer.job.spec", "Part": "slicer.parts.part", "load_part": "slicer.parts.part",
         "slice_part": "slicer.parts.slicing"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'slicer' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_LAZY])


__all__ = [
    "Skeleton", "kernel_normalisation", "load_scene", "save_scene", "generate_lattice", "slice_skeleton",
    "SliceResult", "render", "RenderResult", "run_slice", "SliceJob", "Part", "load_part", "slice_part",
    "SkelsliceError", "SceneError", "UsageError", "OptionError", "GridError", "FormatError",
    "MissingDependencyError", "OutputError", "__version__",
]
