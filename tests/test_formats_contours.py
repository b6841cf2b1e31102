"""Contour formats (CLI, 3MF slice stack, SVG): read back by independent readers.

* 3MF: lib3mf (the 3MF Consortium's library) in strict mode.
* SVG: ElementTree for the structure, CairoSVG as an independent renderer.
* CLI: our reader for all three forms, the ASCII form checked against the
  binary one (the binary form is also read by the ``colain`` crate in
  test_rust_readers.py).

Every round trip compares regions by the pixel centres they contain
(``shapely.contains_xy``), away from the edges, and by area.
"""
from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
import textwrap
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely import MultiPolygon, Polygon, box

from contour_checks import (GRID, as_multipolygon, assert_same_fill, evenodd, pixel_centres, sample_layers,
                            write_all)
from formats import SUFFIXES, WRITERS, writer_for
from formats.common_layer import DIR_HOLE, DIR_OUTER, CliAsciiWriter, CliShortWriter, CliWriter, read_cli
from formats.contour_base import ContourWriter, oriented_polygons
from formats.svg import SvgWriter
from formats.threemf_slices import ThreeMFSliceWriter
from slicer import Skeleton
from slicer.cli.app import main
from slicer.errors import OutputError

lib3mf = pytest.importorskip("lib3mf")

CONTOUR_FORMATS = ["cli", "cli-ascii", "cli-short", "3mf", "svg"]


def z_top(k):
    return GRID.origin[2] + (k + 0.5) * GRID.layer_height


# ============================================================================= registry
def test_registry_and_suffixes():
    for name in CONTOUR_FORMATS:
        assert issubclass(WRITERS[name], ContourWriter) and WRITERS[name].kind == "contours"
    assert writer_for(None, "a/b.CLI") is CliWriter
    assert writer_for(None, "x.3mf") is ThreeMFSliceWriter and writer_for(None, "x.svg") is SvgWriter
    assert writer_for("cli-ascii", "x.cli") is CliAsciiWriter
    assert {SUFFIXES[s] for s in (".cli", ".3mf", ".svg")} == {"cli", "3mf", "svg"}


def test_orientation_is_normalised():
    cw_with_ccw_hole = Polygon([(0, 0), (0, 4), (4, 4), (4, 0)], [[(1, 1), (3, 1), (3, 3), (1, 3)]])
    (p,) = oriented_polygons(cw_with_ccw_hole)
    assert p.exterior.is_ccw and not p.interiors[0].is_ccw
    assert oriented_polygons(None) == [] and oriented_polygons(MultiPolygon()) == []
    with pytest.raises(TypeError, match="LineString"):
        oriented_polygons(shapely.LineString([(0, 0), (1, 1)]))


# ============================================================================= CLI
@pytest.mark.parametrize("cls,form", [(CliWriter, "long"), (CliShortWriter, "short"), (CliAsciiWriter, "ascii")])
def test_cli_round_trip(tmp_path, cls, form):
    out = tmp_path / "s.cli"
    w = write_all(cls, out)
    assert w.dropped_rings == 0
    cli = read_cli(out)
    assert cli.form == form and cli.binary == (form != "ascii")
    assert cli.header["VERSION"] == "200" and cli.header["LAYERS"] == "5"
    x0, y0, z0 = cli.origin
    assert (x0, y0, z0) == pytest.approx((-1.0, -1.0, 0.0))
    assert len(cli.layers) == GRID.layers
    quantum = w.units
    for k, (layer, want) in enumerate(zip(cli.layers, sample_layers())):
        # $$LAYER is the upper surface, measured from the box bottom
        assert layer.z + z0 == pytest.approx(z_top(k), abs=quantum)
        got = shapely.affinity.translate(layer.multipolygon(), x0, y0)
        assert_same_fill(got, want, eps=2 * quantum)


@pytest.mark.parametrize("cls", [CliWriter, CliShortWriter, CliAsciiWriter])
def test_cli_direction_flags_and_closed_rings(tmp_path, cls):
    out = tmp_path / "d.cli"
    write_all(cls, out)
    for layer, want in zip(read_cli(out).layers, sample_layers()):
        want = as_multipolygon(want)
        dirs = [d for d, _ in layer.polylines]
        assert dirs.count(DIR_OUTER) == len(want.geoms)
        assert dirs.count(DIR_HOLE) == sum(len(p.interiors) for p in want.geoms)
        for d, pts in layer.polylines:
            assert np.array_equal(pts[0], pts[-1])            # closed: first point repeated
            assert Polygon(pts).exterior.is_ccw == (d == DIR_OUTER)


