"""Hostile inputs for the CLI fuzz suite (tests/test_fuzz_cli.py), and the check every run must pass.

Strategies
----------
* Numbers: extreme, subnormal, signed-zero, NaN, infinite and huge floats, huge and
  negative integers (:data:`HOSTILE_FLOATS`, :data:`HOSTILE_INTS`), mixed with ordinary
  values; option values as command-line text (``"1e309"``, ``"nan"``, ``"abc"``).
* Scenes: JSON (versions 1 and 2 with mesh parts: missing, extra and mistyped keys, hostile
  numbers anywhere, truncated text), OBJ polylines (hostile tokens and indices) and 3MF
  beam lattices written by hand (hostile attributes, units, missing attributes).

Ordinary values are kept small (coordinates within 1 mm, radii 0.1..0.3 mm, pixels >= 0.1 mm),
and hostile values are the edges: refused, or trivially cheap (a pixel of 1e9 mm). So every
run that is accepted does little work, and the suite stays bounded in time.

:func:`check_run` is the property: exit status 0 or 2 (1 where the command documents it), no
traceback, nothing left behind on exit 2 (no output, no hidden ``.NAME.tmp-*``).

Profiles (registered in tests/conftest.py): ``ci`` (derandomised, the default for this suite)
and ``fuzz-long`` (``pytest --hypothesis-profile=fuzz-long``: random, :data:`LONG_FACTOR` times
the examples).
"""
from __future__ import annotations

import io
import json
import math
import os
import traceback
import zipfile
from dataclasses import dataclass
from pathlib import Path

from hypothesis import settings
from hypothesis import strategies as st

#: examples per test in ``fuzz-long`` relative to ``ci``
LONG_FACTOR = 25
#: runs per command and exit status (printed at the end of the session by tests/conftest.py)
RUNS: dict[str, dict[int, int]] = {}

HOSTILE_FLOATS = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1e-300, 1e-12, 1e-9, 1e9,
                  1.0000001e9, 1e10, 1e154, 1e300, -1e300, 1.7976931348623157e308,
                  -1.7976931348623157e308, math.nan, math.inf, -math.inf]
HOSTILE_INTS = [0, -1, -7, 2**31, -2**31, 2**53 + 1, 2**63, -2**63 - 1, 10**30, 10**400]
#: option values as text: what a user or a script could type
HOSTILE_TEXT = ["nan", "NaN", "inf", "-inf", "+inf", "0", "-0", "-0.0", "-1", "5e-324", "1e-300", "1e-12",
                "1e300", "1e309", "-1e309", "1e9", "1e10", "1e400", "0x10", "1_000", "abc", "", " ", "1,5",
                "9" * 400]
HOSTILE_INT_TEXT = ["0", "-1", "-2147483649", "4294967296", "18446744073709551616", "1e3", "2.5", "nan",
                    "abc", "", "9" * 400]


def fuzz_settings(n: int) -> settings:
    """Settings of one fuzz test with ``n`` examples under ``ci`` (the default here, whatever
    profile the session loaded) or ``n * LONG_FACTOR`` under ``fuzz-long``."""
    if settings.get_current_profile_name() == "fuzz-long":
        return settings(settings.get_profile("fuzz-long"), max_examples=n * LONG_FACTOR)
    return settings(settings.get_profile("ci"), max_examples=n)


# ----------------------------------------------------------------------------- numbers
def hostile_float() -> st.SearchStrategy:
    return st.sampled_from(HOSTILE_FLOATS)


def rarely(draw, n: int) -> bool:
    """True about once in ``n`` draws (False is what Hypothesis tries first and shrinks to)."""
    return draw(st.sampled_from([False] * (n - 1) + [True]))


def mostly(ordinary: st.SearchStrategy, hostile: st.SearchStrategy, n: int = 4) -> st.SearchStrategy:
    """``ordinary`` n - 1 times in n, else ``hostile`` (ordinary is what Hypothesis shrinks to)."""
    return st.sampled_from([False] * (n - 1) + [True]).flatmap(lambda h: hostile if h else ordinary)


@dataclass(frozen=True)
class Opt:
    """An option's values: ``ordinary`` ones (accepted, cheap) and ``hostile`` ones.

    :meth:`pick` draws ordinary values only in a run that is meant to succeed, and ordinary
    or (one time in six) hostile values in a hostile run, so both accepted and refused runs
    are frequent.
    """

    ordinary: st.SearchStrategy
    hostile: st.SearchStrategy

    def pick(self, hostile: bool) -> st.SearchStrategy:
        return mostly(self.ordinary, self.hostile, 6) if hostile else self.ordinary


