"""Pieces the tests share, so that no test module imports another (tests/test_structure.py).

* The CLI through click's ``CliRunner``: :func:`run`, :func:`assert_refused`
  (exit status 2, a message, no traceback).
* :func:`missing_tool`: skip, or fail with ``SKELSLICE_REQUIRE_READERS`` set,
  where an external tool is missing (the fixtures of tests/conftest.py use it too).
* Bad scene files: :data:`BAD_CASES` (one :class:`Case` per kind of bad input),
  :func:`make` to write one, and the JSON scene they vary (:data:`BASE`,
  :func:`scene`, :func:`with_node`, :func:`with_segment`, :data:`OBJ_OK`);
  read by tests/test_scene_io.py and through the CLI by tests/test_cli_errors.py.
* The tracer's stiff scenes: :data:`CASES` (name -> skeleton, pixel size, layer
  height) and :func:`_node26`; tests/test_trace.py, test_spans.py,
  test_union_trace.py.
* One tapered segment along a ray, through the tracer's kernels: :class:`Ray`,
  :func:`check_ray` (support, unimodality and piece bounds against dense
  samples, arbitrated by the extended-precision reference) and the Hypothesis
  strategy :func:`rays`; tests/test_ray_unimodal.py, test_trace.py,
  test_lazy_bounds.py.

The shared fixtures (``ell``, ``checker``, ``uv3dp``) are in tests/conftest.py; the
independent format readers are in tests/format_readers.py.
"""
from __future__ import annotations

import itertools
import json
import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import strategies as st

from slicer import Skeleton
from slicer._kernels.field.segment import SCRATCH
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT, kprime_max, lipschitz, ray_support
from slicer._kernels.rays.walk import eval_along, piece_bounds
from slicer._kernels.runtime.launch import serial
from slicer.cli.app import main
from slicer.model.field import segment_table
from validation import reference_field as ref


# ----------------------------------------------------------------------------- the CLI
def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_refused(r, *needles):
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert "Traceback" not in r.output
    for n in needles:
        assert n in r.output, (n, r.output)

# ----------------------------------------------------------------------------- missing tools
def missing_tool(reason: str) -> None:
    """Skip (or, with ``SKELSLICE_REQUIRE_READERS`` set, fail) for a missing toolchain."""
    if os.environ.get("SKELSLICE_REQUIRE_READERS", "").strip() not in ("", "0"):
        pytest.fail(f"{reason}; SKELSLICE_REQUIRE_READERS is set, so every reader must run")
    pytest.skip(reason)

# ----------------------------------------------------------------------------- bad scene files
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

# ----------------------------------------------------------------------------- the tracer's stiff scenes
def _scene(nodes, segs, radii):
    return Skeleton(np.asarray(nodes, float), np.asarray(segs), np.asarray(radii, float))


CASES = {
    # a vertical strut whose axis is exactly a pixel column: the ray runs along the axis
    "vertical_on_column": (_scene([[0, 0, 0], [0, 0, 3]], [[0, 1]], [[0.5, 0.5]]), 0.1, 0.1),
    # horizontal struts lying exactly in a layer plane (z = 1.0 is a layer centre)
    "horizontal_on_layer": (_scene([[-2, 0, 1.0], [2, 0, 1.0], [0, -2, 1.0], [0, 2, 1.0]],
                                   [[0, 1], [2, 3]], [[0.4, 0.4], [0.3, 0.5]]), 0.1, 0.1),
    "near_constant_taper": (_scene([[0, 0, 0], [2, 1, 2]], [[0, 1]], [[0.4, 0.4 * (1 + 1e-9)]]), 0.08, 0.07),
    "cone_ratio_100": (_scene([[0, 0, 0], [0.5, 0.3, 3]], [[0, 1]], [[0.01, 1.0]]), 0.08, 0.08),
    "thinner_than_pixel": (_scene([[0, 0, 0], [1.5, 0.7, 2.0], [0, 0, 0], [-1, 1, 1]],
                                  [[0, 1], [2, 3]], [[0.03, 0.03], [0.02, 0.04]]), 0.1, 0.1),
    "offset_5000mm": (_scene(np.array([[0, 0, 0], [1, 2, 2.5], [2, 0, 1]]) + 5000.0, [[0, 1], [1, 2]],
                             [[0.3, 0.5], [0.5, 0.25]]), 0.1, 0.09),
    "lone_short_strut": (_scene([[0, 0, 0], [0.3, 0, 0.2]], [[0, 1]], [[0.6, 0.6]]), 0.05, 0.05),
}


