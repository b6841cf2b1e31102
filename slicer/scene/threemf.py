"""3MF input: beam lattices, triangle-mesh objects and clipping meshes.

The 3MF Beam Lattice extension (namespace
``http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02``) stores a
lattice inside a mesh object: the mesh vertices are the nodes and each
``<b:beam v1 v2 r1 r2>`` is a strut whose radius varies linearly from ``r1``
to ``r2`` -- exactly a :class:`~slicer.model.skeleton.Skeleton` segment. The same
object may carry triangles (unified with its lattice), and the lattice may be
clipped by another mesh object (``clippingmode="inside"`` keeps the lattice
inside it, ``"outside"`` outside). Other objects of the build are triangle
meshes. This is what nTop and Netfabb export.

:func:`read_3mf` returns all of it (the CLI's and :func:`slicer.parts.part.load_part`'s
path); :func:`load_3mf` is the beams-only reader behind
:func:`slicer.scene.read.load_scene`, which refuses mesh parts.

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
* Required extensions (``requiredextensions`` of every model part): core,
  beam lattice, production (multi-part models, resolved by lib3mf),
  materials and triangle sets (they do not change the geometry) are
  accepted; any other required extension is refused by its namespace --
  among them slices, beam-lattice balls, secure content, volumetric,
  implicit, displacement and boolean operations.
* Files the 3MF specifications say a consumer must reject are refused: lib3mf
  reports their problems as errors or warnings, and every warning is
  treated as an error, except unknown metadata names (which consumers must
  ignore), beams shorter than ``minlength`` (ignored, as the extension
  requires) and missing production UUIDs (identifiers only).
* Radii: ``r1`` defaults to the lattice's ``radius`` attribute and ``r2`` to
  ``r1`` (as the extension specifies). Every radius must be a finite
  number > 0. Beams shorter than the lattice's ``minlength`` (in the
  object's coordinates) are ignored, as the extension requires.
* Units: the model's ``unit`` (micron, millimeter, centimeter, inch, foot,
  meter) is converted to mm.
* Placement: every build item is instantiated with its transform, and
  components objects recursively with theirs. A lattice's transform must be
  a similarity (rotation, mirror, uniform scale, translation): radii scale by
  its factor. A shear or a non-uniform scale is an error, since a round strut
  would stop being round. Meshes take any non-singular affine transform.
* Meshes: objects of type ``model`` and ``solidsupport`` are solids; they must
  be closed, manifold and outward-oriented (:mod:`slicer.parts.meshes`).
  Self-intersections and overlapping objects are accepted and filled by the
  positive fill rule, as the core specification requires. ``support``
  objects are left out (consumers may ignore them; a note says so);
  ``surface`` objects and level sets are refused.
* Clipping: the clipping mesh is placed with its lattice's transforms.
  One clipped lattice instance per file (clipping acts on its own lattice,
  and all lattices of a file blend into one field).
* ``representationmesh`` is ignored: it is a preview for consumers without
  beam support, never for manufacturing.
* Caps: the integral surface has its own rounded ends, the closest to
  ``cap="sphere"`` (the default); a ``hemisphere`` or ``butt`` cap at a free
  beam end (a vertex of one beam only) is refused. Balls are refused.
* Node positions and mesh vertices pass through lib3mf as float32 (about 7
  significant digits); radii are float64.
* The kernel is the default one (degree 6, sigma 2): 3MF has no field kernel.
"""
from __future__ import annotations

import ctypes
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from xml.parsers import expat

import numpy as np

from slicer.arguments import scene_numbers
from slicer.errors import SceneError
from slicer.input_limits import MAX_TOKEN, Restart, check_allocation, check_members, feed_xml
from slicer.parts.meshes import Mesh, make_mesh
from slicer.model.skeleton import Skeleton
from slicer.constants import SIMILARITY_RTOL

CORE_NS = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
BEAM_NS = "http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02"
BALLS_NS = "http://schemas.microsoft.com/3dmanufacturing/beamlattice/balls/2020/07"
MATERIAL_NS = "http://schemas.microsoft.com/3dmanufacturing/material/2015/02"

