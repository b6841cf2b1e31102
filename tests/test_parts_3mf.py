"""3MF parts built with lib3mf: lattices with clipping meshes, mesh objects, components,
units and transforms, checked voxel by voxel; files a consumer must refuse, refused by name."""
from __future__ import annotations

import zipfile

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from parts_helpers import add_lattice, add_mesh, box_mesh, centres, inside_mesh, write_3mf
from slicer.cli.app import main
from slicer.errors import SceneError
from slicer.model.field import evaluate
from slicer.parts.slicing import slice_part
from slicer.parts.part import load_part
from slicer.scene.threemf import load_3mf

lib3mf = pytest.importorskip("lib3mf")

NODES = [(-3, 0, 0), (3, 0, 0), (0, -3, 0), (0, 3, 0), (0, 0, -3), (0, 0, 3)]
BEAMS = [(0, 1, 0.5, 0.5), (2, 3, 0.5, 0.5), (4, 5, 0.5, 0.4)]
SPHERE = trimesh.creation.icosphere(2, radius=2.0)


def lattice_with_clip(mode, transform=None, unit=None):
    def build(lib, model):
        clip = add_mesh(lib, model, SPHERE.vertices, SPHERE.faces, "ball")
        lat = add_lattice(lib, model, NODES, BEAMS, 0.5, clip=clip, clip_mode=mode)
        return [(lat, transform)]
    return build


def check_voxels(part, res, lattice_ok, margin=1e-3):
    p = centres(res.grid)
    f = evaluate(part.skeleton, p)[0]
    clip = part.of_role("clip-inside") or part.of_role("clip-outside")
    ins, sure = inside_mesh(clip, p, margin)
    sure &= np.abs(f - 1.0) > 1e-6
    want = (f >= 1.0) & (ins if part.of_role("clip-inside") else ~ins)
    got = res.volume().reshape(-1)
    assert want.sum() > 100 and sure.mean() > 0.97
    assert np.array_equal(got[sure], want[sure])


@pytest.mark.parametrize("mode", ["inside", "outside"])
def test_clipped_lattice_every_voxel(tmp_path, mode):
    path = write_3mf(tmp_path / f"{mode}.3mf", lattice_with_clip(mode))
    part = load_part(path)
    assert len(part.of_role(f"clip-{mode}")) == 1 and part.skeleton.n_segments == 3
    res = slice_part(part, 0.15)
    check_voxels(part, res, mode)


def test_clip_mesh_follows_the_lattice_transform_and_units(tmp_path):
    """A build item turned, mirrored, scaled 2x and moved, in inches: lattice and its
    clipping mesh move together (the extension says so)."""
    c, s = 0.6, 0.8
    m = np.array([[c, s, 0], [-s, c, 0], [0, 0, -1.0]]) * 2.0            # rotation, mirror z, scale 2
    t = np.vstack([m, [1.0, -2.0, 3.0]])
    path = write_3mf(tmp_path / "t.3mf", lattice_with_clip("inside", t), unit=lib3mf.ModelUnit.Inch)
    part = load_part(path)
    (clip,) = part.of_role("clip-inside")
    t32 = t.astype(np.float32).astype(np.float64)
    want = (np.asarray(SPHERE.vertices, np.float32).astype(np.float64) @ t32[:3] + t32[3]) * 25.4
    assert np.allclose(np.sort(clip.vertices, axis=0), np.sort(want, axis=0), rtol=1e-6, atol=1e-3)  # float32 text
    assert clip.volume() > 0                                        # the mirror kept the faces outward
    assert np.allclose(part.skeleton.radii.max(), 0.5 * 2 * 25.4)
    res = slice_part(part, 4.0)
    check_voxels(part, res, "inside")


def test_mesh_objects_and_triangles_of_a_lattice_object(tmp_path):
    """A solid cage object and a lattice object that carries triangles of its own: both print."""
    cage_v, cage_f = box_mesh((8, 8, 2), (0, 0, -4))
    own_v, own_f = box_mesh((1, 1, 1), (0, 0, 4))

    def build(lib, model):
        cage = add_mesh(lib, model, cage_v, cage_f, "cage")
        lat = add_lattice(lib, model, NODES, BEAMS, 0.5, triangles=(own_v, own_f))
        return [(cage, None), (lat, None)]
    path = write_3mf(tmp_path / "m.3mf", build)
    part = load_part(path)
    assert len(part.solids()) == 2 and part.skeleton.n_segments == 3
    res = slice_part(part, 0.2)
    p = centres(res.grid)
    f = evaluate(part.skeleton, p)[0]
    ins, sure = inside_mesh(part.solids(), p)
    sure &= np.abs(f - 1) > 1e-6
    want = (f >= 1) | ins
    assert np.array_equal(res.volume().reshape(-1)[sure], want[sure])
    with pytest.raises(SceneError, match=r"object \d+ 'cage' is a triangle mesh \(12 triangles\).*load_part"):
        load_3mf(path)


