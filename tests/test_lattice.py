"""Lattice generator (slicer.scene.lattice) and the ``skelslice lattice`` command."""
from __future__ import annotations

import doctest
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import slicer.scene.lattice
from slicer import SceneError, Skeleton, load_scene
from slicer.cli.app import main
from slicer.scene.lattice import CELL_TYPES, generate_lattice, unit_cell


def _strut_set(skel: Skeleton) -> set[tuple[tuple[float, ...], tuple[float, ...]]]:
    """Struts as unordered pairs of end positions (independent of node numbering)."""
    a, b = skel.endpoints()
    return {tuple(sorted((tuple(p), tuple(q)))) for p, q in zip(a.round(9).tolist(), b.round(9).tolist())}


# ----------------------------------------------------------------------------- unit cells
@pytest.mark.parametrize("cell_type, n_nodes, n_struts", [
    ("cubic", 8, 12),      # 8 corners, 12 edges
    ("bcc", 9, 8),         # corners + centre, 4 body diagonals split at the centre
    ("fcc", 14, 24),       # corners + 6 face centres, 6 faces x 4 half face-diagonals
    ("octet", 14, 36),     # fcc + 12 octahedron edges (15 face-centre pairs - 3 opposite pairs)
    ("kelvin", 24, 36),    # truncated octahedron: 24 vertices, 36 edges
    ("diamond", 18, 16),   # 14 FCC sites + 4 inner atoms with 4 bonds each
])
def test_unit_cell_counts(cell_type, n_nodes, n_struts):
    nodes, struts = unit_cell(cell_type)
    assert nodes.shape == (n_nodes, 3)
    assert struts.shape == (n_struts, 2)
    assert np.all((nodes >= 0) & (nodes <= 1))


@pytest.mark.parametrize("cell_type, length", [
    ("cubic", 1.0), ("bcc", np.sqrt(3) / 2), ("fcc", np.sqrt(2) / 2), ("octet", np.sqrt(2) / 2),
    ("kelvin", np.sqrt(2) / 4), ("diamond", np.sqrt(3) / 4),
])
def test_all_struts_of_a_cell_have_the_same_length(cell_type, length):
    skel = generate_lattice(cell_type, (2, 2, 2), 1.0, 0.05)
    a, b = skel.endpoints()
    np.testing.assert_allclose(np.linalg.norm(b - a, axis=1), length, rtol=1e-12)


def test_kelvin_cell_is_a_truncated_octahedron():
    nodes, struts = unit_cell("kelvin")
    # every vertex of a truncated octahedron has degree 3; its square faces lie on the cube faces
    assert np.bincount(struts.ravel(), minlength=len(nodes)).tolist() == [3] * 24
    on_face = np.sum(np.isclose(nodes, 0) | np.isclose(nodes, 1), axis=1)
    assert on_face.tolist() == [1] * 24