#: namespaces a file may require: name shown in messages
SUPPORTED_EXTENSIONS = {
    CORE_NS: "core",
    BEAM_NS: "beam lattice",
    "http://schemas.microsoft.com/3dmanufacturing/production/2015/06": "production",
    MATERIAL_NS: "materials and properties",
    "http://schemas.microsoft.com/3dmanufacturing/trianglesets/2021/07": "triangle sets",
}
#: known extensions that change the geometry in ways skelslice does not print
UNSUPPORTED_EXTENSIONS = {
    BALLS_NS: "beam lattice balls",
    "http://schemas.microsoft.com/3dmanufacturing/slice/2015/07": "slices",
    "http://schemas.microsoft.com/3dmanufacturing/securecontent/2019/04": "secure content",
    "http://schemas.microsoft.com/3dmanufacturing/securecontent/2019/07": "secure content",
    "http://schemas.3mf.io/3dmanufacturing/volumetric/2022/01": "volumetric",
    "http://schemas.3mf.io/3dmanufacturing/implicit/2023/12": "implicit",
    "http://schemas.3mf.io/3dmanufacturing/displacement/2023/10": "displacement",
    "http://schemas.3mf.io/3dmanufacturing/booleanoperations/2023/07": "boolean operations",
}
#: lib3mf warnings that are not grounds for refusing a file
BENIGN_WARNINGS = {
    32946: "unknown metadata name (consumers must ignore it)",
    32944: "missing production UUID",
    32959: "beams shorter than minlength (consumers must ignore them; they are left out)",
}

#: lib3mf ModelUnit value -> mm per model unit
UNIT_MM = {0: 0.001, 1: 1.0, 2: 10.0, 3: 25.4, 4: 304.8, 5: 1000.0}
#: lib3mf object types
_MODEL, _SUPPORT, _SOLID_SUPPORT, _SURFACE = 1, 2, 3, 4
_CAPS = {0: "sphere", 1: "hemisphere", 2: "butt"}


@dataclass
class ThreeMF:
    """What a 3MF build holds, placed and in mm (see :func:`read_3mf`).

    Attributes
    ----------
    lattice : Skeleton or None
        Every beam of the build.
    solids : list of Mesh
        Triangle meshes to print (objects of the build, and triangles of
        objects that also carry beams), one per instance.
    clip_mode : {"inside", "outside"} or None
    clips : list of Mesh
        The clipping mesh of the (single) clipped lattice instance.
    notes : list of str
        What was left out, and why.
    """

    lattice: Skeleton | None = None
    solids: list[Mesh] = field(default_factory=list)
    clip_mode: str | None = None
    clips: list[Mesh] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    solid_labels: list[str] = field(default_factory=list)


def read_3mf(path, repair: bool = False) -> ThreeMF:
    """Read a 3MF build: beam lattices, mesh objects and clipping meshes, in mm.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.3mf`` package.
    repair : bool
        Repair meshes that only need re-orienting (see :func:`slicer.parts.meshes.make_mesh`).

    Returns
    -------
    ThreeMF

    Raises
    ------
    SceneError
        Not a 3MF package, lib3mf missing or rejecting the file, a required
        extension skelslice does not support, bad beam data (naming the part,
        object and beam), balls, non-sphere caps at free ends, a
        non-similarity transform on a lattice, a mesh that is not a closed
        solid, several clipped lattice instances, or nothing to print.
    """
    src = os.fsdecode(os.fspath(path))
    _scan_package(src)
    model = _read_model(src)
    scale = UNIT_MM.get(int(model.GetUnit()))
    if scale is None:  # pragma: no cover - lib3mf knows only the six units
        raise SceneError(f"unknown model unit {model.GetUnit()!r}", src)
    walk = _Walk(model, src, scale, repair)
    items = model.GetBuildItems()
    item_no = 0
    while items.MoveNext():
        item = items.GetCurrent()
        t = _matrix(item.GetObjectTransform()) if item.HasObjectTransform() else np.eye(4, 3)
        walk.visit(item.GetObjectResource(), t, f"build item {item_no}", 0)
        item_no += 1
    out = ThreeMF(solids=walk.solids, notes=walk.notes)
    out.solid_labels = walk.solid_labels
    if walk.beams:
        nodes, segs, radii, offset = [], [], [], 0
        for p, s, r in walk.beams:
            nodes.append(p)
            segs.append(s + offset)
            radii.append(r)
            offset += len(p)
        nodes_mm, radii_mm = np.concatenate(nodes) * scale, np.concatenate(radii) * scale
        node_entry, radius_entry = _entries(walk.beam_labels)
        scene_numbers(nodes_mm, radii_mm, src, node_entry=node_entry, radius_entry=radius_entry)
        try:
            out.lattice = Skeleton(nodes_mm, np.concatenate(segs), radii_mm, source=src)
        except SceneError as exc:
            raise SceneError(f"after placement: {exc.detail}", src) from None
    if len(walk.clipped) > 1:
        raise SceneError(f"{len(walk.clipped)} clipped beam-lattice instances ({', '.join(walk.clipped)}): "
                         f"clipping acts on one lattice, but all lattices of a file blend into one field; "
                         f"give one clipped lattice per file", src)
    if walk.clip_mode is not None:
        if len(walk.beams) > 1:
            raise SceneError(f"{walk.clipped[0]} clips its lattice, but the build has {len(walk.beams)} "
                             f"lattice instances, which blend into one field; clipping one of them is not "
                             f"supported", src)
        out.clip_mode, out.clips = walk.clip_mode, walk.clips
    if out.lattice is None and not out.solids:
        raise SceneError("nothing to print: the build has no beam lattice and no triangle mesh", src)
    return out


