"""skelslice: slicing of skeleton-based scale-invariant integral surfaces.

Public API
----------
Skeleton, load_scene, save_scene
    Scene model and file format (JSON v1, OBJ polylines).
lattice
    Lattice / microstructure generator.
"""
from __future__ import annotations

from .errors import GridError, OutputError, SceneError, SkelsliceError
from .skeleton import Skeleton, kernel_normalisation

__version__ = "0.1.0"


def load_scene(path, radius: float | None = None) -> Skeleton:
    """Read a scene file (``.json`` scene v1, or ``.obj`` polylines).

    See :func:`slicer.scene_io.load_scene`.
    """
    from .scene_io import load_scene as _load

    return _load(path, radius=radius)


def save_scene(skel: Skeleton, path) -> None:
    """Write a scene as JSON v1, atomically. See :func:`slicer.scene_io.save_scene`."""
    from .scene_io import save_scene as _save

    _save(skel, path)


__all__ = [
    "Skeleton", "kernel_normalisation", "load_scene", "save_scene",
    "SkelsliceError", "SceneError", "GridError", "OutputError", "__version__",
]
