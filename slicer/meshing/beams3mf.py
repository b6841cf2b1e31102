"""3MF output: the skeleton as a Beam Lattice, with a part's meshes.

The package is what :mod:`slicer.scene.threemf` reads (and lib3mf, and the
design tools that exchange lattices)::

    [Content_Types].xml
    _rels/.rels                          -> /3D/3dmodel.model
    3D/3dmodel.model
        <model unit="millimeter" requiredextensions="b">
          <resources>
            <object id="1" type="model">      the clipping mesh, if any
            <object id="2" type="model">      the lattice: <vertices> are the nodes,
              <mesh> ... <b:beamlattice radius minlength cap="sphere"
                           [clippingmode="inside|outside" clippingmesh="1"]>
                <b:beams><b:beam v1 v2 r1 r2/> ...</b:beams>
            <object id="3..." type="model">   each solid mesh
          </resources>
          <build> the lattice and each solid, untransformed </build>
        </model>

* Coordinates and radii are mm, written with :func:`repr` (the shortest
  text that reads back to the same float64). Readers going through lib3mf
  (ours among them) keep node positions, radii and mesh vertices as float32.
* Every segment is one beam, in segment order, with its two end radii
  (``r1`` at ``v1``): tapers are kept. Nodes used by no segment are left out
  (a beam lattice has no isolated nodes); the rest keep their order.
* ``minlength`` is half the shortest segment (capped at 1e-4 mm), so no beam
  is ignored by a reader; ``radius`` (the default beam radius) is the first
  beam's ``r1``, although every beam gives both radii.
* A 3MF lattice has one clipping mesh and one mode: a part with both
  clip-inside and clip-outside meshes is refused; several clip meshes of one
  role are written as one mesh object with several shells (3MF fills
  overlapping shells by the positive rule, i.e. their union, as
  :mod:`slicer.parts.part` does).
* The kernel is not stored (3MF has none): a scene with a kernel other than
  the default (degree 6, sigma 2) is refused, since it would read back as a
  different surface.
* Entries are deflated with fixed timestamps: the same scene gives a
  byte-identical file.
"""
from __future__ import annotations

import io
import zipfile

import numpy as np

from formats.threemf_slices import CONTENT_TYPES, CORE_NS, MODEL_PATH, RELS

from slicer.atomic import write_bytes
from slicer.errors import OutputError
from slicer.model.siis_kernel import DEFAULT_DEGREE, DEFAULT_SIGMA
from slicer.parts.part import Part, as_part
from slicer.scene.threemf import BEAM_NS

_DATE = (1980, 1, 1, 0, 0, 0)
#: largest ``minlength`` written, mm
MAX_MINLENGTH = 1e-4


def _n(x: float) -> str:
    return repr(float(x))


def _vertices(v: np.ndarray, indent: str) -> str:
    return "".join(f'{indent}<vertex x="{_n(p[0])}" y="{_n(p[1])}" z="{_n(p[2])}"/>\n' for p in v.tolist())


def _triangles(f: np.ndarray, indent: str) -> str:
    return "".join(f'{indent}<triangle v1="{a}" v2="{b}" v3="{c}"/>\n' for a, b, c in f.tolist())


def mesh_object(oid: int, vertices: np.ndarray, faces: np.ndarray, name: str) -> str:
    return (f'  <object id="{oid}" type="model" name="{_escape(name)}">\n   <mesh>\n    <vertices>\n'
            + _vertices(vertices, "     ") + "    </vertices>\n    <triangles>\n"
            + _triangles(faces, "     ") + "    </triangles>\n   </mesh>\n  </object>\n")


def _escape(text: str) -> str:
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;"))


def _joined(meshes) -> tuple[np.ndarray, np.ndarray]:
    """Several meshes as one vertex and face list (shells side by side)."""
    vs, fs, off = [], [], 0
    for m in meshes:
        vs.append(m.vertices)
        fs.append(m.faces + off)
        off += len(m.vertices)
    return np.concatenate(vs), np.concatenate(fs)


def _lattice_object(oid: int, skel, clip: tuple[str, int] | None) -> str:
    used, inverse = np.unique(skel.segments, return_inverse=True)
    segs = inverse.reshape(skel.segments.shape)
    length = np.linalg.norm(skel.nodes[skel.segments[:, 1]] - skel.nodes[skel.segments[:, 0]], axis=1)
    minlength = min(MAX_MINLENGTH, 0.5 * float(length.min()))
    attrs = f'radius="{_n(skel.radii[0, 0])}" minlength="{_n(minlength)}" cap="sphere"'
    if clip is not None:
        attrs += f' clippingmode="{clip[0]}" clippingmesh="{clip[1]}"'
    beams = "".join(f'       <b:beam v1="{a}" v2="{b}" r1="{_n(r1)}" r2="{_n(r2)}"/>\n'
                    for (a, b), (r1, r2) in zip(segs.tolist(), skel.radii.tolist()))
    return (f'  <object id="{oid}" type="model" name="lattice">\n   <mesh>\n    <vertices>\n'
            + _vertices(skel.nodes[used], "     ") + "    </vertices>\n    <triangles></triangles>\n"
            + f"    <b:beamlattice {attrs}>\n     <b:beams>\n" + beams
            + "     </b:beams>\n    </b:beamlattice>\n   </mesh>\n  </object>\n")