def _entries(labels: list):
    """Names of a placed lattice's coordinates and radii in the file (for :func:`scene_numbers`):
    ``build item 0, object 1 'lattice': vertex 7 x (placed, mm)`` and ``... beam 3 r2``."""
    node_start = np.cumsum([0] + [len(used) for _, used, _ in labels])
    seg_start = np.cumsum([0] + [len(beams) for _, _, beams in labels])

    def node_entry(i, k):
        n = int(np.searchsorted(node_start, i, side="right")) - 1
        where, used, _ = labels[n]
        return f"{where}: vertex {int(used[i - node_start[n]])} {'xyz'[k]} (placed)"

    def radius_entry(i, j):
        n = int(np.searchsorted(seg_start, i, side="right")) - 1
        where, _, beams = labels[n]
        return f"{where}: beam {int(beams[i - seg_start[n]])} r{j + 1}"

    return node_entry, radius_entry


def load_3mf(path, radius: float | None = None) -> Skeleton:
    """Read the beam lattices of a 3MF file as one skeleton, in mm (beams only).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.3mf`` package.
    radius : float, optional
        Unused: a beam lattice always carries its radii (the lattice's
        ``radius`` attribute is the default). Accepted so that
        :func:`slicer.scene.read.load_scene` can pass its argument through.

    Returns
    -------
    Skeleton
        Nodes ``(n, 3)`` float64 mm (beam ends of all build items, each
        instance placed by its transforms), segments ``(m, 2)`` and radii
        ``(m, 2)`` mm; ``source`` is ``str(path)``.

    Raises
    ------
    SceneError
        As :func:`read_3mf`; also when the build has no beam lattice, or has
        triangle meshes or clipping (read those with
        :func:`slicer.parts.part.load_part`, as the command line does).
    """
    src = os.fsdecode(os.fspath(path))
    if _scan_package(src) == 0:
        raise SceneError("no beam lattice: the 3MF file has no <b:beam> elements "
                         "(a mesh-only part is read by slicer.parts.part.load_part, as the command line does)", src)
    got = read_3mf(src)
    if got.solids or got.clip_mode:
        what = (f"{got.solid_labels[0]} is a triangle mesh ({got.solids[0].n_faces} triangles)"
                if got.solids else "its lattice is clipped by a mesh")
        raise SceneError(f"{what}; load_scene reads beam lattices only: read the file with "
                         f"slicer.parts.part.load_part (the command line does)", src)
    if got.lattice is None:
        raise SceneError("no beam lattice in the build: no build item refers to an object with beams", src)
    return got.lattice