def text_number(lo: float, hi: float, extra=()) -> Opt:
    """An option value as text: an ordinary number in [lo, hi], or hostile text."""
    return Opt(st.floats(lo, hi).map(repr), st.sampled_from(HOSTILE_TEXT + list(extra)))


def text_int(lo: int, hi: int) -> Opt:
    """An integer option as text: ordinary in [lo, hi], or hostile text."""
    return Opt(st.integers(lo, hi).map(str), st.sampled_from(HOSTILE_INT_TEXT))


def opt_tuple(*opts: Opt) -> Opt:
    """Several values of one option (``--at X Y``), each hostile now and then in a hostile run."""
    return Opt(st.tuples(*[o.ordinary for o in opts]), st.tuples(*[mostly(o.ordinary, o.hostile, 3) for o in opts]))


def choice(ordinary: list, hostile: list) -> Opt:
    """A named value: one of ``ordinary``, or one of ``hostile``."""
    return Opt(st.sampled_from(ordinary), st.sampled_from(hostile))


def mistyped() -> st.SearchStrategy:
    """A JSON value of the wrong kind."""
    return st.sampled_from(["x", "", "1.0", True, False, None, [], {}, [1, 2], {"a": 1}, 1.5, -1, 10**400])


# ----------------------------------------------------------------------------- scene files
COORD = st.floats(-1.0, 1.0)
RADIUS = st.floats(0.1, 0.3)

#: a closed box, ASCII STL (mm), for scene version 2 mesh parts
BOX_STL = """solid box
""" + "".join(
    f"facet normal 0 0 0\n outer loop\n" + "".join(f"  vertex {x} {y} {z}\n" for x, y, z in tri)
    + " endloop\nendfacet\n"
    for tri in [
        ((-1, -1, -1), (-1, 1, -1), (1, 1, -1)), ((-1, -1, -1), (1, 1, -1), (1, -1, -1)),
        ((-1, -1, 1), (1, -1, 1), (1, 1, 1)), ((-1, -1, 1), (1, 1, 1), (-1, 1, 1)),
        ((-1, -1, -1), (1, -1, -1), (1, -1, 1)), ((-1, -1, -1), (1, -1, 1), (-1, -1, 1)),
        ((-1, 1, -1), (-1, 1, 1), (1, 1, 1)), ((-1, 1, -1), (1, 1, 1), (1, 1, -1)),
        ((-1, -1, -1), (-1, -1, 1), (-1, 1, 1)), ((-1, -1, -1), (-1, 1, 1), (-1, 1, -1)),
        ((1, -1, -1), (1, 1, -1), (1, 1, 1)), ((1, -1, -1), (1, 1, 1), (1, -1, 1)),
    ]) + "endsolid box\n"


@st.composite
def json_scene(draw) -> dict:
    """A JSON scene document (a dict, possibly broken), version 1 or 2."""
    n = draw(st.integers(2, 4))
    doc: dict = {"skelslice": 1, "units": "mm",
                 "nodes": [[draw(COORD) for _ in range(3)] for _ in range(n)],
                 "segments": [[i, i + 1] for i in range(n - 1)]}
    if draw(st.booleans()):
        doc["radii"] = [draw(RADIUS) for _ in range(n)]
    else:
        doc["segment_radii"] = [[draw(RADIUS), draw(RADIUS)] for _ in range(n - 1)]
    if draw(st.booleans()):
        doc["skelslice"] = 2
        mesh = {"path": draw(st.sampled_from(["box.stl"] * 5 + ["missing.stl", "box.txt", "", "../box.stl"])),
                "role": draw(st.sampled_from(["solid", "solid", "clip-inside", "clip-outside", "bogus", 3]))}
        if draw(st.booleans()):
            mesh["transform"] = [[float(r == c) + (draw(st.floats(-0.2, 0.2)) if c == 3 else 0.0) for c in range(4)]
                                 for r in range(draw(st.sampled_from([3, 3, 3, 4, 2])))]
        if draw(st.booleans()):
            mesh["units"] = draw(st.sampled_from(["mm", "mm", "um", "in", "furlong", 1]))
        doc["meshes"] = [mesh]
        if rarely(draw, 5):          # a mesh-only part
            del doc["nodes"], doc["segments"]
            doc.pop("radii", None)
            doc.pop("segment_radii", None)
    if draw(st.booleans()):
        doc["kernel"] = {"degree": draw(st.sampled_from([2, 4, 6, 6, 16, 18, 3, 0, 10**30, -2])),
                         "sigma": draw(st.floats(1.2, 4.0))}
    for _ in range(draw(st.sampled_from([0, 0, 1, 1, 2]))):
        _corrupt_number(draw, doc)
    for _ in range(draw(st.sampled_from([0, 0, 0, 1, 2]))):
        _mutate(draw, doc)
    return doc


