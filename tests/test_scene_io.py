"""Scene files: JSON v1 and OBJ polylines, round trips, precedence rules and bad input.

``BAD_CASES`` (one entry per kind of bad input) is shared with
``test_cli_errors.py``, which runs every case through the real CLI.
"""
from __future__ import annotations

import json
import os
import string
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slicer import Skeleton, load_scene, save_scene
from slicer.errors import OutputError, SceneError

# ----------------------------------------------------------------------------- helpers
BASE = {
    "skelslice": 1,
    "units": "mm",
    "nodes": [[0, 0, 0], [0, 0, 10], [10, 0, 10], [10, 10, 10]],
    "segments": [[0, 1], [1, 2], [2, 3]],
    "radii": [1.0, 0.5, 0.75, 2.0],
}


def scene(drop=(), **changes) -> str:
    """JSON text of BASE with keys changed or dropped (NaN/Infinity allowed)."""
    d = {k: v for k, v in BASE.items() if k not in drop}
    d.update(changes)
    return json.dumps(d)


def with_node(i, value) -> str:
    nodes = [list(p) for p in BASE["nodes"]]
    nodes[i] = value
    return scene(nodes=nodes)


def with_segment(i, value) -> str:
    segs = [list(s) for s in BASE["segments"]]
    segs[i] = value
    return scene(segments=segs)


OBJ_OK = "v 0 0 0 1\nv 0 0 10 1\nv 10 0 10 1\nl 1 2 3\n"
DIR = object()  # content sentinel: make a directory at the path


class Case(NamedTuple):
    id: str
    name: str  # file name
    content: object  # str, bytes, None (no file) or DIR
    must: tuple  # fragments the message must contain (besides the file name)
    radius: float | None = None