def read_3mf_meshes(path, repair: bool = False) -> list[Mesh]:
    """The solid meshes of a 3MF file used as a mesh file (no beams allowed).

    Raises
    ------
    SceneError
        As :func:`read_3mf`, or the file has beams.
    """
    src = os.fsdecode(os.fspath(path))
    got = read_3mf(src, repair=repair)
    if got.lattice is not None:
        raise SceneError("a mesh file must not contain beam lattices (give this file as the scene instead)", src)
    return got.solids


# ----------------------------------------------------------------------------- lib3mf
def _read_model(src: str):
    try:
        import lib3mf
    except ImportError:
        raise SceneError("reading 3MF needs the lib3mf package: pip install 'skelslice[3mf]'", src) from None
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    reader = model.QueryReader("3mf")
    reader.SetStrictModeActive(False)
    try:
        reader.ReadFromFile(src)
    except lib3mf.ELib3MFException as exc:
        raise SceneError(f"lib3mf cannot read the 3MF file: {exc}", src) from None
    for i in range(reader.GetWarningCount()):
        code, text = reader.GetWarning(i)
        if int(code) not in BENIGN_WARNINGS:
            raise SceneError(f"the 3MF file breaks the specification: {text} (lib3mf warning {int(code)})", src)
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


#: lib3mf's Beam record (packed): Indices uint32[2], Radii float64[2], CapModes int32[2]
_BEAM_DTYPE = np.dtype([("idx", "<u4", 2), ("rad", "<f8", 2), ("cap", "<i4", 2)])


def _bulk(obj, function: str, record: str, count: int, dtype, what: str, src: str) -> np.ndarray:
    """One lib3mf array getter (``lib3mf_meshobject_getvertices`` ...) copied straight into a numpy
    array of ``count`` records: no Python object per vertex. The size is checked against the input
    limit first (:func:`slicer.input_limits.check_allocation`)."""
    import lib3mf

    check_allocation(count, dtype.itemsize, what, src)
    out = np.zeros(count, dtype)
    struct = getattr(lib3mf.Lib3MF, record)
    if ctypes.sizeof(struct) != dtype.itemsize:  # pragma: no cover - a lib3mf with another record layout
        raise SceneError(f"{what}: lib3mf's {record} record has {ctypes.sizeof(struct)} bytes, not "
                         f"{dtype.itemsize}; this lib3mf version is not supported", src)
    buf = (struct * count).from_buffer(out) if count else (struct * 0)()
    needed = ctypes.c_uint64(0)
    wrapper = obj._wrapper
    wrapper.checkError(obj, getattr(wrapper.lib, function)(obj._handle, ctypes.c_uint64(count), needed, buf))
    if needed.value != count:  # pragma: no cover - lib3mf reports its own count
        raise SceneError(f"{what}: lib3mf returned {needed.value:,} records, not {count:,}", src)
    return out


def _vertices(mesh, what: str = "vertices", src: str = "") -> np.ndarray:
    """(n, 3) float64: the mesh object's vertices (float32 in lib3mf), in the object's unit."""
    raw = _bulk(mesh, "lib3mf_meshobject_getvertices", "Position", mesh.GetVertexCount(), np.dtype(("<f4", (3,))),
                what, src)
    return raw.astype(np.float64).reshape(-1, 3)


def _triangles(mesh, what: str = "triangles", src: str = "") -> np.ndarray:
    """(m, 3) int64: the mesh object's triangles (vertex indices)."""
    raw = _bulk(mesh, "lib3mf_meshobject_gettriangleindices", "Triangle", mesh.GetTriangleCount(),
                np.dtype(("<u4", (3,))), what, src)
    return raw.astype(np.int64).reshape(-1, 3)