# ----------------------------------------------------------------------------- tiled counts
# Counts derived by hand for an nx x ny x nz grid. With
#   C = (nx+1)(ny+1)(nz+1)                                   grid corners
#   E = nx(ny+1)(nz+1) + (nx+1)ny(nz+1) + (nx+1)(ny+1)nz     cell edges
#   F = nx ny (nz+1) + nx(ny+1)nz + (nx+1)ny nz              cell faces
#   N = nx ny nz                                             cells
#   S = (nx-1)ny nz + nx(ny-1)nz + nx ny(nz-1)               faces shared by two cells
# cubic   : C nodes, E struts                   (n^3 grid: 3n(n+1)^2 struts)
# bcc     : C + N nodes, 8N struts              (nothing shared but corners)
# fcc     : C + F nodes, 4F struts              (face X's shared by the two cells of a face)
# octet   : C + F nodes, 4F + 12N struts        (octahedron edges are inside the cell)
# kelvin  : 24N - 4S nodes, 36N - 4S struts     (each shared square: 4 nodes, 4 edges once)
# diamond : C - 4 + F + 4N nodes, 16N struts    (the 4 grid-box corners with an odd number of
#           "max" coordinates touch no bond; every other corner touches one)
@pytest.mark.parametrize("cell_type, cells, n_nodes, n_struts", [
    ("cubic", (1, 1, 1), 8, 12),
    ("cubic", (2, 2, 2), 27, 54),          # 3*2*3^2 = 54
    ("cubic", (3, 3, 3), 64, 144),         # 3*3*4^2 = 144
    ("cubic", (3, 2, 1), 24, 46),          # E = 3*3*2 + 4*2*2 + 4*3*1 = 18 + 16 + 12
    ("bcc", (2, 2, 2), 35, 64),            # 27 corners + 8 centres; 8 cells * 8 half-diagonals
    ("bcc", (3, 3, 3), 91, 216),           # 64 + 27; 27 * 8
    ("bcc", (4, 1, 3), 52, 96),            # 5*2*4 + 12; 12 * 8
    ("fcc", (1, 1, 1), 14, 24),
    ("fcc", (2, 2, 2), 63, 144),           # F = 3 * 4 * 3 = 36; 27 + 36; 4 * 36
    ("octet", (2, 2, 2), 63, 240),         # 4 * 36 + 12 * 8
    ("octet", (3, 2, 1), 53, 188),         # F = 6*2 + 3*3*1 + 4*2*1 = 29; C = 24; 4*29 + 12*6
    ("kelvin", (1, 1, 1), 24, 36),
    ("kelvin", (2, 2, 2), 144, 240),       # S = 3 * 4 = 12; 192 - 48; 288 - 48
    ("kelvin", (3, 2, 1), 116, 188),       # N = 6, S = 2*2 + 3*1 + 0 = 7; 144 - 28; 216 - 28
    ("diamond", (1, 1, 1), 14, 16),        # only 4 of the 8 corners are bonded
    ("diamond", (2, 2, 2), 91, 128),       # 27 - 4 + 36 + 32
    ("diamond", (3, 2, 1), 73, 96),        # C = 24, F = 29, N = 6: 20 + 29 + 24; 16 * 6
])
def test_tiled_counts(cell_type, cells, n_nodes, n_struts):
    skel = generate_lattice(cell_type, cells, 2.0, 0.2)
    assert (skel.n_nodes, skel.n_segments) == (n_nodes, n_struts)


def test_combined_cell_types_are_unions():
    # bcc and cubic share only corners: 35 nodes, 64 + 54 struts
    skel = generate_lattice("bcc+cubic", (2, 2, 2), 2.0, 0.2)
    assert (skel.n_nodes, skel.n_segments) == (35, 118)
    # fcc is a subset of octet: the union is octet
    both = generate_lattice("fcc+octet", (2, 2, 2), 2.0, 0.2)
    assert _strut_set(both) == _strut_set(generate_lattice("octet", (2, 2, 2), 2.0, 0.2))


@pytest.mark.parametrize("cell_type", CELL_TYPES)
def test_merged_graph_is_clean(cell_type):
    skel = generate_lattice(cell_type, (3, 2, 2), (1.5, 2.0, 2.5), 0.2)
    seg = skel.segments
    assert len(np.unique(skel.nodes.round(9), axis=0)) == skel.n_nodes      # no duplicate nodes
    assert np.all(seg[:, 0] < seg[:, 1])                                     # stored ascending
    assert len(np.unique(seg, axis=0)) == skel.n_segments                    # no duplicate struts
    assert np.array_equal(np.unique(seg), np.arange(skel.n_nodes))           # no orphan nodes
    z_y_x = skel.nodes[:, ::-1]
    assert all(tuple(p) < tuple(q) for p, q in zip(z_y_x[:-1].tolist(), z_y_x[1:].tolist()))


def test_node_degrees_of_infinite_lattices_appear_inside():
    # the centre node of a 3x3x3 grid sees the infinite lattice
    for cell_type, degree in [("cubic", 6), ("bcc", 8), ("fcc", 12), ("octet", 12)]:
        skel = generate_lattice(cell_type, (2, 2, 2), 1.0, 0.1)
        centre = int(np.argmin(np.linalg.norm(skel.nodes - 1.0, axis=1)))
        assert np.count_nonzero(skel.segments == centre) == degree, cell_type
    kelvin = generate_lattice("kelvin", (3, 3, 3), 1.0, 0.1)
    deg = np.bincount(kelvin.segments.ravel())
    assert set(deg.tolist()) == {3, 4}             # 4 where squares are shared, else 3


