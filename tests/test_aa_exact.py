"""--aa exact: each pixel's grey is the exact area of the section in it."""
from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from formats.printer_profiles import PrintSettings
from slicer import Skeleton
from slicer.raster.antialias import (Z_PLANES, box_filter, check_aa, iter_exact_coverage, output_grid, output_layers,
                              polygon_coverage)
from slicer.contours import grid_box, plane_contours
from slicer.errors import OptionError
from slicer.tracer.grid import SliceGrid
from slicer.tracer.slicing import slice_skeleton

TOL = 1e-4


def _pixel_boxes(g: SliceGrid):
    j, i = np.mgrid[0:g.height, 0:g.width]
    cx = g.origin[0] + i * g.pixel_size[0]
    cy = g.origin[1] - j * g.pixel_size[1]
    hx, hy = 0.5 * g.pixel_size[0], 0.5 * g.pixel_size[1]
    return shapely.box(cx - hx, cy - hy, cx + hx, cy + hy)


def _exact_fraction(geom, g: SliceGrid) -> np.ndarray:
    boxes = _pixel_boxes(g)
    return shapely.area(shapely.intersection(boxes, geom)) / (g.pixel_size[0] * g.pixel_size[1])


def test_polygon_coverage_is_the_area_of_intersection():
    g = SliceGrid((0.05, 0.95, 0.0), (0.1, 0.1), 0.1, 10, 10, 1)
    rng = np.random.default_rng(3)
    for _ in range(10):
        pts = rng.uniform(0.0, 1.0, (12, 2))
        geom = shapely.convex_hull(shapely.multipoints(pts)).difference(
            shapely.Point(*rng.uniform(0.3, 0.7, 2)).buffer(0.1))
        mp = shapely.MultiPolygon([shapely.geometry.polygon.orient(geom, 1.0)])
        assert np.abs(polygon_coverage(mp, g) - _exact_fraction(mp, g)).max() < 1e-12


def test_vertical_strut_disc_is_exact():
    """The middle of a long strut is the disc of radius tau exactly (docs/math.md §1.3)."""
    s = Skeleton([[0, 0, -6], [0, 0, 6]], [[0, 1]], [[0.7, 0.7]])
    g = SliceGrid((-0.8 + 0.0317, 0.8 + 0.0113, 0.0), (0.05, 0.05), 0.05, 34, 34, 1)
    mp = plane_contours(s, 0.0, TOL, (-2, -2, 2, 2))
    cov = polygon_coverage(mp, g)
    disc = shapely.Point(0, 0).buffer(0.7, quad_segs=4096)
    ref = _exact_fraction(disc, g)
    px_area = 0.05 * 0.05
    # the contour's error: at most TOL across the boundary inside each pixel
    per_pixel = TOL * 2 * 0.05 * math.sqrt(2) / px_area
    assert np.abs(cov - ref).max() <= per_pixel
    assert abs(cov.sum() * px_area - math.pi * 0.49) <= TOL * 2 * math.pi * 0.7


def test_horizontal_slab_is_exact_and_aa_z_within_its_bound():
    """A long horizontal strut's section at height z is the strip |y| <= sqrt(tau^2 - z^2)."""
    tau = 0.5
    s = Skeleton([[-8, 0, 0], [8, 0, 0]], [[0, 1]], [[tau, tau]])
    h = 0.1
    g = SliceGrid((-0.475, 0.6 + 0.013, -0.25), (0.05, 0.05), h, 20, 25, 5)
    box = (-1, -1, 1, 1)
    for z in (-0.2, 0.0, 0.35):
        w = math.sqrt(tau * tau - z * z)
        strip = shapely.box(-1, -w, 1, w)
        cov = polygon_coverage(plane_contours(s, z, TOL, box), g)
        assert np.abs(cov - _exact_fraction(strip, g)).max() <= TOL * 2 * 0.05 / 0.05 ** 2
    # --aa-z: the mean of Z_PLANES exact areas per voxel, against the voxel's exact volume
    res = _GridOnly(g)
    covs = list(iter_exact_coverage(s, res, True, TOL))
    for k, cov in enumerate(covs):
        zk = g.origin[2] + k * h
        zs = zk - h / 2 + (np.arange(2000) + 0.5) * h / 2000
        vol = np.mean([_exact_fraction(shapely.box(-1, -math.sqrt(max(tau * tau - z * z, 0)), 1,
                                                   math.sqrt(max(tau * tau - z * z, 0))), g) for z in zs[::50]],
                      axis=0)
        # documented bound L h / (4 S) with L the largest |d coverage / dz| (the strip's edge moves
        # by |z| / w per mm, over a 0.05 mm pixel), plus the contour tolerance
        zmax = max(abs(zk) + h / 2, 1e-9)
        wmin = math.sqrt(max(tau * tau - zmax * zmax, 1e-12))
        L = (zmax / wmin) / 0.05
        bound = L * h / (4 * Z_PLANES) + 0.03 + TOL * 40    # + the 40-plane reference's own error
        assert np.abs(cov - vol).max() <= bound