def _node26():
    dirs = [d for d in itertools.product((-1, 0, 1), repeat=3) if d != (0, 0, 0)]
    nodes = [[0.0, 0.0, 0.0]] + [list(1.6 * np.array(d, float)) for d in dirs]
    segs = [[0, i + 1] for i in range(26)]
    radii = [[0.25, 0.12]] * 26
    return _scene(nodes, segs, radii)


CASES["node_26_struts"] = (_node26(), 0.1, 0.1)
# a strut whose support cone has a vertical generator (horizontal extent = sigma (r1 - r0),
# A = 3e-17 for slicing rays) blended with a horizontal one: the support entry of its
# rays used to come up to 0.1 of the field late, 10 voxels misclassified
_H = 0.4 / np.sqrt(2)
CASES["critical_taper_blend"] = (_scene([[0, 0, 0], [_H, _H, 1.0], [-1, 0.6, 0.3], [2, 0.6, 0.3]], [[0, 1], [2, 3]],
                                        [[0.1, 0.3], [0.2, 0.2]]), 0.04, 0.04)

# ----------------------------------------------------------------------------- one segment along a ray
#: samples of the field on [t_in, t_out] (and on each piece)
DENSE = 3001
PIECE = 301
#: monotonicity departures below this fraction of the peak are not examined
NOISE = 1e-12
#: the compiled field's accuracy relative to the reference (tests/test_field.py,
#: validation/stiff.py: 1e-10; degree 16: 5e-9)
REL, REL16 = 1e-10, 5e-9
#: the compiled field's absolute accuracy (as in :func:`arbitrate`): where a ray only grazes a
#: support (tangent to it), the closed form and the reference give zero only to rounding
#: (values of 1e-24 to 1e-22 on a degree-2 kernel), so "no field" means "at most this"
FIELD_ZERO = 1e-14