def test_cli_ascii_matches_binary(tmp_path):
    write_all(CliWriter, tmp_path / "b.cli")
    write_all(CliAsciiWriter, tmp_path / "a.cli")
    b, a = read_cli(tmp_path / "b.cli"), read_cli(tmp_path / "a.cli")
    assert a.units == b.units and np.allclose(a.origin, b.origin)
    for la, lb in zip(a.layers, b.layers, strict=True):
        assert la.z == pytest.approx(lb.z, abs=1e-9)
        assert [d for d, _ in la.polylines] == [d for d, _ in lb.polylines]
        for (_, pa), (_, pb) in zip(la.polylines, lb.polylines):
            assert pa.shape == pb.shape and np.abs(pa - pb).max() < 2e-6   # mm


def test_cli_binary_layout(tmp_path):
    out = tmp_path / "h.cli"
    write_all(CliWriter, out)
    data = out.read_bytes()
    head, _, geom = data.partition(b"$$HEADEREND")
    lines = head.decode().splitlines()
    assert lines[0] == "$$HEADERSTART" and "$$BINARY" in lines and "$$UNITS/0.001" in lines
    assert "$$VERSION/200" in lines and "$$LAYERS/5" in lines and not any("$$DATE" in s for s in lines)
    # geometry starts right after the D, with a long layer command at z = 0.2 mm = 200 units
    assert geom[:6] == np.array([127], "<u2").tobytes() + np.array([200.0], "<f4").tobytes()
    assert geom[6:8] == np.array([130], "<u2").tobytes()


def test_cli_short_refuses_out_of_range(tmp_path):
    out = tmp_path / "far.cli"
    far = [box(0, 0, 1, 1)] + [None] * 4
    with pytest.raises(OutputError, match=r"layer 0: a coordinate .* short CLI form"):
        write_all(CliShortWriter, out, far, units=1e-5)       # 65535 units = 0.65 mm < 1 mm
    assert not out.exists() and not list(tmp_path.iterdir())


def test_cli_drops_rings_below_quantisation(tmp_path):
    out = tmp_path / "tiny.cli"
    speck = Polygon([(3, 3), (3.001, 3), (3.001, 3.001)])
    w = write_all(CliShortWriter, out, [MultiPolygon([box(0, 0, 2, 2), speck])] + [None] * 4)  # 5 um units
    assert w.dropped_rings == 1
    assert [d for d, _ in read_cli(out).layers[0].polylines] == [DIR_OUTER]


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4), st.integers(0, 2), st.floats(0.05, 0.4), st.booleans()),
                min_size=1, max_size=8, unique_by=lambda t: (t[0], t[1])))
def test_cli_property_random_cells(tmp_path_factory, cells):
    """Random disjoint squares, some with a hole: areas and flags survive any form."""
    polys = []
    for i, j, inset, hole in cells:
        outer = box(2 * i + inset, 2 * j + inset, 2 * i + 2 - inset, 2 * j + 2 - inset)
        polys.append(Polygon(outer.exterior.coords,
                             [outer.buffer(-0.4, join_style="mitre").exterior.coords] if hole else []))
    mp = MultiPolygon(polys)
    d = tmp_path_factory.mktemp("prop")
    for cls in (CliWriter, CliShortWriter):
        out = d / f"{cls.__name__}.cli"
        w = write_all(cls, out, [mp, None, None, None, None])
        cli = read_cli(out)
        layer = cli.layers[0]
        assert sum(d == DIR_OUTER for d, _ in layer.polylines) == len(polys)
        assert sum(d == DIR_HOLE for d, _ in layer.polylines) == sum(h for *_, h in cells)
        assert layer.multipolygon().area == pytest.approx(mp.area, abs=mp.length * w.units + 1e-9)