BAD_CASES = [
    # --- the file itself
    Case("missing-file", "nope.json", None, ("cannot read", "No such file")),
    Case("directory", "adir.json", DIR, ("cannot read", "directory")),
    Case("unknown-suffix", "scene.txt", scene(), ("unknown scene file type", "'.txt'", ".json", ".obj")),
    Case("no-suffix", "scene", scene(), ("unknown scene file type", "no suffix")),
    Case("not-utf8", "bin.json", b'{"skelslice": 1,\n "units": "\xff\xfe"}', ("line 2", "UTF-8", "0xff")),
    Case("empty-json", "empty.json", "  \n", ("empty",)),
    # --- JSON syntax and structure
    Case("invalid-json", "syntax.json", '{"skelslice": 1,\n "units": "mm"\n "nodes": []}',
         ("invalid JSON", "line 3, column 2", "Expecting ',' delimiter", '"nodes"')),
    Case("trailing-comma", "comma.json", '{"skelslice": 1, "nodes": [[0, 0, 0],]}',
         ("invalid JSON", "line 1, column 38")),
    Case("deep-nesting", "deep.json", "[" * 100000 + "]" * 100000, ("nested too deeply",)),
    Case("huge-integer-literal", "digits.json", '{"skelslice": ' + "9" * 5000 + "}", ("invalid JSON", "too many digits")),
    Case("duplicate-key", "dup.json", scene()[:-1] + ', "nodes": []}', ("duplicate key", '"nodes"')),
    Case("top-level-array", "list.json", "[1, 2, 3]", ("top level", "JSON object", "an array", "[1, 2, 3]")),
    Case("top-level-string", "str.json", '"scene"', ("top level", "a string", '"scene"')),
    Case("missing-version", "nover.json", scene(drop=("skelslice",)), ('"skelslice"', "missing")),
    Case("version-3", "v3.json", scene(skelslice=3), ('"skelslice" = 3', "version 3", "reads versions 1, 2", "upgrade")),
    Case("meshes-in-version-1", "v1mesh.json", scene(meshes=[{"path": "a.stl"}]),
         ('"meshes" needs scene format version 2', '"skelslice": 2')),
    Case("version-string", "vstr.json", scene(skelslice="1"), ('"skelslice" = "1"', "integer")),
    Case("version-bool", "vbool.json", scene(skelslice=True), ('"skelslice" = true', "integer")),
    Case("version-float", "vfloat.json", scene(skelslice=1.0), ('"skelslice" = 1.0', "integer")),
    Case("unknown-key", "unk.json", scene(segment_radius=[[1, 1]] * 3),
         ("unknown key", '"segment_radius"', 'did you mean "segment_radii"', '"x-"', '"metadata"')),
    Case("unknown-keys", "unk2.json", scene(name="a", colour="red"), ("unknown keys", '"name"', '"colour"')),
    Case("missing-units", "nounits.json", scene(drop=("units",)), ('missing key "units"',)),
    Case("missing-nodes-segments", "nonodes.json", scene(drop=("nodes", "segments")),
         ("missing keys", '"nodes"', '"segments"')),
    Case("unknown-units", "ft.json", scene(units="ft"), ('"units" = "ft"', "not supported", '"mm"', '"in"')),
    Case("units-case", "MM.json", scene(units="MM"), ('"units" = "MM"', '"mm"')),
    Case("units-number", "u1.json", scene(units=1), ('"units" = 1',)),
    Case("units-overflow", "uover.json", scene(units="m", nodes=[[1e306, 0, 0]] + BASE["nodes"][1:]),
         ("overflow", "from m to mm")),
    # --- numbers
    Case("nan-node", "nan.json", with_node(1, [0, 0, float("nan")]), ("nodes[1][2] = NaN", "not a finite number")),
    Case("inf-radius", "inf.json", scene(radii=[1, 1, float("inf"), 1]), ("radii[2] = Infinity", "not a finite")),
    Case("neg-inf-segment-radius", "ninf.json",
         scene(segment_radii=[[1, 1], [1, float("-inf")], [1, 1]]), ("segment_radii[1][1] = -Infinity", "finite")),
    Case("overflow-literal", "1e999.json", scene().replace('"nodes": [[0, 0, 0]', '"nodes": [[1e999, 0, 0]'),
         ("nodes[0][0] = Infinity", "not a finite")),
    Case("huge-int", "bigint.json", scene().replace('"nodes": [[0, 0, 0]', '"nodes": [[1' + "0" * 400 + ", 0, 0]"),
         ("nodes[0][0] = 1000", "too large")),
    Case("bool-coordinate", "bool.json", with_node(2, [10, True, 10]), ("nodes[2][1] = true", "a boolean", "not a number")),
    Case("string-coordinate", "strnum.json", with_node(0, ["1.5", 0, 0]), ('nodes[0][0] = "1.5"', "a string", "not a number")),
    Case("null-coordinate", "null.json", with_node(0, [None, 0, 0]), ("nodes[0][0] is null", "not a number")),
    Case("string-radius", "strr.json", scene(radii=[1, "0.5", 1, 1]), ('radii[1] = "0.5"', "a string")),
    # --- shapes
    Case("node-2-coords", "short.json", with_node(3, [1, 2]), ("nodes[3] = [1, 2]", "2 numbers", "[x, y, z]")),
    Case("node-4-coords", "long.json", with_node(0, [1, 2, 3, 4]), ("nodes[0] = [1, 2, 3, 4]", "4 numbers")),
    Case("node-not-array", "nodenum.json", with_node(1, 5), ("nodes[1] = 5", "a number", "[x, y, z]")),
    Case("nodes-not-array", "nodesobj.json", scene(nodes={"a": 1}), ('"nodes" = {"a": 1}', "an object", "array")),
    Case("segments-not-array", "segsstr.json", scene(segments="0-1"), ('"segments" = "0-1"', "a string")),
    Case("segment-3-entries", "seg3.json", with_segment(0, [0, 1, 2]), ("segments[0] = [0, 1, 2]", "3 entries", "[i, j]")),
    Case("segment-not-array", "segnum.json", with_segment(2, 7), ("segments[2] = 7", "a number")),
    Case("radii-not-array", "radnum.json", scene(radii=1.0), ('"radii" = 1.0', "array")),
    Case("segment-radii-not-pair", "srpair.json", scene(segment_radii=[[1, 1], [1], [1, 1]]),
         ("segment_radii[1] = [1]", "1 number;", "[r_i, r_j]")),
    Case("radii-length", "rlen.json", scene(radii=[1, 1, 1]), ('"radii" has 3 entries', "4 nodes")),
    Case("segment-radii-length", "srlen.json", scene(segment_radii=[[1, 1], [1, 1]]),
         ('"segment_radii" has 2 entries', "3 segments")),
    # --- values
    Case("zero-radius", "r0.json", scene(radii=[1, 0, 1, 1]), ("radii[1] = 0", "> 0")),
    Case("negative-segment-radius", "rneg.json", scene(segment_radii=[[1, 1], [1, 1], [-0.5, 1]]),
         ("segment_radii[2][0] = -0.5", "> 0")),
    Case("index-out-of-range", "oor.json", with_segment(2, [2, 57]), ("segments[2][1] = 57", "out of range", "4 nodes")),
    Case("negative-index", "negidx.json", with_segment(0, [-1, 1]), ("segments[0][0] = -1", "out of range")),
    Case("float-index", "fidx.json", with_segment(1, [1.0, 2]), ("segments[1][0] = 1.0", "not an integer")),
    Case("fraction-index", "fidx2.json", with_segment(1, [1, 2.5]), ("segments[1][1] = 2.5", "not an integer")),
    Case("bool-index", "bidx.json", with_segment(1, [1, True]), ("segments[1][1] = true", "a boolean")),
    Case("string-index", "sidx.json", with_segment(1, ["1", 2]), ('segments[1][0] = "1"', "a string")),
    Case("self-loop", "loop.json", with_segment(1, [1, 1]), ("segments[1] = [1, 1]", "itself", "zero-length")),
    Case("coincident-nodes", "coinc.json", with_node(1, [0, 0, 0]), ("segment 0", "(0, 1)", "zero length")),
    Case("no-radii", "norad.json", scene(drop=("radii",)), ("no radii", '"radii"', '"segment_radii"', "--radius")),
    Case("no-segments", "noseg.json", scene(segments=[], radii=[1, 1, 1, 1]), ('"segments" is empty',)),
    # --- kernel
    Case("odd-degree", "deg5.json", scene(kernel={"degree": 5}), ("kernel degree", "even", "5")),
    Case("float-degree", "deg6f.json", scene(kernel={"degree": 6.0}), ("kernel degree", "6.0")),
    Case("large-degree", "deg18.json", scene(kernel={"degree": 18}), ("kernel degree", "18")),
    Case("bool-degree", "degb.json", scene(kernel={"degree": True}), ("kernel degree", "True")),
    Case("sigma-1", "sig1.json", scene(kernel={"sigma": 1}), ("kernel sigma", "> 1", "1.0")),
    Case("sigma-small", "sig05.json", scene(kernel={"degree": 6, "sigma": 0.5}), ("kernel sigma", "0.5")),
    Case("sigma-nan", "signan.json", scene(kernel={"sigma": float("nan")}), ("kernel.sigma = NaN", "finite")),
    Case("sigma-string", "sigstr.json", scene(kernel={"sigma": "2"}), ("kernel sigma", "'2'")),
    Case("sigma-huge-int", "sigbig.json", scene().replace('"units"', '"kernel": {"sigma": 1' + "0" * 400 + '}, "units"'),
         ("kernel.sigma = 1000", "too large")),
    Case("unknown-kernel-key", "kkey.json", scene(kernel={"degree": 6, "sigmaa": 2}),
         ("unknown kernel key", '"sigmaa"', 'did you mean "sigma"')),
    Case("kernel-not-object", "karr.json", scene(kernel=[6, 2]), ('"kernel" = [6, 2]', "must be an object")),
    # --- OBJ
    Case("obj-empty", "empty.obj", "", ("empty",)),
    Case("obj-face", "face.obj", "v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 1\n\nf 1 2 3\n", ("line 5", "'f 1 2 3'", "faces")),
    Case("obj-face-fo", "fo.obj", OBJ_OK + "fo 1 2 3\n", ("line 5", "'fo 1 2 3'", "faces")),
    Case("obj-vertex-2", "v2.obj", "v 0 0 0 1\nv 1 2\nl 1 2\n", ("line 2", "'v 1 2'", "2 numbers", "v x y z radius")),
    Case("obj-vertex-colours", "vc.obj", "v 0 0 0 1 0.5 0.5\nv 1 0 0\nl 1 2\n",
         ("line 1", "6 numbers", "vertex colours")),
    Case("obj-vertex-text", "vt.obj", "v 0 0 0 1\nv 1 a 0 1\nl 1 2\n", ("line 2", "'a' is not a number")),
    Case("obj-vertex-nan", "vnan.obj", "v 0 0 0 1\nv 1 nan 0 1\nl 1 2\n", ("line 2", "'nan' is not a number")),
    Case("obj-vertex-underscore", "vus.obj", "v 0 0 0 1\nv 1_0 0 0 1\nl 1 2\n", ("line 2", "'1_0' is not a number")),
    Case("obj-vertex-overflow", "vinf.obj", "v 0 0 0 1\nv 1e999 0 0 1\nl 1 2\n", ("line 2", "'1e999'", "not a finite")),
    Case("obj-radius-zero", "r0.obj", "v 0 0 0 1\nv 0 0 1 1\nv 1 0 0 0\nl 1 2 3\n", ("line 3", "radius 0", "> 0")),
    Case("obj-radius-negative", "rneg.obj", "v 0 0 0 -0.5\nv 0 0 1 1\nl 1 2\n", ("line 1", "radius -0.5")),
    Case("obj-line-one-index", "l1.obj", OBJ_OK + "l 2\n", ("line 5", "'l 2'", "at least two")),
    Case("obj-index-zero", "l0.obj", OBJ_OK + "l 0 1\n", ("line 5", "index 0", "start at 1")),
    Case("obj-index-out-of-range", "loor.obj", OBJ_OK + "# more\nl 3 9\n", ("line 6", "'l 3 9'", "vertex index 9", "3 vertices")),
    Case("obj-relative-out-of-range", "lrel.obj", "v 0 0 0 1\nv 1 0 0 1\nl -5 -1\n",
         ("line 3", "-5", "before the first vertex", "2 vertices")),
    Case("obj-index-float", "lf.obj", OBJ_OK + "l 1 2.5\n", ("line 5", "'2.5' is not a vertex index")),
    Case("obj-index-text", "lt.obj", OBJ_OK + "l 1 x\n", ("line 5", "'x' is not a vertex index")),
    Case("obj-self-loop", "lself.obj", OBJ_OK + "l 2 2\n", ("line 5", "'l 2 2'", "zero-length", "vertex 2 is joined to itself")),
    Case("obj-coincident", "lco.obj", "v 0 0 0 1\nv 1 1 1 1\nv 1 1 1 1\nl 1 2 3\n",
         ("line 4", "zero-length", "vertices 2 and 3", "[1.0, 1.0, 1.0]")),
    Case("obj-mixed-radii", "mixed.obj", "v 0 0 0 1\nv 0 0 10\nv 10 0 10 1\nl 1 2 3\n",
         ("line 2", "vertex 2 has no radius", "--radius")),
    Case("obj-no-radii", "norad.obj", "v 0 0 0\nv 0 0 10\nl 1 2\n", ("no vertex has a radius", "--radius")),
    Case("obj-unknown-statement", "unk.obj", OBJ_OK + "foo 1 2\n", ("line 5", "unknown OBJ statement", "'foo'")),
    Case("obj-point", "p.obj", OBJ_OK + "p 1\n", ("line 5", "'p 1'", "point")),
    Case("obj-curve", "curv.obj", OBJ_OK + "curv 0 1 1 2\n", ("line 5", "free-form")),
    Case("obj-no-lines", "nol.obj", "v 0 0 0 1\nv 1 0 0 1\n", ("no line elements",)),
    Case("obj-not-utf8", "bin.obj", b"v 0 0 0 1\n\x80\x81\n", ("line 2", "UTF-8", "0x80")),
]


