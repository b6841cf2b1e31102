"""Scene files: the JSON scene format (versions 1 and 2) and OBJ polylines.

Reading validates everything and guesses nothing: any problem raises
:class:`~slicer.errors.SceneError` whose message names the file, the entry
(``segments[12][1]``, ``kernel.sigma``, or ``line 17`` for OBJ) and the
offending value, e.g.::

    scene.json: segments[3][1] = 57 is out of range (there are 40 nodes; indices are 0-based)

JSON scene, version 1
---------------------
::

    {"skelslice": 1, "units": "mm",
     "nodes": [[x, y, z], ...],
     "segments": [[i, j], ...],
     "radii": [r_node, ...],
     "segment_radii": [[r_i, r_j], ...],
     "kernel": {"degree": 6, "sigma": 2.0}}

* ``"skelslice"`` (the format version, the integer 1), ``"units"``,
  ``"nodes"`` and ``"segments"`` are required. Segment indices are 0-based
  node indices (JSON integers).
* Radii: ``"radii"`` gives one radius per node; ``"segment_radii"`` gives a
  radius at each end of each segment and wins when both are present (both are
  still validated). With neither, the ``radius`` argument (CLI ``--radius``)
  gives every segment end that radius; without it the file is rejected.
* ``"kernel"`` is optional, and so are its keys ``"degree"`` (even integer,
  default 6) and ``"sigma"`` (> 1, default 2.0). Other kernel keys are errors.
* ``"units"``: one of ``"mm"``, ``"um"``, ``"cm"``, ``"m"``, ``"in"``. Node
  positions and radii are converted to mm on reading (``um``: divided by 1000;
  ``cm``: x 10; ``m``: x 1000; ``in``: x 25.4); ``"mm"`` is read bit-exactly.
  Files are always written in mm.
* Unknown top-level keys are errors (a misspelt ``"segment_radius"`` must not
  be ignored silently), with a "did you mean" hint. Two kinds of extra keys
  are allowed and ignored, so files can carry data for other tools and stay
  readable: ``"metadata"`` (any JSON value) and any key starting with
  ``"x-"``. The key set of version 1 is closed: a future format that adds keys
  gets a new version number, which this reader rejects with an "upgrade"
  hint, so erroring on unknown keys cannot break forward compatibility.
* Duplicate keys, ``NaN``/``Infinity`` (which Python's :mod:`json` would
  accept), booleans or strings where numbers are expected, floats where
  indices are expected, and an empty ``"segments"`` list are errors.

JSON scene, version 2: meshes
-----------------------------
Version 2 is version 1 plus one key, ``"meshes"``: triangle meshes that the
lattice fills or is trimmed by (see :mod:`slicer.parts.part`)::

    {"skelslice": 2, "units": "mm", "nodes": [...], "segments": [...], "radii": [...],
     "meshes": [{"path": "shell.stl", "role": "solid"},
                {"path": "body.3mf", "role": "clip-inside",
                 "transform": [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0]]}]}

* Every version 1 file reads as before; ``"meshes"`` in a version 1 file is an
  error that names the version to use.
* Each entry has ``"path"`` (required: an ``.stl``, ``.obj``, ``.ply`` or
  ``.3mf`` file, relative to the scene file's folder), ``"role"`` (``"solid"``,
  the default, ``"clip-inside"`` or ``"clip-outside"``), ``"transform"``
  (optional: 3 or 4 rows of 4 numbers, acting on column vectors, ``p' = A p + t``;
  the translation ``t`` is in the scene's units; a 4th row must be ``[0, 0, 0,
  1]``) and ``"units"`` (the mesh file's unit, default the scene's; not allowed
  for 3MF files, which carry their own). ``"metadata"`` and ``"x-"`` keys are
  ignored; any other key is an error.
* With ``"meshes"``, ``"nodes"`` and ``"segments"`` may be left out (or empty)
  together: a mesh-only part. Clipping meshes need a lattice.
* :func:`load_scene` returns the skeleton only and refuses a scene with
  meshes; :func:`slicer.parts.part.load_part` reads both.
* ``"groups"`` (version 2): contiguous segment ranges with a role (``model``,
  ``support``, ``pad``) that blend within and unite between, as supported
  scenes hold them (:mod:`slicer.supports.groups`); the skeleton is then a
  :class:`slicer.supports.groups.GroupedSkeleton`.

OBJ polylines
-------------
* ``v x y z`` or ``v x y z radius`` (mm) and ``l i j k ...`` line elements:
  1-based indices, negative ones relative to the last vertex read so far (as
  in OBJ), ``i/t`` forms accepted (the texture index is ignored). A polyline
  ``l a b c`` makes the segments a-b and b-c, in file order.
* Every vertex used by a segment needs a radius: its own 4th number, else the
  ``radius`` argument. **File radii win**: ``radius`` is only a default for
  vertices without one (so it fills the gaps of a file where only some
  vertices have a radius). Without ``radius``, a used vertex lacking a radius
  is an error naming its line.
* Comments (``#`` to the end of the line), blank lines, ``\\`` line
  continuations and statements that do not change the skeleton (``vn``,
  ``vt``, ``vp``, ``o``, ``g``, ``s``, ``mg``, ``usemtl``, ``mtllib``, and
  render attributes) are ignored. Faces (``f``, ``fo``), points (``p``),
  free-form curves and surfaces, and unknown statements are errors naming the
  line: a face is not a skeleton, and dropping it silently would slice
  something other than what the file describes.
* OBJ has no kernel: scenes read from OBJ use the default kernel.

Writing
-------
:func:`save_scene` writes JSON v1 (``.json``) or OBJ (``.obj``) atomically
(temporary file in the same directory, flush, fsync, :func:`os.replace`).
``load_scene(save_scene(s))`` reproduces ``nodes``, ``segments``, ``radii``
and the kernel bit-exactly for JSON, and for OBJ whenever every node has one
radius (otherwise nodes whose segment ends disagree are duplicated, which
leaves the surface unchanged).
"""
from __future__ import annotations