def test_scale_origin_and_anisotropic_cells():
    skel = generate_lattice("cubic", (2, 1, 1), (2.0, 3.0, 4.0), 0.3, origin=(10, -5, 1))
    np.testing.assert_array_equal(skel.nodes.min(axis=0), [10, -5, 1])
    np.testing.assert_array_equal(skel.nodes.max(axis=0), [14, -2, 5])
    assert skel.degree == 6 and skel.sigma == 2.0
    other = generate_lattice("cubic", 1, 1.0, 0.3, degree=4, sigma=3.0)
    assert (other.degree, other.sigma) == (4, 3.0)


def test_merging_is_robust_to_rounding():
    # 0.1 mm cells far from the origin: positions are not exact binary fractions
    skel = generate_lattice("octet", (3, 3, 3), 0.1, 0.01, origin=(1000.3, -7.7, 0.1))
    assert (skel.n_nodes, skel.n_segments) == (
        64 + 3 * 9 * 4, 4 * 3 * 9 * 4 + 12 * 27)


# ----------------------------------------------------------------------------- radii
def test_constant_radius():
    skel = generate_lattice("bcc", (2, 2, 2), 2.0, 0.35)
    assert skel.radii.shape == (64, 2)
    assert np.all(skel.radii == 0.35)


@pytest.mark.parametrize("axis, k", [("x", 0), ("y", 1), ("z", 2)])
def test_linear_grading_is_evaluated_at_strut_ends(axis, k):
    skel = generate_lattice("cubic", (2, 2, 2), 2.0, 0.3, radius_top=0.7, grading_axis=axis,
                            origin=(1.0, 2.0, 3.0))
    a, b = skel.endpoints()
    lo, hi = skel.nodes[:, k].min(), skel.nodes[:, k].max()
    for p, r in ((a, skel.radii[:, 0]), (b, skel.radii[:, 1])):
        np.testing.assert_allclose(r, 0.3 + 0.4 * (p[:, k] - lo) / (hi - lo), rtol=1e-14)
    assert skel.radii.min() == pytest.approx(0.3) and skel.radii.max() == pytest.approx(0.7)
    along = np.abs(b - a)[:, k] > 0
    assert np.all(skel.radii[along, 0] != skel.radii[along, 1])     # tapered along the axis
    assert np.all(skel.radii[~along, 0] == skel.radii[~along, 1])   # constant across it


def test_grading_may_decrease_and_uses_the_trimmed_extent():
    skel = generate_lattice("cubic", (1, 1, 4), 1.0, 0.5, radius_top=0.1,
                            envelope=("box", (0, 0, 1), (1, 1, 3)))
    z = skel.endpoints()[0][:, 2]
    assert z.min() == 1.0
    np.testing.assert_allclose(skel.radii[z == 1.0, 0], 0.5)
    assert skel.radii.min() == pytest.approx(0.1)


def test_radius_fn():
    def fn(p):
        return 0.2 + 0.01 * p[:, 0] + 0.02 * p[:, 2]

    skel = generate_lattice("octet", (2, 2, 1), 3.0, None, radius_fn=fn)
    a, b = skel.endpoints()
    np.testing.assert_allclose(skel.radii[:, 0], fn(a), rtol=1e-14)
    np.testing.assert_allclose(skel.radii[:, 1], fn(b), rtol=1e-14)


def test_radius_fn_gets_a_copy():
    def fn(p):
        p[:] = 0.0  # must not corrupt the lattice
        return np.full(len(p), 0.3)

    skel = generate_lattice("cubic", 1, 1.0, None, radius_fn=fn)
    assert skel.nodes.max() == 1.0


@pytest.mark.parametrize("fn, match", [
    (lambda p: np.ones((len(p), 1)), r"radius_fn must return shape \(8,\)"),
    (lambda p: np.ones(3), r"radius_fn must return shape \(8,\).*got \(3,\)"),
    (lambda p: 0.5 - p[:, 0], "radius_fn returned -0.5 at node"),
    (lambda p: np.where(p[:, 2] > 0, np.nan, 1.0), "radius_fn returned nan"),
    (lambda p: ["a"] * len(p), "radius_fn must return an array of numbers"),
])
def test_radius_fn_errors(fn, match):
    with pytest.raises(SceneError, match=match):
        generate_lattice("cubic", 1, 1.0, None, radius_fn=fn)