def make(case: Case, directory: Path) -> Path:
    """Create the case's file in ``directory`` and return its path."""
    path = directory / case.name
    if case.content is DIR:
        path.mkdir()
    elif isinstance(case.content, bytes):
        path.write_bytes(case.content)
    elif case.content is not None:
        path.write_text(case.content, encoding="utf-8")
    return path


def random_skeleton(rng, n=30, m=60, degree=6, sigma=2.0) -> Skeleton:
    nodes = rng.normal(size=(n, 3)) * 10 ** rng.uniform(-3, 3, size=(n, 1))
    a = rng.integers(0, n, m)
    b = (a + rng.integers(1, n, m)) % n
    radii = rng.uniform(0.01, 1.0, size=(m, 2)) / 3.0
    return Skeleton(nodes, np.stack([a, b], axis=1), radii, degree, sigma)


def assert_same(s: Skeleton, t: Skeleton) -> None:
    for name in ("nodes", "segments", "radii"):
        x, y = getattr(s, name), getattr(t, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name
    assert (s.degree, s.sigma) == (t.degree, t.sigma)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case", BAD_CASES, ids=[c.id for c in BAD_CASES])
def test_bad_input_raises_scene_error_naming_file_entry_and_value(case, tmp_path):
    path = make(case, tmp_path)
    with pytest.raises(SceneError) as info:
        load_scene(path, radius=case.radius)
    msg = str(info.value)
    assert info.value.source == str(path)
    assert msg.startswith(f"{path}: "), msg
    for fragment in case.must:
        assert fragment in msg, f"{fragment!r} not in {msg!r}"
    assert "\n" not in msg
    assert isinstance(info.value, ValueError)


def test_bad_cases_are_unique():
    ids = [c.id for c in BAD_CASES]
    names = [c.name for c in BAD_CASES]
    assert len(set(ids)) == len(ids) and len(set(names)) == len(names)


@pytest.mark.parametrize("radius", [0, -1.0, float("nan"), float("inf"), True, "1"])
def test_bad_radius_argument(radius, tmp_path):
    path = tmp_path / "s.obj"
    path.write_text(OBJ_OK)
    with pytest.raises(SceneError, match="radius"):
        load_scene(path, radius=radius)


# ----------------------------------------------------------------------------- JSON reading
def test_json_minimal_and_kernel_defaults(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene())
    s = load_scene(p)
    assert s.source == str(p)
    assert s.nodes.tolist() == [[0, 0, 0], [0, 0, 10], [10, 0, 10], [10, 10, 10]]
    assert s.segments.tolist() == [[0, 1], [1, 2], [2, 3]]
    assert s.radii.tolist() == [[1.0, 0.5], [0.5, 0.75], [0.75, 2.0]]
    assert (s.degree, s.sigma) == (6, 2.0)


@pytest.mark.parametrize("kernel, expected", [
    ({}, (6, 2.0)), ({"degree": 4}, (4, 2.0)), ({"sigma": 3}, (6, 3.0)), ({"degree": 8, "sigma": 1.5}, (8, 1.5)),
])
def test_json_kernel_partial(kernel, expected, tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(kernel=kernel))
    s = load_scene(p)
    assert (s.degree, s.sigma) == expected
    assert type(s.sigma) is float


def test_segment_radii_win_over_radii(tmp_path):
    p = tmp_path / "s.json"
    seg_r = [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]
    p.write_text(scene(segment_radii=seg_r))
    assert load_scene(p).radii.tolist() == seg_r
    p.write_text(scene(drop=("radii",), segment_radii=seg_r))
    assert load_scene(p).radii.tolist() == seg_r
    # the losing "radii" is still validated
    p.write_text(scene(radii=[1, 1, -1, 1], segment_radii=seg_r))
    with pytest.raises(SceneError, match=r"radii\[2\] = -1"):
        load_scene(p)


def test_json_radius_argument_is_a_default_only(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(drop=("radii",)))
    assert load_scene(p, radius=0.25).radii.tolist() == [[0.25, 0.25]] * 3
    p.write_text(scene())  # the file's radii win
    assert load_scene(p, radius=0.25).radii.tolist() == [[1.0, 0.5], [0.5, 0.75], [0.75, 2.0]]


@pytest.mark.parametrize("units, factor", [("mm", 1.0), ("um", 1e-3), ("cm", 10.0), ("m", 1000.0), ("in", 25.4)])
def test_units_are_converted_to_mm(units, factor, tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(units=units))
    s = load_scene(p)
    np.testing.assert_allclose(s.nodes, np.array(BASE["nodes"]) * factor, rtol=1e-15)
    np.testing.assert_allclose(s.radii[:, 0], np.array(BASE["radii"])[:3] * factor, rtol=1e-15)
    # the radius argument is in mm whatever the file's units
    p.write_text(scene(units=units, drop=("radii",)))
    assert load_scene(p, radius=0.3).radii.tolist() == [[0.3, 0.3]] * 3


def test_metadata_and_x_keys_are_ignored(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(metadata={"name": "cube", "author": [1, 2]}, **{"x-tool": {"v": 3}, "x-": None}))
    assert load_scene(p).n_segments == 3


def test_json_accepts_bom_pathlike_and_str(tmp_path):
    p = tmp_path / "s.JSON"
    p.write_bytes(b"\xef\xbb\xbf" + scene().encode())
    assert load_scene(p).n_segments == 3
    assert load_scene(str(p)).n_segments == 3


def test_json_unused_nodes_and_integer_coordinates(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(nodes=BASE["nodes"] + [[5, 5, 5]], radii=[1, 1, 1, 1, 1]))
    s = load_scene(p)
    assert s.n_nodes == 5 and s.nodes.dtype == np.float64


# ----------------------------------------------------------------------------- OBJ reading
def test_obj_polylines_relative_indices_and_ignored_statements(tmp_path):
    text = (
        "# exported by hand\n"
        "mtllib x.mtl\no lattice\ng struts\ns off\nusemtl steel\n"
        "v 0 0 0 0.5\n"
        "v 0 0 10 0.5   # inline comment\n"
        "vn 0 0 1\nvt 0 0\nvp 0.5\n"
        "v 10 0 10 \\\n  0.25\n"          # continuation line
        "\n"
        "l 1 2 3\n"                        # polyline: two segments
        "v 10 10 10 0.75\n"
        "l -2 -1\n"                        # relative: vertices 3 and 4
        "l 4/1 1/2\n"                      # v/vt form
        "l 5 1\n"                          # forward absolute reference
        "v 20 20 20 1.0\n"
    )
    p = tmp_path / "s.obj"
    p.write_text(text)
    s = load_scene(p)
    assert s.segments.tolist() == [[0, 1], [1, 2], [2, 3], [3, 0], [4, 0]]
    assert s.nodes.tolist()[2] == [10, 0, 10]
    assert s.radii.tolist() == [[0.5, 0.5], [0.5, 0.25], [0.25, 0.75], [0.75, 0.5], [1.0, 0.5]]
    assert (s.degree, s.sigma) == (6, 2.0)


def test_obj_crlf_and_uppercase_suffix(tmp_path):
    p = tmp_path / "S.OBJ"
    p.write_bytes(OBJ_OK.replace("\n", "\r\n").encode())
    assert load_scene(p).segments.tolist() == [[0, 1], [1, 2]]


def test_obj_radius_argument_fills_missing_radii_and_file_radii_win(tmp_path):
    p = tmp_path / "s.obj"
    p.write_text("v 0 0 0\nv 0 0 10 2.0\nv 10 0 10\nl 1 2 3\n")
    s = load_scene(p, radius=0.5)
    assert s.radii.tolist() == [[0.5, 2.0], [2.0, 0.5]]
    p.write_text("v 0 0 0\nv 0 0 10\nl 1 2\n")
    assert load_scene(p, radius=0.5).radii.tolist() == [[0.5, 0.5]]


def test_obj_unused_vertex_without_radius_is_fine(tmp_path):
    p = tmp_path / "s.obj"
    p.write_text(OBJ_OK + "v 50 50 50\n")
    assert load_scene(p).n_nodes == 4


# ----------------------------------------------------------------------------- writing
@pytest.mark.parametrize("seed", range(5))
def test_json_round_trip_is_bit_exact(seed, tmp_path):
    rng = np.random.default_rng(seed)
    s = random_skeleton(rng, degree=int(rng.choice([2, 4, 6, 8, 16])), sigma=float(rng.uniform(1.01, 5)))
    p = tmp_path / "s.json"
    save_scene(s, p)
    assert_same(s, load_scene(p))
    json.loads(p.read_text())  # strict JSON (no NaN literals)


def test_json_round_trip_awkward_floats(tmp_path):
    # the awkward floats within the scene limits (docs/scene-format.md, "Limits"): subnormal and
    # signed-zero coordinates, 17-digit values, the largest coordinate and radius magnitude
    nodes = [[0.1 + 0.2, 1 / 3, -0.0], [5e-324, 1e8, -1.2345678901234567e8], [2.0 ** -1074 * 3, 1e-300, 7.0]]
    s = Skeleton(nodes, [[0, 1], [1, 2]], [[1.0000000000000002, 1e9], [1 / 7, 2.0 ** 0.5]], 4, 1.0000000000000002)
    p = tmp_path / "s.json"
    s.save(p)
    assert_same(s, load_scene(p))


@pytest.mark.parametrize("seed", range(3))
def test_obj_round_trip_is_exact_when_nodes_have_one_radius(seed, tmp_path):
    rng = np.random.default_rng(seed)
    n, m = 20, 40
    nodes = rng.normal(size=(n, 3)) * 7
    a = rng.integers(0, n, m)
    seg = np.stack([a, (a + rng.integers(1, n, m)) % n], axis=1)
    node_r = rng.uniform(0.01, 0.3, n) / 3
    s = Skeleton(nodes, seg, node_r[seg])
    p = tmp_path / "s.obj"
    save_scene(s, p)
    t = load_scene(p)
    assert_same(s, t)


def test_obj_round_trip_with_per_segment_radii_keeps_the_surface(tmp_path):
    s = random_skeleton(np.random.default_rng(7))
    p = tmp_path / "s.obj"
    save_scene(s, p)
    t = load_scene(p)
    assert t.n_segments == s.n_segments and t.n_nodes >= s.n_nodes
    sa, sb = s.endpoints()
    ta, tb = t.endpoints()
    assert sa.tobytes() == ta.tobytes() and sb.tobytes() == tb.tobytes()
    assert s.radii.tobytes() == t.radii.tobytes()
    assert t.nodes[: s.n_nodes].tobytes() == s.nodes.tobytes()


def test_obj_writer_refuses_a_non_default_kernel(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]], 4, 2.0)
    with pytest.raises(OutputError, match="kernel.*json"):
        save_scene(s, tmp_path / "s.obj")
    assert not list(tmp_path.iterdir())