# ============================================================================= 3MF
def read_3mf(path):
    """Slices read by lib3mf in strict mode: [(ztop, [ring (n, 2) ...]), ...], zbottom."""
    wrapper = lib3mf.get_wrapper()
    model = wrapper.CreateModel()
    reader = model.QueryReader("3mf")
    reader.SetStrictModeActive(True)
    reader.ReadFromFile(str(path))
    assert reader.GetWarningCount() == 0
    stacks = model.GetSliceStacks()
    assert stacks.Count() == 1 and stacks.MoveNext()
    stack = stacks.GetCurrentSliceStack()
    out = []
    for i in range(stack.GetSliceCount()):
        s = stack.GetSlice(i)
        verts = np.array([list(v.Coordinates) for v in s.GetVertices()], dtype=np.float64).reshape(-1, 2)
        rings = []
        for j in range(s.GetPolygonCount()):
            idx = list(s.GetPolygonIndices(j))
            assert idx[0] == idx[-1], "polygon not closed"
            rings.append(verts[idx])
        out.append((s.GetZTop(), rings))
    return out, stack.GetBottomZ()


def test_3mf_read_back_by_lib3mf(tmp_path):
    out = tmp_path / "s.3mf"
    write_all(ThreeMFSliceWriter, out)
    slices, zbottom = read_3mf(out)
    assert zbottom == pytest.approx(0.0, abs=1e-6)
    assert len(slices) == GRID.layers
    for k, ((ztop, rings), want) in enumerate(zip(slices, sample_layers())):
        assert ztop == pytest.approx(z_top(k), abs=1e-6)               # lib3mf stores float32
        want = as_multipolygon(want)
        assert len(rings) == len(want.geoms) + sum(len(p.interiors) for p in want.geoms)
        for r in rings:  # positive fill rule: outer CCW, holes CW, so signed areas sum to the area
            assert Polygon(r).is_valid
        assert sum(shapely.Polygon(r).area * (1 if shapely.LinearRing(r).is_ccw else -1)
                   for r in rings) == pytest.approx(want.area, abs=1e-5)
        assert_same_fill(evenodd(rings), want, eps=1e-5)


def test_3mf_package_declares_lowres_slices(tmp_path):
    out = tmp_path / "p.3mf"
    write_all(ThreeMFSliceWriter, out)
    with zipfile.ZipFile(out) as z:
        assert z.testzip() is None
        assert sorted(z.namelist()) == ["3D/3dmodel.model", "[Content_Types].xml", "_rels/.rels"]
        root = ET.fromstring(z.read("3D/3dmodel.model"))
    ns = {"c": "http://schemas.microsoft.com/3dmanufacturing/core/2015/02",
          "s": "http://schemas.microsoft.com/3dmanufacturing/slice/2015/07"}
    assert root.get("requiredextensions") == "s" and root.get("unit") == "millimeter"
    obj = root.find("c:resources/c:object", ns)
    assert obj.get(f"{{{ns['s']}}}meshresolution") == "lowres"
    assert obj.get(f"{{{ns['s']}}}slicestackid") == root.find("c:resources/s:slicestack", ns).get("id")


def test_lib3mf_is_a_strict_judge(tmp_path):
    """The reader the tests rely on rejects what a broken writer would produce."""
    out = tmp_path / "ok.3mf"
    write_all(ThreeMFSliceWriter, out)
    with zipfile.ZipFile(out) as z:
        model = z.read("3D/3dmodel.model").decode()
    broken = {
        "ztop": model.replace('ztop="0.6"', 'ztop="0.3"'),                      # not increasing
        "open": re.sub(r'<s:segment v2="0"/></s:polygon>', "</s:polygon>", model, count=1),  # not closed
    }
    for name, text in broken.items():
        assert text != model
        bad = tmp_path / f"{name}.3mf"
        with zipfile.ZipFile(out) as src, zipfile.ZipFile(bad, "w") as dst:
            for n in src.namelist():
                dst.writestr(n, text if n == "3D/3dmodel.model" else src.read(n))
        with pytest.raises(lib3mf.ELib3MFException):
            read_3mf(bad)


# ============================================================================= SVG
SVG = "{http://www.w3.org/2000/svg}"
SK = "{urn:skelslice:svg:1}"


def parse_path(d: str) -> list[np.ndarray]:
    rings = []
    for part in d.split("Z"):
        nums = re.findall(r"-?\d+(?:\.\d+)?", part)
        if nums:
            rings.append(np.array(nums, dtype=np.float64).reshape(-1, 2))
    return rings