def test_components_place_meshes(tmp_path):
    v, f = box_mesh((1, 1, 1))

    def build(lib, model):
        box = add_mesh(lib, model, v, f, "box")
        comp = model.AddComponentsObject()
        for dx in (0.0, 3.0):
            tr = lib.Transform()
            for r in range(4):
                for c in range(3):
                    tr.Fields[r][c] = float(np.vstack([np.eye(3), [dx, 0, 0]])[r][c])
            comp.AddComponent(box, tr)
        return [(comp, np.vstack([np.eye(3), [0, 0, 10.0]]))]
    part = load_part(write_3mf(tmp_path / "c.3mf", build))
    assert part.skeleton is None and len(part.solids()) == 2
    b = np.stack([m.bounds() for m in part.solids()])
    assert np.allclose(sorted(b[:, 0, 0]), [-0.5, 2.5]) and np.allclose(b[:, 0, 2], 9.5)


def test_mesh_only_3mf_slices(tmp_path):
    v, f = box_mesh((2, 2, 2), (0, 0, 1))
    path = write_3mf(tmp_path / "box.3mf", lambda lib, model: [(add_mesh(lib, model, v, f, "box"), None)])
    r = CliRunner().invoke(main, ["slice", str(path), "-o", str(tmp_path / "s"), "--pixel-size", "0.5", "-q"])
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "s").glob("*.png"))) == 6            # 2 mm in 0.5 mm layers, plus margins


def test_short_beams_are_ignored(tmp_path):
    def build(lib, model):
        lat = add_lattice(lib, model, NODES + [(0, 0, 3.00001)], BEAMS + [(5, 6, 0.5, 0.5)], 0.5)
        lat.BeamLattice().SetMinLength(1e-3)
        return [(lat, None)]
    part = load_part(write_3mf(tmp_path / "s.3mf", build))
    assert part.skeleton.n_segments == 3 and any("shorter than the lattice's minlength" in n for n in part.notes)


def test_representation_mesh_is_ignored(tmp_path):
    def build(lib, model):
        rep = add_mesh(lib, model, SPHERE.vertices, SPHERE.faces, "preview")
        lat = add_lattice(lib, model, NODES, BEAMS, 0.5)
        lat.BeamLattice().SetRepresentation(rep.GetResourceID())
        return [(lat, None)]
    part = load_part(write_3mf(tmp_path / "r.3mf", build))
    assert part.meshes == () and part.skeleton.n_segments == 3


def test_support_objects_left_out_with_a_note(tmp_path):
    v, f = box_mesh((1, 1, 1))

    def build(lib, model):
        sup = add_mesh(lib, model, v, f, "support")
        sup.SetType(lib.ObjectType.Support)
        return [(sup, None), (add_lattice(lib, model, NODES, BEAMS, 0.5), None)]
    part = load_part(write_3mf(tmp_path / "s.3mf", build))
    assert part.meshes == () and any("support structure" in n for n in part.notes)
    r = CliRunner().invoke(main, ["info", str(tmp_path / "s.3mf")])
    assert r.exit_code == 0 and "support structure" in r.output


# ----------------------------------------------------------------------------- refusals
def refused(path, *needles):
    r = CliRunner().invoke(main, ["slice", str(path), "-o", str(path.with_suffix(".out")), "--pixel-size", "0.2"])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and r.output.startswith(f"error: {path}")
    for n in needles:
        assert n in r.output, r.output


def test_balls_refused(tmp_path):
    def build(lib, model):
        return [(add_lattice(lib, model, NODES, BEAMS, 0.5, ball=True), None)]
    refused(write_3mf(tmp_path / "b.3mf", build), "the lattice has balls", "does not print balls")


def test_butt_cap_at_a_free_end_refused(tmp_path):
    caps = [(lib3mf.BeamLatticeCapMode.Sphere, lib3mf.BeamLatticeCapMode.Butt), (0, 0), (0, 0)]

    def build(lib, model):
        return [(add_lattice(lib, model, NODES, BEAMS, 0.5, caps=caps), None)]
    refused(write_3mf(tmp_path / "c.3mf", build), "beam 0 has a 'butt' cap at its free end (vertex 1)")


def test_cap_at_a_joint_is_accepted(tmp_path):
    nodes = [(0, 0, 0), (3, 0, 0), (0, 3, 0)]
    beams = [(0, 1, 0.5, 0.5), (0, 2, 0.5, 0.5)]
    caps = [(lib3mf.BeamLatticeCapMode.Butt, 0), (lib3mf.BeamLatticeCapMode.HemiSphere, 0)]
    part = load_part(write_3mf(tmp_path / "j.3mf",
                               lambda lib, model: [(add_lattice(lib, model, nodes, beams, 0.5, caps=caps), None)]))
    assert part.skeleton.n_segments == 2