def test_save_rejects_unknown_suffix_and_empty_scene(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    with pytest.raises(OutputError, match=r"unknown scene file type '\.txt'"):
        save_scene(s, tmp_path / "s.txt")
    with pytest.raises(OutputError, match="no segments"):
        save_scene(Skeleton(np.zeros((0, 3)), np.zeros((0, 2), int), np.zeros((0, 2))), tmp_path / "e.json")
    assert not list(tmp_path.iterdir())


def test_save_replaces_atomically_and_cleans_up_on_failure(tmp_path, monkeypatch):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    p = tmp_path / "s.json"
    p.write_text("old")
    save_scene(s, p)
    assert load_scene(p).n_segments == 1
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.json"]
    before = p.read_bytes()

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match="No space left on device") as info:
        save_scene(Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[1, 1]]), p)
    assert str(p) in str(info.value)
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.json"]


def test_save_into_missing_directory(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    with pytest.raises(OutputError, match="No such file or directory"):
        save_scene(s, tmp_path / "nope" / "s.json")


def test_saved_file_has_default_permissions(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    p = tmp_path / "s.json"
    save_scene(s, p)
    umask = os.umask(0)
    os.umask(umask)
    assert p.stat().st_mode & 0o777 == 0o666 & ~umask


# ----------------------------------------------------------------------------- fuzz
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _load_or_scene_error(path: Path, text, radius=None):
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        s = load_scene(path, radius=radius)
    except SceneError as exc:
        assert str(exc).startswith(f"{path}: ")
        return None
    assert isinstance(s, Skeleton) and s.n_segments > 0
    return s


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 10) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=3),
    max_leaves=12,
)