import difflib
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slicer._version import __version__
from slicer.arguments import scene_numbers
from slicer.errors import SceneError
from slicer.input_limits import check_file_size
from slicer.scene.threemf import load_3mf
from slicer.scene.write import FORMAT_VERSION, SUFFIXES, write_scene
from slicer.model.skeleton import DEFAULT_DEGREE, DEFAULT_SIGMA, Skeleton
from slicer.supports.groups import with_groups

#: accepted "units": (multiplier, divisor) converting to mm
UNITS: dict[str, tuple[float, float]] = {
    "mm": (1.0, 1.0),
    "um": (1.0, 1000.0),
    "cm": (10.0, 1.0),
    "m": (1000.0, 1.0),
    "in": (25.4, 1.0),
}

_KEYS = ("skelslice", "units", "nodes", "segments", "radii", "segment_radii", "kernel")
_KERNEL_KEYS = ("degree", "sigma")
#: format versions read; version 2 adds "meshes"
READ_VERSIONS = (1, 2)
_MESH_KEYS = ("path", "role", "transform", "units")
_MESH_ROLES = ("solid", "clip-inside", "clip-outside")
_MAX_SHOWN = 60


# ----------------------------------------------------------------------------- public API
def load_scene(path, radius: float | None = None) -> Skeleton:
    """Read a scene file: a ``.json`` scene (version 1), ``.obj`` polylines or a
    ``.3mf`` Beam Lattice (see :mod:`slicer.scene.threemf`).

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix (case-insensitive) selects the format.
    radius : float, optional
        Default radius (mm) for segment ends the file gives no radius for:
        OBJ vertices without a 4th number, or a JSON scene without
        ``"radii"``/``"segment_radii"``. Radii in the file always win.

    Returns
    -------
    Skeleton
        In mm, with ``source`` set to ``str(path)``.

    Raises
    ------
    SceneError
        If the file cannot be read or is malformed in any way; the message
        names the file, the entry (or OBJ line) and the offending value.

    Examples
    --------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> p = os.path.join(d, "s.obj")
    >>> with open(p, "w") as f:
    ...     _ = f.write("v 0 0 0\\nv 0 0 10\\nv 5 0 10\\nl 1 2 3\\n")
    >>> s = load_scene(p, radius=0.5)
    >>> s.segments.tolist(), s.radii.tolist()
    ([[0, 1], [1, 2]], [[0.5, 0.5], [0.5, 0.5]])
    """
    src = os.fspath(path)
    if isinstance(src, bytes):
        src = os.fsdecode(src)
    if radius is not None:
        _check_radius_argument(radius)
    if Path(src).suffix.lower() == ".3mf":  # 3MF Beam Lattice (read only)
        return load_3mf(src, radius)
    fmt = SUFFIXES.get(Path(src).suffix.lower())
    if fmt is None:
        raise SceneError(
            f"unknown scene file type {Path(src).suffix or '(no suffix)'!r}; "
            f"expected a .json scene, .obj polylines or a .3mf beam lattice", src)
    text = _read_text(src)
    if fmt == "json":
        skel, meshes = _scene_from_json(_parse_json(text, src), src, radius)
        if meshes:
            raise SceneError(f'the scene has {len(meshes)} mesh{"es" if len(meshes) > 1 else ""} ("meshes"); '
                             f'load_scene reads the lattice only: read it with slicer.parts.part.load_part '
                             f'(the command line does)', src)
        return skel
    return _skeleton_from_obj(text, src, radius)