def _corrupt_number(draw, doc: dict) -> None:
    """Replace one number of the document (a coordinate, radius, sigma or transform entry) by a
    hostile float or integer."""
    places = []
    for key in ("nodes", "segment_radii", "meshes"):
        for row in doc.get(key, ()) if isinstance(doc.get(key), list) else ():
            rows = row.get("transform", []) if isinstance(row, dict) else [row]
            places += [(r, i) for r in rows if isinstance(r, list) for i in range(len(r))]
    if isinstance(doc.get("radii"), list):
        places += [(doc["radii"], i) for i in range(len(doc["radii"]))]
    if isinstance(doc.get("kernel"), dict):
        places.append((doc["kernel"], "sigma"))
    if places:
        where, i = draw(st.sampled_from(places))
        where[i] = draw(st.one_of(hostile_float(), hostile_float(), st.sampled_from(HOSTILE_INTS)))


def _mutate(draw, doc: dict) -> None:
    """One hostile change: a missing, extra or mistyped key, a hostile version, unit or index."""
    keys = sorted(doc)
    kind = draw(st.sampled_from(["drop", "extra", "mistype", "version", "units", "index", "metadata"]))
    if kind == "drop" and keys:
        doc.pop(draw(st.sampled_from(keys)))
    elif kind == "extra":
        doc[draw(st.sampled_from(["segment_radius", "node", "x-tool", "colour", "Units"]))] = draw(mistyped())
    elif kind == "mistype" and keys:
        doc[draw(st.sampled_from(keys))] = draw(mistyped())
    elif kind == "version":
        doc["skelslice"] = draw(st.one_of(st.sampled_from([0, 3, "1", 1.0, None]), st.sampled_from(HOSTILE_INTS)))
    elif kind == "units":
        doc["units"] = draw(st.sampled_from(["MM", "um", "m", "in", "km", "", None, 1]))
    elif kind == "index" and isinstance(doc.get("segments"), list) and doc["segments"]:
        seg = doc["segments"][0]
        if isinstance(seg, list) and seg:
            seg[draw(st.integers(0, len(seg) - 1))] = draw(st.one_of(st.sampled_from(HOSTILE_INTS),
                                                                      st.sampled_from([1.5, -0.0, 1e300, "0"])))
    elif kind == "metadata":
        doc["metadata"] = draw(mistyped())


def json_text(doc: dict, draw_cut: int | None = None) -> str:
    """The document as JSON text (NaN and Infinity as Python writes them; cut short if asked)."""
    text = json.dumps(doc, allow_nan=True)
    return text if draw_cut is None else text[:draw_cut]


OBJ_NUMBER = mostly(st.floats(-1, 1).map(repr),
                    st.sampled_from(["nan", "inf", "-inf", "1e400", "-0", "5e-324", "1e-300", "1e300",
                                     "1e10", "0x1", "abc", "1e", "--1"]), n=8)
OBJ_RADIUS = mostly(st.floats(0.1, 0.3).map(repr),
                    st.sampled_from(["0", "-0.2", "nan", "inf", "1e-300", "5e-324", "1e300", "1e9"]), n=8)
OBJ_INDEX = st.one_of(st.integers(-4, 4).map(str),
                      st.sampled_from(["99999999999999999999", "-99999999999999999999", "1/1", "2/x", "x", "1.5"]))


@st.composite
def obj_scene(draw) -> str:
    """OBJ polylines with hostile numbers, indices and statements."""
    lines = []
    n = draw(st.integers(2, 4))
    for _ in range(n):
        parts = [draw(OBJ_NUMBER) for _ in range(3)]
        if not rarely(draw, 6):
            parts.append(draw(OBJ_RADIUS))
        lines.append("v " + " ".join(parts))
    idx = [str(i) for i in range(1, n + 1)]
    if rarely(draw, 4):
        idx[draw(st.integers(0, n - 1))] = draw(OBJ_INDEX)
    lines.append("l " + " ".join(idx))
    if rarely(draw, 4):
        lines.insert(draw(st.integers(0, len(lines))),
                     draw(st.sampled_from(["f 1 2 3", "p 1", "vt 0 0", "# comment", "o name", "curv 0 1 1 2",
                                           "bogus 1", "v", "l", "l 1", "\\"])))
    return "\n".join(lines) + "\n"


_CONTENT_TYPES = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>
</Types>"""
_RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
<Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>"""

TMF_NUMBER = mostly(st.floats(-1, 1).map(repr),
                    st.sampled_from(["nan", "INF", "1e400", "-0", "5e-324", "1e-300", "1e30", "1e10", "abc", ""]), n=8)