def _beams(lattice, what: str, src: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lattice's beams: indices (m, 2) int64, radii (m, 2) float64 (object unit), cap modes (m, 2) int64."""
    raw = _bulk(lattice, "lib3mf_beamlattice_getbeams", "Beam", lattice.GetBeamCount(), _BEAM_DTYPE, what, src)
    return raw["idx"].astype(np.int64), raw["rad"].astype(np.float64), raw["cap"].astype(np.int64)


class _Walk:
    """Instantiates the objects of the build (recursively through components)."""

    def __init__(self, model, src: str, scale: float, repair: bool):
        self.model, self.src, self.scale, self.repair = model, src, scale, repair
        self.beams: list = []
        #: per lattice instance: (where, file vertex index of each node, file beam index of each segment)
        self.beam_labels: list = []
        self.solids: list[Mesh] = []
        self.clips: list[Mesh] = []
        self.clip_mode: str | None = None
        self.clipped: list[str] = []
        self.notes: list[str] = []
        self.solid_labels: list[str] = []

    def mesh(self, vertices: np.ndarray, faces: np.ndarray, t: np.ndarray, name: str) -> Mesh:
        """A placed, checked mesh (mm): 3MF row-vector transform, faces reversed by a mirror."""
        v = (vertices @ t[:3] + t[3]) * self.scale
        f = faces[:, ::-1] if np.linalg.det(t[:3]) < 0 else faces
        if not abs(np.linalg.det(t[:3])) > 0:
            raise SceneError(f"{name}: the transform is singular (it flattens the mesh)", self.src)
        return make_mesh(v, f, f"{self.src}: {name}", check_self_intersections=False, repair=self.repair)

    def visit(self, obj, t: np.ndarray, where: str, depth: int) -> None:
        if depth > 64:
            raise SceneError(f"{where}: components are nested more than 64 deep (a cycle?)", self.src)
        label = _object_label(obj)
        if obj.IsComponentsObject():
            for i in range(obj.GetComponentCount()):
                c = obj.GetComponent(i)
                tc = _matrix(c.GetTransform()) if c.HasTransform() else np.eye(4, 3)
                self.visit(c.GetObjectResource(), _compose(tc, t), f"{where}, {label}, component {i}", depth + 1)
            return
        if hasattr(obj, "IsLevelSetObject") and obj.IsLevelSetObject():
            raise SceneError(f"{where}: {label} is a level set (volumetric extension), which skelslice does not "
                             f"print", self.src)
        kind = int(obj.GetType())
        mesh = self.model.GetMeshObjectByID(obj.GetResourceID())
        lattice = mesh.BeamLattice()
        n_tri = mesh.GetTriangleCount()
        if kind == _SUPPORT:
            self.notes.append(f"{where}: {label} is a support structure (type \"support\"); left out: skelslice "
                              f"prints no support meshes")
            return
        if kind == _SURFACE:
            raise SceneError(f"{where}: {label} is an open surface (type \"surface\"), which a resin printer "
                             f"cannot print as a solid; remove it from the build", self.src)
        if kind not in (_MODEL, _SOLID_SUPPORT):
            raise SceneError(f"{where}: {label} has type {kind}, which is not printable", self.src)
        if lattice.GetBeamCount():
            self._lattice(mesh, lattice, t, where, label)
        if n_tri:
            name = f"{where}, {label}"
            self.solids.append(self.mesh(_vertices(mesh, f"{name}: vertices", self.src),
                                         _triangles(mesh, f"{name}: triangles", self.src), t, name))
            self.solid_labels.append(f"{where}: {label}")

    def _lattice(self, mesh, lattice, t: np.ndarray, item: str, label: str) -> None:
        src = self.src
        where = f"{item}, {label}"
        mode, _ = lattice.GetBallOptions()
        if int(mode) != 0 or lattice.GetBallCount():
            raise SceneError(f"{where}: the lattice has balls (beam lattice balls extension); skelslice does not "
                             f"print balls", src)
        k = _radius_scale(t, item, src)
        verts = _vertices(mesh, f"{where}: vertices", src)
        idx, rad, caps = _beams(lattice, f"{where}: beams", src)
        length = np.linalg.norm(verts[idx[:, 1]] - verts[idx[:, 0]], axis=1)
        keep = ~(length < lattice.GetMinLength())
        if not keep.all():
            self.notes.append(f"{where}: {int((~keep).sum()):,} beams shorter than the lattice's minlength "
                              f"{lattice.GetMinLength():g} ignored (as the beam lattice extension requires)")
            idx, rad, caps = idx[keep], rad[keep], caps[keep]
        if not len(idx):
            return
        valence = np.bincount(idx.ravel(), minlength=len(verts))
        free = valence[idx] == 1
        bad = free & (caps != 0)
        if bad.any():
            b, e = (int(x) for x in np.argwhere(bad)[0])
            raise SceneError(f"{where}: beam {b} has a {_CAPS.get(int(caps[b, e]), '?')!r} cap at its free end "
                             f"(vertex {int(idx[b, e])}); the integral surface ends round, like cap=\"sphere\": "
                             f"change the cap mode ({int(bad.sum())} free ends have other caps)", src)
        used, inverse = np.unique(idx, return_inverse=True)
        pts = verts[used] @ t[:3] + t[3]
        self.beams.append((pts, inverse.reshape(idx.shape), rad * k))
        self.beam_labels.append((where, used, np.nonzero(keep)[0]))
        cmode, cid = lattice.GetClipping()
        if int(cmode) != 0:
            self.clipped.append(where)
            cobj = self.model.GetMeshObjectByID(int(cid))
            if cobj.BeamLattice().GetBeamCount():
                raise SceneError(f"{where}: the clipping mesh {_object_label(cobj)} has beams; it must be a "
                                 f"triangle mesh", src)
            self.clip_mode = "inside" if int(cmode) == 1 else "outside"
            name = f"{where}, clipping mesh {_object_label(cobj)}"
            self.clips.append(self.mesh(_vertices(cobj, f"{name}: vertices", src),
                                        _triangles(cobj, f"{name}: triangles", src), t, name))


# ----------------------------------------------------------------------------- XML scan
def _scan_package(src: str) -> int:
    """Check every model part (required extensions, metadata, beams); return the number of beams.

    Streams the XML through expat in time linear in the part's size (see
    :func:`slicer.input_limits.feed_xml`), so a large lattice is never held
    as a tree; members past the input limits are refused first.
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
        check_members(zf, src)
        for name in models:
            try:
                total += _scan_part(zf, name, src)
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
                raise SceneError(f"/{name}: the package is corrupt ({exc})", src) from None
    return total


def _required(attrs: dict, nsmap: dict, part: str, src: str) -> None:
    """Refuse a model part that requires an extension skelslice does not support."""
    for prefix in (attrs.get("requiredextensions") or "").split():
        uri = nsmap.get(prefix)
        if uri is None:
            raise SceneError(f"{part}: required extension prefix {prefix!r} is not declared (no xmlns:{prefix})",
                             src)
        if uri in SUPPORTED_EXTENSIONS:
            continue
        what = UNSUPPORTED_EXTENSIONS.get(uri)
        raise SceneError(f"{part}: the file requires the 3MF {what + ' ' if what else ''}extension {uri} "
                         f"(prefix {prefix!r}), which skelslice does not support", src)


class _PartScan:
    """The checks of one model part, as expat start-element handlers (tags are ``"namespace local"``).

    Counts each object's vertices (for the beams' indices) and triangles: a
    solid object with 1 to 3 triangles is refused as soon as it ends, before
    lib3mf reads its vertices.
    """

    VERTEX, TRIANGLE = f"{CORE_NS} vertex", f"{CORE_NS} triangle"
    BEAM, OBJECT = f"{BEAM_NS} beam", f"{CORE_NS} object"

    def __init__(self, part: str, src: str, parser=None, condensed: "_Condenser | None" = None):
        self.part, self.src, self.parser, self.condensed = part, src, parser, condensed
        self.nsmap: dict[str, str] = {}
        self.label, self.solid, self.seen_vert, self.seen_tri, self.beam_no, self.total = "", False, 0, 0, 0, 0
        #: where the object's <vertices> and <triangles> start in the bytes expat is given
        self.runs: dict[bytes, list[int]] = {b"vertex": [], b"triangle": []}
        self.others = {f"{CORE_NS} model": self._model, f"{BEAM_NS} beamlattice": self._lattice,
                       f"{CORE_NS} metadata": self._metadata, f"{MATERIAL_NS} color": self._color,
                       f"{CORE_NS} vertices": self._run(b"vertex"), f"{CORE_NS} triangles": self._run(b"triangle")}

    def _run(self, item: bytes):
        def start(attrs: dict) -> None:
            if self.condensed is not None:
                self.runs[item].append(self.parser.CurrentByteIndex)
        return start

    def _hidden(self, item: bytes) -> int:
        """Items of the object's runs the condenser left out (each run has ended by the time it is asked)."""
        return 0 if self.condensed is None else sum(self.condensed.counts.get(at, 0) for at in self.runs[item])

    @property
    def n_vert(self) -> int:
        return self.seen_vert + self._hidden(b"vertex")

    @property
    def n_tri(self) -> int:
        return self.seen_tri + self._hidden(b"triangle")

    def namespace(self, prefix, uri) -> None:
        self.nsmap.setdefault(prefix or "", uri)

    def start(self, tag: str, attrs: dict) -> None:
        if tag == self.VERTEX:
            self.seen_vert += 1
        elif tag == self.TRIANGLE:
            self.seen_tri += 1
        elif tag == self.BEAM:
            self._beam(attrs)
        elif tag == self.OBJECT:
            self.end_object()
            name = attrs.get("name")
            self.label = f"object {attrs.get('id')}" + (f" {name!r}" if name else "")
            self.solid = attrs.get("type", "model") in ("model", "solidsupport")
            self.seen_vert, self.seen_tri, self.beam_no = 0, 0, 0
            self.runs = {b"vertex": [], b"triangle": []}
        else:
            check = self.others.get(tag)
            if check is not None:
                check(attrs)

    def end_object(self) -> None:
        """Refuse the object just read if it is a solid with too few triangles to close."""
        n_tri = self.n_tri
        if self.solid and 0 < n_tri < 4:
            raise SceneError(f"{self.part}, {self.label}: not a closed solid: {n_tri} triangles "
                             f"({self.n_vert:,} vertices); a closed surface needs at least 4", self.src)

    def _model(self, attrs: dict) -> None:
        _required(attrs, self.nsmap, self.part, self.src)

    def _lattice(self, attrs: dict) -> None:
        _radius(attrs.get("radius"), "radius", f"{self.part}, {self.label}, beamlattice", self.src, required=True)

    def _metadata(self, attrs: dict) -> None:
        if attrs.get("name") is None:
            raise SceneError(f"{self.part}: a <metadata> element has no name attribute (it is required)", self.src)

    def _color(self, attrs: dict) -> None:
        if attrs.get("color") is None:
            raise SceneError(f"{self.part}: a <m:color> element has no color attribute (it is required)", self.src)

    def _beam(self, attrs: dict) -> None:
        src = self.src
        where = f"{self.part}, {self.label}, beam {self.beam_no}"
        n_vert = self.n_vert
        v1 = _index(attrs.get("v1"), "v1", n_vert, where, src)
        v2 = _index(attrs.get("v2"), "v2", n_vert, where, src)
        if v1 == v2:
            raise SceneError(f"{where}: v1 = v2 = {v1}: a beam joins a vertex to itself", src)
        for attr in ("r1", "r2"):
            _radius(attrs.get(attr), attr, where, src, required=False)
        self.beam_no += 1
        self.total += 1