def beam_lattice_model(scene) -> str:
    """The 3D model part (XML text) of a scene as a 3MF beam lattice.

    Parameters
    ----------
    scene : Skeleton or Part
        A lattice, with solid and clipping meshes for a part.

    Returns
    -------
    str

    Raises
    ------
    OutputError
        No lattice, a non-default kernel, or both clip-inside and
        clip-outside meshes (see the module docstring).
    """
    part: Part = as_part(scene)
    skel = part.skeleton
    if skel is None or skel.n_segments == 0:
        raise OutputError("a beam lattice needs a lattice: the scene has no segments")
    if skel.degree != DEFAULT_DEGREE or skel.sigma != DEFAULT_SIGMA:
        raise OutputError(f"3MF cannot store the kernel (degree {skel.degree}, sigma {skel.sigma}); "
                          f"write a .json scene, or use the default kernel (degree {DEFAULT_DEGREE}, "
                          f"sigma {DEFAULT_SIGMA})")
    inside, outside = part.clips("clip-inside"), part.clips("clip-outside")
    if inside and outside:
        raise OutputError(f"a 3MF beam lattice has one clipping mode: the part has {len(inside)} clip-inside and "
                          f"{len(outside)} clip-outside meshes")
    objects, clip, oid = [], None, 1
    if inside or outside:
        v, f = _joined(inside or outside)
        objects.append(mesh_object(oid, v, f, "clipping mesh"))
        clip = ("inside" if inside else "outside", oid)
        oid += 1
    lattice_id = oid
    objects.append(_lattice_object(oid, skel, clip))
    items = [lattice_id]
    for m in part.solids():
        oid += 1
        objects.append(mesh_object(oid, m.vertices, m.faces, m.name))
        items.append(oid)
    build = "".join(f'  <item objectid="{i}"/>\n' for i in items)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<model xmlns="{CORE_NS}" xmlns:b="{BEAM_NS}" unit="millimeter" xml:lang="en-US" '
            f'requiredextensions="b">\n <metadata name="Application">skelslice</metadata>\n <resources>\n'
            + "".join(objects) + " </resources>\n <build>\n" + build + " </build>\n</model>\n")


def package(model: str) -> bytes:
    """A 3MF package (zip) holding ``model`` as its 3D model part, deflated, fixed timestamps."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for name, text in (("[Content_Types].xml", CONTENT_TYPES), ("_rels/.rels", RELS), (MODEL_PATH, model)):
            info = zipfile.ZipInfo(name, date_time=_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, text.encode("utf-8"))
    return buf.getvalue()


def write_beam_lattice(scene, path, force: bool = False) -> dict:
    """Write a scene as a 3MF beam lattice, atomically.

    Parameters
    ----------
    scene : Skeleton or Part
    path : str or os.PathLike
        The ``.3mf`` file.
    force : bool
        Replace an existing file.

    Returns
    -------
    dict
        ``nodes``, ``beams``, ``clipping`` (mode or None), ``solids`` and ``bytes``.

    Raises
    ------
    OutputError
        As :func:`beam_lattice_model`, or the file cannot be written.

    Examples
    --------
    >>> import os, tempfile
    >>> from slicer import Skeleton
    >>> from slicer.scene.threemf import load_3mf
    >>> s = Skeleton([[0, 0, 0], [0, 0, 4]], [[0, 1]], [[1.0, 0.5]])
    >>> path = os.path.join(tempfile.mkdtemp(), "strut.3mf")
    >>> write_beam_lattice(s, path)["beams"]
    1
    >>> load_3mf(path).radii.tolist()      # exact here: 1 and 0.5 are float32 numbers
    [[1.0, 0.5]]
    """
    part = as_part(scene)
    data = package(beam_lattice_model(part))
    write_bytes(path, data, force=force)
    inside, outside = part.clips("clip-inside"), part.clips("clip-outside")
    return {"nodes": int(np.unique(part.skeleton.segments).size), "beams": part.skeleton.n_segments,
            "clipping": "inside" if inside else ("outside" if outside else None),
            "solids": len(part.solids()), "bytes": len(data)}


__all__ = ["beam_lattice_model", "mesh_object", "package", "write_beam_lattice"]