@dataclass(frozen=True)
class MeshEntry:
    """One ``"meshes"`` entry of a version 2 scene, resolved.

    Attributes
    ----------
    path : str
        The mesh file (resolved against the scene's folder).
    role : str
    scale : float
        mm per mesh-file unit (STL/OBJ/PLY; 3MF files use their own).
    transform : (3, 4) float64 or None
        In mm: ``p' = A p + t``.
    """

    path: str
    role: str
    scale: float
    transform: np.ndarray | None


def read_json_scene(path, radius: float | None = None) -> tuple[Skeleton | None, list[MeshEntry]]:
    """Read a JSON scene of any supported version: its skeleton (None for a
    mesh-only scene) and its mesh entries (read them with
    :func:`slicer.parts.part.load_part`).

    Raises
    ------
    SceneError
    """
    src = os.fsdecode(os.fspath(path))
    if radius is not None:
        _check_radius_argument(radius)
    return _scene_from_json(_parse_json(_read_text(src), src), src, radius)


def save_scene(skel: Skeleton, path) -> None:
    """Write a scene atomically: JSON v1 for ``.json``, OBJ polylines for ``.obj``.

    See :func:`slicer.scene.write.write_scene`.

    Raises
    ------
    TypeError
        ``skel`` is not a :class:`Skeleton`.
    OutputError
        Unknown suffix, unwritable location, no segments, or a non-default
        kernel for OBJ.
    """
    if not isinstance(skel, Skeleton):
        raise TypeError(f"save_scene expects a Skeleton, got {type(skel).__name__}")
    write_scene(skel, path)


# ----------------------------------------------------------------------------- reading helpers
def _check_radius_argument(radius) -> None:
    ok = (not isinstance(radius, bool) and isinstance(radius, (int, float, np.integer, np.floating))
          and math.isfinite(radius) and radius > 0)
    if not ok:
        raise SceneError(f"radius (--radius) must be a finite number > 0, got {radius!r}")


def _read_text(src: str) -> str:
    try:
        check_file_size(src)
        raw = Path(src).read_bytes()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise SceneError(f"cannot read the scene file: {reason}", src) from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        bad = raw[exc.start:exc.start + 1].hex()
        raise SceneError(
            f"line {line}: not UTF-8 text (byte 0x{bad} at offset {exc.start}); "
            f"is this a scene file?", src) from None


def _show(value: Any) -> str:
    """The value as it looks in JSON, shortened."""
    try:
        s = json.dumps(value)
    except (TypeError, ValueError, RecursionError):
        s = repr(value)
    return s if len(s) <= _MAX_SHOWN else s[:_MAX_SHOWN - 3] + "..."


def _is(where: str, value: Any) -> str:
    """``where = value is a string`` (``where is null`` for null)."""
    if value is None:
        return f"{where} is null"
    return f"{where} = {_show(value)} is {_kind(value)}"


def _plural(k: int, word: str) -> str:
    return f"{k} {word}" + ("" if k == 1 else "s")


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__  # pragma: no cover - json yields only the above


# ----------------------------------------------------------------------------- JSON
class _DuplicateKey(Exception):
    pass