def test_radius_fn_excludes_radius():
    with pytest.raises(SceneError, match="either radius .* or radius_fn"):
        generate_lattice("cubic", 1, 1.0, 0.3, radius_fn=lambda p: np.ones(len(p)))
    with pytest.raises(SceneError, match="radius_fn must be callable"):
        generate_lattice("cubic", 1, 1.0, None, radius_fn=3.0)


# ----------------------------------------------------------------------------- envelopes
def test_box_envelope_equals_smaller_grid():
    big = generate_lattice("bcc", (4, 4, 4), 1.0, 0.1, envelope=("box", (0, 0, 0), (2, 2, 2)))
    small = generate_lattice("bcc", (2, 2, 2), 1.0, 0.1)
    np.testing.assert_array_equal(big.nodes, small.nodes)
    np.testing.assert_array_equal(big.segments, small.segments)


def test_box_envelope_keeps_struts_with_both_ends_inside():
    full = generate_lattice("octet", (3, 3, 3), 1.0, 0.1)
    lo, hi = np.array([0.2, 0.0, 0.5]), np.array([2.5, 3.0, 2.2])
    cut = generate_lattice("octet", (3, 3, 3), 1.0, 0.1, envelope=("box", lo, hi))
    a, b = full.endpoints()
    inside = lambda p: np.all((p >= lo) & (p <= hi), axis=1)  # noqa: E731
    keep = inside(a) & inside(b)
    assert cut.n_segments == np.count_nonzero(keep) > 0
    expected = {tuple(sorted((tuple(p), tuple(q))))
                for p, q in zip(a[keep].round(9).tolist(), b[keep].round(9).tolist())}
    assert _strut_set(cut) == expected
    assert np.array_equal(np.unique(cut.segments), np.arange(cut.n_nodes))   # orphans dropped


def test_cylinder_envelope():
    full = generate_lattice("bcc+cubic", (4, 4, 3), 2.0, 0.2)
    cut = generate_lattice("bcc+cubic", (4, 4, 3), 2.0, 0.2,
                           envelope=("cylinder", (4.0, 4.0), 2.0, 1.0, 6.0))
    d = np.hypot(cut.nodes[:, 0] - 4.0, cut.nodes[:, 1] - 4.0)
    assert np.all(d <= 2.0 + 1e-9)
    assert cut.nodes[:, 2].min() >= 1.0 and cut.nodes[:, 2].max() <= 6.0
    a, b = full.endpoints()
    ok = lambda p: (np.hypot(p[:, 0] - 4, p[:, 1] - 4) <= 2) & (p[:, 2] >= 1) & (p[:, 2] <= 6)  # noqa: E731
    assert cut.n_segments == np.count_nonzero(ok(a) & ok(b))
    # nodes exactly on the cylinder wall are inside: (2, 4) is at distance 2 exactly
    assert np.any(np.all(cut.nodes[:, :2] == [2.0, 4.0], axis=1))
    assert not np.any(np.all(cut.nodes[:, :2] == [2.0, 2.0], axis=1))


