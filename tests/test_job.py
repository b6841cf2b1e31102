"""The job as data (SliceJob), refusals before any tracing, the public API facade."""
from __future__ import annotations

import importlib

import sys

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import slicer
import slicer.render.rendering
from slicer.cli.app import main
from slicer.errors import FormatError, GridError, MissingDependencyError, OptionError, UsageError
from slicer.tracer.grid import make_grid
from slicer.job.run import footprint_lower_bound, run_slice
from slicer.job.spec import OPTIONS, SliceJob
from slicer.scene.lattice import generate_lattice
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import trace


def test_from_options_round_trips_every_option():
    values = {"pixel_size": 0.05, "pixel_size_y": 0.06, "layer_height": 0.04, "bounds": (0, 0, 0, 1, 1, 1),
              "method": "sampling", "bucket": 32, "threads": 1, "strict": True, "printer": "prusa-sl1s",
              "at": (10.0, 20.0), "aa": 2, "aa_z": True, "gamma": 1.5, "exposure": 3.0, "bottom_exposure": 20.0,
              "bottom_layers": 4, "fmt": "zip", "force": True, "contour_tol": 0.002, "contours": "c.json",
              "scene_name": "s.json", "max_memory": "2GB", "executor": "threads", "workers": 2,
              "scheduler": "tcp://h:1", "tile": 64, "slab": 10, "prefetch": True, "blend": "union"}
    assert set(values) == set(OPTIONS)
    job = SliceJob.from_options(**values)
    assert job.to_options() == values
    assert job.grid.pixel_size_y == 0.06 and job.trace.method == "sampling" and job.printing.at == (10.0, 20.0)
    assert job.scale.slab == 10 and job.scale.prefetch is True and job.output.contours == "c.json"
    assert job.replace(aa=4).printing.aa == 4 and job.printing.aa == 2


def test_unknown_option_is_named():
    with pytest.raises(OptionError, match="unknown slicing option 'pixelsize'"):
        SliceJob.from_options(pixelsize=0.05)


@pytest.mark.parametrize("options, error, match", [
    ({}, OptionError, "--pixel-size is required without --printer"),
    ({"pixel_size": -1}, OptionError, "pixel size must be a finite number > 0, got -1"),
    ({"pixel_size": 0.05, "aa": 17}, OptionError, "--aa must be an integer from 1 to 16, got 17"),
    ({"pixel_size": 0.05, "gamma": 0}, OptionError, "--gamma must be a finite number > 0, got 0"),
    ({"pixel_size": 0.05, "at": (1, 2)}, OptionError, "--at needs --printer"),
    ({"pixel_size": 0.05, "aa": 2, "at": (1, 2)}, OptionError, "--at needs --printer"),
    ({"printer": "prusa-sl1s", "pixel_size": 0.05}, OptionError, "--pixel-size cannot be combined"),
    ({"printer": "prusa-sl1s", "bounds": (0, 0, 0, 1, 1, 1)}, OptionError, "--bounds cannot be combined"),
    ({"printer": "nope"}, OptionError, "unknown printer 'nope'"),
    ({"pixel_size": 0.05, "method": "magic"}, OptionError, "unknown method 'magic'"),
    ({"pixel_size": 0.05, "bottom_layers": -1}, OptionError, "--bottom-layers must be an integer >= 0"),
    ({"pixel_size": 0.05, "exposure": float("nan")}, OptionError, "--exposure must be a finite number > 0"),
    ({"pixel_size": 0.05, "contour_tol": 0}, OptionError, "--contour-tol must be a finite number > 0"),
    ({"pixel_size": 0.05, "slab": 0}, OptionError, "--slab must be an integer >= 1"),
    ({"printer": "prusa-sl1s", "exposure": 99}, FormatError, "exposure 99 s is outside"),
])
def test_resolve_refuses_by_name(options, error, match):
    with pytest.raises(error, match=match):
        SliceJob.from_options(**options).resolve("out.sl1s" if error is FormatError else "out")
    assert issubclass(error, UsageError)


def test_resolve_with_a_printer_takes_its_pitch_and_format():
    r = SliceJob.from_options(printer="prusa-sl1s", aa=2).resolve("part")
    assert r.fmt == "sl1s" and r.pitch == (0.025, 0.025) and r.layer_height == 0.05
    assert r.settings.printer.name == "prusa-sl1s" and r.settings.aa == 2


def _scenes():
    """Random small skeletons: a few struts of random direction, length and taper."""
    def build(rows):
        nodes, segs, radii = [], [], []
        for (x, y, z, dx, dy, dz, r0, r1) in rows:
            k = len(nodes)
            nodes += [[x, y, z], [x + dx, y + dy, z + dz]]
            segs.append([k, k + 1])
            radii.append([r0, r1])
        return Skeleton(nodes, segs, radii)

    c = st.floats(-3, 3)
    d = st.floats(-4, 4).filter(lambda v: abs(v) > 0.2)
    r = st.floats(0.05, 0.8)
    return st.lists(st.tuples(c, c, c, d, d, d, r, r), min_size=1, max_size=4).map(build)


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(skel=_scenes(), pitch=st.sampled_from([0.1, 0.23]))
def test_footprint_lower_bound_lies_inside_the_traced_footprint(skel, pitch):
    """Soundness of the cheap plate check: the box found without tracing is
    never larger than the box of the traced inside voxels."""
    grid = make_grid(skel.support_bounds(), pitch)
    box = footprint_lower_bound(skel, grid)
    res = trace(skel, grid)
    if res.n_runs == 0:
        assert box is None
        return
    if box is None:              # no centre near a node is inside (thin struts): no bound, no refusal
        return
    j, i = np.divmod(res.pix, grid.width)
    traced = np.array([[i.min(), j.min(), res.k0.min()], [i.max(), j.max(), res.k1.max() - 1]])
    assert np.all(box[0] >= traced[0]) and np.all(box[1] <= traced[1]), (box, traced)


