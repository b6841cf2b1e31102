"""3MF Beam Lattice input: beams with two radii as a scene.

The 3MF Beam Lattice extension (namespace
``http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02``) stores a
lattice inside a mesh object: the mesh vertices are the nodes and each
``<b:beam v1 v2 r1 r2>`` is a strut whose radius varies linearly from ``r1``
to ``r2`` -- exactly a :class:`~slicer.skeleton.Skeleton` segment. This is
what nTop and Netfabb export.

Reading uses `lib3mf <https://pypi.org/project/lib3mf/>`_ (the 3MF
Consortium's reference library) for the package, units, objects, components
and build-item transforms. Because lib3mf silently replaces some invalid
values (a negative or non-numeric ``r1`` becomes the lattice's default
radius) and reports a bad vertex index without saying which beam, the model
XML is first checked by a streaming scan that names the part, object and beam
of any problem::

    part.3mf: /3D/3dmodel.model, object 1 'lattice', beam 17: v2 = 99 is out of range (the mesh has 40 vertices; indices are 0-based)

Rules
-----
* Radii: ``r1`` defaults to the lattice's ``radius`` attribute and ``r2`` to
  ``r1`` (as the extension specifies). Every radius must be a finite
  number > 0.
* Units: the model's ``unit`` (micron, millimeter, centimeter, inch, foot,
  meter) is converted to mm.
* Placement: every build item is instantiated with its transform, and
  components objects recursively with theirs. A transform must be a
  similarity (rotation, mirror, uniform scale, translation): radii scale by
  its factor. A shear or a non-uniform scale is an error, since a round strut
  would stop being round.
* Node positions are stored by lib3mf as float32 (about 7 significant
  digits); radii are float64.
* Ignored: cap modes (the integral surface has its own rounded ends), balls,
  beam sets, triangles of objects that also have beams (usually a hull or a
  preview). Errors: a build without any beam, an object in the build with
  triangles and no beams (it would not be printed), a clipping mesh.
* The kernel is the default one (degree 6, sigma 2): 3MF has no field kernel.
"""
from __future__ import annotations

import math
import os
import zipfile
from xml.etree import ElementTree as ET

import numpy as np

from .errors import SceneError
from .skeleton import Skeleton

CORE_NS = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
BEAM_NS = "http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02"

#: lib3mf ModelUnit value -> mm per model unit
UNIT_MM = {0: 0.001, 1: 1.0, 2: 10.0, 3: 25.4, 4: 304.8, 5: 1000.0}
#: relative tolerance on the singular values of a similarity transform
SIMILARITY_RTOL = 1e-5


def load_3mf(path, radius: float | None = None) -> Skeleton:
    """Read the beam lattices of a 3MF file as one skeleton, in mm.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.3mf`` package.
    radius : float, optional
        Unused: a beam lattice always carries its radii (the lattice's
        ``radius`` attribute is the default). Accepted so that
        :func:`slicer.scene_io.load_scene` can pass its argument through.

    Returns
    -------
    Skeleton
        Nodes ``(n, 3)`` float64 mm (beam ends of all build items, each
        instance placed by its transforms), segments ``(m, 2)`` and radii
        ``(m, 2)`` mm; ``source`` is ``str(path)``.

    Raises
    ------
    SceneError
        Not a 3MF package, lib3mf missing or rejecting the file, no beam
        lattice in the build, a beam index out of range, a radius that is
        not a finite number > 0, a non-similarity transform, a clipping mesh,
        or a build object with triangles and no beams. The message names the
        file and, for beam data, the part, object and beam index.
    """
    src = os.fsdecode(os.fspath(path))
    n_beams = _scan_package(src)
    if n_beams == 0:
        raise SceneError("no beam lattice: the 3MF file has no <b:beam> elements "
                         "(skelslice reads the 3MF Beam Lattice extension, not triangle meshes)", src)
    model = _read_model(src)
    scale = UNIT_MM.get(int(model.GetUnit()))
    if scale is None:  # pragma: no cover - lib3mf knows only the six units
        raise SceneError(f"unknown model unit {model.GetUnit()!r}", src)

    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    items = model.GetBuildItems()
    item_no = 0
    while items.MoveNext():
        item = items.GetCurrent()
        where = f"build item {item_no}"
        t = _matrix(item.GetObjectTransform()) if item.HasObjectTransform() else np.eye(4, 3)
        _collect(item.GetObjectResource(), t, where, src, parts, depth=0)
        item_no += 1
    if not parts or sum(len(p[1]) for p in parts) == 0:
        raise SceneError("no beam lattice in the build: no build item refers to an object with beams", src)

    nodes, segs, radii, offset = [], [], [], 0
    for p, s, r in parts:
        nodes.append(p)
        segs.append(s + offset)
        radii.append(r)
        offset += len(p)
    nodes_mm = np.concatenate(nodes) * scale
    radii_mm = np.concatenate(radii) * scale
    try:
        return Skeleton(nodes_mm, np.concatenate(segs), radii_mm, source=src)
    except SceneError as exc:
        raise SceneError(f"after placement: {exc.detail}", src) from None