TMF_RADIUS = mostly(st.floats(0.1, 0.3).map(repr),
                    st.sampled_from(["0", "-0.2", "nan", "1e-300", "5e-324", "1e30", "1e9", "x"]), n=8)


@st.composite
def tmf_scene(draw) -> bytes:
    """A beam-lattice 3MF package written by hand, with hostile attributes."""
    n = draw(st.integers(2, 4))
    verts = "".join(f'<vertex x="{draw(TMF_NUMBER)}" y="{draw(TMF_NUMBER)}" z="{draw(TMF_NUMBER)}"/>'
                    for _ in range(n))
    beams = []
    for i in range(n - 1):
        v1, v2 = str(i), str(i + 1)
        if rarely(draw, 5):
            v2 = draw(st.sampled_from(["-1", str(n), "99999999999", "x", v1]))
        attrs = f'v1="{v1}" v2="{v2}"'
        if draw(st.booleans()):
            attrs += f' r1="{draw(TMF_RADIUS)}"'
        if draw(st.booleans()):
            attrs += f' r2="{draw(TMF_RADIUS)}"'
        if rarely(draw, 6):
            attrs += f' cap1="{draw(st.sampled_from(["sphere", "hemisphere", "butt", "round"]))}"'
        beams.append(f"<b:beam {attrs}/>")
    unit = draw(st.sampled_from(["millimeter"] * 6 + ["micron", "centimeter", "meter", "inch", "foot", "parsec"]))
    radius = draw(TMF_RADIUS)
    minlength = draw(st.sampled_from(["0.0001"] * 6 + ["0", "1e300", "-1", "nan"]))
    model = f"""<?xml version="1.0" encoding="UTF-8"?>
<model unit="{unit}" xml:lang="en-US" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
 xmlns:b="http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02" requiredextensions="b">
 <resources>
  <object id="1" type="model" name="strut"><mesh><vertices>{verts}</vertices><triangles/>
  <b:beamlattice radius="{radius}" minlength="{minlength}" cap="sphere"><b:beams>{''.join(beams)}</b:beams>
  </b:beamlattice></mesh></object>
 </resources>
 <build><item objectid="1"/></build>
</model>"""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", _CONTENT_TYPES)
        z.writestr("_rels/.rels", _RELS)
        z.writestr("3D/3dmodel.model", model)
    return buf.getvalue()


@st.composite
def scene_file(draw) -> tuple[str, bytes]:
    """(file name, bytes) of a hostile scene: JSON (now and then cut short), OBJ or 3MF."""
    kind = draw(st.sampled_from(["json", "json", "json", "obj", "3mf"]))
    if kind == "json":
        text = json_text(draw(json_scene()))
        if rarely(draw, 10):
            text = text[:draw(st.integers(0, len(text)))]
        return "scene.json", text.encode()
    if kind == "obj":
        return "scene.obj", draw(obj_scene()).encode()
    return "scene.3mf", draw(tmf_scene())


def write_inputs(folder: Path, name: str, data: bytes) -> Path:
    """Write the scene (and the box mesh that version 2 scenes refer to) into ``folder``."""
    (folder / "box.stl").write_text(BOX_STL)
    path = folder / name
    path.write_bytes(data)
    return path


# ----------------------------------------------------------------------------- the property
def check_run(result, folder: Path, before: set[str], allowed=(0, 2), what: str = "") -> None:
    """The fuzz property for one CliRunner run in ``folder`` (which held ``before`` beforehand).

    * the command ended by exiting (no exception escaped), with a status in ``allowed``;
    * no traceback in its output;
    * no hidden temporary ``.NAME.tmp-*`` left, whatever the status;
    * on exit 2, nothing new at all in ``folder``.
    """
    exc = result.exception
    out = result.output + (result.stderr if result.stderr_bytes is not None else "")
    if exc is not None and not isinstance(exc, SystemExit):
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        raise AssertionError(f"{what}: the command raised {type(exc).__name__}: {exc}\n{tb}\n{out[-3000:]}")
    assert result.exit_code in allowed, f"{what}: exit status {result.exit_code}\n{out[-3000:]}"
    assert "Traceback" not in out, f"{what}: a traceback\n{out[-3000:]}"
    now = set(os.listdir(folder))
    left = sorted(n for n in now if ".tmp-" in n)
    assert not left, f"{what}: hidden temporaries left behind: {left}\n{out[-3000:]}"
    if result.exit_code == 2:
        new = sorted(now - before)
        assert not new, f"{what}: exit 2 but {new} written\n{out[-3000:]}"