def test_svg_structure_and_round_trip(tmp_path):
    out = tmp_path / "s.svg"
    write_all(SvgWriter, out)
    root = ET.parse(out).getroot()
    x0, y1 = (float(v) for v in root.get(f"{SK}origin").split())
    assert (x0, y1) == pytest.approx((-1.0, 7.0))
    assert root.get("viewBox") == "0 0 12 8" and root.get("width") == "12mm"
    groups = root.findall(f"{SVG}g")
    assert len(groups) == GRID.layers
    for k, (g, want) in enumerate(zip(groups, sample_layers())):
        assert g.get("id") == f"layer{k:05d}" and g.get("fill-rule") == "evenodd"
        assert float(g.get(f"{SK}z")) == pytest.approx(GRID.origin[2] + k * GRID.layer_height)
        want = as_multipolygon(want)
        paths = g.findall(f"{SVG}path")
        assert len(paths) == len(want.geoms)                 # one path per region
        rings = []
        for p in paths:
            svg_rings = parse_path(p.get("d"))
            # holes wound opposite to their outline, inside the same path
            signs = {shapely.LinearRing(r).is_ccw for r in svg_rings[1:]}
            assert not signs or signs == {not shapely.LinearRing(svg_rings[0]).is_ccw}
            rings += [np.column_stack([x0 + r[:, 0], y1 - r[:, 1]]) for r in svg_rings]
        assert_same_fill(evenodd(rings), want, eps=2e-6)


def test_svg_renders_holes_empty_in_cairosvg(tmp_path):
    """An independent renderer fills each layer as the polygons say (holes stay black)."""
    try:
        import cairosvg
    except (ImportError, OSError) as exc:  # OSError: the cairo C library is missing
        pytest.skip(f"cairosvg unavailable: {exc}")
    from PIL import Image

    out = tmp_path / "r.svg"
    write_all(SvgWriter, out)
    tree = ET.parse(out)
    ET.register_namespace("", "http://www.w3.org/2000/svg")
    for k, want in [(0, sample_layers()[0]), (3, sample_layers()[3])]:
        for i, g in enumerate(tree.getroot().findall(f"{SVG}g")):
            g.set("display", "inline" if i == k else "none")
        buf = io.BytesIO()
        tree.write(buf)
        png = cairosvg.svg2png(bytestring=buf.getvalue(), output_width=GRID.width, output_height=GRID.height)
        img = np.asarray(Image.open(io.BytesIO(png)).convert("L")) >= 128
        assert img.shape == (GRID.height, GRID.width)
        X, Y = pixel_centres()
        inside = shapely.contains_xy(want, X, Y)
        near = shapely.dwithin(as_multipolygon(want).boundary, shapely.points(X, Y), 0.75 * GRID.pixel_size[0])
        assert np.array_equal(img[~near], inside[~near])
        assert inside.sum() > 100 and (inside & ~near).sum() > 0


# ============================================================================= protocol, atomicity
@pytest.mark.parametrize("name", CONTOUR_FORMATS)
def test_existing_output_needs_force_and_is_replaced_whole(tmp_path, name):
    out = tmp_path / f"o{WRITERS[name].suffix}"
    out.write_bytes(b"old")
    with pytest.raises(OutputError, match="already exists"):
        write_all(WRITERS[name], out)
    assert out.read_bytes() == b"old"
    write_all(WRITERS[name], out, force=True)
    assert out.read_bytes() != b"old"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


@pytest.mark.parametrize("name", CONTOUR_FORMATS)
def test_failure_mid_stack_leaves_nothing(tmp_path, name):
    out = tmp_path / f"o{WRITERS[name].suffix}"
    with pytest.raises(RuntimeError):
        with WRITERS[name](out, GRID) as w:
            w.write_layer(0, GRID.origin[2], sample_layers()[0])
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", CONTOUR_FORMATS)
def test_same_input_same_bytes(tmp_path, name):
    a, b = tmp_path / f"a{WRITERS[name].suffix}", tmp_path / f"b{WRITERS[name].suffix}"
    write_all(WRITERS[name], a)
    write_all(WRITERS[name], b)
    assert a.read_bytes() == b.read_bytes()


def test_layer_order_z_and_gaps(tmp_path):
    with pytest.raises(OutputError, match="out of order"):
        with CliWriter(tmp_path / "a.cli", GRID) as w:
            w.write_layer(2, GRID.origin[2] + 0.4, None)
            w.write_layer(1, GRID.origin[2] + 0.2, None)
    with pytest.raises(OutputError, match="z = 0.3"):
        with CliWriter(tmp_path / "b.cli", GRID) as w:
            w.write_layer(0, 0.3, None)
    assert list(tmp_path.iterdir()) == []
    # layers not given are written empty: the file always has grid.layers layers
    with CliWriter(tmp_path / "c.cli", GRID) as w:
        w.write_layer(3, GRID.origin[2] + 3 * GRID.layer_height, box(0, 0, 1, 1))
    cli = read_cli(tmp_path / "c.cli")
    assert [len(layer.polylines) for layer in cli.layers] == [0, 0, 0, 1, 0]


