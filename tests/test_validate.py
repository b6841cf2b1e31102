"""Meshed reference, metrics, `skelslice validate` and the error-vs-time sweep."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import shapely
from click.testing import CliRunner

from slicer import Skeleton
from slicer.cli.app import main
from validation.metrics import compare_layer, hausdorff, polygon_rings, rasterize_rings
from validation.reference_mesh import reference_mesh, reference_sections

FRAME = Skeleton([[0, 0, 0], [6, 0, 0], [6, 6, 0], [0, 6, 0], [3, 3, 3]],
                 [[0, 1], [1, 2], [2, 3], [3, 0], [0, 4], [2, 4]], [[0.6, 0.6]] * 4 + [[0.6, 0.3]] * 2)


def test_reference_mesh_is_a_closed_manifold_of_the_field():
    s = Skeleton([[0, 0, -3], [0, 0, 3]], [[0, 1]], [[1.0, 1.0]])
    man, info = reference_mesh(s, 0.1)
    assert man.status().name == "NoError" and man.genus() == 0
    # the field's solid: a cylinder of radius 1 with free ends only ~0.25 tau
    # beyond the end points (docs/math.md §1.5), not capsule caps of radius 1
    zmin, zmax = man.bounding_box()[2], man.bounding_box()[5]
    assert 3.2 < zmax < 3.3 and -3.3 < zmin < -3.2
    sec = man.slice(0.0)
    assert sec.area() == pytest.approx(math.pi, rel=3e-3)
    assert 0 < info.error_3d < 0.01


def test_section_of_a_band_equals_the_whole_mesh_section():
    edge = 0.1
    man, _ = reference_mesh(FRAME, edge)
    lo = FRAME.support_bounds()[0] - edge
    # a height between grid planes of the whole-box mesh, as the band expects
    z = float(lo[2] + 14.5 * edge)
    sec = reference_sections(FRAME, [z], edge)[0]
    assert sec.polygons.is_valid
    assert sec.polygons.area == pytest.approx(man.slice(z).area(), rel=1e-9)
    finer = reference_sections(FRAME, [z], edge / 2)[0]
    assert finer.info.error_3d < sec.info.error_3d        # chordal error shrinks with the edge


def test_rasterize_matches_point_in_polygon():
    rng = np.random.default_rng(3)
    poly = shapely.Point(0.1, -0.2).buffer(1.3, 7).difference(shapely.Point(0.3, 0.1).buffer(0.4, 5))
    poly = shapely.MultiPolygon([poly, shapely.box(1.6, 1.6, 2.4, 2.1)])
    origin, ps = (-2.0 + rng.uniform(0, 0.1), 2.5), (0.043, 0.051)
    H, W = 100, 110
    got = rasterize_rings(polygon_rings(poly), origin, ps, H, W)
    X, Y = np.meshgrid(origin[0] + np.arange(W) * ps[0], origin[1] - np.arange(H) * ps[1])
    want = shapely.contains_xy(poly, X, Y)
    assert np.array_equal(got, want)


def test_hausdorff_matches_shapely():
    a = shapely.Point(0, 0).buffer(1, 40)
    b = shapely.Point(0.02, 0.01).buffer(0.99, 31)
    want = shapely.hausdorff_distance(a.boundary, b.boundary, densify=0.25)
    assert hausdorff(polygon_rings(a), polygon_rings(b)) == pytest.approx(want, rel=1e-12)


def test_metrics_catch_a_wrong_reference():
    from slicer.contours import layer_contours, layer_mask
    from slicer.tracer.slicing import slice_skeleton

    r = slice_skeleton(FRAME, 0.1)
    k = int(np.argmax([m.sum() for m in r.iter_layers(1)]))
    z = r.grid.origin[2] + k * r.grid.layer_height
    ours = layer_contours(FRAME, r, k)
    good = compare_layer(FRAME, ours, ours, z, layer_mask(r, k), r.grid.origin[:2], r.grid.pixel_size, tol=1e-3)
    assert good["iou"] == 1.0 and good["hausdorff"] < 1e-12
    # rows of pixel centres lie exactly on the horizontal struts' surface (|y| = tau): either side is right
    assert good["pixel_mismatch"] == good["contour_raster_mismatch"]
    assert good["contour_raster_unexplained"] == 0
    bad_ref = shapely.affinity.translate(ours, 0.05, 0.0)
    bad = compare_layer(FRAME, ours, bad_ref, z, layer_mask(r, k), r.grid.origin[:2], r.grid.pixel_size,
                        ref_bound=1e-3)
    assert bad["hausdorff"] == pytest.approx(0.05, rel=1e-6)
    assert bad["iou"] < 0.99 and bad["pixel_mismatch"] > 0 and bad["pixel_mismatch_unexplained"] > 0


def test_validate_passes_on_a_small_lattice():
    from sample_lattices import load_sample
    from validation.validate import validate

    rep = validate(load_sample("octet_2x2x2"), pixels=96, layers_checked=3)
    assert rep["passed"], rep["checks"]
    assert len(rep["layers"]) == 3
    for row in rep["layers"]:
        assert row["hausdorff"] <= row["mesh_bound"] + 1e-3
        assert row["vertex_max_3d"] <= 1e-3
        assert row["pixel_mismatch_unexplained"] == 0
        assert row["iou"] > 0.99


def test_cli_validate_pass_fail_and_report(tmp_path):
    from sample_lattices import sample_path

    scene = str(sample_path("cubic_2x2x2"))
    runner = CliRunner()
    rep = tmp_path / "rep"
    res = runner.invoke(main, ["validate", scene, "--pixels", "80", "--layers-checked", "2", "--report", str(rep)])
    assert res.exit_code == 0, res.output
    assert "[pass] hausdorff_within_mesh_bound" in res.output
    data = json.loads((rep / "report.json").read_text())
    assert data["passed"] and len(data["layers"]) == 2 and data["images"]
    for name in data["images"]:
        assert (rep / name).stat().st_size > 0
    # a threshold that cannot hold: exit status 1, the failed check named
    res = runner.invoke(main, ["validate", scene, "--pixels", "80", "--layers-checked", "1",
                               "--max-hausdorff", "1e-9"])
    assert res.exit_code == 1
    assert "[FAIL] max_hausdorff" in res.output
    # an existing report folder is refused before any work (status 2)
    res = runner.invoke(main, ["validate", scene, "--pixels", "80", "--report", str(rep)])
    assert res.exit_code == 2 and "already exists" in res.output


def test_python_m_slicer_validate_json(tmp_path):
    from sample_lattices import sample_path

    out = subprocess.run([sys.executable, "-m", "slicer", "validate", str(sample_path("cubic_2x2x2")),
                          "--pixels", "64", "--layers-checked", "1", "--min-iou", "0.99", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["checks"]["min_iou"] and data["passed"]


def test_error_time_sweep_small(tmp_path):
    from validation.error_time import format_table, pareto, sweep

    cfgs = [{"method": "interval", "pixels": 32, "layers": 16, "tol": 1e-3, "bucket": 64},
            {"method": "interval", "pixels": 32, "layers": 16, "tol": 1e-2, "bucket": 64},
            {"method": "dense", "pixels": 32, "layers": 16, "tol": None, "bucket": None}]
    res = sweep("cubic_2x2x2", configs=cfgs, ref_pixels=192, ref_tol=1e-4)
    rows = res["rows"]
    assert len(rows) == 3
    # the contour error follows the tolerance; the dense baseline has no root refinement
    assert rows[0]["error_layer"] <= 1e-3 < rows[2]["error_layer"]
    assert rows[0]["error_layer"] < rows[1]["error_layer"] <= 1e-2
    front = pareto(rows, "error_layer")
    assert front and all(0 <= i < 3 for i in front)
    assert "Pareto" in format_table(res)
    json.dumps(res)
    pytest.importorskip("matplotlib")
    from validation.error_time import plot

    assert plot(res, tmp_path / "p.png").stat().st_size > 1000


def test_error_time_contours_compares_the_two_routes_on_one_grid(tmp_path):
    """``--contours PIXELS LAYERS`` runs the raster route and the guaranteed
    contours, each at 1, 10 and 0.1 um, on that grid, and the JSON says so."""
    from validation.error_time import main as error_time

    out = tmp_path / "et.json"
    assert error_time(["--model", "cubic_2x2x2", "--contours", "16", "8", "--ref-pixels", "64",
                       "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    rows = res["rows"]
    assert [(r["method"], r["tol"]) for r in rows] == [(m, t) for t in (1e-3, 1e-2, 1e-4)
                                                      for m in ("interval", "guaranteed")]
    assert {(r["pixels"], r["layers"]) for r in rows} == {(16, 8)}
    assert res["reference"]["pixels"] == 64 and "--contours" in res["command"]
    assert all(np.isfinite(r["error_layer"]) and r["seconds"] > 0 and r["evaluations"] > 0 for r in rows)
    assert all(r["contour_vertices"] > 0 for r in rows)


@pytest.mark.parametrize("method", ["interval", "dense"])
def test_error_time_routes_end_as_the_outputs_do_on_any_thread_count(method):
    """Each route's kept layers are the MultiPolygons the contour outputs write
    from its rings (:func:`slicer.contours.finish_rings`: simplified at tol/4
    where there is a tolerance), computed here layer by layer, and the same
    with one thread or two (the layers run on the threads)."""
    from sample_lattices import load_sample
    from slicer._kernels.runtime.launch import numba_threads
    from slicer.contours import finish_rings, grid_box, mask_rings
    from slicer.model.field import evaluate
    from slicer.tracer.grid import make_grid
    from slicer.tracer.slicing import trace
    from validation.error_time import run_config, square_box
    from validation.metrics import polygon_rings

    skel = load_sample("cubic_2x2x2")
    tol = 1e-2 if method == "interval" else None
    cfg = {"method": method, "pixels": 40, "layers": 12, "tol": tol, "bucket": 64 if tol else None}
    keep = {3, 6, 9}
    runs = []
    for threads in (1, 2):
        with numba_threads(threads):
            runs.append(run_config(skel, cfg, keep)[1])
    (x0, y0, x1, y1), (z0, z1) = square_box(skel)
    h = (z1 - z0) / 12
    grid = make_grid(skel.support_bounds(), (x1 - x0) / 40, layer_height=h, bounds=(x0, y0, z0, x1, y1, z1))
    if method == "interval":
        masks = list(trace(skel, grid).iter_layers(1))
    simplified = 0
    for k in sorted(keep):
        z = grid.centres_z()[k]
        if method == "interval":
            rings = mask_rings(skel, masks[k].astype(bool), grid.origin[:2], grid.pixel_size, z, tol)
        else:
            X, Y = np.meshgrid(grid.centres_x(), grid.centres_y())
            p = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
            V = evaluate(skel, p)[0].reshape(grid.height, grid.width)
            rings = mask_rings(skel, V >= 1.0, grid.origin[:2], grid.pixel_size, z, refine=False, values=V)
        want = polygon_rings(finish_rings(rings, tol, grid_box(grid)))
        for got in runs:
            assert len(got[k]) == len(want) and all(np.array_equal(a, b) for a, b in zip(got[k], want))
        simplified += sum(r.shape[0] for r in rings) - sum(r.shape[0] for r in want)
    # the finishing did something where there is a tolerance to simplify to
    assert (simplified > 0) == (method == "interval")


def test_cli_bench_needs_a_benchmark():
    res = CliRunner().invoke(main, ["bench"])
    assert res.exit_code == 2 and "error, table1" in res.output


def test_contour_cost_measures_the_slice_commands_grid(tmp_path):
    """``--pixel-size`` gives ``contour_cost`` the grid of ``slice --pixel-size``
    (not the sweep's), and the table and JSON report both jobs on it."""
    from sample_lattices import load_sample
    from slicer.tracer.slicing import slice_skeleton
    from validation.contour_cost import main as contour_cost

    out = tmp_path / "cost.json"
    assert contour_cost(["--model", "cubic_2x2x2", "--pixel-size", "0.4", "--tol", "0.01", "--repeat", "1",
                         "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    grid = slice_skeleton(load_sample("cubic_2x2x2"), 0.4).grid
    assert (res["grid"]["width"], res["grid"]["height"], res["grid"]["layers"]) == (grid.width, grid.height,
                                                                                    grid.layers)
    assert res["grid"]["pixel_size"] == 0.4 and "--pixel-size 0.4" in res["command"]
    assert res["guaranteed"]["counts"]["vertices"] > 0 and res["trace"]["counts"]["evaluations"] > 0