def _no_duplicates(pairs):
    out = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _parse_json(text: str, src: str):
    if not text.strip():
        raise SceneError("the file is empty; expected a JSON scene {\"skelslice\": 1, ...}", src)
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates)
    except json.JSONDecodeError as exc:
        lines = text.split("\n")
        line = lines[exc.lineno - 1] if exc.lineno <= len(lines) else ""
        start = max(0, exc.colno - 21)
        near = line[start:exc.colno + 20].strip()
        hint = f" near {near!r}" if near else ""
        raise SceneError(f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}{hint}",
                         src) from None
    except _DuplicateKey as exc:
        raise SceneError(f"invalid scene: duplicate key {_show(exc.args[0])} in a JSON object; "
                         f"each key may appear once", src) from None
    except RecursionError:
        raise SceneError("invalid JSON: arrays or objects are nested too deeply", src) from None
    except ValueError as exc:  # integers with more than sys.get_int_max_str_digits() digits
        why = str(exc)
        if "digits" in why:
            why = "a number has too many digits"
        raise SceneError(f"invalid JSON: {why}", src) from None


def _number(value, where: str, src: str) -> float:
    t = type(value)
    if t is float:
        if not math.isfinite(value):
            raise SceneError(f"{where} = {_show(value)} is not a finite number", src)
        return value
    if t is int:
        try:
            return float(value)
        except OverflowError:
            raise SceneError(f"{where} = {_show(value)} is too large for a float", src) from None
    raise SceneError(f"{_is(where, value)}, not a number", src)


def _array(value, name: str, what: str, src: str) -> list:
    if type(value) is not list:
        raise SceneError(f'"{name}" = {_show(value)} must be an array of {what}, got {_kind(value)}', src)
    return value


def _rows(value, name: str, width: int, item: str, form: str, src: str) -> list[list[float]]:
    """Validate an array of fixed-width rows of numbers (nodes, segment_radii)."""
    out = []
    for i, row in enumerate(_array(value, name, f"{item}s {form}", src)):
        if type(row) is not list:
            raise SceneError(f"{_is(f'{name}[{i}]', row)}; a {item} is {form}", src)
        if len(row) != width:
            raise SceneError(f"{name}[{i}] = {_show(row)} has {_plural(len(row), 'number')}; "
                             f"a {item} is {form}", src)
        out.append([_number(x, f"{name}[{i}][{k}]", src) for k, x in enumerate(row)])
    return out


def _positive(values, name: str, src: str, nested: bool) -> None:
    """Radii must be > 0 (finiteness is already checked)."""
    for i, v in enumerate(values):
        for k, r in (enumerate(v) if nested else ((None, v),)):
            if not r > 0:
                where = f"{name}[{i}]" + ("" if k is None else f"[{k}]")
                raise SceneError(f"{where} = {_show(r)} is not a valid radius; radii must be > 0", src)


def _segments(value, n: int, src: str) -> list[list[int]]:
    form = "[i, j] (two 0-based node indices)"
    out = []
    for i, row in enumerate(_array(value, "segments", f"segments {form}", src)):
        if type(row) is not list:
            raise SceneError(f"{_is(f'segments[{i}]', row)}; a segment is {form}", src)
        if len(row) != 2:
            raise SceneError(f"segments[{i}] = {_show(row)} has {len(row)} {'entry' if len(row) == 1 else 'entries'}; "
                             f"a segment is {form}", src)
        for k, v in enumerate(row):
            where = f"segments[{i}][{k}]"
            if type(v) is not int:
                what = f"{where} = {_show(v)} is not an integer" if type(v) is float else \
                    f"{_is(where, v)}, not an integer"
                raise SceneError(f"{what}; segment ends are 0-based node indices", src)
            if not 0 <= v < n:
                raise SceneError(f"{where} = {v} is out of range (there are {n} nodes; "
                                 f"indices are 0-based)", src)
        if row[0] == row[1]:
            raise SceneError(f"segments[{i}] = {_show(row)} joins node {row[0]} to itself "
                             f"(a zero-length segment)", src)
        out.append(row)
    return out


def _unknown_keys_message(unknown: list[str], known) -> str:
    parts = []
    for k in unknown:
        close = difflib.get_close_matches(k, known, n=1)
        parts.append(_show(k) + (f" (did you mean {_show(close[0])}?)" if close else ""))
    return ", ".join(parts)