def test_surface_object_refused(tmp_path):
    v, f = box_mesh((1, 1, 1))

    def build(lib, model):
        s = add_mesh(lib, model, v, f, "skin")
        s.SetType(lib.ObjectType.Surface)
        return [(s, None)]
    refused(write_3mf(tmp_path / "s.3mf", build), "'skin' is an open surface")


def test_open_mesh_object_refused_with_counts(tmp_path):
    v, f = box_mesh((1, 1, 1))
    path = write_3mf(tmp_path / "o.3mf", lambda lib, model: [(add_mesh(lib, model, v, f[1:], "hull"), None)])
    refused(path, "object 1 'hull': not a closed solid (11 faces): 3 open edges")


def test_self_intersecting_object_accepted_by_positive_fill(tmp_path):
    """The 3MF core specification: consumers must accept self-intersections (positive fill)."""
    a = trimesh.creation.box(extents=(2, 2, 2))
    b = a.copy()
    b.apply_translation((1, 1, 1))
    u = trimesh.util.concatenate([a, b])
    part = load_part(write_3mf(tmp_path / "x.3mf", lambda lib, model: [(add_mesh(lib, model, u.vertices, u.faces,
                                                                                 "two"), None)]))
    res = slice_part(part, 0.25)
    p = centres(res.grid)
    want = np.all(np.abs(p) <= 1, axis=1) | np.all(np.abs(p - 1) <= 1, axis=1)
    assert np.array_equal(res.volume().reshape(-1), want)


def test_two_clipped_instances_refused(tmp_path):
    def build(lib, model):
        clip = add_mesh(lib, model, SPHERE.vertices, SPHERE.faces, "ball")
        lat = add_lattice(lib, model, NODES, BEAMS, 0.5, clip=clip)
        return [(lat, None), (lat, np.vstack([np.eye(3), [10, 0, 0]]))]
    refused(write_3mf(tmp_path / "two.3mf", build), "2 clipped beam-lattice instances")


MODEL = """<?xml version="1.0" encoding="UTF-8"?>
<model unit="millimeter" xml:lang="en-US" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02" {ns}>
 {meta}<resources><object id="1" type="model"><mesh><vertices>
  <vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" y="1" z="0"/><vertex x="0" y="0" z="1"/>
 </vertices><triangles><triangle v1="0" v2="2" v3="1"/><triangle v1="0" v2="1" v3="3"/>
 <triangle v1="0" v2="3" v3="2"/><triangle v1="1" v2="2" v3="3"/></triangles></mesh></object></resources>
 <build><item objectid="1"/></build>
</model>"""
TYPES = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>"""
RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
<Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>"""


def hand(path, ns="", meta=""):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", TYPES)
        z.writestr("_rels/.rels", RELS)
        z.writestr("3D/3dmodel.model", MODEL.format(ns=ns, meta=meta))
    return path


def test_hand_written_tetrahedron_reads(tmp_path):
    part = load_part(hand(tmp_path / "t.3mf"))
    assert part.solids()[0].volume() == pytest.approx(1 / 6)


@pytest.mark.parametrize("ns, needles", [
    ('xmlns:s="http://schemas.microsoft.com/3dmanufacturing/slice/2015/07" requiredextensions="s"',
     ("requires the 3MF slices extension", "prefix 's'")),
    ('xmlns:v="http://example.com/vendor/2024" requiredextensions="v"',
     ("requires the 3MF extension http://example.com/vendor/2024", "does not support")),
    ('requiredextensions="q"', ("required extension prefix 'q' is not declared",)),
])
def test_required_extensions_refused_by_name(tmp_path, ns, needles):
    refused(hand(tmp_path / "r.3mf", ns=ns), *needles)


def test_supported_required_extensions_accepted(tmp_path):
    ns = ('xmlns:m="http://schemas.microsoft.com/3dmanufacturing/material/2015/02" '
          'xmlns:p="http://schemas.microsoft.com/3dmanufacturing/production/2015/06" requiredextensions="m p"')
    assert load_part(hand(tmp_path / "ok.3mf", ns=ns)).solids()


@pytest.mark.parametrize("meta, needles", [
    ('<metadata name="Title">a</metadata><metadata name="Title">b</metadata>',
     ("breaks the specification", "Duplicate Model Metadata")),
    ("<metadata>no name</metadata>", ("<metadata> element has no name attribute",)),
])
def test_files_a_consumer_must_reject(tmp_path, meta, needles):
    refused(hand(tmp_path / "bad.3mf", meta=meta), *needles)


def test_unknown_metadata_name_is_ignored(tmp_path):
    assert load_part(hand(tmp_path / "m.3mf", meta='<metadata name="NoSuchName">x</metadata>')).solids()