# ----------------------------------------------------------------------------- lib3mf
def _read_model(src: str):
    try:
        import lib3mf
    except ImportError:  # pragma: no cover - lib3mf is a dependency
        raise SceneError("reading 3MF needs the lib3mf package: pip install 'skelslice[3mf]'", src) from None
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    reader = model.QueryReader("3mf")
    reader.SetStrictModeActive(False)
    try:
        reader.ReadFromFile(src)
    except lib3mf.ELib3MFException as exc:
        raise SceneError(f"lib3mf cannot read the 3MF file: {exc}", src) from None
    return model


def _matrix(tr) -> np.ndarray:
    """A lib3mf Transform as a (4, 3) float64 array: rows m0, m1, m2, translation.

    3MF transforms act on row vectors: ``p' = p @ M[:3] + M[3]``.
    """
    return np.array([[float(tr.Fields[r][c]) for c in range(3)] for r in range(4)], dtype=np.float64)


def _compose(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """The transform applying ``inner`` then ``outer``."""
    out = np.empty((4, 3))
    out[:3] = inner[:3] @ outer[:3]
    out[3] = inner[3] @ outer[:3] + outer[3]
    return out


def _radius_scale(t: np.ndarray, where: str, src: str) -> float:
    sv = np.linalg.svd(t[:3], compute_uv=False)
    if not (sv[-1] > 0 and sv[0] - sv[-1] <= SIMILARITY_RTOL * sv[0]):
        raise SceneError(
            f"{where}: the transform is not a similarity (scale factors {', '.join(f'{v:.6g}' for v in sv)}); "
            f"round beams would stop being round. Use rotations, mirrors, translations and uniform scales only",
            src)
    return float(np.mean(sv))


def _object_label(obj) -> str:
    name = obj.GetName()
    rid = obj.GetModelResourceID() if hasattr(obj, "GetModelResourceID") else obj.GetResourceID()
    return f"object {rid}" + (f" {name!r}" if name else "")


def _collect(obj, t: np.ndarray, where: str, src: str, parts: list, depth: int) -> None:
    if depth > 64:
        raise SceneError(f"{where}: components are nested more than 64 deep (a cycle?)", src)
    label = _object_label(obj)
    if obj.IsComponentsObject():
        for i in range(obj.GetComponentCount()):
            c = obj.GetComponent(i)
            tc = _matrix(c.GetTransform()) if c.HasTransform() else np.eye(4, 3)
            _collect(c.GetObjectResource(), _compose(tc, t), f"{where}, {label}, component {i}",
                     src, parts, depth + 1)
        return
    mesh = obj  # lib3mf's factory returns a MeshObject
    lattice = mesh.BeamLattice()
    beams = lattice.GetBeams() if lattice.GetBeamCount() else []
    if not beams:
        if mesh.GetTriangleCount():
            raise SceneError(
                f"{where}: {label} is a triangle mesh ({mesh.GetTriangleCount()} triangles) without a beam "
                f"lattice; skelslice slices beam lattices only, so it would not be printed. Remove it from "
                f"the build", src)
        return
    mode, _ = lattice.GetClipping()
    if int(mode) != 0:
        raise SceneError(f"{where}: {label} clips its beam lattice with a mesh (clipping mode {int(mode)}); "
                         f"clipping is not supported", src)
    k = _radius_scale(t, where, src)
    verts = np.array([list(v.Coordinates) for v in mesh.GetVertices()], dtype=np.float64).reshape(-1, 3)
    idx = np.array([[b.Indices[0], b.Indices[1]] for b in beams], dtype=np.int64)
    rad = np.array([[b.Radii[0], b.Radii[1]] for b in beams], dtype=np.float64)
    used, inverse = np.unique(idx, return_inverse=True)
    pts = verts[used] @ t[:3] + t[3]
    parts.append((pts, inverse.reshape(idx.shape), rad * k))


# ----------------------------------------------------------------------------- XML scan
def _scan_package(src: str) -> int:
    """Check every beam of every model part; return the number of beams.

    Streams the XML (``iterparse``) so a large lattice is never held as a tree.
    """
    try:
        zf = zipfile.ZipFile(src)
    except FileNotFoundError:
        raise SceneError("cannot read the scene file: No such file or directory", src) from None
    except IsADirectoryError:
        raise SceneError("cannot read the scene file: Is a directory", src) from None
    except (zipfile.BadZipFile, OSError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else "not a zip archive"
        raise SceneError(f"not a 3MF package ({why}); a .3mf file is a zip archive", src) from None
    total = 0
    with zf:
        models = [n for n in zf.namelist() if n.lower().endswith(".model")]
        if not models:
            raise SceneError("not a 3MF package: it has no .model part (expected /3D/3dmodel.model)", src)
        for name in models:
            with zf.open(name) as fh:
                total += _scan_part(fh, "/" + name, src)
    return total


def _scan_part(fh, part: str, src: str) -> int:
    obj_tag, vert_tag = f"{{{CORE_NS}}}object", f"{{{CORE_NS}}}vertex"
    lat_tag, beam_tag = f"{{{BEAM_NS}}}beamlattice", f"{{{BEAM_NS}}}beam"
    label, n_vert, beam_no, total = "", 0, 0, 0
    try:
        for event, el in ET.iterparse(fh, events=("start", "end")):
            tag = el.tag
            if event == "start":
                if tag == obj_tag:
                    name = el.get("name")
                    label = f"object {el.get('id')}" + (f" {name!r}" if name else "")
                    n_vert, beam_no = 0, 0
                elif tag == lat_tag:
                    _radius(el.get("radius"), "radius", f"{part}, {label}, beamlattice", src, required=True)
                continue
            if tag == vert_tag:
                n_vert += 1
            elif tag == beam_tag:
                where = f"{part}, {label}, beam {beam_no}"
                v1 = _index(el.get("v1"), "v1", n_vert, where, src)
                v2 = _index(el.get("v2"), "v2", n_vert, where, src)
                if v1 == v2:
                    raise SceneError(f"{where}: v1 = v2 = {v1}: a beam joins a vertex to itself", src)
                for attr in ("r1", "r2"):
                    _radius(el.get(attr), attr, where, src, required=False)
                beam_no += 1
                total += 1
            el.clear()  # keep memory flat: children of finished elements are dropped
    except ET.ParseError as exc:
        raise SceneError(f"{part}: invalid XML ({exc})", src) from None
    return total


def _index(text: str | None, attr: str, n_vert: int, where: str, src: str) -> int:
    if text is None:
        raise SceneError(f"{where}: the {attr} attribute is missing", src)
    try:
        v = int(text.strip())
    except ValueError:
        raise SceneError(f"{where}: {attr} = {text!r} is not a vertex index (a non-negative integer)", src) \
            from None
    if not 0 <= v < n_vert:
        raise SceneError(f"{where}: {attr} = {v} is out of range (the mesh has {n_vert} vertices; "
                         f"indices are 0-based)", src)
    return v


def _radius(text: str | None, attr: str, where: str, src: str, required: bool) -> float:
    if text is None:
        if required:
            raise SceneError(f"{where}: the {attr} attribute (default beam radius) is missing", src)
        return math.nan
    try:
        r = float(text.strip())
    except ValueError:
        raise SceneError(f"{where}: {attr} = {text!r} is not a number", src) from None
    if not (math.isfinite(r) and r > 0):
        raise SceneError(f"{where}: {attr} = {text.strip()} is not a valid radius; radii must be finite and > 0",
                         src)
    return r


__all__ = ["load_3mf", "UNIT_MM"]