def _scene_from_json(data, src: str, radius: float | None) -> tuple[Skeleton | None, list[MeshEntry]]:
    if type(data) is not dict:
        raise SceneError(f"the top level must be a JSON object {{\"skelslice\": 1, ...}}, "
                         f"got {_kind(data)} {_show(data)}", src)
    if "skelslice" not in data:
        raise SceneError('missing the format key "skelslice" (the version, 1); '
                         'this does not look like a skelslice scene', src)
    version = data["skelslice"]
    if type(version) is not int:
        raise SceneError(f'"skelslice" = {_show(version)} must be the integer format version '
                         f'{FORMAT_VERSION}', src)
    if version not in READ_VERSIONS:
        raise SceneError(f'"skelslice" = {version}: scene format version {version} is not supported '
                         f'(skelslice {__version__} reads versions {", ".join(map(str, READ_VERSIONS))}); '
                         f'upgrade skelslice', src)
    keys = _KEYS + (("meshes", "groups") if version >= 2 else ())
    unknown = [k for k in data if k not in keys and k != "metadata" and not k.startswith("x-")]
    if "meshes" in unknown:
        raise SceneError('"meshes" needs scene format version 2: write "skelslice": 2 '
                         '(version 1 files have no meshes)', src)
    if "groups" in unknown:
        raise SceneError('"groups" needs scene format version 2: write "skelslice": 2 '
                         '(version 1 files have no groups)', src)
    if unknown:
        raise SceneError(f"unknown key{'s' if len(unknown) > 1 else ''} "
                         f"{_unknown_keys_message(unknown, keys + ('metadata',))}; "
                         f'extra data must go under "metadata" or keys starting with "x-"', src)
    lattice_keys = [k for k in ("nodes", "segments") if k in data]
    mesh_only = "meshes" in data and not lattice_keys
    missing = [k for k in ("units",) + (() if mesh_only else ("nodes", "segments")) if k not in data]
    if missing:
        raise SceneError("missing key" + ("s " if len(missing) > 1 else " ")
                         + ", ".join(f'"{k}"' for k in missing), src)

    units = data["units"]
    if type(units) is not str or units not in UNITS:
        raise SceneError(f'"units" = {_show(units)} is not supported; use one of '
                         + ", ".join(f'"{u}"' for u in UNITS), src)
    meshes = _mesh_entries(data["meshes"], units, src) if "meshes" in data else []
    if mesh_only or ("meshes" in data and data.get("nodes") == [] and data.get("segments") == []):
        for k in ("radii", "segment_radii"):
            if k in data:
                raise SceneError(f'"{k}" is given but the scene has no lattice ("nodes" and "segments" '
                                 f'are {"empty" if lattice_keys else "absent"})', src)
        if not meshes:
            raise SceneError('the scene has neither a lattice nor a mesh ("meshes" is empty)', src)
        if "groups" in data:
            raise SceneError('"groups" is given but the scene has no lattice', src)
        return None, meshes

    nodes = _rows(data["nodes"], "nodes", 3, "node", "[x, y, z]", src)
    n = len(nodes)
    segments = _segments(data["segments"], n, src)
    if not segments:
        raise SceneError('"segments" is empty; a scene needs at least one segment', src)
    m = len(segments)

    node_radii = seg_radii = None
    if "radii" in data:
        node_radii = [_number(r, f"radii[{i}]", src)
                      for i, r in enumerate(_array(data["radii"], "radii", "numbers (one radius per node)", src))]
        _positive(node_radii, "radii", src, nested=False)
        if len(node_radii) != n:
            raise SceneError(f'"radii" has {len(node_radii)} entries but there are {n} nodes; '
                             f'give one radius per node (or use "segment_radii")', src)
    if "segment_radii" in data:
        seg_radii = _rows(data["segment_radii"], "segment_radii", 2, "segment radius pair", "[r_i, r_j]", src)
        _positive(seg_radii, "segment_radii", src, nested=True)
        if len(seg_radii) != m:
            raise SceneError(f'"segment_radii" has {len(seg_radii)} entries but there are {m} segments; '
                             f'give one [r_i, r_j] pair per segment', src)

    degree, sigma = DEFAULT_DEGREE, DEFAULT_SIGMA
    if "kernel" in data:
        kernel = data["kernel"]
        if type(kernel) is not dict:
            raise SceneError(f'"kernel" = {_show(kernel)} must be an object such as '
                             f'{{"degree": {DEFAULT_DEGREE}, "sigma": {DEFAULT_SIGMA}}}', src)
        bad = [k for k in kernel if k not in _KERNEL_KEYS]
        if bad:
            raise SceneError(f"unknown kernel key{'s' if len(bad) > 1 else ''} "
                             f"{_unknown_keys_message(bad, _KERNEL_KEYS)}; "
                             f'the kernel has only "degree" and "sigma"', src)
        degree = kernel.get("degree", DEFAULT_DEGREE)
        if "sigma" in kernel:
            sigma = kernel["sigma"]
            if type(sigma) in (int, float):
                sigma = _number(sigma, "kernel.sigma", src)

    seg_arr = np.array(segments, dtype=np.int64).reshape(m, 2)
    nodes_arr = np.array(nodes, dtype=np.float64).reshape(n, 3)
    if seg_radii is not None:
        radii_arr = np.array(seg_radii, dtype=np.float64).reshape(m, 2)
    elif node_radii is not None:
        radii_arr = np.array(node_radii, dtype=np.float64)[seg_arr]
    elif radius is None:
        raise SceneError('no radii: give "radii" (one per node) or "segment_radii" '
                         '(one [r_i, r_j] pair per segment), or pass --radius', src)
    else:
        radii_arr = None  # the radius argument is in mm already
    if units != "mm":
        mul, div = UNITS[units]
        with np.errstate(over="ignore", under="ignore"):
            nodes_arr = nodes_arr * mul / div
            if radii_arr is not None:
                radii_arr = radii_arr * mul / div
        for name, arr in (("coordinates", nodes_arr), ("radii", radii_arr)):
            if arr is not None and not np.all(np.isfinite(arr)):
                raise SceneError(f"{name} overflow when converted from {units} to mm", src)
        if radii_arr is not None and not np.all(radii_arr > 0):
            raise SceneError(f"radii underflow to 0 when converted from {units} to mm", src)
    if radii_arr is None:
        radii_arr = np.full((m, 2), float(radius))
    scene_numbers(nodes_arr, radii_arr, src, node_entry=lambda i, k: f"nodes[{i}][{k}]",
                  radius_entry=_json_radius_entry(seg_arr, seg_radii is not None, node_radii is not None))
    skel = Skeleton(nodes_arr, seg_arr, radii_arr, degree, sigma, source=src)
    if "groups" in data:                    # struts that unite by groups (docs/supports.md)
        skel = with_groups(skel, data["groups"], src)
    return skel, meshes