def test_kill_mid_write_leaves_no_output(tmp_path):
    """A process killed in the middle of a stack leaves nothing at the target."""
    out = tmp_path / "killed.3mf"
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from contour_checks import GRID, sample_layers
        from formats.threemf_slices import ThreeMFSliceWriter
        with ThreeMFSliceWriter({str(out)!r}, GRID) as w:
            for k in range(GRID.layers):
                w.write_layer(k, GRID.origin[2] + k * GRID.layer_height, sample_layers()[0])
                w.fh.flush()
                if k == 2:
                    print("mid-stack", flush=True)
                    time.sleep(60)
    """)
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "mid-stack"
        assert [f.name.startswith(".killed.3mf.tmp-") for f in tmp_path.iterdir()] == [True]
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert not out.exists()


# ============================================================================= through the CLI
@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "y.json"
    Skeleton([[0, 0, 0], [0, 0, 2], [1, 0, 3], [-1, 0, 3], [1.5, 0.3, 0.5]], [[0, 1], [1, 2], [1, 3], [0, 4]],
             [[0.5, 0.3], [0.3, 0.25], [0.3, 0.25], [0.3, 0.2]]).save(p)
    return p


@pytest.fixture(scope="module")
def png_stack(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("png") / "stack"
    r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--pixel-size", "0.05",
                                  "--layer-height", "0.1", "-q"])
    assert r.exit_code == 0, r.output
    import json

    from PIL import Image

    meta = json.loads((out / "slices.json").read_text())
    imgs = [np.asarray(Image.open(out / f)) > 127 for f in meta["files"]]
    return meta, imgs


def _centres(meta):
    px, py = meta["pixel_size"]
    x0, y0, _ = meta["origin"]
    return np.meshgrid(x0 + np.arange(meta["width"]) * px, y0 - np.arange(meta["height"]) * py)


@pytest.mark.parametrize("fmt", ["cli", "cli-ascii", "3mf", "svg"])
def test_slice_command_contours_match_images(scene, png_stack, tmp_path, fmt):
    """Contours read back and rasterised at the pixel centres give the PNG stack."""
    meta, imgs = png_stack
    suffix = {"cli-ascii": ".cli", "cli": ".cli"}.get(fmt, "." + fmt)
    out = tmp_path / f"c{suffix}"
    r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--pixel-size", "0.05",
                                  "--layer-height", "0.1", "--format", fmt, "-q"])
    assert r.exit_code == 0, r.output
    if fmt.startswith("cli"):
        cli = read_cli(out)
        layers = [shapely.affinity.translate(lay.multipolygon(), *cli.origin[:2]) for lay in cli.layers]
    elif fmt == "3mf":
        layers = [evenodd(rings) for _, rings in read_3mf(out)[0]]
    else:
        root = ET.parse(out).getroot()
        x0, y1 = (float(v) for v in root.get(f"{SK}origin").split())
        layers = [evenodd([np.column_stack([x0 + q[:, 0], y1 - q[:, 1]])
                           for p in g.findall(f"{SVG}path") for q in parse_path(p.get("d"))])
                  for g in root.findall(f"{SVG}g")]
    assert len(layers) == len(imgs) == meta["layers"]
    X, Y = _centres(meta)
    pts = shapely.points(X, Y)
    total = 0
    for mp, img in zip(layers, imgs):
        got = shapely.contains_xy(mp, X, Y)
        # contour vertices are on the surface to 1e-3 mm: only centres that close may differ
        near = shapely.dwithin(mp.boundary, pts, 3e-3) if not mp.is_empty else np.zeros_like(img)
        assert np.array_equal(got[~near], img[~near])
        total += int(img.sum())
    assert total > 1000


def test_slice_command_unknown_format_lists_contour_formats(scene, tmp_path):
    r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(tmp_path / "x.out"), "--pixel-size", "0.1",
                                  "--format", "dxf"])
    assert r.exit_code == 2 and "cli-ascii" in r.output and "3mf" in r.output
