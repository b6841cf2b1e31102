"""Bad input through the real entry points: ``skelslice info`` must exit 2 with a
one-line message naming the file, the entry and the value, and never a traceback.

Every case of ``BAD_CASES`` (``tests/helpers.py``; ``test_scene_io.py`` reads them
through the API) runs through ``slicer.cli.app.main`` (in-process, with click's
``CliRunner``); a few also run as subprocesses through ``python -m slicer`` and the
installed ``skelslice`` console script.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

import slicer.cli.app
from helpers import BAD_CASES, OBJ_OK, make


def invoke(*args: str):
    return CliRunner().invoke(slicer.cli.app.main, list(args))


def assert_clean_error(result, path, fragments=()):
    """Exit status 2, 'error: <path>: ...' on stderr, one line, no traceback."""
    everything = result.output + (result.stderr or "")
    assert result.exit_code == 2, everything
    assert "Traceback" not in everything
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"error: {path}: "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], f"{fragment!r} not in {lines[0]!r}"


# ----------------------------------------------------------------------------- in-process
@pytest.mark.parametrize("case", BAD_CASES, ids=[c.id for c in BAD_CASES])
def test_info_bad_input_exits_2_naming_file_entry_and_value(case, tmp_path):
    path = make(case, tmp_path)
    args = ["info", str(path)]
    if case.radius is not None:
        args += ["--radius", str(case.radius)]
    assert_clean_error(invoke(*args), path, case.must)


@pytest.mark.parametrize("case_id", ["index-out-of-range", "nan-node", "obj-face", "invalid-json"])
def test_info_bad_input_with_json_and_options(case_id, tmp_path):
    case = next(c for c in BAD_CASES if c.id == case_id)
    path = make(case, tmp_path)
    result = invoke("info", str(path), "--json", "--pixel-size", "0.05")
    assert_clean_error(result, path, case.must)


@pytest.mark.parametrize("args, fragment", [
    (["--radius", "-1"], "--radius"),
    (["--radius", "nan"], "--radius"),
    (["--radius", "inf"], "--radius"),
    (["--radius", "abc"], "--radius"),
    (["--pixel-size", "0"], "--pixel-size"),
    (["--pixel-size", "-0.05"], "--pixel-size"),
    (["--bogus"], "--bogus"),
])
def test_info_bad_options_are_usage_errors(args, fragment, tmp_path):
    path = tmp_path / "s.obj"
    path.write_text(OBJ_OK)
    result = invoke("info", str(path), *args)
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    assert fragment in result.stderr and "Usage:" in result.stderr


def test_info_without_argument_is_a_usage_error():
    result = invoke("info")
    assert result.exit_code == 2
    assert "Missing argument 'SCENE'" in result.stderr


# ----------------------------------------------------------------------------- subprocesses
def _run(cmd, cwd):
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300, env=env)


def _console_script() -> str:
    """The installed ``skelslice`` entry point (``[project.scripts]``); its
    absence is a packaging defect, not a reason to skip."""
    here = Path(sys.executable).with_name("skelslice")
    script = str(here) if here.exists() else shutil.which("skelslice")
    assert script is not None, "the skelslice console script is not installed (pip install -e .)"
    return script


SUBPROCESS_CASES = ["index-out-of-range", "missing-file", "obj-mixed-radii"]


def _subprocess_check(proc, path, fragments):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: "), proc.stderr
    for fragment in fragments:
        assert fragment in lines[0]


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES[:2])
def test_python_m_slicer_info_bad_input(case_id, tmp_path):
    case = next(c for c in BAD_CASES if c.id == case_id)
    path = make(case, tmp_path)
    proc = _run([sys.executable, "-m", "slicer", "info", str(path)], tmp_path)
    _subprocess_check(proc, path, case.must)


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES[1:])
def test_console_script_info_bad_input(case_id, tmp_path):
    script = _console_script()
    case = next(c for c in BAD_CASES if c.id == case_id)
    path = make(case, tmp_path)
    proc = _run([script, "info", str(path)], tmp_path)
    _subprocess_check(proc, path, case.must)


def test_console_script_info_happy_path(tmp_path):
    script = _console_script()
    path = tmp_path / "s.obj"
    path.write_text(OBJ_OK)
    proc = _run([script, "info", str(path), "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["segments"] == 2


# ----------------------------------------------------------------------------- happy path
CRAFTED = {
    "skelslice": 1, "units": "mm",
    "nodes": [[0, 0, 0], [0, 0, 10], [10, 0, 10],   # a bent strut, thin at node 2
              [20, 0, 0], [20, 0, 0.3],            # isolated, 0.3 mm long, radius 1: no surface
              [30, 0, 0], [30, 0, 1],              # radius 0.1 -> 1 over 1 mm: end balls nest
              [50, 50, 50]],                       # unused
    "segments": [[0, 1], [1, 2], [3, 4], [5, 6], [2, 1]],
    "segment_radii": [[1, 1], [1, 0.02], [1, 1], [0.1, 1], [0.02, 1]],
    "kernel": {"degree": 6, "sigma": 2.0},
}


@pytest.fixture
def crafted(tmp_path):
    path = tmp_path / "crafted.json"
    path.write_text(json.dumps(CRAFTED))
    return path


def test_info_text_counts_and_warnings(crafted):
    result = invoke("info", str(crafted), "--pixel-size", "0.05")
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "Traceback" not in out and result.stderr == ""
    assert f"scene:           {crafted}" in out
    assert "nodes:           8" in out
    assert "segments:        5" in out
    assert "kernel:          degree 6, sigma 2" in out
    assert "skeleton bounds: [0, 0, 0] .. [30, 0, 10]" in out
    assert "support bounds:  [-2, -2, -2] .. [32, 2, 12]" in out
    assert "radius:          0.02 .. 1 mm" in out
    assert "segment length:  0.3 .. 10 mm" in out
    assert "warnings:        5" in out
    assert "2 segments thinner than a pixel" in out and "(segments 1, 4)" in out
    assert "1 isolated segment shorter than 0.688 x mean radius" in out and "(segment 2)" in out
    assert "end support balls nest" in out and "(segment 3)" in out
    assert "1 duplicate segment" in out and "(segment 4)" in out
    assert "1 node not used by any segment (node 7)" in out


def test_info_without_pixel_size_skips_the_thin_check(crafted):
    result = invoke("info", str(crafted))
    assert result.exit_code == 0
    assert "thinner than a pixel" not in result.stdout
    assert "pass --pixel-size" in result.stdout
    assert "warnings:        4" in result.stdout


def test_info_json(crafted):
    result = invoke("info", str(crafted), "--json", "--pixel-size", "0.05")
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["scene"] == str(crafted)
    assert (data["nodes"], data["segments"]) == (8, 5)
    assert data["kernel"] == {"degree": 6, "sigma": 2.0}
    assert data["bounds"]["skeleton"] == [[0, 0, 0], [30, 0, 10]]
    assert data["bounds"]["support"] == [[-2, -2, -2], [32, 2, 12]]
    assert (data["radius"]["min"], data["radius"]["max"]) == (0.02, 1.0)
    assert (data["segment_length"]["min"], data["segment_length"]["max"]) == (0.3, 10.0)
    assert data["pixel_size"] == 0.05
    warnings = {w["kind"]: w for w in data["warnings"]}
    assert set(warnings) == {"thin", "short_isolated", "nested_ends", "duplicate", "unused_nodes"}
    assert warnings["thin"]["segments"] == [1, 4] and warnings["thin"]["count"] == 2
    assert warnings["short_isolated"]["segments"] == [2]
    assert warnings["nested_ends"]["segments"] == [3]
    assert warnings["duplicate"]["segments"] == [4]
    assert warnings["unused_nodes"]["nodes"] == [7]


def test_info_clean_obj_scene_with_radius(tmp_path):
    path = tmp_path / "s.obj"
    path.write_text("v 0 0 0\nv 0 0 10\nv 10 0 10\nl 1 2 3\n")
    result = invoke("info", str(path), "--radius", "0.5", "--pixel-size", "0.05")
    assert result.exit_code == 0, result.output
    assert "segments:        2" in result.stdout
    assert "radius:          0.5 .. 0.5 mm" in result.stdout
    assert "warnings:        none" in result.stdout


def test_info_lists_at_most_ten_offenders(tmp_path):
    n = 25  # 25 isolated, too-short segments
    nodes = [[3.0 * i, 0, 0] for i in range(n)] + [[3.0 * i, 0, 0.1] for i in range(n)]
    scene = {"skelslice": 1, "units": "mm", "nodes": nodes,
             "segments": [[i, n + i] for i in range(n)], "radii": [1.0] * (2 * n)}
    path = tmp_path / "many.json"
    path.write_text(json.dumps(scene))
    result = invoke("info", str(path), "--json")
    w = json.loads(result.stdout)["warnings"][0]
    assert w["kind"] == "short_isolated" and w["count"] == 25 and len(w["segments"]) == 10
    assert w["message"].endswith("(segments 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, ...)")
