"""Writing scenes: the JSON scene format (version 1) and OBJ polylines.

The format is described in :mod:`slicer.scene.read` (which reads it) and in
``docs/scene-format.md``. Files are always written in mm, atomically
(:mod:`slicer.atomic`), and ``load_scene(write_scene(s))`` gives ``s`` back
bit-exactly for JSON.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from slicer.atomic import write_bytes
from slicer.errors import OutputError
from slicer.model.siis_kernel import DEFAULT_DEGREE, DEFAULT_SIGMA

#: the scene format version written and read
FORMAT_VERSION = 1
#: scene file suffix -> format
SUFFIXES = {".json": "json", ".obj": "obj"}


def scene_document(skel) -> dict[str, Any]:
    """The scene as a JSON-ready dict (format version 1, ``segment_radii`` form, mm).

    Parameters
    ----------
    skel : slicer.model.skeleton.Skeleton

    Returns
    -------
    dict
    """
    return {
        "skelslice": FORMAT_VERSION,
        "units": "mm",
        "nodes": skel.nodes.tolist(),
        "segments": skel.segments.tolist(),
        "segment_radii": skel.radii.tolist(),
        "kernel": {"degree": skel.degree, "sigma": skel.sigma},
    }


def write_scene(skel, path) -> None:
    """Write a scene atomically: JSON v1 for ``.json``, OBJ polylines for ``.obj``.

    The file is first written to a temporary file in the same directory,
    flushed and fsynced, then moved over ``path`` with :func:`os.replace`; on
    any failure the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    skel : slicer.model.skeleton.Skeleton
    path : str or os.PathLike

    Raises
    ------
    OutputError
        Unknown suffix, unwritable location, a scene
        :func:`slicer.scene.read.load_scene` would reject (no segments), or a non-default kernel for OBJ (which cannot
        store it: use ``.json``).
    """
    dst = os.fspath(path)
    if isinstance(dst, bytes):
        dst = os.fsdecode(dst)
    fmt = SUFFIXES.get(Path(dst).suffix.lower())
    if fmt is None:
        raise OutputError(
            f"{dst}: unknown scene file type {Path(dst).suffix or '(no suffix)'!r}; "
            f"use .json (scene v1) or .obj (polylines)")
    if skel.n_segments == 0:
        raise OutputError(f"{dst}: the scene has no segments; such a file could not be read back")
    if fmt == "json":
        data = (json.dumps(scene_document(skel), allow_nan=False, separators=(", ", ": ")) + "\n").encode()
    else:
        data = obj_text(skel, dst).encode()
    write_bytes(dst, data, force=True)


def _fmt(x: float) -> str:
    return repr(float(x))


def obj_text(skel, dst: str) -> str:
    """The OBJ polylines of a skeleton (one ``v x y z radius`` per node, a node
    whose segment ends disagree on the radius gets one vertex per radius).

    Raises
    ------
    OutputError
        A non-default kernel (OBJ cannot store it).
    """
    if skel.degree != DEFAULT_DEGREE or skel.sigma != DEFAULT_SIGMA:
        raise OutputError(
            f"{dst}: OBJ cannot store the kernel (degree {skel.degree}, sigma {skel.sigma}); "
            f"save as .json, or use the default kernel (degree {DEFAULT_DEGREE}, sigma {DEFAULT_SIGMA})")
    n = skel.n_nodes
    node_r: list[float | None] = [None] * n
    extra: dict[tuple[int, float], int] = {}
    ends = np.zeros_like(skel.segments)
    for s, ((a, b), (ra, rb)) in enumerate(zip(skel.segments.tolist(), skel.radii.tolist())):
        for k, (i, r) in enumerate(((a, ra), (b, rb))):
            if node_r[i] is None:
                node_r[i] = r
                ends[s, k] = i
            elif node_r[i] == r:
                ends[s, k] = i
            else:  # another radius at the same node: a separate vertex, same point
                ends[s, k] = extra.setdefault((i, r), n + len(extra))
    out = ["# skelslice scene: OBJ polylines, units mm",
           "# 'v x y z radius' (radius at this vertex), 'l i j' (one segment per line)"]
    for p, r in zip(skel.nodes.tolist(), node_r):
        out.append("v " + " ".join(_fmt(c) for c in p) + ("" if r is None else " " + _fmt(r)))
    for (i, r) in extra:
        out.append("v " + " ".join(_fmt(c) for c in skel.nodes[i].tolist()) + " " + _fmt(r))
    out.extend(f"l {a + 1} {b + 1}" for a, b in ends.tolist())
    return "\n".join(out) + "\n"


__all__ = ["FORMAT_VERSION", "SUFFIXES", "scene_document", "write_scene", "obj_text"]
