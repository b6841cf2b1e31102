"""Hostile and corrupt files through the real entry point: refused in one line, fast, or read correctly.

Every case is generated here and run as ``python -m slicer COMMAND FILE`` in a
subprocess, bounded in time (a generous subprocess timeout, never a timed
assertion) and in memory (the peak resident size of the children). A refusal
is exit status 2, one line on stderr that names the file and the number,
no traceback, nothing written. The sizes are those of the measured failures
(a 64 MiB comment or attribute, lying counts of billions) or, where the point
is the early refusal, smaller ones that still show it.

The limits themselves are documented in docs/cli.md (``--max-input-bytes``,
``--max-input-ratio``) and implemented in :mod:`slicer.input_limits`.
"""
from __future__ import annotations

import io
import json
import os
import resource
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formats.goo import HEADER_SIZE, MAGIC

#: seconds a case may take before the run counts as a hang (the cases take a few seconds at most)
TIMEOUT = 60
#: the most resident memory a case's process may reach, bytes
MEMORY = 2 << 30
MIB = 1 << 20

CONTENT_TYPES = ('<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxmlformats.org/package/'
                 '2006/content-types"><Default Extension="rels" ContentType="application/vnd.openxmlformats-'
                 'package.relationships+xml"/><Default Extension="model" ContentType="application/vnd.ms-'
                 'package.3dmanufacturing-3dmodel+xml"/></Types>')
RELS = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.openxmlformats.org/package/'
        '2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft'
        '.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
HEAD = (b'<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" '
        b'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">')
TETRA_V = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (0, 0, 10)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def _mesh_xml(verts, faces) -> bytes:
    v = "".join(f'<vertex x="{x}" y="{y}" z="{z}"/>' for x, y, z in verts)
    f = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in faces)
    return (f'<resources><object id="1" type="model"><mesh><vertices>{v}</vertices><triangles>{f}</triangles>'
            f'</mesh></object></resources><build><item objectid="1"/></build></model>').encode()


TETRA = _mesh_xml(TETRA_V, TETRA_F)


def _package(path: Path, pieces, method=zipfile.ZIP_DEFLATED) -> Path:
    """A 3MF package whose model part is the concatenation of ``pieces`` (bytes), streamed."""
    with zipfile.ZipFile(path, "w", method) as z:
        z.writestr("[Content_Types].xml", CONTENT_TYPES)
        z.writestr("_rels/.rels", RELS)
        with z.open("3D/3dmodel.model", "w", force_zip64=True) as fh:
            for piece in pieces:
                fh.write(piece)
    return path


def _long(prefix: bytes, mib: int, suffix: bytes):
    yield prefix
    block = b"a" * MIB
    for _ in range(mib):
        yield block
    yield suffix


