"""Parts: a lattice together with the triangle meshes it fills, or is trimmed by.

A :class:`Part` is a :class:`~slicer.model.skeleton.Skeleton` (or none) and meshes
with roles:

``solid``
    Printed as it is, united with everything else (a shell, a skin, a cage).
``clip-inside``
    The lattice is kept only inside it (lattice ∩ mesh).
``clip-outside``
    The lattice is kept only outside it (lattice − mesh).

The printed solid is ``((lattice ∩ CI) − CO) ∪ S`` where ``CI`` is the union
of the ``clip-inside`` meshes (everything when there are none), ``CO`` the
union of the ``clip-outside`` meshes and ``S`` the union of the solids.
Clipping acts on the lattice only, never on solids. Each union is filled by
the positive fill rule (:mod:`slicer.parts.mesh_slicing`), so overlapping meshes of
one role print as their union. A mesh's surface counts as inside it, as the
lattice's ``F = 1`` does: a clip-outside mesh removes the lattice on its
surface too.

Reading (:func:`load_part`): JSON scenes (with ``"meshes"``, format version
2, :mod:`slicer.scene.read`), 3MF builds (:func:`slicer.scene.threemf.read_3mf`),
STL/PLY meshes (a mesh-only part), OBJ polylines (a lattice); plus meshes
given separately (the command line's ``--solid``, ``--clip-inside``,
``--clip-outside``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slicer.errors import SceneError
from slicer.parts.meshes import Mesh, read_mesh_file
from slicer.scene.threemf import read_3mf, read_3mf_meshes
from slicer.scene.read import load_scene, read_json_scene
from slicer.model.skeleton import Skeleton

#: mesh roles
ROLES = ("solid", "clip-inside", "clip-outside")
#: scene suffixes that are meshes (a mesh-only part)
MESH_SCENE_SUFFIXES = (".stl", ".ply")


@dataclass(frozen=True)
class PartMesh:
    """A mesh with its role in a part."""

    mesh: Mesh
    role: str

    def __post_init__(self):
        if self.role not in ROLES:
            raise SceneError(f"{self.mesh.name}: unknown mesh role {self.role!r}; use one of {', '.join(ROLES)}")


@dataclass(frozen=True, eq=False)
class Part:
    """A lattice and meshes with roles (see the module docstring).

    Attributes
    ----------
    skeleton : Skeleton or None
    meshes : tuple of PartMesh
    source : str or None
        The file the part came from.
    notes : tuple of str
        What reading left out or repaired, for the user to see.

    Raises
    ------
    SceneError
        Nothing to print, or clipping meshes without a lattice.
    """

    skeleton: Skeleton | None
    meshes: tuple[PartMesh, ...] = ()
    source: str | None = None
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self):
        object.__setattr__(self, "meshes", tuple(self.meshes))
        if self.skeleton is None and not self.solids():
            if self.meshes:
                raise SceneError("the part has clipping meshes but no lattice to clip (and no solid mesh)",
                                 self.source)
            raise SceneError("nothing to print: the part has neither a lattice nor a mesh", self.source)
        if self.skeleton is None and (self.clips("clip-inside") or self.clips("clip-outside")):
            raise SceneError("the part has clipping meshes but no lattice to clip", self.source)

    # ------------------------------------------------------------------ roles
    def of_role(self, role: str) -> list[Mesh]:
        """The meshes with ``role``."""
        return [pm.mesh for pm in self.meshes if pm.role == role]

    def solids(self) -> list[Mesh]:
        return self.of_role("solid")

    def clips(self, role: str) -> list[Mesh]:
        return self.of_role(role)

    @property
    def has_meshes(self) -> bool:
        return bool(self.meshes)

    @property
    def has_clips(self) -> bool:
        return any(pm.role != "solid" for pm in self.meshes)

    def with_meshes(self, extra) -> "Part":
        """This part with more :class:`PartMesh` objects."""
        return Part(self.skeleton, (*self.meshes, *extra), self.source, self.notes)

    # ------------------------------------------------------------------ geometry
    def support_bounds(self) -> np.ndarray:
        """A box containing everything the part can print, (2, 3) float64 mm.

        The lattice's support box joined with the solids' bounds (clipping
        meshes only remove lattice).
        """
        boxes = [m.bounds() for m in self.solids()]
        if self.skeleton is not None:
            boxes.append(self.skeleton.support_bounds())
        b = np.stack(boxes)
        return np.array([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])

    def print_bounds(self) -> np.ndarray:
        """A box containing what the part prints, (2, 3) float64 mm: the lattice's support
        box (cut to the clip-inside meshes' bounds, if any) joined with the solids'."""
        boxes = [m.bounds() for m in self.solids()]
        if self.skeleton is not None:
            lat = self.skeleton.support_bounds()
            ci = [m.bounds() for m in self.clips("clip-inside")]
            if ci:
                c = np.stack(ci)
                lat = np.array([np.maximum(lat[0], c[:, 0].min(axis=0)), np.minimum(lat[1], c[:, 1].max(axis=0))])
            if np.all(lat[1] >= lat[0]):
                boxes.append(lat)
        b = np.stack(boxes) if boxes else self.support_bounds()[None]
        return np.array([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])

    def describe(self) -> str:
        """One line: what the part holds."""
        out = []
        if self.skeleton is not None:
            out.append(f"lattice of {self.skeleton.n_segments:,} segments")
        for role in ROLES:
            ms = self.of_role(role)
            if ms:
                out.append(f"{len(ms)} {role} mesh{'es' if len(ms) > 1 else ''} "
                           f"({sum(m.n_faces for m in ms):,} faces)")
        return ", ".join(out)


def as_part(scene) -> Part:
    """A :class:`Part` from a Part or a Skeleton (a lattice alone)."""
    if isinstance(scene, Part):
        return scene
    if isinstance(scene, Skeleton):
        return Part(scene, (), scene.source)
    raise TypeError(f"expected a Part or a Skeleton, got {type(scene).__name__}")


def read_meshes(path, scale: float = 1.0, repair: bool = False) -> list[Mesh]:
    """The meshes of a mesh file: STL/OBJ/PLY (one mesh, ``scale`` mm per unit) or
    3MF (every mesh object of its build, in its own unit)."""
    src = os.fsdecode(os.fspath(path))
    if Path(src).suffix.lower() == ".3mf":
        return read_3mf_meshes(src, repair=repair)
    return [read_mesh_file(src, scale=scale, repair=repair)]


def load_part(path, radius: float | None = None, meshes=(), repair: bool = False) -> Part:
    """Read a scene as a part.

    Parameters
    ----------
    path : str or os.PathLike
        ``.json`` (a scene, version 1 or 2 with ``"meshes"``), ``.3mf`` (a
        build: lattices, mesh objects, clipping), ``.stl`` / ``.ply`` (a
        mesh-only part) or ``.obj`` (polylines: a lattice).
    radius : float, optional
        Default radius for segment ends the file gives none for (see
        :func:`slicer.scene.read.load_scene`).
    meshes : iterable of (role, path)
        More meshes, in mm (STL/OBJ/PLY) or in their 3MF unit.
    repair : bool
        Repair meshes that only need re-orienting or dropping faces with a
        repeated corner; what changed is listed in ``Part.notes``.

    Returns
    -------
    Part

    Raises
    ------
    SceneError
        Naming the file and the problem.
    """
    src = os.fsdecode(os.fspath(path))
    suffix = Path(src).suffix.lower()
    notes: list[str] = []
    pms: list[PartMesh] = []
    if suffix == ".3mf":
        got = read_3mf(src, repair=repair)
        skel = got.lattice
        pms += [PartMesh(m, "solid") for m in got.solids]
        if got.clip_mode is not None:
            pms += [PartMesh(m, f"clip-{got.clip_mode}") for m in got.clips]
        notes += got.notes
    elif suffix in MESH_SCENE_SUFFIXES:
        skel = None
        pms.append(PartMesh(read_mesh_file(src, repair=repair), "solid"))
    elif suffix == ".json":
        skel, entries = read_json_scene(src, radius)
        for e in entries:
            for m in read_meshes(e.path, e.scale, repair):
                pms.append(PartMesh(m.transformed(e.transform) if e.transform is not None else m, e.role))
    else:
        skel = load_scene(src, radius=radius)
    for role, mpath in meshes:
        for m in read_meshes(mpath, 1.0, repair):
            pms.append(PartMesh(m, role))
    for pm in pms:
        notes += pm.mesh.notes
    return Part(skel, tuple(pms), src, tuple(notes))


__all__ = ["Part", "PartMesh", "ROLES", "as_part", "load_part", "read_meshes", "MESH_SCENE_SUFFIXES"]