def _json_radius_entry(seg_arr: np.ndarray, by_segment: bool, by_node: bool):
    """The name of the radius at end j of segment i in a JSON scene (for :func:`scene_numbers`)."""
    if by_segment:
        return lambda i, j: f"segment_radii[{i}][{j}]"
    if by_node:
        return lambda i, j: f"radii[{int(seg_arr[i, j])}]"
    return lambda i, j: "the radius (--radius)"


def _mesh_entries(value, units: str, src: str) -> list[MeshEntry]:
    """The ``"meshes"`` entries of a version 2 scene, checked and resolved."""
    out = []
    folder = Path(src).parent
    mul, div = UNITS[units]
    for i, e in enumerate(_array(value, "meshes", 'objects {"path": ..., "role": ...}', src)):
        where = f"meshes[{i}]"
        if type(e) is not dict:
            raise SceneError(f'{_is(where, e)}; a mesh entry is an object {{"path": "part.stl", "role": "solid"}}',
                             src)
        bad = [k for k in e if k not in _MESH_KEYS and k != "metadata" and not k.startswith("x-")]
        if bad:
            raise SceneError(f"{where}: unknown key{'s' if len(bad) > 1 else ''} "
                             f"{_unknown_keys_message(bad, _MESH_KEYS)}; a mesh entry has "
                             + ", ".join(f'"{k}"' for k in _MESH_KEYS), src)
        if "path" not in e:
            raise SceneError(f'{where}: missing key "path" (the mesh file)', src)
        path = e["path"]
        if type(path) is not str or not path.strip():
            raise SceneError(f'{_is(where + ".path", path)}; it must be the name of a mesh file', src)
        full = Path(path) if Path(path).is_absolute() else folder / path
        suffix = full.suffix.lower()
        if suffix not in (".stl", ".obj", ".ply", ".3mf"):
            raise SceneError(f'{where}.path = {_show(path)}: unknown mesh file type {suffix or "(no suffix)"!r}; '
                             f'use .stl, .obj, .ply or .3mf', src)
        role = e.get("role", "solid")
        if type(role) is not str or role not in _MESH_ROLES:
            raise SceneError(f'{where}.role = {_show(role)} is not a mesh role; use one of '
                             + ", ".join(f'"{r}"' for r in _MESH_ROLES), src)
        scale = mul / div
        if "units" in e:
            u = e["units"]
            if suffix == ".3mf":
                raise SceneError(f'{where}.units: a 3MF file carries its own unit; remove "units"', src)
            if type(u) is not str or u not in UNITS:
                raise SceneError(f'{where}.units = {_show(u)} is not supported; use one of '
                                 + ", ".join(f'"{x}"' for x in UNITS), src)
            scale = UNITS[u][0] / UNITS[u][1]
        transform = None
        if "transform" in e:
            rows = e["transform"]
            if type(rows) is not list or len(rows) not in (3, 4):
                raise SceneError(f'{where}.transform = {_show(rows)} must be 3 or 4 rows of 4 numbers '
                                 f'([[a, b, c, tx], [d, e, f, ty], [g, h, i, tz]])', src)
            m = np.array(_rows(rows, f"{where}.transform", 4, "row", "[a, b, c, t]", src), dtype=np.float64)
            if m.shape[0] == 4 and not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
                raise SceneError(f"{where}.transform: the 4th row must be [0, 0, 0, 1], got {_show(m[3].tolist())}",
                                 src)
            if not abs(np.linalg.det(m[:3, :3])) > 0:
                raise SceneError(f"{where}.transform is singular (it flattens the mesh)", src)
            transform = m[:3].copy()
            transform[:, 3] *= mul / div          # translation: scene units to mm
        out.append(MeshEntry(os.fspath(full), role, float(scale), transform))
    return out