@pytest.mark.parametrize("envelope, match", [
    (("box", (5, 5, 5), (6, 6, 6)), "keeps no strut"),
    (("box", (0, 0, 0), (1, 1)), "envelope box hi must be 3 finite numbers"),
    (("box", (0, 0, 0), (1, 0, 1)), "hi > lo"),
    (("cylinder", (0, 0), -1.0, 0, 1), "envelope cylinder radius must be a finite number > 0"),
    (("cylinder", (0, 0), 1.0, 1, 1), "z1 > z0"),
    (("cylinder", (0, 0, 0), 1.0, 0, 1), r"centre \(x, y\) must be 2 finite numbers"),
    (("sphere", (0, 0, 0), 1.0), "envelope must be None"),
    ("box", "envelope must be None"),
])
def test_envelope_errors(envelope, match):
    with pytest.raises(SceneError, match=match):
        generate_lattice("cubic", (2, 2, 2), 1.0, 0.1, envelope=envelope)


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize("kwargs, match", [
    (dict(cell_type="hexagonal"), r"unknown cell type 'hexagonal'.*valid types: cubic, bcc, fcc, "
                                  r"octet, kelvin, diamond"),
    (dict(cell_type="bcc+foo"), "unknown cell type 'foo'"),
    (dict(cell_type=3), "cell_type must be a name"),
    (dict(cells=(2, 0, 2)), r"cells\[1\] must be an integer >= 1, got 0"),
    (dict(cells=(2, 2, -1)), r"cells\[2\] must be an integer >= 1, got -1"),
    (dict(cells=(2, 2.5, 2)), r"cells\[1\] must be an integer >= 1, got 2.5"),
    (dict(cells=(True, 2, 2)), r"cells\[0\] must be an integer"),
    (dict(cells=(2, 2)), "cells must be three counts"),
    (dict(cell_size=0.0), "cell_size must be a finite number > 0, got 0.0"),
    (dict(cell_size=-2), "cell_size must be a finite number > 0, got -2"),
    (dict(cell_size=float("nan")), "cell_size must be a finite number > 0, got nan"),
    (dict(cell_size=(1.0, 0.0, 1.0)), r"cell_size\[1\] must be a finite number > 0"),
    (dict(cell_size=(1.0, 1.0)), "cell_size must be one number or three"),
    (dict(radius=0.0), "radius must be a finite number > 0, got 0.0"),
    (dict(radius=-0.1), "radius must be a finite number > 0, got -0.1"),
    (dict(radius="thick"), "radius must be a number > 0, got 'thick'"),
    (dict(radius=None), "radius must be a number > 0, got None"),
    (dict(radius=True), "radius must be a number > 0, got True"),
    (dict(radius_top=0.0), "radius_top must be a finite number > 0, got 0.0"),
    (dict(radius_top=float("inf")), "radius_top must be a finite number > 0, got inf"),
    (dict(grading_axis="w"), "grading_axis must be one of 'x', 'y', 'z', got 'w'"),
    (dict(origin=(0, 0)), "origin must be 3 finite numbers"),
    (dict(origin=(0, 0, float("nan"))), "origin must be 3 finite numbers"),
    (dict(cells=(1000, 1000, 1000)), r"would need 8000000000 struts \(limit"),
    (dict(degree=5), "kernel degree must be an even integer"),
    (dict(sigma=1.0), "kernel sigma must be a finite number > 1"),
])
def test_errors_name_parameter_and_value(kwargs, match):
    args = dict(cell_type="bcc", cells=(2, 2, 2), cell_size=1.0, radius=0.1)
    args.update(kwargs)
    with pytest.raises(SceneError, match=match):
        generate_lattice(**args)


def test_errors_are_value_errors():
    with pytest.raises(ValueError):
        generate_lattice("bcc", (2, 2, 2), 1.0, -1.0)