def _scan_part(zf: zipfile.ZipFile, name: str, src: str) -> int:
    """Scan one model part: first with its vertex and triangle runs condensed (:class:`_Condenser`),
    again on its own bytes when the condenser cannot vouch for a run."""
    try:
        return _scan_once(zf, name, src, _Condenser())
    except Restart:
        return _scan_once(zf, name, src, None)


def _scan_once(zf: zipfile.ZipFile, name: str, src: str, condenser) -> int:
    part = "/" + name
    parser = expat.ParserCreate(namespace_separator=" ")
    scan = _PartScan(part, src, parser, condenser)
    parser.StartNamespaceDeclHandler = scan.namespace
    parser.StartElementHandler = scan.start
    try:
        with zf.open(name) as fh:
            feed_xml(parser, fh, zf.getinfo(name), part, src, transform=condenser)
    except expat.ExpatError as exc:
        if condenser is not None:
            raise Restart() from None                   # the error is named on the part's own bytes
        raise SceneError(f"{part}: invalid XML ({exc})", src) from None
    scan.end_object()
    return scan.total


class _Condenser:
    """Leaves the items out of ``<vertices>`` and ``<triangles>`` runs before expat sees them, and counts them.

    A mesh part is mostly vertex and triangle elements, whose only use to the
    scan is their number; expat calling Python once for each of millions of
    them was most of the scan. The condenser finds the runs in the bytes
    (``bytes.find`` and ``bytes.count``, no Python per element), passes the
    runs' start and end tags on, and records how many items each held, by
    where its start tag is in the bytes expat is given (``counts``).

    It vouches only for what the bytes alone decide: with no comment, CDATA
    section or processing instruction in the part (after the XML
    declaration), ``<vertices>`` can only be a start tag ('<' is escaped in
    text and forbidden in attribute values), and a run may hold nothing but
    ``<vertex`` (``<triangle``) tags and their end tags. Anything else --
    a comment, another tag inside a run, an unfinished run at the end, an
    item longer than :data:`slicer.input_limits.MAX_TOKEN` -- raises
    :class:`slicer.input_limits.Restart`, and the part is scanned again on
    its own bytes.
    """

    RUNS = {b"<vertices>": (b"</vertices>", b"<vertex", b"</vertex>"),
            b"<triangles>": (b"</triangles>", b"<triangle", b"</triangle>")}
    KEEP = max(len(m) for m in RUNS) - 1

    def __init__(self):
        self.counts: dict[int, int] = {}
        self.carry = b""
        self.out = 0                      # bytes given to expat so far
        self.run = None                   # (end tag, item, item end, where its start tag was given) inside a run
        self.items = 0                    # items of the current run so far
        self.started = False

    def feed(self, data: bytes) -> bytes:
        buf = self.carry + data
        if not self.started:
            decl = 0
            if buf.startswith(b"<?xml") or b"<?xml".startswith(buf):
                decl = buf.find(b"?>") + 2
                if decl < 2:                                 # the declaration is not whole yet
                    if len(buf) > 4096:
                        raise Restart()
                    self.carry = buf
                    return b""
            self.started, self.carry = True, b""
            self._specials(buf[decl:])
            head, buf = buf[:decl], buf[decl:]
        else:
            self._specials(data)
            head = b""
        out = [head]
        while True:
            if self.run is None:
                hits = [(buf.find(m), m) for m in self.RUNS]
                at, mark = min(((i, m) for i, m in hits if i >= 0), default=(-1, None))
                if at < 0:
                    cut = max(0, len(buf) - self.KEEP)
                    out.append(buf[:cut])
                    self.carry = buf[cut:]
                    break
                end = at + len(mark)
                out.append(buf[:end])
                self.run = (*self.RUNS[mark], self.out + sum(map(len, out)) - len(mark))
                self.items, buf = 0, buf[end:]
            else:
                end_tag, item, item_end, where = self.run
                stop = buf.find(end_tag)
                body = buf[:stop] if stop >= 0 else buf[:max(0, buf.rfind(b"<"))]
                self._take(body, item, item_end)
                if stop < 0:
                    self.carry = buf[len(body):]
                    if len(self.carry) > MAX_TOKEN:
                        raise Restart()
                    break
                self.counts[where] = self.items
                self.run, buf = None, buf[stop:]
        given = b"".join(out)
        self.out += len(given)
        return given

    def finish(self) -> bytes:
        if self.run is not None:
            raise Restart()
        self.out += len(self.carry)
        return self.carry

    def _specials(self, data: bytes) -> None:
        """Restart at a comment, CDATA section, declaration or processing instruction (also split between
        pieces: the last byte before ``data`` is still in ``carry``)."""
        if b"<!" in data or b"<?" in data or (self.carry[-1:] + data[:1]) in (b"<!", b"<?"):
            raise Restart()

    def _take(self, body: bytes, item: bytes, item_end: bytes) -> None:
        """Count the items of a piece of a run; raise Restart if it holds anything else."""
        n = body.count(item) - (body.count(b"<triangles") if item == b"<triangle" else 0)
        if body.count(b"<") != n + body.count(item_end):
            raise Restart()
        self.items += n


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


__all__ = ["load_3mf", "read_3mf", "read_3mf_meshes", "ThreeMF", "UNIT_MM", "SUPPORTED_EXTENSIONS",
           "UNSUPPORTED_EXTENSIONS"]