@FUZZ
@given(st.text(alphabet=string.printable + "\x00\u00e9\u2028", max_size=200), st.sampled_from([".json", ".obj"]))
def test_fuzz_random_text(tmp_path, text, suffix):
    _load_or_scene_error(tmp_path / ("fuzz" + suffix), text)


@FUZZ
@given(st.data())
def test_fuzz_garbled_valid_files(tmp_path, data):
    suffix = data.draw(st.sampled_from([".json", ".obj"]))
    text = scene(kernel={"degree": 6, "sigma": 2.0}) if suffix == ".json" else OBJ_OK + "v 1 1 1 0.5\nl 4 -2\n"
    chars = list(text)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(chars)))
        op = data.draw(st.sampled_from(["delete", "insert", "replace"]))
        c = data.draw(st.sampled_from(list('0123456789.-+eE[]{},:" \n/#ablvfnNI')))
        if op == "insert":
            chars.insert(i, c)
        elif chars and i < len(chars):
            if op == "delete":
                del chars[i]
            else:
                chars[i] = c
    radius = data.draw(st.sampled_from([None, 0.5]))
    _load_or_scene_error(tmp_path / ("garbled" + suffix), "".join(chars), radius)


@FUZZ
@given(st.data())
def test_fuzz_structured_json(tmp_path, data):
    d = json.loads(scene(segment_radii=[[1, 1], [1, 1], [1, 1]], kernel={"degree": 6, "sigma": 2.0}))
    for _ in range(data.draw(st.integers(1, 3))):
        key = data.draw(st.sampled_from(sorted(d) + ["extra", "x-extra"]))
        target = d
        value = d.get(key)
        # descend into nested lists/dicts of the chosen key now and then
        while isinstance(value, (list, dict)) and value and data.draw(st.booleans()):
            target, key = value, data.draw(st.sampled_from(list(range(len(value))) if isinstance(value, list)
                                                           else sorted(value)))
            value = target[key]
        target[key] = data.draw(json_values)
    _load_or_scene_error(tmp_path / "structured.json", json.dumps(d))


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(["v", "l", "f", "vn", "o", "#", "", "p", "v/", "\\"]),
                          st.lists(st.sampled_from(["0", "1", "-1", "2", "3", "-2", "1.5", "-0.5", "1e3", "nan",
                                                    "x", "1/2", "//", "0.0", "4"]), max_size=5)),
                max_size=12),
       st.sampled_from([None, 1.0]))
