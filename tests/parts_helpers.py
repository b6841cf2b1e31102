"""Independent references and builders for the parts tests.

* :func:`winding_number`: the generalized winding number of a triangle mesh at
  points (sum of the faces' signed solid angles, van Oosterom & Strackee) -- a
  point-in-mesh test by another method than the slicer's (plane cuts and
  row crossings), used to check every voxel centre.
* :func:`write_3mf`: 3MF files written with lib3mf (beam lattices, clipping
  meshes, mesh objects, components, units).
"""
from __future__ import annotations

import numpy as np
import trimesh

from slicer.parts.meshes import make_mesh


def winding_number(tri: np.ndarray, points: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Generalized winding number of the faces ``tri`` ((m, 3, 3)) at ``points`` ((n, 3))."""
    out = np.zeros(points.shape[0])
    for s in range(0, points.shape[0], chunk):
        p = points[s:s + chunk, None, :]
        a, b, c = tri[None, :, 0] - p, tri[None, :, 1] - p, tri[None, :, 2] - p
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        num = np.einsum("ijk,ijk->ij", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ijk,ijk->ij", a, b) * lc + np.einsum("ijk,ijk->ij", b, c) * la
               + np.einsum("ijk,ijk->ij", c, a) * lb)
        out[s:s + chunk] = (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)
    return out


def centres(grid) -> np.ndarray:
    """Every voxel centre of a grid, (layers * height * width, 3), in layer, row, column order."""
    z, y, x = np.meshgrid(grid.centres_z(), grid.centres_y(), grid.centres_x(), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def inside_mesh(meshes, points: np.ndarray, margin: float = 1e-3):
    """(inside, sure): the winding number rounds to 1 or more, and whether it is within
    ``margin`` of a whole number (off the surface it is one; on or very near the surface
    it is a fraction, and this test does not decide the point)."""
    w = sum(winding_number(m.triangles(), points) for m in meshes) if meshes else np.zeros(len(points))
    r = np.rint(w)
    return r >= 1, np.abs(w - r) < margin


def tmesh(tm: trimesh.Trimesh, name: str = "mesh"):
    """A checked slicer mesh from a trimesh mesh."""
    return make_mesh(tm.vertices, tm.faces, name)


def rotated(tm: trimesh.Trimesh, seed: int, shift=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """``tm`` turned by a random rotation and moved (generic positions)."""
    rng = np.random.default_rng(seed)
    out = tm.copy()
    out.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
    out.apply_translation(np.asarray(shift) + 0.01 * rng.random(3))
    return out


# ----------------------------------------------------------------------------- 3MF with lib3mf
def _pos(lib3mf, p):
    v = lib3mf.Position()
    for i in range(3):
        v.Coordinates[i] = float(p[i])
    return v


def _transform(lib3mf, m):
    """A (4, 3) row-vector matrix as a lib3mf Transform."""
    t = lib3mf.Transform()
    for r in range(4):
        for c in range(3):
            t.Fields[r][c] = float(m[r][c])
    return t


def add_mesh(lib3mf, model, vertices, faces, name: str):
    obj = model.AddMeshObject()
    obj.SetName(name)
    for p in vertices:
        obj.AddVertex(_pos(lib3mf, p))
    for f in faces:
        t = lib3mf.Triangle()
        t.Indices[0], t.Indices[1], t.Indices[2] = (int(x) for x in f)
        obj.AddTriangle(t)
    return obj


def add_lattice(lib3mf, model, nodes, beams, radius: float, name: str = "lattice", triangles=None,
                clip=None, clip_mode: str = "inside", caps=None, ball: bool = False):
    """A mesh object with a beam lattice (``beams``: (a, b, ra, rb)); ``triangles``:
    (vertices, faces) of the object's own mesh; ``clip``: a mesh object clipping it."""
    obj = model.AddMeshObject()
    obj.SetName(name)
    base = 0
    if triangles is not None:
        for p in triangles[0]:
            obj.AddVertex(_pos(lib3mf, p))
        for f in triangles[1]:
            t = lib3mf.Triangle()
            t.Indices[0], t.Indices[1], t.Indices[2] = (int(x) for x in f)
            obj.AddTriangle(t)
        base = len(triangles[0])
    for p in nodes:
        obj.AddVertex(_pos(lib3mf, p))
    lat = obj.BeamLattice()
    lat.SetMinLength(1e-4)
    for q, (a, b, ra, rb) in enumerate(beams):
        beam = lib3mf.Beam()
        beam.Indices[0], beam.Indices[1] = base + a, base + b
        beam.Radii[0], beam.Radii[1] = ra, rb
        if caps is not None:
            beam.CapModes[0], beam.CapModes[1] = caps[q]
        lat.AddBeam(beam)
    if clip is not None:
        mode = {"inside": lib3mf.BeamLatticeClipMode.Inside, "outside": lib3mf.BeamLatticeClipMode.Outside}[clip_mode]
        lat.SetClipping(mode, clip.GetResourceID())
    if ball:
        lat.SetBallOptions(lib3mf.BeamLatticeBallMode.All, radius)
    return obj


def write_3mf(path, build, unit=None):
    """Write a 3MF with lib3mf. ``build(lib3mf, model)`` adds objects and returns a list
    of ``(object, (4, 3) transform or None)`` build items."""
    import lib3mf

    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    if unit is not None:
        model.SetUnit(unit)
    for obj, m in build(lib3mf, model):
        model.AddBuildItem(obj, _transform(lib3mf, m) if m is not None else wrapper.GetIdentityTransform())
    model.QueryWriter("3mf").WriteToFile(str(path))
    return path


def box_mesh(extents, centre=(0.0, 0.0, 0.0)):
    """(vertices, faces) of an outward box."""
    b = trimesh.creation.box(extents=extents)
    b.apply_translation(centre)
    return np.asarray(b.vertices), np.asarray(b.faces)