def test_footprint_lower_bound_is_tight_on_a_strut():
    """On a straight strut the march from the end nodes reaches the traced extent."""
    s = Skeleton([[0, 0, 0], [10, 0, 0]], [[0, 1]], [[0.5, 0.5]])
    grid = make_grid(s.support_bounds(), 0.05)
    box = footprint_lower_bound(s, grid)
    res = trace(s, grid)
    j, i = np.divmod(res.pix, grid.width)
    assert box[0, 0] == i.min() and box[1, 0] == i.max()


def test_too_big_for_the_plate_is_refused_before_tracing(tmp_path, monkeypatch):
    """The plate check runs before any tracing: tracing is made to fail loudly."""
    import slicer.job.run

    def no_tracing(*a, **k):
        raise AssertionError("traced before refusing")

    monkeypatch.setattr(slicer.job.run, "slice_skeleton", no_tracing)
    monkeypatch.setattr(slicer.job.run, "slice_planned", no_tracing)
    lat = generate_lattice("cubic", (30, 3, 1), 5.0, 0.4)          # 150 x 15 mm
    with pytest.raises(GridError, match=r"at least 150\.\d\d x 15\.\d\d mm\) does not fit .*128 x 81 mm"):
        run_slice(lat, tmp_path / "x.sl1s", printer="prusa-sl1s", progress=False)
    assert not (tmp_path / "x.sl1s").exists()


def test_too_tall_for_the_printer_is_refused_before_tracing(tmp_path, monkeypatch):
    import slicer.job.run

    monkeypatch.setattr(slicer.job.run, "slice_skeleton", lambda *a, **k: pytest.fail("traced"))
    tall = Skeleton([[60, 40, 0], [60, 40, 160]], [[0, 1]], [[0.5, 0.5]])
    with pytest.raises(GridError, match=r"at least 16\d\.\d\d mm tall.*at most 150 mm"):
        run_slice(tall, tmp_path / "t.sl1s", printer="prusa-sl1s", progress=False)


def test_run_slice_takes_a_job_or_options_not_both(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[0.5, 0.5]])
    job = SliceJob.from_options(pixel_size=0.1)
    a = run_slice(s, tmp_path / "a", job, progress=False)
    b = run_slice(s, tmp_path / "b", pixel_size=0.1, progress=False)
    assert {k: a[k] for k in ("width", "height", "layers")} == {k: b[k] for k in ("width", "height", "layers")}
    assert (tmp_path / "a" / "layer_00000.png").read_bytes() == (tmp_path / "b" / "layer_00000.png").read_bytes()
    with pytest.raises(TypeError, match="not both"):
        run_slice(s, tmp_path / "c", job, pixel_size=0.1)


def test_public_api_is_importable_from_slicer():
    for name in ("Skeleton", "load_scene", "save_scene", "generate_lattice", "slice_skeleton", "run_slice",
                 "SliceJob", "SliceResult", "render", "RenderResult", "Part", "load_part", "slice_part"):
        assert callable(getattr(slicer, name)), name
        assert getattr(slicer, name).__doc__, name
    assert slicer.run_slice is run_slice and slicer.SliceJob is SliceJob
    # the function, not the folder of the same name (importing its modules must not shadow it)
    importlib.import_module("slicer.render.output")
    assert slicer.render is importlib.import_module("slicer.render.rendering").render
    img = slicer.render(Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[0.5, 0.5]]), size=(9, 9), view="top")
    assert img.rgba.shape == (9, 9, 4) and img.rgba[4, 4, 3] > 0 and img.rgba[0, 0, 3] == 0
    with pytest.raises(AttributeError):
        slicer.no_such_name


def test_bench_subcommands_and_legacy_flags_agree_on_refusals():
    r = CliRunner().invoke(main, ["bench", "table1", "--plot", "x.png"])
    assert r.exit_code == 2 and "No such option '--plot'" in r.output
    r = CliRunner().invoke(main, ["bench", "--table1", "--plot", "x.png"])
    assert r.exit_code == 2 and "--plot is only available with the error benchmark" in r.output
    r = CliRunner().invoke(main, ["bench", "--error", "table1"])
    assert r.exit_code == 2 and "either --error or the `table1` subcommand" in r.output
    for args in (["bench", "error", "--json", "/no/such/dir/x.json"], ["bench", "--error", "--json", "/no/such/dir/x.json"]):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 2 and "/no/such/dir does not exist" in r.output, args


def test_missing_optional_dependency_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)          # import matplotlib -> ImportError
    r = CliRunner().invoke(main, ["bench", "error", "--plot", "x.png"])
    assert r.exit_code == 2
    assert "pip install 'skelslice[plot]'" in r.output and "matplotlib" in r.output
    with pytest.raises(MissingDependencyError) as info:
        slicer.errors.require("matplotlib", "plot", "--plot")
    assert isinstance(info.value, ImportError) and info.value.extra == "plot"