def test_fuzz_obj_statements(tmp_path, lines, radius):
    text = "\n".join(" ".join([k, *args]) for k, args in lines)
    _load_or_scene_error(tmp_path / "tokens.obj", text, radius)


# ----------------------------------------------------------------------------- float64 limits
_LIMIT_CASES = [
    ('{"skelslice": 1, "units": "m", "nodes": [[0, 0, 0], [0, 0, 1e7]], "segments": [[0, 1]], "radii": [1, 1]}',
     ".json", "nodes[1][2] = 1e+10 mm is beyond the supported magnitude 1e+09 mm"),
    ('{"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1]], "segments": [[0, 1]], '
     '"segment_radii": [[1, 5e-324]]}', ".json", "segment_radii[0][1] = 5e-324 mm is below the smallest supported "
                                                  "radius 1e-09 mm"),
    ('{"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1], [0, 0, 2]], "segments": [[0, 1], [1, 2]], '
     '"radii": [1, 1, 1e12]}', ".json", "radii[2] = 1e+12 mm is beyond"),
    ("v 0 0 0 1e-6\nv 1e5 0 0 1\nl 1 2\n", ".obj",
     "line 2: vertex 2 x = 100000.0 mm is more than 1e+09 times the smallest radius (line 1: vertex 1 radius = "
     "1e-06 mm)"),
    ("v 0 0 0 1\nv 1e308 0 0 1\nl 1 2\n", ".obj", "line 2: vertex 2 x = 1e+308 mm is beyond"),
]