# ----------------------------------------------------------------------------- OBJ
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_INDEX = re.compile(r"[+-]?\d+\Z")
_OBJ_IGNORED = frozenset({
    "vn", "vt", "vp", "o", "g", "s", "mg", "usemtl", "mtllib", "lod", "bevel", "c_interp",
    "d_interp", "shadow_obj", "trace_obj", "ctech", "stech", "maplib", "usemap",
})
_OBJ_FREEFORM = frozenset({
    "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm", "trim", "hole", "scrv",
    "sp", "end", "con",
})


def _obj_lines(text: str):
    """(line number, tokens) of each statement, comments stripped, continuations joined."""
    pending: list[str] = []
    first = 0
    for no, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].rstrip()
        if not pending:
            first = no
        if line.endswith("\\"):
            pending.append(line[:-1])
            continue
        pending.append(line)
        tokens = " ".join(pending).split()
        pending = []
        if tokens:
            yield first, tokens
    if pending:
        tokens = " ".join(pending).split()
        if tokens:
            yield first, tokens


def _statement(tokens: list[str]) -> str:
    s = " ".join(tokens)
    return repr(s if len(s) <= _MAX_SHOWN else s[:_MAX_SHOWN - 3] + "...")


def _skeleton_from_obj(text: str, src: str, radius: float | None) -> Skeleton:
    coords: list[list[float]] = []
    vradius: list[float | None] = []
    vline: list[int] = []
    segs: list[tuple[int, int]] = []
    sline: list[int] = []
    stmt: dict[int, str] = {}
    for no, tokens in _obj_lines(text):
        key, args = tokens[0], tokens[1:]
        where = f"line {no}: {_statement(tokens)}"
        if key == "v":
            if len(args) not in (3, 4):
                extra = " (vertex colours are not supported)" if len(args) in (6, 7) else ""
                raise SceneError(f"{where} has {len(args)} numbers; a vertex is 'v x y z' or "
                                 f"'v x y z radius'{extra}", src)
            vals = []
            for a in args:
                if not _NUMBER.match(a):
                    raise SceneError(f"{where}: {a!r} is not a number", src)
                x = float(a)
                if not math.isfinite(x):
                    raise SceneError(f"{where}: {a!r} is not a finite number", src)
                vals.append(x)
            r = None
            if len(vals) == 4:
                r = vals.pop()
                if not r > 0:
                    raise SceneError(f"{where}: radius {args[3]} is not valid; radii must be > 0", src)
            coords.append(vals)
            vradius.append(r)
            vline.append(no)
        elif key == "l":
            if len(args) < 2:
                raise SceneError(f"{where}: a line element needs at least two vertex indices", src)
            idx = []
            for a in args:
                head = a.split("/", 1)[0]
                if not _INDEX.match(head):
                    raise SceneError(f"{where}: {a!r} is not a vertex index", src)
                i = int(head)
                if i == 0:
                    raise SceneError(f"{where}: vertex index 0 is invalid; OBJ indices start at 1 "
                                     f"(negative ones count back from the last vertex)", src)
                if i < 0:
                    j = len(coords) + i
                    if j < 0:
                        raise SceneError(f"{where}: relative vertex index {i} points before the first "
                                         f"vertex (only {len(coords)} vertices are defined above)", src)
                    idx.append(j)
                else:
                    idx.append(i - 1)
            stmt[no] = _statement(tokens)
            for a, b in zip(idx[:-1], idx[1:]):
                segs.append((a, b))
                sline.append(no)
        elif key in ("f", "fo"):
            raise SceneError(f"{where}: faces are not a skeleton; describe the struts as polylines "
                             f"('l i j ...'), one per strut or chain of struts", src)
        elif key == "p":
            raise SceneError(f"{where}: point elements are not supported; a skeleton is made of "
                             f"segments ('l i j ...')", src)
        elif key in _OBJ_FREEFORM:
            raise SceneError(f"{where}: free-form curves and surfaces are not supported; "
                             f"use polylines ('l i j ...')", src)
        elif key in _OBJ_IGNORED:
            continue
        else:
            raise SceneError(f"{where}: unknown OBJ statement {key!r}; a skeleton OBJ has "
                             f"'v x y z [radius]' and 'l i j ...' lines", src)

    nv = len(coords)
    if not text.strip():
        raise SceneError("the file is empty; expected OBJ polylines ('v x y z [radius]', 'l i j ...')", src)
    if not segs:
        raise SceneError("no line elements ('l i j ...'): the file describes no segments", src)
    for (a, b), no in zip(segs, sline):
        for i in (a, b):
            if i >= nv:
                raise SceneError(f"line {no}: {stmt[no]}: vertex index {i + 1} is out of range "
                                 f"(the file has {nv} vertices)", src)
    nodes = np.array(coords, dtype=np.float64).reshape(nv, 3)
    seg_arr = np.array(segs, dtype=np.int64).reshape(-1, 2)
    with np.errstate(over="ignore", invalid="ignore"):     # huge coordinates are refused below, by name
        length = np.linalg.norm(nodes[seg_arr[:, 1]] - nodes[seg_arr[:, 0]], axis=1)
    bad = np.nonzero(~(length > 0))[0]
    if bad.size:
        k = int(bad[0])
        a, b = (int(i) for i in seg_arr[k])
        why = (f"vertex {a + 1} is joined to itself" if a == b else
               f"vertices {a + 1} and {b + 1} are both at {nodes[a].tolist()}")
        raise SceneError(f"line {sline[k]}: {stmt[sline[k]]}: zero-length segment: {why}", src)

    have = [r is not None for r in vradius]
    if radius is None:
        used = np.zeros(nv, dtype=bool)
        used[seg_arr.ravel()] = True
        lacking = [i for i in range(nv) if used[i] and not have[i]]
        if lacking:
            i = lacking[0]
            if any(have):
                raise SceneError(
                    f"line {vline[i]}: vertex {i + 1} has no radius while other vertices have one; "
                    f"add a 4th number 'v x y z radius' or pass --radius as a default", src)
            raise SceneError("no vertex has a radius: write vertices as 'v x y z radius' "
                             "or pass --radius", src)
    default = float(radius) if radius is not None else math.nan
    vr = np.array([default if r is None else r for r in vradius], dtype=np.float64)
    scene_numbers(nodes, vr[seg_arr], src, node_entry=lambda i, k: f"line {vline[i]}: vertex {i + 1} {'xyz'[k]}",
                  radius_entry=lambda i, j: (f"line {vline[seg_arr[i, j]]}: vertex {seg_arr[i, j] + 1} radius"
                                             if vradius[seg_arr[i, j]] is not None else "the radius (--radius)"))
    return Skeleton(nodes, seg_arr, vr[seg_arr], source=src)


__all__ = ["load_scene", "save_scene", "read_json_scene", "MeshEntry", "FORMAT_VERSION", "READ_VERSIONS", "UNITS",
           "SUFFIXES"]
