"""3MF Beam Lattice input: files built with lib3mf and written by hand, read, checked, sliced."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner

from slicer import Skeleton, load_scene
from slicer.cli.app import main
from slicer.errors import SceneError
from slicer.scene.threemf import load_3mf
from slicer.tracer.slicing import slice_skeleton

lib3mf = pytest.importorskip("lib3mf")

NODES = [(0.0, 0.0, 0.0), (0.0, 0.0, 2.0), (1.5, 0.0, 3.0), (-1.5, 0.25, 3.0), (7.0, 7.0, 7.0)]  # node 4 unused
BEAMS = [(0, 1, 0.5, 0.375), (1, 2, 0.375, 0.25), (1, 3, 0.375, 0.25)]


def _pos(p):
    v = lib3mf.Position()
    for i in range(3):
        v.Coordinates[i] = p[i]
    return v


def _transform(m):
    """A (4, 3) row-vector matrix as a lib3mf Transform."""
    t = lib3mf.Transform()
    for r in range(4):
        for c in range(3):
            t.Fields[r][c] = m[r][c]
    return t


def build_3mf(path, nodes=NODES, beams=BEAMS, unit=None, item_transform=None, components=None,
              extra_mesh=False):
    """Write a beam-lattice 3MF with lib3mf.

    ``components``: list of (4, 3) transforms; the build item is then a
    components object holding the lattice once per transform.
    """
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    if unit is not None:
        model.SetUnit(unit)
    mesh = model.AddMeshObject()
    mesh.SetName("lattice")
    for p in nodes:
        mesh.AddVertex(_pos(p))
    lattice = mesh.BeamLattice()
    lattice.SetMinLength(1e-4)
    for a, b, ra, rb in beams:
        beam = lib3mf.Beam()
        beam.Indices[0], beam.Indices[1] = a, b
        beam.Radii[0], beam.Radii[1] = ra, rb
        lattice.AddBeam(beam)
    item = mesh
    if components is not None:
        comp = model.AddComponentsObject()
        for m in components:
            comp.AddComponent(mesh, _transform(m))
        item = comp
    model.AddBuildItem(item, _transform(item_transform) if item_transform is not None
                       else wrapper.GetIdentityTransform())
    if extra_mesh:
        solid = model.AddMeshObject()
        solid.SetName("hull")
        for p in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]:
            solid.AddVertex(_pos(p))
        for tri in [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]:
            t = lib3mf.Triangle()
            t.Indices[0], t.Indices[1], t.Indices[2] = tri
            solid.AddTriangle(t)
        model.AddBuildItem(solid, wrapper.GetIdentityTransform())
    model.QueryWriter("3mf").WriteToFile(str(path))
    return path


CONTENT_TYPES = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>
</Types>"""
RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
<Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>"""


def hand_3mf(path, beams_xml, lattice_attrs='radius="0.4" minlength="0.0001" cap="sphere"', unit="centimeter",
             vertices=((0, 0, 0), (0, 0, 0.25), (0.125, 0, 0.3)), lattice=True):
    """A 3MF package written by hand (no lib3mf), as another producer would."""
    verts = "".join(f'<vertex x="{x}" y="{y}" z="{z}"/>' for x, y, z in vertices)
    lat = (f'<b:beamlattice {lattice_attrs}><b:beams>{beams_xml}</b:beams></b:beamlattice>'
           if lattice else "")
    model = f"""<?xml version="1.0" encoding="UTF-8"?>
<model unit="{unit}" xml:lang="en-US" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
 xmlns:b="http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02" requiredextensions="b">
 <resources>
  <object id="1" type="model" name="strut"><mesh><vertices>{verts}</vertices><triangles/>{lat}</mesh></object>
 </resources>
 <build><item objectid="1"/></build>
