"""Writing a surface mesh: STL (binary), PLY (binary), OBJ or 3MF, atomically.

The 3MF package has one mesh object in mm (3MF core; the package layout of
:mod:`slicer.meshing.beams3mf`). The other formats are trimesh's exporters.
Every file is written whole to a temporary file beside the target and moved
over it (:mod:`slicer.atomic`): nothing is left behind on failure.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from formats.threemf_slices import CORE_NS

from slicer.atomic import check_destination, write_bytes
from slicer.errors import OutputError
from slicer.meshing.beams3mf import mesh_object, package

#: file suffix -> format name
MESH_SUFFIXES = {".stl": "stl", ".ply": "ply", ".obj": "obj", ".3mf": "3mf"}


def mesh_format(path) -> str:
    """The format of an output path from its suffix.

    Raises
    ------
    OutputError
        An unknown suffix.
    """
    suffix = Path(str(path)).suffix.lower()
    fmt = MESH_SUFFIXES.get(suffix)
    if fmt is None:
        raise OutputError(f"{path}: unknown mesh file type {suffix or '(no suffix)'!r}; "
                          f"use {', '.join(MESH_SUFFIXES)}")
    return fmt


def mesh_bytes(vertices: np.ndarray, faces: np.ndarray, fmt: str) -> bytes:
    """The file contents of a mesh in format ``fmt`` (a value of :data:`MESH_SUFFIXES`).

    Parameters
    ----------
    vertices : (v, 3) float64, mm
    faces : (t, 3) int64
        Counter-clockwise seen from outside.
    """
    if fmt == "3mf":
        model = ('<?xml version="1.0" encoding="UTF-8"?>\n'
                 f'<model xmlns="{CORE_NS}" unit="millimeter" xml:lang="en-US">\n'
                 ' <metadata name="Application">skelslice</metadata>\n <resources>\n'
                 + mesh_object(1, vertices, faces, "surface")
                 + ' </resources>\n <build>\n  <item objectid="1"/>\n </build>\n</model>\n')
        return package(model)
    tm = trimesh.Trimesh(vertices, faces, process=False)
    data = tm.export(file_type=fmt)
    return data.encode() if isinstance(data, str) else bytes(data)


def write_mesh(vertices: np.ndarray, faces: np.ndarray, path, force: bool = False) -> int:
    """Write a mesh atomically in the format of ``path``'s suffix; return the bytes written.

    Raises
    ------
    OutputError
        An unknown suffix, an existing file without ``force``, or a write failure.
    """
    fmt = mesh_format(path)
    check_destination(path, force)
    data = mesh_bytes(vertices, faces, fmt)
    write_bytes(path, data, force=force)
    return len(data)


__all__ = ["MESH_SUFFIXES", "mesh_format", "mesh_bytes", "write_mesh"]