def run_cli(args, cwd: Path):
    """``python -m slicer ARGS`` in ``cwd``: (exit status, stderr); checks the time and memory bounds."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "2", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    r = subprocess.run([sys.executable, "-m", "slicer", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                       timeout=TIMEOUT, env=env)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024   # the largest child so far
    assert peak < MEMORY, f"a child reached {peak / 2**30:.2f} GiB"
    return r.returncode, r.stderr


def assert_refused(args, cwd: Path, *needles: str) -> str:
    """Exit 2 with one line naming every needle, no traceback, nothing new in ``cwd``."""
    before = sorted(p.name for p in cwd.iterdir())
    status, err = run_cli(args, cwd)
    assert status == 2, (status, err[-2000:])
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-2000:]
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert sorted(p.name for p in cwd.iterdir()) == before
    return lines[0]


# ----------------------------------------------------------------------------- 3MF
def test_64_mib_comment_is_refused_by_its_compression_ratio(tmp_path):
    f = _package(tmp_path / "c.3mf", _long(HEAD + b"<!--", 64, b"-->" + TETRA))
    line = assert_refused(["info", f], tmp_path, "c.3mf", "3D/3dmodel.model", "--max-input-ratio")
    assert "67,109," in line                                   # the declared size, as a number


@pytest.mark.parametrize("prefix,suffix", [(b"<!--", b"-->"), (b'<metadata name="', b'">x</metadata>')],
                         ids=["comment", "attribute"])
def test_64_mib_token_is_refused_in_linear_time(prefix, suffix, tmp_path):
    """Without the ratio limit the scan meets the token itself: refused past 16 MiB, not re-scanned
    at every feed (the quadratic scan took minutes on these files)."""
    f = _package(tmp_path / "t.3mf", _long(HEAD + prefix, 64, suffix + TETRA))
    assert_refused(["--max-input-ratio", "none", "info", f], tmp_path, "t.3mf", "/3D/3dmodel.model",
                   "longer than 16,777,216 bytes")


def test_stored_member_past_the_byte_limit_is_refused(tmp_path):
    """An uncompressed (stored) member is held to --max-input-bytes, which can be raised."""
    pad = b'<vertex x="5" y="5" z="5"/>' * (2 * MIB // 27)          # unused vertices: 2 MiB of genuine XML
    f = _package(tmp_path / "s.3mf", [HEAD, TETRA.replace(b"</vertices>", pad + b"</vertices>")],
                 method=zipfile.ZIP_STORED)
    assert_refused(["--max-input-bytes", "1MiB", "info", f], tmp_path, "3D/3dmodel.model", "1,048,576",
                   "--max-input-bytes")
    status, err = run_cli(["--max-input-bytes", "8MiB", "info", f], tmp_path)
    assert status == 0, err
    assert "lib3mf" not in err


def test_many_vertices_and_one_triangle_refused_by_the_scan(tmp_path):
    """A solid with fewer than four triangles is refused while the model is scanned, before lib3mf
    converts its vertices (the 5-million-vertex file of the issue, here 200,000)."""
    body = (b'<resources><object id="1" type="model"><mesh><vertices>' + b'<vertex x="0" y="0" z="0"/>' * 200_000
            + b'</vertices><triangles><triangle v1="0" v2="1" v3="2"/></triangles></mesh></object></resources>'
              b'<build><item objectid="1"/></build></model>')
    f = _package(tmp_path / "v.3mf", [HEAD, body])
    assert_refused(["--max-input-ratio", "none", "info", f], tmp_path, "object 1", "1 triangles",
                   "200,000 vertices")


def test_deep_nesting_is_refused(tmp_path):
    f = _package(tmp_path / "d.3mf", [HEAD, b"<a>" * 200_000, b"</a>" * 200_000, TETRA])
    assert_refused(["info", f], tmp_path, "d.3mf")


def test_genuine_3mf_mesh_is_read(tmp_path):
    f = _package(tmp_path / "g.3mf", [HEAD, TETRA])
    status, err = run_cli(["info", f], tmp_path)
    assert status == 0, err


@pytest.mark.parametrize("damage", ["truncated", "flipped", "magic"])
def test_damaged_3mf(damage, tmp_path):
    """Truncated or with a flipped byte in the compressed model: exit 2 in one line, or read correctly."""
    f = _package(tmp_path / "x.3mf", [HEAD, TETRA])
    raw = bytearray(f.read_bytes())
    if damage == "truncated":
        raw = raw[:len(raw) * 2 // 3]
    elif damage == "flipped":
        with zipfile.ZipFile(f) as z:
            info = z.getinfo("3D/3dmodel.model")
        raw[info.header_offset + 30 + len(info.filename) + 20] ^= 0xFF
    else:
        raw[:4] = b"GIF8"
    f.write_bytes(bytes(raw))
    assert_refused(["info", f], tmp_path, "x.3mf")


# ----------------------------------------------------------------------------- STL, PLY, JSON
def _stl(triangles: np.ndarray, count: int) -> bytes:
    rec = b"".join(struct.pack("<12fH", 0, 0, 0, *t.ravel(), 0) for t in triangles)
    return b"\0" * 80 + struct.pack("<I", count) + rec


TETRA_TRI = np.array(TETRA_V, float)[np.array(TETRA_F)]


@pytest.mark.parametrize("count,data,needle", [
    (2**32 - 1, TETRA_TRI, "declares 4,294,967,295 triangles"),      # lying count
    (4, TETRA_TRI[:2], "declares 4 triangles"),                      # truncated
    (2, TETRA_TRI[:2], "2 triangles; a closed surface needs at least 4"),
], ids=["lying-count", "truncated", "too-few"])
def test_binary_stl_header(count, data, needle, tmp_path):
    f = tmp_path / "m.stl"
    f.write_bytes(_stl(data, count))
    assert_refused(["info", f], tmp_path, "m.stl", needle)


def test_genuine_binary_stl_is_read(tmp_path):
    f = tmp_path / "m.stl"
    f.write_bytes(_stl(TETRA_TRI, 4))
    status, err = run_cli(["info", f], tmp_path)
    assert status == 0, err


PLY_HEAD = ("ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
            "element face {nf}\nproperty list uchar int vertex_indices\nend_header\n")


@pytest.mark.parametrize("fmt,nv,needle", [
    ("ascii", 4_000_000_000, "4,000,000,000 vertex"),
    ("binary_little_endian", 4_000_000_000, "4,000,000,000 vertex"),
    ("binary_little_endian", 40_000_000, "40,000,000 vertex"),
    ("ascii", 10**30, "--max-input-bytes"),
], ids=["ascii", "binary", "binary-small-lie", "ascii-huge"])
def test_ply_lying_counts(fmt, nv, needle, tmp_path):
    f = tmp_path / "m.ply"
    body = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n3 0 2 3\n3 1 2 3\n" if fmt == "ascii" else "\0" * 100
    f.write_bytes(PLY_HEAD.format(fmt=fmt, nv=nv, nf=4).encode() + body.encode())
    if nv == 10**30:
        f.write_bytes(PLY_HEAD.format(fmt=fmt, nv=nv, nf=4).encode() + b"0 " * 10)
        assert_refused(["--max-input-bytes", "none", "info", f], tmp_path, "m.ply", "vertex", "the file has 20")
        return
    assert_refused(["info", f], tmp_path, "m.ply", needle)


def test_json_past_the_byte_limit_and_deeply_nested(tmp_path):
    big = tmp_path / "big.json"
    big.write_text(json.dumps({"skelslice": 1, "nodes": [[0, 0, 0]] * 100_000}))
    assert_refused(["--max-input-bytes", "100kB", "info", big], tmp_path, "big.json", "--max-input-bytes")
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    assert_refused(["info", deep], tmp_path, "deep.json")


# ----------------------------------------------------------------------------- printer files read back
def _zip_stack(path: Path, doc: dict, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("slices.json", json.dumps(doc))
        for name, data in members.items():
            z.writestr(name, data)
    return path


def _png(h: int, w: int) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.zeros((h, w), np.uint8)).save(buf, "PNG")
    return buf.getvalue()


GRID = {"origin": [0, 0, 0], "pixel_size": [0.1, 0.1], "layer_height": 0.1, "width": 4, "height": 4}


def test_zip_stack_bomb_member(tmp_path):
    """A 64 MiB slices.json that compresses 1000 : 1."""
    f = tmp_path / "b.zip"
    with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("slices.json", b"{" + b" " * (64 * MIB) + b"}")
    assert_refused(["check", f], tmp_path, "b.zip", "slices.json", "--max-input-ratio")


def test_zip_stack_lying_layer_count(tmp_path):
    doc = {**GRID, "layers": 1000, "files": [f"{k:05d}.png" for k in range(1000)]}
    f = _zip_stack(tmp_path / "l.zip", doc, {"00000.png": _png(4, 4)})
    assert_refused(["check", f], tmp_path, "l.zip", "1,000 layer files", "00001.png")


def test_zip_stack_huge_declared_image(tmp_path):
    doc = {**GRID, "width": 10**6, "height": 10**6, "layers": 1, "files": ["00000.png"]}
    f = _zip_stack(tmp_path / "h.zip", doc, {"00000.png": _png(4, 4)})
    assert_refused(["check", f], tmp_path, "h.zip", "1,000,000 x 1,000,000 px", "--max-input-bytes")


def _goo(n: int, xres: int, yres: int, records: bytes = b"") -> bytes:
    head = bytearray(HEADER_SIZE)
    head[0:4], head[4:12] = b"V3.0", MAGIC
    struct.pack_into(">IHH", head, 195310, n, xres, yres)
    struct.pack_into(">5f", head, 195320, 10.0, 10.0, 10.0, 0.05, 2.0)
    struct.pack_into(">I", head, 195470, HEADER_SIZE)
    return bytes(head) + records


def _goo_record(size: int, payload: bytes) -> bytes:
    return b"\0" * 64 + b"\r\n" + struct.pack(">I", size) + b"\x55" + payload


@pytest.mark.parametrize("n,xres,yres,records,needle", [
    (10**9, 4, 4, b"", "says 1,000,000,000 layers"),
    (1, 65535, 65535, _goo_record(2, b"\0") + b"\0" * 8, "65,535 x 65,535 px"),
    (1, 4, 4, _goo_record(10**9, b"\0" * 10), "layer 0: the record says 1,000,000,000 bytes"),
    (1, 4, 4, _goo_record(3, b"\0\0\0\0\r\n"), "layer 0"),
], ids=["lying-layers", "huge-image", "lying-record", "bad-checksum"])
def test_goo_lying_tables(n, xres, yres, records, needle, tmp_path):
    f = tmp_path / "p.goo"
    f.write_bytes(_goo(n, xres, yres, records))
    assert_refused(["check", f], tmp_path, "p.goo", needle)


def test_goo_wrong_magic_and_truncated(tmp_path):
    f = tmp_path / "p.goo"
    f.write_bytes(b"V2.0" + _goo(1, 4, 4)[4:])
    assert_refused(["check", f], tmp_path, "p.goo", "not a GOO")
    f.write_bytes(_goo(1, 4, 4)[:1000])
    assert_refused(["check", f], tmp_path, "p.goo", "not a GOO")


def test_nanodlp_lying_layer_count(tmp_path):
    f = tmp_path / "p.nanodlp"
    with zipfile.ZipFile(f, "w") as z:
        z.writestr("plate.json", json.dumps({"LayersCount": 10**6}))
        z.writestr("options.json", json.dumps({"PWidth": 4, "PHeight": 4, "XPixelSize": 0.1, "YPixelSize": 0.1}))
        z.writestr("profile.json", json.dumps({"Depth": 50, "Title": "x"}))
        z.writestr("1.png", _png(4, 4))
    assert_refused(["check", f], tmp_path, "p.nanodlp", "1,000,000 layers", "1000000.png")


def test_sl1_bomb_member(tmp_path):
    f = tmp_path / "p.sl1"
    with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("config.ini", b"jobDir = p\n" + b"#" * (32 * MIB))
    assert_refused(["check", f], tmp_path, "p.sl1", "config.ini", "--max-input-ratio")


@pytest.mark.parametrize("suffix", [".ctb", ".pwmx"])
def test_printer_files_check_does_not_read_are_refused_by_name(suffix, tmp_path):
    f = tmp_path / f"p{suffix}"
    f.write_bytes(b"\xff" * 1000)
    assert_refused(["check", f], tmp_path, f"p{suffix}")


# ----------------------------------------------------------------------------- bulk arrays out of lib3mf
def test_bulk_arrays_equal_lib3mf_objects():
    """Vertices, triangles and beams copied out of lib3mf in one piece equal lib3mf's own
    per-record objects (the slow reference), caps and radii included."""
    import lib3mf
    from slicer.scene.threemf import _beams, _triangles, _vertices

    rng = np.random.default_rng(5)
    model = lib3mf.get_wrapper().CreateModel()
    obj = model.AddMeshObject()
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    for p in pts:
        v = lib3mf.Position()
        v.Coordinates[0], v.Coordinates[1], v.Coordinates[2] = (float(x) for x in p)
        obj.AddVertex(v)
    for f in rng.integers(0, 50, size=(30, 3)):
        t = lib3mf.Triangle()
        t.Indices[0], t.Indices[1], t.Indices[2] = (int(x) for x in f)
        obj.AddTriangle(t)
    lat = obj.BeamLattice()
    for a, b in rng.integers(0, 50, size=(20, 2)):
        beam = lib3mf.Beam()
        beam.Indices[0], beam.Indices[1] = int(a), int(b)
        beam.Radii[0], beam.Radii[1] = float(rng.random()), float(rng.random())
        beam.CapModes[0], beam.CapModes[1] = int(rng.integers(0, 3)), int(rng.integers(0, 3))
        lat.AddBeam(beam)
    want_v = np.array([list(v.Coordinates) for v in obj.GetVertices()], np.float64)
    want_t = np.array([list(t.Indices) for t in obj.GetTriangleIndices()], np.int64)
    beams = lat.GetBeams()
    assert np.array_equal(_vertices(obj), want_v) and np.array_equal(_vertices(obj), pts.astype(np.float64))
    assert np.array_equal(_triangles(obj), want_t)
    idx, rad, caps = _beams(lat, "beams", "x.3mf")
    assert np.array_equal(idx, [[b.Indices[0], b.Indices[1]] for b in beams])
    assert np.array_equal(rad, [[b.Radii[0], b.Radii[1]] for b in beams])
    assert np.array_equal(caps, [[b.CapModes[0], b.CapModes[1]] for b in beams])


# ----------------------------------------------------------------------------- generated damage
def _genuine(kind: str, folder: Path) -> Path:
    """A small genuine file of each kind the readers take."""
    from formats.goo import encode_layer

    p = folder / f"genuine.{kind}"
    if kind == "3mf":
        _package(p, [HEAD, TETRA], method=zipfile.ZIP_STORED)
    elif kind == "stl":
        p.write_bytes(_stl(TETRA_TRI, 4))
    elif kind == "ply":
        p.write_bytes(PLY_HEAD.format(fmt="binary_little_endian", nv=4, nf=4).encode()
                      + np.array(TETRA_V, "<f4").tobytes()
                      + b"".join(struct.pack("<B3i", 3, *f) for f in TETRA_F))
    elif kind == "json":
        p.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1]],
                                 "segments": [[0, 1]], "radii": [0.2, 0.2]}))
    elif kind == "zip":
        _zip_stack(p, {**GRID, "layers": 2, "files": ["0.png", "1.png"]}, {"0.png": _png(4, 4), "1.png": _png(4, 4)})
    elif kind == "goo":
        payload, checksum = encode_layer(np.zeros((4, 4), np.uint8))
        rec = _goo_record(len(payload) + 2, payload) + bytes([checksum]) + b"\r\n"
        p.write_bytes(_goo(2, 4, 4, rec + rec))
    elif kind == "nanodlp":
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.zeros((4, 2, 3), np.uint8), "RGB").save(buf, "PNG")
        with zipfile.ZipFile(p, "w") as z:
            z.writestr("plate.json", json.dumps({"LayersCount": 2}))
            z.writestr("options.json", json.dumps({"PWidth": 6, "PHeight": 4, "XPixelSize": 0.1,
                                                   "YPixelSize": 0.1}))
            z.writestr("profile.json", json.dumps({"Depth": 50, "Title": "x"}))
            z.writestr("1.png", buf.getvalue())
            z.writestr("2.png", buf.getvalue())
    return p


def _damage(raw: bytes, data) -> bytes:
    """Truncated, a few flipped bytes, or a 4-byte field overwritten with a huge or zero count."""
    how = data.draw(st.sampled_from(["truncate", "flip", "lie"]), label="damage")
    if how == "truncate":
        return raw[:data.draw(st.integers(0, len(raw) - 1), label="cut")]
    out = bytearray(raw)
    if how == "flip":
        for _ in range(data.draw(st.integers(1, 3), label="flips")):
            at = data.draw(st.integers(0, len(raw) - 1), label="at")
            out[at] ^= data.draw(st.integers(1, 255), label="mask")
        return bytes(out)
    at = data.draw(st.integers(0, len(raw) - 4), label="at")
    value = data.draw(st.sampled_from([0, 1, 3, 2**31 - 1, 2**32 - 1, 10**6, 65535 * 65537]), label="count")
    out[at:at + 4] = struct.pack(data.draw(st.sampled_from(["<I", ">I"]), label="order"), value)
    return bytes(out)


SCENE_KINDS = ["3mf", "stl", "ply", "json"]
STACK_KINDS = ["zip", "goo", "nanodlp"]


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_fuzz_damaged_scene_files(kind, tmp_path_factory):
    """Every damaged scene or mesh file: `skelslice info` exits 0 or 2, no traceback (fuzz_helpers.check_run)."""
    from click.testing import CliRunner
    from fuzz_helpers import check_run, fuzz_settings
    from hypothesis import given

    from slicer.cli.app import main

    raw = _genuine(kind, tmp_path_factory.mktemp("genuine")).read_bytes()
    assert CliRunner().invoke(main, ["info", str(_genuine(kind, tmp_path_factory.mktemp("ok")))]).exit_code == 0

    @fuzz_settings(25)
    @given(st.data())
    def run(data):
        folder = tmp_path_factory.mktemp("fuzz")
        f = folder / f"damaged.{kind}"
        f.write_bytes(_damage(raw, data))
        before = set(os.listdir(folder))
        check_run(CliRunner().invoke(main, ["info", str(f)], catch_exceptions=True), folder, before,
                  what=f"info damaged.{kind}")

    run()


@pytest.mark.parametrize("kind", STACK_KINDS)
def test_fuzz_damaged_stacks(kind, tmp_path_factory):
    """Every damaged printer file or zip stack is read whole, or refused with a ReadError (which
    `check` and `preview` print in one line), before any layer of an absurd size is made."""
    from fuzz_helpers import fuzz_settings
    from hypothesis import given

    from formats.readback import open_stack
    from slicer.errors import ReadError

    raw = _genuine(kind, tmp_path_factory.mktemp("genuine")).read_bytes()
    assert len(list(open_stack(_genuine(kind, tmp_path_factory.mktemp("ok"))).layers())) == 2

    @fuzz_settings(25)
    @given(st.data())
    def run(data):
        f = tmp_path_factory.mktemp("fuzz") / f"damaged.{kind}"
        f.write_bytes(_damage(raw, data))
        try:
            for img in open_stack(f).layers():
                assert img.nbytes <= 1 << 20
        except ReadError:
            pass

    run()


# ----------------------------------------------------------------------------- the condensed scan
@st.composite
def _model_parts(draw):
    """Model XML: objects with vertex and triangle runs and beams (indices in and out of range), the
    runs' items written in the forms 3MF writers use, with comments, processing instructions, odd
    spacing and foreign elements now and then."""
    junk = st.sampled_from([b"", b"", b"", b"\n  ", b"<!-- <vertices> </vertices> -->", b"<?pi x?>",
                            b"<![CDATA[x]]>" if draw(st.booleans()) else b"", b'<m:x xmlns:m="urn:x"/>'])
    out = [HEAD]
    for oid in range(draw(st.integers(1, 3))):
        nv, nt = draw(st.integers(0, 9)), draw(st.integers(0, 6))
        out.append(f'<resources><object id="{oid + 1}" type="model"><mesh>'.encode())
        v = b"".join(draw(st.sampled_from([b'<vertex x="0" y="0" z="%d"/>', b'<vertex x="0" y="0" z="%d"></vertex>',
                                            b'<vertex  z="%d" x="1" y="2" />'])) % k + draw(junk) for k in range(nv))
        t = b"".join(draw(st.sampled_from([b'<triangle v1="0" v2="1" v3="%d"/>',
                                            b'<triangle v1="0" v2="1" v3="%d" p1="1"/>'])) % k + draw(junk)
                     for k in range(nt))
        open_v = draw(st.sampled_from([b"<vertices>", b"<vertices >"]))
        out.append(open_v + draw(junk) + v + b"</vertices>" + draw(junk) + b"<triangles>" + t + b"</triangles>")
        beams = b"".join(b'<b:beam v1="%d" v2="%d"/>' % (draw(st.integers(0, 10)), draw(st.integers(0, 10)))
                         for _ in range(draw(st.integers(0, 3))))
        if beams:
            out.append(b'<b:beamlattice xmlns:b="http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02" '
                       b'radius="1"><b:beams>' + beams + b"</b:beams></b:beamlattice>")
        out.append(b"</mesh></object></resources>")
    out.append(b'<build><item objectid="1"/></build></model>')
    return b"".join(out)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(xml=_model_parts(), feed=st.integers(1, 40))
def test_condensed_scan_finds_what_the_element_scan_finds(xml, feed, tmp_path_factory):
    """The scan with vertex and triangle runs condensed (fed in pieces of 1 to 40 bytes) counts, accepts
    and refuses exactly as the scan of every element does, or hands the part over to it."""
    import slicer.input_limits as limits
    from slicer.errors import SceneError
    from slicer.scene.threemf import _Condenser, _scan_once

    f = _package(tmp_path_factory.mktemp("c") / "m.3mf", [xml], method=zipfile.ZIP_STORED)

    def outcome(condenser):
        try:
            with zipfile.ZipFile(f) as z:
                return "ok", _scan_once(z, "3D/3dmodel.model", str(f), condenser)
        except SceneError as exc:
            return "refused", str(exc)
        except limits.Restart:
            return "restart", None

    old = limits.FEED
    limits.FEED = feed
    try:
        plain, condensed = outcome(None), outcome(_Condenser())
    finally:
        limits.FEED = old
    assert plain[0] != "restart"
    if condensed[0] == "restart":
        assert any(m in xml[40:] for m in (b"<!", b"<?", b"<vertices >", b"</vertex>", b"<m:x")) or "invalid" in str(plain)
    else:
        assert condensed == plain


def test_condensed_scan_counts_without_a_restart(tmp_path):
    """A plain mesh part is scanned condensed: its runs' items are counted from the bytes."""
    from slicer.scene.threemf import _Condenser, _scan_once

    f = _package(tmp_path / "m.3mf", [HEAD, TETRA])
    condenser = _Condenser()
    with zipfile.ZipFile(f) as z:
        assert _scan_once(z, "3D/3dmodel.model", str(f), condenser) == 0
    assert sorted(condenser.counts.values()) == [4, 4]