</model>"""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", CONTENT_TYPES)
        z.writestr("_rels/.rels", RELS)
        z.writestr("3D/3dmodel.model", model)
    return path


# ============================================================================= reading
def test_lib3mf_lattice_read(tmp_path):
    s = load_scene(build_3mf(tmp_path / "l.3mf"))
    assert isinstance(s, Skeleton) and s.source == str(tmp_path / "l.3mf")
    ends = s.nodes[s.segments]                                       # (m, 2, 3)
    want = np.array([[NODES[a], NODES[b]] for a, b, _, _ in BEAMS])
    assert np.array_equal(ends, want)
    assert np.array_equal(s.radii, [[ra, rb] for _, _, ra, rb in BEAMS])
    assert s.n_nodes == 4                                            # the unused vertex is dropped
    assert (s.degree, s.sigma) == (6, 2.0)


def test_units_and_similarity_transform(tmp_path):
    c, k = 0.6, 0.8                                                   # rotation about z, scale 2
    rot = np.array([[c, k, 0], [-k, c, 0], [0, 0, 1.0]]) * 2.0       # (lib3mf stores float32)
    m = np.vstack([rot, [10.0, -4.0, 1.0]])
    s = load_3mf(build_3mf(tmp_path / "t.3mf", unit=lib3mf.ModelUnit.Inch, item_transform=m))
    m32 = m.astype(np.float32).astype(np.float64)
    p = np.array(NODES[:4]) @ m32[:3] + m32[3]
    assert np.allclose(s.nodes, p * 25.4, rtol=1e-6, atol=1e-9)
    assert np.allclose(s.radii, np.array([[ra, rb] for *_, ra, rb in BEAMS]) * 2.0 * 25.4, rtol=1e-6)


def test_components_place_each_instance(tmp_path):
    shift = [np.vstack([np.eye(3), [dx, 0, 0]]) for dx in (0.0, 5.0)]
    s = load_3mf(build_3mf(tmp_path / "c.3mf", components=shift, item_transform=np.vstack([np.eye(3), [0, 0, 1]])))
    assert s.n_segments == 2 * len(BEAMS)
    xs = sorted({round(float(x), 6) for x in s.nodes[:, 0]})
    assert xs == [-1.5, 0.0, 1.5, 3.5, 5.0, 6.5]
    assert s.nodes[:, 2].min() == 1.0


def test_hand_written_package_defaults(tmp_path):
    """Default radius from the lattice, r2 defaulting to r1, centimetres to mm."""
    path = hand_3mf(tmp_path / "h.3mf", '<b:beam v1="0" v2="1"/><b:beam v1="1" v2="2" r1="0.05"/>'
                                        '<b:beam v1="0" v2="2" r1="0.05" r2="0.025"/>')
    s = load_scene(path)
    assert np.allclose(s.radii, [[4.0, 4.0], [0.5, 0.5], [0.5, 0.25]])
    assert np.allclose(s.nodes[s.segments[0]], [[0, 0, 0], [0, 0, 2.5]])


@pytest.mark.parametrize("beams,attrs,needle", [
    ('<b:beam v1="0" v2="1"/><b:beam v1="1" v2="7" r1="0.1"/>', None,
     "object 1 'strut', beam 1: v2 = 7 is out of range (the mesh has 3 vertices"),
    ('<b:beam v1="0" v2="1"/><b:beam v1="1" v2="2" r1="-0.5"/>', None, "beam 1: r1 = -0.5 is not a valid radius"),
    ('<b:beam v1="0" v2="1" r2="0"/>', None, "beam 0: r2 = 0 is not a valid radius"),
    ('<b:beam v1="0" v2="1" r1="nan"/>', None, "beam 0: r1 = nan is not a valid radius"),
    ('<b:beam v1="0" v2="x"/>', None, "beam 0: v2 = 'x' is not a vertex index"),
    ('<b:beam v1="2" v2="2"/>', None, "beam 0: v1 = v2 = 2"),
    ('<b:beam v1="0" v2="1"/>', 'radius="-1" minlength="0.0001"', "beamlattice: radius = -1 is not a valid radius"),
])
def test_bad_beam_data_named(tmp_path, beams, attrs, needle):
    kw = {"lattice_attrs": attrs} if attrs else {}
    path = hand_3mf(tmp_path / "bad.3mf", beams, **kw)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: /3D/3dmodel.model, object 1 'strut'") and needle in msg, msg


@pytest.mark.parametrize("beams,needle", [
    ('<b:beam v1="0" v2="1" r1="1e-20"/><b:beam v1="1" v2="2"/>',
     "build item 0, object 1 'strut': beam 0 r1 = 1e-19 mm is below the smallest supported radius 1e-09 mm"),
    ('<b:beam v1="0" v2="1"/><b:beam v1="1" v2="2" r2="2e8"/>',          # centimetres: 2e9 mm
     "build item 0, object 1 'strut': beam 1 r2 = 2e+09 mm is beyond the supported magnitude 1e+09 mm"),
])
def test_numbers_float64_cannot_resolve_are_named(tmp_path, beams, needle):
    """docs/scene-format.md "Limits", checked on the placed lattice and named by build item, object,
    beam and end."""
    path = hand_3mf(tmp_path / "bad.3mf", beams)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    assert str(e.value).startswith(f"{path}: ") and needle in str(e.value), str(e.value)


def test_no_beam_lattice(tmp_path):
    path = hand_3mf(tmp_path / "mesh.3mf", "", lattice=False)
    with pytest.raises(SceneError, match=r"mesh\.3mf: no beam lattice"):
        load_scene(path)


def test_triangle_object_beside_lattice_refused(tmp_path):
    with pytest.raises(SceneError, match=r"build item 1: object \d+ 'hull' is a triangle mesh \(4 triangles\)"):
        load_3mf(build_3mf(tmp_path / "x.3mf", extra_mesh=True))


def test_non_similarity_transform_refused(tmp_path):
    m = np.vstack([np.diag([1.0, 2.0, 1.0]), [0, 0, 0]])
    with pytest.raises(SceneError, match=r"build item 0: the transform is not a similarity"):
        load_3mf(build_3mf(tmp_path / "s.3mf", item_transform=m))


def test_not_a_package(tmp_path):
    p = tmp_path / "text.3mf"
    p.write_text("solid nothing\n")
    with pytest.raises(SceneError, match=r"text\.3mf: not a 3MF package \(not a zip archive\)"):
        load_scene(p)
    with pytest.raises(SceneError, match="No such file"):
        load_scene(tmp_path / "missing.3mf")
    bad_xml = tmp_path / "xml.3mf"
    with zipfile.ZipFile(bad_xml, "w") as z:
        z.writestr("3D/3dmodel.model", "<model><unclosed></model>")
    with pytest.raises(SceneError, match=r"/3D/3dmodel.model: invalid XML"):
        load_scene(bad_xml)


# ============================================================================= slicing
def test_slice_3mf_same_as_json(tmp_path):
    """A 3MF lattice slices exactly like the same skeleton given as JSON."""
    path = build_3mf(tmp_path / "l.3mf")
    s3 = load_scene(path)
    sj = Skeleton(np.array(NODES), [(a, b) for a, b, *_ in BEAMS], [(ra, rb) for *_, ra, rb in BEAMS])
    a, b = slice_skeleton(s3, 0.1), slice_skeleton(sj, 0.1)
    assert a.grid == b.grid and a.n_runs == b.n_runs > 0
    assert all(np.array_equal(x, y) for x, y in zip(a.iter_layers(), b.iter_layers()))


def test_slice_command_reads_3mf(tmp_path):
    path = build_3mf(tmp_path / "l.3mf")
    out = tmp_path / "stack"
    r = CliRunner().invoke(main, ["slice", str(path), "-o", str(out), "--pixel-size", "0.1", "-q"])
    assert r.exit_code == 0, r.output
    meta = json.loads((out / "slices.json").read_text())
    assert meta["layers"] > 30 and meta["scene"] == str(path)
    bad = hand_3mf(tmp_path / "bad.3mf", '<b:beam v1="0" v2="9"/>')
    r = CliRunner().invoke(main, ["slice", str(bad), "-o", str(tmp_path / "o2"), "--pixel-size", "0.1"])
    assert r.exit_code == 2 and "beam 0: v2 = 9 is out of range" in r.output and "Traceback" not in r.output
