"""Meshes out of a scene: the integral surface as a certified triangle mesh
(:func:`mesh_scene`, :mod:`slicer.meshing.surface`), with a part's solid and
clipping meshes (:func:`mesh_part`, :mod:`slicer.meshing.composite`), and the
skeleton as a 3MF beam lattice (:func:`write_beam_lattice`,
:mod:`slicer.meshing.beams3mf`)."""
from __future__ import annotations

from slicer.meshing.beams3mf import write_beam_lattice
from slicer.meshing.composite import mesh_part
from slicer.meshing.output import write_mesh
from slicer.meshing.surface import DEFAULT_TOL, SurfaceMesh, mesh_scene

__all__ = ["mesh_scene", "mesh_part", "SurfaceMesh", "DEFAULT_TOL", "write_mesh", "write_beam_lattice"]
