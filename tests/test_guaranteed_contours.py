"""Guaranteed contours against a dense independent section, on scenes whose
features the pixel-centre raster cannot show: slanted needles with sub-pixel
tips, planes grazing a strut's top, sub-pixel islands, near-tangent necks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from slicer import Skeleton
from slicer.contours import check_resolvable, iter_contours, mask_rings, plane_contours
from slicer.contours.cells import _root_grid, plane_segments
from slicer.errors import OptionError
from slicer.model.field import evaluate
from slicer.tracer.slicing import slice_skeleton
from validation.independent import assemble, boundary_hausdorff, dense_section

TOL = 1e-3
STEP = 0.004                       # the dense section's grid
SAMPLING = STEP * math.sqrt(2)     # its boundary's distance to the exact one (features wider than STEP)

SCENES = {
    # tapering struts at shallow slopes: their sections end in tips far thinner than a pixel
    "needles": Skeleton([[-1.5, 0, -1], [1.5, 0.3, 1], [-1, 1, -1], [1.2, 0.8, 1.0]], [[0, 1], [2, 3]],
                        [[0.01, 0.3], [0.3, 0.005]]),
    # a horizontal strut: layers near its top cut a strip narrower than a pixel
    "grazing": Skeleton([[-2, 0, 0], [2, 0, 0]], [[0, 1]], [[0.3, 0.3]]),
    # blobs a fraction of a pixel across, between pixel centres
    "islands": Skeleton([[0.03, 0.04, 0], [0.06, 0.05, 0.02], [0.55, 0.23, 0], [0.56, 0.24, 0.01]],
                        [[0, 1], [2, 3]], [[0.03, 0.02], [0.02, 0.02]]),
    # two struts whose gap closes along z: a neck that pinches off
    "necks": Skeleton([[0, 0, -1], [0, 0, 1], [0.55, 0, -1], [0.8, 0, 1]], [[0, 1], [2, 3]],
                      [[0.3, 0.3], [0.3, 0.3]]),
}


def _support_box(s: Skeleton, z: float):
    """The plane's support box from the skeleton's own data (independent of slicer's boxes)."""
    a, b = s.endpoints()
    r = s.sigma * s.radii
    lo = np.minimum(a - r[:, :1], b - r[:, 1:])
    hi = np.maximum(a + r[:, :1], b + r[:, 1:])
    m = (lo[:, 2] <= z) & (z <= hi[:, 2])
    if not m.any():
        return None
    return lo[m, 0].min(), lo[m, 1].min(), hi[m, 0].max(), hi[m, 1].max()


def _check_plane(s, z, ours):
    box = _support_box(s, z)
    ref = dense_section(s, z, box, STEP) if box is not None else assemble([])
    assert ours.is_valid
    if ours.is_empty or ref.is_empty:     # a tangent plane: whatever one of them holds is thinner than the errors
        assert ours.buffer(-TOL).is_empty and ref.buffer(-SAMPLING).is_empty, z
        return ref
    h = boundary_hausdorff(ours, ref)
    assert h <= TOL + SAMPLING, (z, h)
    return ref


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_layer_within_tolerance_of_the_dense_section(name):
    s = SCENES[name]
    if name == "islands":          # no pixel centre is inside: the default bounds would be empty
        r = slice_skeleton(s, 0.1, layer_height=0.01, bounds=(-0.2, -0.2, -0.05, 0.8, 0.5, 0.05))
    else:
        r = slice_skeleton(s, 0.1, layer_height=0.1)
    assert r.grid.layers >= 5
    n = 0
    for k, z, mp in iter_contours(s, r, TOL):
        ref = _check_plane(s, z, mp)
        n += 1
    assert n == r.grid.layers


@pytest.mark.parametrize("name, zs", [
    ("needles", [-0.97, -0.9, 0.93, 0.98]),
    ("grazing", [0.3 - 0.002, 0.3 - 0.0005, 0.3 - 2e-5]),
    ("islands", [0.0, 0.005, 0.01, 0.02]),
    ("necks", [-0.9, -0.3, 0.0, 0.4, 0.9]),
])
def test_thin_features_between_pixel_centres_appear(name, zs):
    s = SCENES[name]
    for z in zs:
        ours = plane_contours(s, z, TOL)
        ref = _check_plane(s, z, ours)
        assert len(ours.geoms) == len(ref.geoms)


#: four struts lying in the plane z = 0 meet a vertical one at a node
CROSS = Skeleton([[0, 0, 0], [2, 0, 0], [-2, 0, 0], [0, 2, 0], [0, -2, 0], [0, 0, 1.5]],
                 [[0, 1], [0, 2], [0, 3], [0, 4], [0, 5]], [[0.3, 0.3]] * 4 + [[0.2, 0.2]])


@pytest.mark.parametrize("name, z, crest", [("grazing", 0.3, 2.8), ("cross", 0.3, 3.2), ("cross", -0.3, 3.2)])
def test_planes_tangent_to_struts_lying_in_them_settle_on_the_crests(name, z, crest):
    """A plane through the top (or bottom) of struts lying in it touches them along
    lines (``crest`` mm of them away from the struts' ends), where the field's crest
    is within rounding of 1 and its in-plane gradient vanishes. Crest cells settle
    those (docs/math.md §10.1): the finest leaves are a tenth of the one per finest
    side that the crests alone would take when split down to them. The section is
    the dense one's, except for tails along the crests narrower than its grid."""
    s = CROSS if name == "cross" else SCENES[name]
    st: dict = {}
    ours = plane_contours(s, z, TOL, stats=st)
    _, _, s0, _, _, levels = _root_grid(s, plane_segments(s, z), TOL, None)
    h = s0 / 2 ** levels
    assert st["thin_leaves"] > 0
    assert st["small_leaves"] < 0.1 * crest / h, (st["small_leaves"], crest / h)
    ref = dense_section(s, z, _support_box(s, z), STEP)
    assert ours.is_valid
    assert ref.difference(ours.buffer(TOL + SAMPLING)).is_empty
    assert ours.difference(ref.buffer(TOL + SAMPLING)).buffer(-STEP / 2).is_empty


def test_the_raster_contours_miss_what_the_guaranteed_ones_keep():
    """The motivating failure: at 0.1 mm pixels, sub-pixel islands and a grazing
    strip hold no pixel centre, so the raster's marching squares lose them."""
    for name, z, origin in (("islands", 0.005, (-0.5, 0.8)), ("grazing", 0.3 - 0.0005, (-2.5, 0.85))):
        s = SCENES[name]
        H, W = 18, 51 if name == "grazing" else 14
        j, i = np.mgrid[0:H, 0:W]
        pts = np.column_stack([origin[0] + 0.1 * i.ravel(), origin[1] - 0.1 * j.ravel(), np.full(H * W, z)])
        mask = (evaluate(s, pts)[0] >= 1.0).reshape(H, W)       # the tracer's exact pixel-centre raster
        old = mask_rings(s, mask, origin, (0.1, 0.1), z, TOL)
        ours = plane_contours(s, z, TOL)
        ref = dense_section(s, z, _support_box(s, z), STEP)
        assert not mask.any() and old == []
        assert len(ours.geoms) == len(ref.geoms) >= 1
        assert ours.area == pytest.approx(ref.area, rel=0.25)


def test_tolerance_below_float64_resolution_is_refused():
    s = Skeleton([[1e5, 0, 0], [1e5, 0, 1]], [[0, 1]], [[0.5, 0.5]])
    with pytest.raises(OptionError, match="1e-09"):
        check_resolvable(s, 1e-9)
    assert check_resolvable(s, 1e-3) == 1e-3


def test_cli_refuses_an_unresolvable_tolerance_before_any_work(tmp_path):
    import json

    from click.testing import CliRunner

    from slicer.cli.app import main

    scene = tmp_path / "far.json"
    scene.write_text(json.dumps({"skelslice": 1, "units": "mm", "nodes": [[1e5, 0, 0], [1e5, 0, 2]],
                                 "segments": [[0, 1]], "radii": [0.5, 0.5]}))
    out = tmp_path / "far.svg"
    res = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--pixel-size", "0.1",
                                    "--contour-tol", "1e-9"])
    assert res.exit_code == 2 and "--contour-tol" in res.output and "1e-09" in res.output and not out.exists()