def test_docstring_examples():
    result = doctest.testmod(slicer.scene.lattice, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 4 and result.failed == 0


# ----------------------------------------------------------------------------- CLI
def _invoke(*args):
    return CliRunner().invoke(main, ["lattice", *args])


def test_cli_writes_a_scene(tmp_path):
    out = tmp_path / "bcc.json"
    res = _invoke("bcc", "--cells", "2", "2", "2", "--cell-size", "5", "--radius", "0.5", "-o", str(out))
    assert res.exit_code == 0, res.output
    skel = load_scene(out)
    ref = generate_lattice("bcc", (2, 2, 2), 5.0, 0.5)
    np.testing.assert_array_equal(skel.nodes, ref.nodes)
    np.testing.assert_array_equal(skel.segments, ref.segments)
    np.testing.assert_array_equal(skel.radii, ref.radii)
    line = res.output.strip()
    assert "\n" not in line
    assert "bcc" in line and "35 nodes" in line and "64 struts" in line and "[10, 10, 10]" in line


def test_cli_grading_envelope_and_kernel(tmp_path):
    out = tmp_path / "graded.json"
    res = _invoke("octet", "--cells", "4", "4", "3", "--cell-size", "2,2,3", "--radius", "0.2:0.4",
                  "--axis", "x", "--envelope-cylinder", "4", "4", "3.5", "0", "9",
                  "--origin", "0", "0", "0", "--degree", "4", "--sigma", "2.5", "-o", str(out))
    assert res.exit_code == 0, res.output
    ref = generate_lattice("octet", (4, 4, 3), (2, 2, 3), 0.2, radius_top=0.4, grading_axis="x",
                           envelope=("cylinder", (4, 4), 3.5, 0, 9), degree=4, sigma=2.5)
    skel = load_scene(out)
    np.testing.assert_array_equal(skel.segments, ref.segments)
    np.testing.assert_array_equal(skel.radii, ref.radii)
    assert (skel.degree, skel.sigma) == (4, 2.5)

    out2 = tmp_path / "box.json"
    res = _invoke("cubic", "--cells", "3", "3", "3", "--cell-size", "1", "--radius", "0.1",
                  "--envelope-box", "0", "0", "0", "2", "2", "2", "-o", str(out2))
    assert res.exit_code == 0, res.output
    assert load_scene(out2).n_segments == 54


@pytest.mark.parametrize("args, needle", [
    (["--radius", "0.3:abc"], "'abc' is not a number"),
    (["--radius", "-1"], "R must be a finite number > 0"),
    (["--radius", "0.3:0"], "R_TOP must be a finite number > 0"),
    (["--radius", "1:2:3"], "expected R or R:R_TOP"),
    (["--radius", "0.3", "--cell-size", "0"], "cell size must be a finite number > 0"),
    (["--radius", "0.3", "--cell-size", "1,2"], "three comma-separated sizes"),
    (["--radius", "0.3", "--cells", "2", "0", "2"], "--cells"),
    (["--radius", "0.3", "--axis", "w"], "--axis"),
    (["--radius", "0.3", "--envelope-box", "0", "0", "0", "1", "1", "1",
      "--envelope-cylinder", "0", "0", "1", "0", "1"], "at most one of --envelope-box"),
    (["--radius", "0.3", "--envelope-box", "5", "5", "5", "6", "6", "6"], "error: envelope"),
    (["--radius", "0.3", "--degree", "3"], "error: kernel degree"),
    (["--radius", "0.3", "TYPE=hexagonal"], "error: unknown cell type 'hexagonal'"),
])
def test_cli_bad_input_exits_2_without_traceback(tmp_path, args, needle):
    args = list(args)
    cell_type = "bcc"
    if args[-1].startswith("TYPE="):
        cell_type = args.pop()[5:]
    base = {"--cells": ["2", "2", "2"], "--cell-size": ["1"]}
    for opt in list(base):
        if opt in args:
            del base[opt]
    flat = [x for k, v in base.items() for x in (k, *v)]
    out = tmp_path / "x.json"
    res = _invoke(cell_type, *flat, *args, "-o", str(out))
    assert res.exit_code == 2, res.output
    assert needle in res.output
    assert "Traceback" not in res.output
    assert not out.exists()


def test_cli_help_lists_the_options():
    res = _invoke("--help")
    assert res.exit_code == 0
    for word in ("TYPE", "--cells", "--cell-size", "--radius", "R[:R_TOP]", "--axis", "--envelope-box",
                 "--envelope-cylinder", "--degree", "--sigma", "--output", *CELL_TYPES):
        assert word in res.output


def test_cli_subprocess(tmp_path):
    out = tmp_path / "kelvin.json"
    proc = subprocess.run(
        [sys.executable, "-m", "slicer", "lattice", "kelvin", "--cells", "2", "2", "2",
         "--cell-size", "6", "--radius", "0.4:0.6", "-o", str(out)],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "144 nodes, 240 struts" in proc.stdout
    skel = load_scene(out)
    assert (skel.n_nodes, skel.n_segments) == (144, 240)
    assert skel.radii.min() == pytest.approx(0.4) and skel.radii.max() == pytest.approx(0.6)

    bad = subprocess.run(
        [sys.executable, "-m", "slicer", "lattice", "bcc", "--cells", "2", "2", "2",
         "--cell-size", "1", "--radius", "0.3:abc", "-o", str(tmp_path / "bad.json")],
        capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
    assert "'abc' is not a number" in bad.stderr and "Traceback" not in bad.stderr