class _GridOnly:
    """A result stand-in: the exact coverage only needs the grid."""

    def __init__(self, grid):
        self.grid = grid


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_matches_aa16_within_the_supersampling_error(seed):
    rng = np.random.default_rng(seed)
    n = 4
    nodes = rng.uniform(-1.5, 1.5, (n, 3))
    segs = [[i, i + 1] for i in range(n - 1)]
    s = Skeleton(nodes, segs, rng.uniform(0.2, 0.5, (len(segs), 2)))
    r16 = slice_skeleton(s, 0.1 / 16, layer_height=0.1)     # 4 of its layers are compared
    g_out = output_grid(r16.grid, 16)
    settings = PrintSettings(None, r16.grid.layer_height, aa=16)
    assert output_layers(r16, settings)[0] == g_out
    ks = np.linspace(0, g_out.layers - 1, 4).astype(int)
    sub = list(_nth(r16.iter_layers(1), set(ks)))
    for k, img in zip(ks, sub):
        cov16 = box_filter(img.astype(float), 16)[0][:g_out.height, :g_out.width]
        z = g_out.origin[2] + k * g_out.layer_height
        cov = polygon_coverage(plane_contours(s, z, TOL, grid_box(g_out)), g_out)
        d = np.abs(cov - cov16)
        # 16 x 16 point samples: a boundary crossing a pixel miscounts at most the
        # sub-pixels it cuts, ~2 * 16 of 256, and on average far fewer
        assert d.max() <= 0.13
        edge = (cov > 0) & (cov < 1) | (cov16 > 0) & (cov16 < 1)
        if edge.any():
            assert d[edge].mean() <= 0.02


def _nth(it, keep):
    for k, item in enumerate(it):
        if k in keep:
            yield item


def test_check_aa_accepts_exact_and_refuses_words():
    assert check_aa("exact", 1.0) == (1, 1.0)
    assert check_aa("4", 1.0) == (4, 1.0)
    with pytest.raises(OptionError, match="exact"):
        check_aa("fine", 1.0)


def test_cli_aa_exact_writes_the_disc_area(tmp_path):
    import json

    from click.testing import CliRunner
    from PIL import Image

    from slicer.cli.app import main

    scene = tmp_path / "strut.json"
    scene.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 6]],
                                 "segments": [[0, 1]], "radii": [0.5, 0.5]}))
    out = tmp_path / "stack"
    res = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--pixel-size", "0.1",
                                    "--layer-height", "0.1", "--aa", "exact"])
    assert res.exit_code == 0, res.output
    files = sorted(out.glob("*.png"))
    img = np.asarray(Image.open(files[len(files) // 2]), dtype=float) / 255.0
    assert 0 < ((img > 0) & (img < 1)).sum()                       # greys on the rim
    assert img.sum() * 0.01 == pytest.approx(math.pi * 0.25, abs=img.size * 0.01 / 510)   # 8-bit rounding
    bad = CliRunner().invoke(main, ["slice", str(scene), "-o", str(tmp_path / "x"), "--aa", "most"])
    assert bad.exit_code == 2 and "exact" in bad.output and not (tmp_path / "x").exists()