@pytest.mark.parametrize("text,suffix,needle", _LIMIT_CASES)
def test_numbers_float64_cannot_resolve_are_refused_by_name(text, suffix, needle, tmp_path):
    """docs/scene-format.md "Limits": the entry, its value (as people write it) and the limit."""
    p = tmp_path / f"s{suffix}"
    p.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(p)
    assert needle in str(exc.value) and str(p) in str(exc.value), str(exc.value)
    assert len(str(exc.value)) < 400


def test_numbers_at_the_limits_are_read(tmp_path):
    """Coordinates of 1e9 mm with a 1 mm strut, radii of 1e-9 mm near the origin, subnormal and
    signed-zero coordinates: inside the limits, read exactly."""
    p = tmp_path / "s.json"
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[1e9, 0, 0], [1e9, 0, 5], [-0.0, 5e-324, 0], '
                 '[0, 0, 1e-6]], "segments": [[0, 1], [2, 3]], "segment_radii": [[1, 1], [1e-9, 1e-9]]}')
    with pytest.raises(SceneError, match="more than 1e\\+09 times the smallest radius"):
        load_scene(p)                    # 1e9 mm is 1e18 times the 1e-9 mm strut
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[1e9, 0, 0], [1e9, 0, 5]], "segments": [[0, 1]], '
                 '"radii": [1, 1]}')
    assert load_scene(p).nodes[0, 0] == 1e9
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[-0.0, 5e-324, 0], [0, 0, 1e-6]], "segments": [[0, 1]], '
                 '"radii": [1e-9, 1e-9]}')
    s = load_scene(p)
    assert s.nodes[0, 1] == 5e-324 and s.radii.min() == 1e-9