class Ray:
    """One segment and one ray ``o + t d``, with the kernels' view of them."""

    def __init__(self, skel: Skeleton, o, d):
        self.skel = skel
        self.o = np.asarray(o, float)
        self.d = np.asarray(d, float)
        self.seg = segment_table(skel)
        n, sigma, norm = skel.degree, skel.sigma, skel.normalisation
        self.rec = np.zeros((1, NHIT))
        self.hit = ray_support(self.seg, 0, *self.o, *self.d, n, sigma, norm, kprime_max(n, sigma, norm),
                               self.rec, 0)

    def points(self, t):
        return self.o + np.asarray(t, float)[:, None] * self.d

    def field(self, t):
        return self.skel.field(self.points(t))

    def slope(self, t):
        return self.skel.gradient(self.points(t)) @ self.d

    def exact(self, t):
        """The extended-precision reference at ``o + t d``."""
        s = self.skel
        a, b = s.nodes[s.segments[0, 0]], s.nodes[s.segments[0, 1]]
        f = ref.segment_field(a, b, s.radii[0, 0], s.radii[0, 1], self.points(t), degree=s.degree, sigma=s.sigma)
        return np.asarray(f[0] if isinstance(f, tuple) else f, dtype=float)

    def piece(self, ta, tb, strict):
        """piece_bounds for [ta, tb], the ends evaluated with eval_along."""
        s = self.skel
        hprim = np.zeros(1, np.int64)
        sarr = np.zeros(1, np.int64)
        F = np.zeros((2, 1))
        FP = np.zeros((2, 1))
        ct = np.full(1, np.nan)
        cf = np.zeros(1)
        cfp = np.zeros(1)
        scratch = np.empty(SCRATCH)
        for row, t in enumerate((ta, tb)):
            eval_along(self.seg, hprim, self.rec, sarr, 1, (*self.o, *self.d), t,
                       (s.degree // 2, 1.0 / s.sigma**2, s.normalisation), scratch, F, FP, row, (ct, cf, cfp))
        return piece_bounds(self.rec, sarr, 1, F, FP, 0, 1, ta, tb, strict), (F[0, 0], F[1, 0])

    def describe(self):
        s = self.skel
        return (f"Skeleton({s.nodes.tolist()}, [[0, 1]], {s.radii.tolist()}, degree={s.degree}, "
                f"sigma={s.sigma}); o = {self.o.tolist()}, d = {self.d.tolist()}")


def _monotone_violations(f, sign, scale):
    """Indices i where f[i + 1] - f[i] goes against ``sign`` by more than NOISE * scale."""
    df = np.diff(f)
    return np.flatnonzero(sign * df < -(NOISE * scale + FIELD_ZERO))


def arbitrate(ray, t, f, what):
    """The reference at ``t``, after checking that the compiled samples ``f``
    are within the compiled field's documented accuracy of it (so that a
    departure from monotonicity in ``f`` may be put down to rounding)."""
    fr = ray.exact(t)
    rel = REL16 if ray.skel.degree >= 16 else REL
    err = np.abs(f - fr)
    assert np.all(err <= rel * np.abs(fr) + 1e-14), (
        f"{what}: compiled field {f.tolist()} vs reference {fr.tolist()} at t = {t.tolist()}: "
        f"error {err.max()!r} beyond {rel:g} relative; {ray.describe()}")
    return fr


def assert_monotone(ray, t, f, sign, scale, what):
    """``f`` sampled at ``t`` is monotone in the direction ``sign`` (+1 up, -1
    down); departures beyond NOISE are re-examined with the reference."""
    for i in _monotone_violations(f, sign, scale)[:4]:
        w = np.arange(max(0, i - 3), min(len(t), i + 5))
        fr = arbitrate(ray, t[w], f[w], what)
        assert np.all(sign * np.diff(fr) >= -(NOISE * scale + FIELD_ZERO)), (
            f"{what}: the field is not monotone ({'up' if sign > 0 else 'down'}) near t = {t[i]!r}: "
            f"reference {fr.tolist()}; {ray.describe()}")


def assert_unimodal(ray, t, f, what):
    """Non-decreasing up to the largest sample, non-increasing after it."""
    fm = float(f.max())
    im = int(np.argmax(f))
    near = 4                                  # the peak's neighbourhood: noise decides the argmax there
    lo, hi = max(0, im - near), min(len(t), im + near + 1)
    assert_monotone(ray, t[:lo + 1], f[:lo + 1], +1, fm, what)
    assert_monotone(ray, t[hi - 1:], f[hi - 1:], -1, fm, what)
    def one_peak(v):
        k = int(np.argmax(v))
        return np.all(np.diff(v[:k + 1]) >= -(NOISE * fm + FIELD_ZERO)) and np.all(np.diff(v[k:]) <= NOISE * fm + FIELD_ZERO)

    if not one_peak(f[lo:hi]):
        fr = arbitrate(ray, t[lo:hi], f[lo:hi], what)
        assert one_peak(fr), (f"{what}: two maxima near the peak t = {t[im]!r}: reference {fr.tolist()}; "
                              f"{ray.describe()}")


def check_ray(ray: Ray, pieces=()):
    """Every property of tests/test_ray_unimodal.py's docstring for one ray; ``pieces`` are
    extra fractions (u, v) of [t_in, t_out] delimiting pieces to test.
    Returns the field sampled on [t_in, t_out] (None for a miss)."""
    with serial():                  # many small batches: no thread-pool wake-up per call
        return _check_ray(ray, pieces)


def _check_ray(ray, pieces):
    L = ray.seg[0, 6]
    reach = L + 2 * ray.skel.sigma * ray.seg[0, 9]
    if not ray.hit:
        t = np.linspace(-reach, 2 * reach, DENSE)
        assert ray.field(t).max() <= FIELD_ZERO, f"ray_support missed a ray the field reaches; {ray.describe()}"
        return None
    tin, tout, tstar, fmax = (ray.rec[0, k] for k in (H_TIN, H_TOUT, H_TSTAR, H_FMAX))
    assert tin < tout
    # nothing of the field outside [t_in, t_out]
    outside = np.concatenate([np.linspace(tin - reach, tin, 400), np.linspace(tout, tout + reach, 400)])
    f_out = ray.field(outside)
    assert f_out.max() <= FIELD_ZERO, (f"field {f_out.max()!r} at t = {outside[np.argmax(f_out)]!r} outside "
                                f"[t_in, t_out] = [{tin!r}, {tout!r}]; {ray.describe()}")
    t = np.linspace(tin, tout, DENSE)
    f = ray.field(t)
    assert f.max() <= fmax + FIELD_ZERO, f"field {f.max()!r} above H_FMAX {fmax!r}; {ray.describe()}"
    if f.max() <= FIELD_ZERO:
        return f
    assert_unimodal(ray, t, f, "whole ray")
    cuts = [(tin, tstar), (tstar, tout), (tin, tout)]
    cuts += [(tin + u * (tout - tin), tin + (u + v * (1 - u)) * (tout - tin)) for u, v in pieces]
    for ta, tb in cuts:
        if not (tin <= ta < tb <= tout):
            continue
        check_piece(ray, ta, tb, float(f.max()))
    return f


def check_piece(ray, ta, tb, peak):
    tp = np.linspace(ta, tb, PIECE)
    fp = ray.field(tp)
    slack = 1e-9 * peak + 1e-300                   # the compiled field's own rounding
    for strict in (False, True):
        (lo, hi, mono), (f0, f1) = ray.piece(ta, tb, strict)
        what = f"piece [{ta!r}, {tb!r}] strict={strict}"
        assert fp.min() >= lo - slack and fp.max() <= hi + slack, (
            f"{what}: samples {fp.min()!r}..{fp.max()!r} outside the bounds [{lo!r}, {hi!r}]; {ray.describe()}")
        if strict:
            assert mono == 0
        elif mono:
            assert_monotone(ray, tp, fp, mono, peak, what + f" (called monotone {mono:+d})")
    K = lipschitz(ray.rec, 0, ta, tb)
    slope = np.abs(ray.slope(tp))
    assert slope.max() <= K * (1 + 1e-9) + 1e-12, (
        f"piece [{ta!r}, {tb!r}]: slope {slope.max()!r} above the Lipschitz bound {K!r}; {ray.describe()}")


# ----------------------------------------------------------------------------- random rays
def _unit(v):
    return v / np.linalg.norm(v)


def _direction(z, phi):
    s = math.sqrt(max(0.0, 1.0 - z * z))
    return np.array([s * math.cos(phi), s * math.sin(phi), z])


FAMILIES = ["general", "nested", "critical_E", "critical_A", "axis", "thin_tip"]


@st.composite
def rays(draw):
    """A segment (taper ratio 1..1e4, optionally nested or critical) and a ray
    through (or near) its support."""
    family = draw(st.sampled_from(FAMILIES))
    degree = draw(st.sampled_from([2, 4, 6, 8, 16]))
    sigma = draw(st.sampled_from([1.25, 2.0, 3.0]))
    r1 = 10 ** draw(st.floats(-1.3, 0.0))
    ratio = 10 ** draw(st.floats(0.0, 4.0))
    r0 = r1 / ratio
    if family == "nested":                                   # sigma (r1 - r0) > L
        L = sigma * (r1 - r0) * draw(st.floats(0.05, 0.999))
    elif family == "critical_E":                             # L = sigma (r1 - r0), to rounding
        L = sigma * (r1 - r0) * (1 + draw(st.sampled_from([0.0, 1e-15, -1e-15, 1e-9, -1e-9])))
    else:
        L = 10 ** draw(st.floats(-1.3, 0.7))
        if family == "critical_A" and not sigma * (r1 - r0) < 0.95 * L:
            L = sigma * (r1 - r0) * draw(st.floats(1.05, 20.0))
    if not L > 1e-4 * r1:
        L = 1e-4 * r1 + sigma * (r1 - r0)
    u = _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi)))
    a = np.array([draw(st.floats(-1, 1)) for _ in range(3)])
    b = a + L * u
    flip = draw(st.booleans())
    skel = Skeleton([b, a] if flip else [a, b], [[0, 1]], [[r1, r0]] if flip else [[r0, r1]], degree, sigma)
    seg = segment_table(skel)
    A0, U, Ls, dtau = seg[0, 0:3], seg[0, 3:6], seg[0, 6], seg[0, 8] * seg[0, 6]
    side = _unit(np.cross(U, _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi))) + 1e-3))
    if family == "critical_A":
        # sin(angle to the axis) = sigma dtau / L: A = |D|^2 - (D.d)^2 - sigma^2 dtau^2 = 0
        sn = sigma * dtau / Ls * (1 + draw(st.sampled_from([0.0, 1e-14, -1e-14, 1e-8, -1e-8, 1e-4, -1e-4])))
        d = math.sqrt(1 - sn * sn) * U + sn * side
    elif family == "axis":
        d = _unit(U + draw(st.sampled_from([0.0, 1e-9, 1e-4, 1e-2])) * side)
    else:
        d = _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi)))
    if draw(st.booleans()):
        d = -d
    s = 0.0 if family == "thin_tip" else draw(st.floats(-0.1, 1.1))
    tau = seg[0, 7] + dtau * min(max(s, 0.0), 1.0)
    off = _unit(np.cross(d, side) + 1e-3 * side) * sigma * tau * draw(st.floats(0.0, 1.1))
    q = A0 + s * Ls * U + off
    o = q - (Ls + 2 * sigma * seg[0, 9]) * d
    pieces = draw(st.lists(st.tuples(st.floats(0, 1), st.floats(0.001, 1)), min_size=2, max_size=4))
    return family, Ray(skel, o, d), pieces
