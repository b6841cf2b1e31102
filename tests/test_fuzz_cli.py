"""Fuzzing every command through the real entry point: hostile scenes and hostile numbers.

Each test draws a scene file (tests/fuzz_helpers.py: JSON versions 1 and 2, OBJ, 3MF) and
a set of option values, runs the command with click's CliRunner on :func:`slicer.cli.app.main`
in a fresh folder, and checks :func:`fuzz_helpers.check_run`: exit 0 or 2 (1 where the command
documents it: ``check`` found a blocking problem, ``validate`` a failed comparison), no
traceback, nothing left behind on exit 2. A few runs go through the installed ``skelslice``
executable in a subprocess (the console script, SIGTERM on the contour path).

Bounded and deterministic by default (the ``ci`` profile, derandomised); run longer with
``pytest tests/test_fuzz_cli.py --hypothesis-profile=fuzz-long`` (docs/development.md).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from formats.printer_profiles import PRINTERS
from slicer.cli.app import main

from fuzz_helpers import (RUNS, Opt, check_run, choice, fuzz_settings, json_scene, json_text, opt_tuple, rarely,
                          scene_file, text_int, text_number, write_inputs)
from interrupting import interrupt_and_check, start_slice, wait_mid_write

ROOT = Path(__file__).resolve().parent.parent
CUBIC = ROOT / "sample_lattices" / "cubic_2x2x2.json"
#: a small valid scene every option test can also run on (hostile options, sane scene)
STRUT = {"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1], [0.5, 0, 1.5]],
         "segments": [[0, 1], [1, 2]], "radii": [0.25, 0.2, 0.15]}
PRINTER_NAMES = sorted(PRINTERS)


def _record(name: str, status: int) -> None:
    runs = RUNS.setdefault(name, {})
    runs[status] = runs.get(status, 0) + 1


def _run(args: list[str], folder: Path, allowed=(0, 2), name: str = "") -> None:
    """Run ``skelslice ARGS`` in ``folder`` and check the fuzz property."""
    before = set(os.listdir(folder))
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        result = CliRunner().invoke(main, args, catch_exceptions=True)
    finally:
        os.chdir(cwd)
    _record(name, result.exit_code)
    check_run(result, folder, before, allowed, what=f"skelslice {' '.join(map(str, args))}")


def _options(draw, table: dict, hostile: bool) -> list[str]:
    """Some of the options of ``table`` (name -> :class:`Opt`, or a strategy of flags/choices)."""
    out: list[str] = []
    for name, spec in table.items():
        if rarely(draw, 4):
            value = draw(spec.pick(hostile) if isinstance(spec, Opt) else spec)
            if value is True:
                out.append(name)
            elif value is not False:
                out += [name, *(value if isinstance(value, tuple) else (value,))]
    return out


# sane ranges are small (bounded work); hostile text is the edges (refused or cheap)
PIXEL = text_number(0.15, 0.6)
LAYER = text_number(0.15, 0.6)
COORD_OPT = text_number(-3.0, 3.0)
GRID = {
    "--pixel-size-y": PIXEL,
    "--layer-height": LAYER,
    "--bounds": opt_tuple(text_number(-3, -1), text_number(-3, -1), text_number(-3, -1),
                          text_number(1, 3), text_number(1, 3), text_number(1, 3)),
}
TRACE = {
    "--method": st.sampled_from(["interval", "sampling", "segment"]),
    "--bucket": text_int(0, 64),
    "--threads": text_int(1, 2),
    "--strict": st.booleans(),
    "--blend": choice(["sum"], ["union", "max"]),
}
PRINT = {
    "--printer": choice(PRINTER_NAMES, ["bogus", ""]),
    "--at": opt_tuple(text_number(0.0, 60.0), text_number(0.0, 60.0)),
    "--aa": text_int(1, 3),
    "--aa-z": st.booleans(),
    "--gamma": text_number(0.5, 2.0),
    "--exposure": text_number(0.5, 10.0),
    "--bottom-exposure": text_number(0.5, 30.0),
    "--bottom-layers": text_int(0, 5),
}
SCALE = {
    "--max-memory": choice(["auto", "none", "64MB", "1.5GiB"], ["1", "0", "-1GB", "1e400GB", "abc",
                                                              "18446744073709551616"]),
    "--executor": st.sampled_from(["serial", "threads"]),
    "--tile": text_int(16, 64),
    "--slab": text_int(1, 8),
    "--workers": text_int(1, 2),
}
FORMATS = ["png", "zip", "svg", "cli", "geojson", "sl1s", "goo", "ctb", "nanodlp", "pws", "bogus"]


def _scene_in(folder: Path, data) -> Path:
    name, raw = data
    return write_inputs(folder, name, raw)


@st.composite
def _run_kind(draw):
    """(hostile, (file name, bytes)): a hostile run (hostile scene file, or the small valid scene with
    hostile option values now and then) or an ordinary one (the valid scene, ordinary values)."""
    hostile = draw(st.sampled_from([True, False]))
    if hostile and draw(st.booleans()):
        return True, draw(scene_file())
    return hostile, ("scene.json", json.dumps(STRUT).encode())


SUFFIX = {"zip": ".zip", "sl1s": ".sl1s", "goo": ".goo", "svg": ".svg", "cli": ".cli", "geojson": ".geojson",
          "ctb": ".ctb", "nanodlp": ".nanodlp", "pws": ".pws"}


@fuzz_settings(80)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_slice(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        printer = draw(st.booleans())
        fmt = draw(st.sampled_from(([None, "png", "zip", "svg", "cli", "geojson"] if not printer else
                                    [None, "sl1s", "goo", "ctb", "nanodlp", "pws", "png"])
                                   + (["bogus", "ctb"] if hostile else [])))
        args = ["slice", str(scene), "-o", f"out{SUFFIX.get(fmt, '')}", "-q"]
        if fmt is not None:
            args += ["--format", fmt]
        table = {**GRID, **TRACE, **SCALE, **{k: v for k, v in PRINT.items() if printer or k not in ("--printer",
                                                                                                     "--at")},
                 "--contour-tol": text_number(2e-3, 2e-2), "--radius": text_number(0.1, 0.3)}
        if printer:
            args += ["--printer", draw(PRINT["--printer"].pick(hostile))]
            table.pop("--bounds")
            table.pop("--pixel-size-y")
        else:
            args += ["--pixel-size", draw(PIXEL.pick(hostile))]
        args += _options(draw, table, hostile)
        if rarely(draw, 5):
            args.append("--dry-run")
        _run(args, folder, name="slice")


@fuzz_settings(60)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_render(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    size = Opt(st.integers(1, 12).map(str), st.sampled_from(["0", "-1", "16385", "99999999999999999999", "2.5",
                                                               "nan"]))
    table = {
        "--size": opt_tuple(size, size),
        "--view": choice(["iso", "top", "front", "side"], ["bottom", "bogus"]),
        "--camera": choice(["ortho", "perspective"], ["fisheye"]),
        "--fov": text_number(5.0, 120.0, extra=["180", "179.9999999", "-35"]),
        "--eye": opt_tuple(text_number(-20, 20), text_number(-20, 20), text_number(-20, 20)),
        "--target": opt_tuple(text_number(-2, 2), text_number(-2, 2), text_number(-2, 2)),
        "--opacity": text_number(0.05, 1.0),
        "--max-opacity": text_number(0.05, 1.0),
        "--opaque": st.booleans(),
        "--tolerance": text_number(1e-4, 1e-2),
        "--roots-out": choice(["roots.npz"], ["out.png"]),
        "--bisection": st.booleans(),
        "--strict": st.booleans(),
        "--transparent": st.booleans(),
        "--bucket": text_int(1, 16),
        "--threads": text_int(1, 2),
        "--radius": text_number(0.1, 0.3),
    }
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        args = ["render", str(scene), "-o", "out.png", "-q", "--size", "8", "8"] + _options(draw, table, hostile)
        _run(args, folder, name="render")


@fuzz_settings(25)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_validate(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    table = {
        "--mesh-edge": text_number(0.1, 0.3),
        "--layers-checked": text_int(1, 2),
        "--contour-tol": text_number(2e-3, 2e-2),
        "--max-hausdorff": text_number(0.0, 1.0),
        "--min-iou": text_number(0.0, 1.0),
        "--pixels": text_int(2, 16),
        "--layer-height": LAYER,
        "--method": choice(["interval", "sampling", "segment"], ["bogus"]),
        "--threads": text_int(1, 2),
        "--report": choice(["report"], ["scene.json"]),
        "--json": st.booleans(),
    }
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        args = ["validate", str(scene), "--pixel-size", draw(text_number(0.2, 0.5).pick(hostile)),
                "--layers-checked", "1"]
        _run(args + _options(draw, table, hostile), folder, allowed=(0, 1, 2), name="validate")


@fuzz_settings(50)
@given(data=scene_file(), st_data=st.data())
def test_fuzz_info(data, st_data):
    draw = st_data.draw
    table = {"--pixel-size": text_number(0.01, 1.0), "--radius": text_number(0.1, 0.3), "--json": st.booleans(),
             "--blend": choice(["sum", "union"], ["max"])}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        _run(["info", str(scene)] + _options(draw, table, True), folder, name="info")


@fuzz_settings(50)
@given(hostile=st.booleans(), st_data=st.data())
def test_fuzz_lattice(hostile, st_data):
    draw = st_data.draw
    cells = text_int(1, 3)
    r = text_number(0.05, 0.4)
    radius = Opt(st.one_of(r.ordinary, st.tuples(r.ordinary, r.ordinary).map(":".join)),
                 st.one_of(r.hostile, st.tuples(r.ordinary, r.hostile).map(":".join),
                           st.sampled_from(["0.1:", ":0.2", "1:2:3", "0.2:nan"])))
    c = text_number(1.0, 4.0)
    cell_size = Opt(st.one_of(c.ordinary, st.tuples(c.ordinary, c.ordinary, c.ordinary).map(",".join)),
                    st.one_of(c.hostile, st.tuples(c.ordinary, c.hostile, c.ordinary).map(",".join)))
    types = choice(["cubic", "bcc", "fcc", "octet", "kelvin", "bcc+cubic"], ["bogus", ""])
    args = ["lattice", draw(types.pick(hostile)),
            "--cells", *draw(opt_tuple(cells, cells, cells).pick(hostile)), "--cell-size",
            draw(cell_size.pick(hostile)), "--radius", draw(radius.pick(hostile)),
            "-o", draw(choice(["l.json", "l.obj"], ["l.txt", "."]).pick(hostile))]
    table = {
        "--axis": choice(["x", "y", "z"], ["w"]),
        "--origin": opt_tuple(COORD_OPT, COORD_OPT, COORD_OPT),
        "--envelope-box": opt_tuple(text_number(-1, 1), text_number(-1, 1), text_number(-1, 1),
                                    text_number(2, 8), text_number(2, 8), text_number(2, 8)),
        "--envelope-cylinder": opt_tuple(text_number(0, 4), text_number(0, 4), text_number(0.5, 4),
                                         text_number(-1, 1), text_number(2, 8)),
        "--degree": Opt(st.sampled_from(["2", "4", "6", "8"]), st.sampled_from(["3", "0", "-2", "18", "1e400"])),
        "--sigma": text_number(1.1, 4.0),
    }
    with tempfile.TemporaryDirectory() as d:
        _run(args + _options(draw, table, hostile), Path(d), name="lattice")


@fuzz_settings(30)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_check(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    table = {**GRID, **{k: TRACE[k] for k in ("--method", "--threads")},
             "--min-feature": text_number(0.0, 1.0), "--min-island-area": text_number(0.0, 1.0),
             "--min-trap-volume": text_number(0.0, 1.0), "--max-area-jump": text_number(0.0, 10.0),
             "--fail-on": choice(["islands", "thin", "traps", "islands,traps"], ["bogus", ""]),
             "--json": choice(["report.json"], ["scene.json", "."]), "--radius": text_number(0.1, 0.3)}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        args = ["check", str(scene), "-q", "--pixel-size", draw(PIXEL.pick(hostile))] + _options(draw, table, hostile)
        _run(args, folder, allowed=(0, 1, 2), name="check")


@fuzz_settings(15)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_preview(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    table = {"--layer-height": LAYER, "--contour-tol": text_number(2e-3, 2e-2), "--render-size": text_int(8, 24),
             "--no-check": st.booleans(), "--no-contours": st.booleans(), "--radius": text_number(0.1, 0.3)}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        args = ["preview", str(scene), "-o", "view.html", "--pixel-size", draw(PIXEL.pick(hostile)),
                "--render-size", "16"]
        _run(args + _options(draw, table, hostile), folder, allowed=(0, 2), name="preview")


@fuzz_settings(20)
@given(st_data=st.data())
def test_fuzz_printers_and_bench_refusals(st_data):
    """``printers`` (no numbers: its flags and stray arguments) and ``bench`` with values it must
    refuse before running anything (a benchmark that started would take minutes)."""
    draw = st_data.draw
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        _run(["printers", *draw(st.sampled_from([[], ["--json"], ["extra"], ["--bogus"]]))], folder,
             name="printers")
        bad = draw(st.sampled_from([
            ["--repeat", draw(st.sampled_from(["0", "-1", "nan", "99999999999999999999", "abc"]))],
            ["--threads", draw(st.sampled_from(["0", "-5", "2.5", "1e400"]))],
            [draw(st.sampled_from(["error", "table1", "parts"])), "--model",
             draw(st.sampled_from(["bogus", "", "../jellyfish"]))],
            ["--model", "jellyfish"],
            ["--table1", "--error"],
            ["bogus-subcommand"],
            ["table1", "--repeat", "0"],
            ["error", "--plot", "x.png", "--json", "x.png"],
            ["error", "--plot", draw(st.sampled_from(["x.txt", "x", "x.png/"]))],
            ["--error", "--plot", "x.png", "--json", "./x.png"],
            ["table1", "--plot", "x.png"],
        ]))
        _run(["bench", *bad], folder, allowed=(2,), name="bench")


@fuzz_settings(60)
@given(doc=json_scene(), cut=st.integers(0, 400))
def test_fuzz_truncated_json_through_info(doc, cut):
    """JSON cut anywhere: a named syntax error (exit 2), never a traceback."""
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = write_inputs(folder, "scene.json", json_text(doc, cut).encode())
        _run(["info", str(scene)], folder, name="info-truncated")


# ----------------------------------------------------------------------------- the installed command
def _skelslice() -> str:
    exe = shutil.which("skelslice") or str(Path(sys.executable).parent / "skelslice")
    assert Path(exe).exists(), "the skelslice console script is not installed (pip install -e .)"
    return exe


HUGE = {"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 10], [1e308, 0, 10]],
        "segments": [[0, 1], [1, 2]], "radii": [1, 1, 1]}

#: the measured failures, each through the installed executable: (args, text the error names)
ISSUE_CASES = [
    (["slice", "{huge}", "-o", "out", "--pixel-size", "0.1"], "nodes[2][0] = 1e+308"),
    (["info", "{huge}"], "nodes[2][0] = 1e+308"),
    (["render", "{huge}", "-o", "out.png", "--size", "20", "20"], "nodes[2][0] = 1e+308"),
    (["slice", "{cubic}", "-o", "out.sl1s", "--printer", "prusa-sl1s", "--at", "1e308", "0"], "--at"),
    (["slice", "{cubic}", "-o", "out", "--pixel-size", "0.1", "--layer-height", "1e-300"], "1e-300"),
    (["slice", "{cubic}", "-o", "out", "--pixel-size", "0.1", "--bounds", "0", "0", "0", "1e300", "1", "1"],
     "1e+300"),
    (["validate", "{cubic}", "--pixel-size", "0.1", "--mesh-edge", "1e-300"], "mesh edge = 1e-300"),
    (["slice", "{cubic}", "-o", "out.svg", "--format", "svg", "--pixel-size", "0.1", "--contour-tol", "1e-300"],
     "--contour-tol = 1e-300"),
    (["render", "{cubic}", "-o", "out.png", "--size", "8", "8", "--eye", "0", "0", "1e300", "--target", "0", "0",
      "0"], "eye[2] = 1e+300"),
    (["lattice", "cubic", "--cells", "2", "2", "2", "--cell-size", "1e300", "--radius", "1", "-o", "out.json"],
     "1e+300"),
]


@pytest.mark.parametrize("args,needle", ISSUE_CASES, ids=[f"{a[0]}-{i}" for i, (a, _) in enumerate(ISSUE_CASES)])
def test_hostile_numbers_through_the_installed_command(args, needle, tmp_path):
    """Exit 2, a named error with the value as people write it, no traceback, nothing written."""
    huge = tmp_path / "huge.json"
    huge.write_text(json.dumps(HUGE))
    argv = [a.format(huge=huge, cubic=CUBIC) for a in args]
    r = subprocess.run([_skelslice(), *argv], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                       env={**os.environ, "NUMBA_NUM_THREADS": "2"})
    assert r.returncode == 2, (r.returncode, r.stderr[-3000:])
    assert "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr[-3000:]
    assert needle in r.stderr, r.stderr
    assert len(r.stderr) < 600, r.stderr                     # one readable line, no 300-digit numbers
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.json"]


def test_render_warns_when_nothing_is_visible(tmp_path):
    """A camera looking away from the model: the image is written, with a warning saying it is empty."""
    r = subprocess.run([_skelslice(), "render", str(CUBIC), "-o", "out.png", "--size", "8", "8", "--eye", "100",
                        "100", "100", "--target", "200", "200", "200", "--camera", "perspective"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "warning: nothing is visible" in r.stderr
    visible = subprocess.run([_skelslice(), "render", str(CUBIC), "-o", "seen.png", "--size", "8", "8"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert visible.returncode == 0 and "nothing is visible" not in visible.stderr, visible.stderr


def test_sigterm_on_the_contour_path_cleans_up(tmp_path):
    """SIGTERM (``timeout``, job schedulers) while SVG contours are refined at a fine tolerance
    (minutes of work on the cubic lattice): exit 143, no traceback, no hidden temporary left."""
    out = tmp_path / "out.svg"
    proc = start_slice(CUBIC, out, "--format", "svg", "--pixel-size", "0.1", "--contour-tol", "1e-7")
    wait_mid_write(proc, out, size=0)
    interrupt_and_check(proc, out, signal.SIGTERM)


# ----------------------------------------------------------------------------- defects the fuzz suite found
@pytest.mark.parametrize("printer,suffix,extra", [("anycubic-photon-mono", ".pwmo", ["--slab", "1"]),
                                                  ("elegoo-mars-4-ultra", ".goo", ["--slab", "1", "--aa", "3"]),
                                                  ("prusa-sl1s", ".svg", ["--slab", "1"])])
def test_printer_jobs_streamed_in_slabs_are_placed_like_in_memory(printer, suffix, extra, tmp_path):
    """A printer job traced in several slabs (``--slab``, or a memory budget) is placed on the plate
    from the extent its first pass found (it raised AttributeError), and writes the same bytes as
    the job traced in memory."""
    scene = tmp_path / "strut.json"
    scene.write_text(json.dumps(STRUT))
    outs = []
    for name, more in (("streamed", extra), ("memory", [a for a in extra if a in ("--aa", "3")])):
        (tmp_path / name).mkdir()
        out = tmp_path / name / f"x{suffix}"
        r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--printer", printer, "-q", *more])
        assert r.exit_code == 0 and r.exception is None, (r.output, r.exception)
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


@fuzz_settings(15)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_supports(kind, st_data):
    hostile, data = kind
    draw = st_data.draw
    length = text_number(0.0, 3.0)
    table = {"--layer-height": LAYER, "--tip-radius": text_number(0.1, 0.3), "--elevation": length,
             "--pad": st.sampled_from([True, False]), "--no-pad": st.booleans(), "--pad-thickness": length,
             "--pad-margin": length, "--pillar-radius": text_number(0.2, 0.6), "--head-length": length,
             "--penetration": length, "--bridge-length": length, "--critical-angle": text_number(0.0, 89.0),
             "--tree-distance": length, "--blend": choice(["sum", "union"], ["max"]),
             "--printer": choice(PRINTER_NAMES[:1], ["bogus"]), "--radius": text_number(0.1, 0.3),
             "--force": st.booleans()}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        args = ["supports", str(scene), "-o", "sup.json", "-q", "--pixel-size", draw(PIXEL.pick(hostile))]
        _run(args + _options(draw, table, hostile), folder, allowed=(0, 2), name="supports")


MESH_SUFFIX = [".stl", ".ply", ".obj", ".3mf", ".xyz"]


@fuzz_settings(9)
@given(kind=_run_kind(), st_data=st.data())
def test_fuzz_mesh(kind, st_data):
    """``mesh``: exit 0, 1 (the bound could not be certified, documented) or 2; a tolerance is
    always given (the mesh's cost grows as 1/tol²), ordinary ones coarse enough to stay quick."""
    hostile, data = kind
    draw = st_data.draw
    table = {"--uniform": st.booleans(), "--threads": text_int(1, 2), "--radius": text_number(0.1, 0.3),
             "--blend": choice(["sum"], ["union", "max"]), "--force": st.booleans()}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        scene = _scene_in(folder, data)
        beams = rarely(draw, 4)
        suffix = ".3mf" if beams and not hostile else draw(st.sampled_from(MESH_SUFFIX[:4] + (MESH_SUFFIX[4:]
                                                                                             if hostile else [])))
        tol = text_number(0.1, 0.3, extra=["1e-6"]).pick(hostile)
        args = ["mesh", str(scene), "-o", f"out{suffix}", "-q", "--tol", draw(tol)] + (["--beams"] if beams else [])
        _run(args + _options(draw, table, hostile), folder, allowed=(0, 1, 2), name="mesh")