@pytest.mark.parametrize("seed", range(6))
def test_random_scenes_within_tolerance_of_the_dense_section(seed):
    """Random tapering struts, small and thin against a 0.1 mm pixel, two planes each."""
    rng = np.random.default_rng(1000 + seed)
    n = int(rng.integers(3, 6))
    nodes = rng.uniform(-0.6, 0.6, (n, 3))
    segs = [[i, i + 1] for i in range(n - 1)]
    radii = rng.uniform(0.02, 0.2, (len(segs), 2))
    s = Skeleton(nodes, segs, radii)
    lo, hi = s.support_bounds()
    for z in rng.uniform(lo[2] + 0.1 * (hi[2] - lo[2]), hi[2] - 0.1 * (hi[2] - lo[2]), 2):
        ours = plane_contours(s, float(z), TOL)
        ref = _check_plane(s, float(z), ours)
        assert len(ours.geoms) == len(ref.geoms)


def test_planes_on_threads_give_the_serial_contours_and_counts():
    """Layer planes computed on 2 threads: the same polygons, bit for bit, and
    the same work counts as one plane after the other."""
    s = Skeleton([[-1, 0, -1], [1, 0.2, 1], [0, -1, -1], [0.1, 1, 1], [-1, -1, 0], [1, 1, 0]],
                 [[0, 1], [2, 3], [4, 5]], [[0.2, 0.1], [0.15, 0.25], [0.2, 0.2]])
    res = slice_skeleton(s, 0.1)
    got = {}
    for workers in (1, 2):
        st: dict = {}
        got[workers] = ([(k, z, mp.wkb) for k, z, mp in iter_contours(s, res, TOL, stats=st, workers=workers)], st)
    assert got[1] == got[2]
    assert len(got[1][0]) == res.grid.layers and got[1][1]["evaluations"] > 0
