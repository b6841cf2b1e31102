"""Layer contours: shapes with known answers, vertices on the surface, winding,
validity, consistency with the exact raster, GeoJSON output."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from slicer import Skeleton
from slicer.cli.app import main
from slicer.contours import (iter_contours, layer_contours, layer_mask, mask_rings, rings_to_multipolygon,
                             solve_crossings)
from slicer.contours.roots import project_to_contour
from slicer.model.field import evaluate
from slicer.tracer.slicing import slice_skeleton
from validation.metrics import polygon_rings, rasterize_rings

TOL = 1e-3


def _surface_distance_3d(skel, rings, z):
    xy = np.concatenate(rings)
    f, g = evaluate(skel, np.column_stack([xy, np.full(len(xy), z)]), gradient=True)
    return np.abs(f - 1) / np.linalg.norm(g, axis=1)


def _dense_boundary(mp, per_edge=8):
    pts = []
    for r in polygon_rings(mp):
        q = np.roll(r, -1, axis=0)
        s = (np.arange(per_edge) / per_edge)[None, :, None]
        pts.append((r[:, None] + s * (q - r)[:, None]).reshape(-1, 2))
    return np.concatenate(pts)


def test_vertical_strut_is_a_circle_of_radius_tau():
    tau = 0.8
    s = Skeleton([[0.3, -0.2, -6], [0.3, -0.2, 6]], [[0, 1]], [[tau, tau]])
    r = slice_skeleton(s, 0.07)
    k = r.grid.layers // 2
    mp = layer_contours(s, r, k)
    assert mp.is_valid and len(mp.geoms) == 1 and not mp.geoms[0].interiors
    assert mp.geoms[0].exterior.is_ccw
    # a long constant strut has its surface exactly at distance tau; every
    # point of the contour (vertices and chords) is within tol of that circle
    p = _dense_boundary(mp)
    rad = np.hypot(p[:, 0] - 0.3, p[:, 1] + 0.2)
    assert np.abs(rad - tau).max() <= TOL
    assert abs(mp.area - math.pi * tau**2) <= 2 * math.pi * tau * TOL


def test_square_frame_has_a_clockwise_hole():
    nodes = [[0, 0, 0], [8, 0, 0], [8, 8, 0], [0, 8, 0]]
    s = Skeleton(nodes, [[0, 1], [1, 2], [2, 3], [3, 0]], [[0.7, 0.7]] * 4)
    r = slice_skeleton(s, 0.1)
    ks = [k for k in range(r.grid.layers) if abs(r.grid.origin[2] + k * r.grid.layer_height) < 0.3]
    for k in ks:
        z = r.grid.origin[2] + k * r.grid.layer_height
        mp = layer_contours(s, r, k)
        assert mp.is_valid
        assert len(mp.geoms) == 1
        poly = mp.geoms[0]
        assert len(poly.interiors) == 1
        assert poly.exterior.is_ccw and not poly.interiors[0].is_ccw
        # the hole is the inner square, inset by the strut's half-width at this z
        half = math.sqrt(0.7**2 - z**2)
        hole = shapely.Polygon(poly.interiors[0])
        assert hole.bounds[0] == pytest.approx(half, abs=0.02)
        assert max(_surface_distance_3d(s, polygon_rings(mp), z)) <= TOL


def _assert_raster_within_tol(s, raster, mask, g, z, tol=TOL):
    """The contours' raster is the tracer's except at pixel centres within
    ``tol`` of the surface (a vertex may lie on either side of such a centre)."""
    j, i = np.nonzero(raster != mask)
    if j.size:
        p = np.column_stack([g.origin[0] + i * g.pixel_size[0], g.origin[1] - j * g.pixel_size[1],
                             np.full(j.size, z)])
        f, grad = evaluate(s, p, True)
        assert (np.abs(f - 1.0) / np.hypot(grad[:, 0], grad[:, 1]) <= tol).all()
    assert j.size <= max(4, mask.sum() // 100)


def test_contours_reproduce_the_raster_and_vertices_lie_on_the_surface():
    from sample_lattices import load_sample

    s = load_sample("octet_2x2x2")
    r = slice_skeleton(s, 0.12)
    st_ = {}
    n = 0
    for k, z, mp in iter_contours(s, r, stats=st_):
        if k % 9 or k > 60:       # iter_contours over a few layers, checks on some
            if k > 60:
                break
            continue
        n += 1
        assert mp.is_valid
        rings = polygon_rings(mp)
        g = r.grid
        raster = rasterize_rings(rings, g.origin[:2], g.pixel_size, g.height, g.width)
        _assert_raster_within_tol(s, raster, layer_mask(r, k), g, z)
        if rings:
            assert _surface_distance_3d(s, rings, z).max() <= TOL
            for poly in mp.geoms:
                assert poly.exterior.is_ccw
                assert not any(h.is_ccw for h in poly.interiors)
    assert n >= 5 and st_["vertices"] > 0 and st_["refined"] > 0


def test_grid_border_clips_the_solid():
    s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
    # the box cuts the strut in half: x < 0 only
    r = slice_skeleton(s, 0.1, bounds=(-2, -2, -1, 0.0, 2, 1))
    k = r.grid.layers // 2
    mp = layer_contours(s, r, k)
    assert mp.is_valid and len(mp.geoms) == 1
    assert mp.bounds[2] == pytest.approx(0.0, abs=1e-12)          # the grid's box face
    assert mp.area == pytest.approx(math.pi / 2, rel=2e-3)


def test_saddles_follow_the_cell_centre():
    # a 2 x 2 checkerboard: one marching-squares cell with a saddle
    mask = np.array([[True, False], [False, True]])
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[0.1, 0.1]])   # not evaluated in values mode
    joined = mask_rings(s, mask, (0, 0), (1, 1), 0.0, refine=False, values=np.array([[2.0, 0], [0, 2.0]]))
    split = mask_rings(s, mask, (0, 0), (1, 1), 0.0, refine=False, values=np.array([[1.5, 0], [0, 1.5]]))
    assert len(joined) == 1 and len(split) == 2
    for rings in (joined, split):
        mp = rings_to_multipolygon(rings)
        assert mp.is_valid
        assert np.array_equal(rasterize_rings(polygon_rings(mp), (0, 0), (1, 1), 2, 2), mask)


def _slow_root(skel, a, b, tol=1e-13):
    lo, hi = 0.0, 1.0
    while (hi - lo) * np.linalg.norm(b - a) > tol:
        m = 0.5 * (lo + hi)
        if evaluate(skel, a + m * (b - a))[0][0] >= 1.0:
            lo = m
        else:
            hi = m
    return 0.5 * (lo + hi)


def test_root_solve_matches_slow_bisection():
    s = Skeleton([[0, 0, 0], [3, 1, 2], [5, -1, 2]], [[0, 1], [1, 2]], [[0.4, 0.9], [0.9, 0.3]])
    rng = np.random.default_rng(7)
    t = rng.uniform(0.05, 0.95, 12)
    centre = np.array([0, 0, 0]) + t[:, None] * np.array([3, 1, 2])
    d = rng.normal(size=(12, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    a = centre
    b = centre + 3.0 * d
    for tol in (1e-3, 1e-6):
        pts, tt, ok, _ = solve_crossings(s, a, b, tol)
        assert ok.all()
        for q in range(len(a)):
            ref = _slow_root(s, a[q], b[q])
            assert abs(tt[q] - ref) * 3.0 <= tol


def test_root_solve_with_a_slope_bound_is_within_half_the_tolerance_and_cheaper():
    """Radial edges across a vertical strut of radius 1: |dF/dl| is at least the least
    sampled radial slope times 0.9 on each edge; the vertices stay within tol/2."""
    s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
    rng = np.random.default_rng(3)
    phi = rng.uniform(0, 2 * np.pi, 40)
    ra = rng.uniform(0.90, 0.999, 40)
    rb = rng.uniform(1.001, 1.08, 40)
    e = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(40)])
    a, b = ra[:, None] * e, rb[:, None] * e
    w = np.linspace(0, 1, 201)
    slope = np.array([np.abs(np.gradient(evaluate(s, a[q] + w[:, None] * (b[q] - a[q]))[0],
                                         w * (rb[q] - ra[q]))).min() for q in range(40)])
    tol = 1e-3
    _, t_ref, _, _ = solve_crossings(s, a, b, 1e-12)
    _, t0, ok0, n0 = solve_crossings(s, a, b, tol)
    _, t1, ok1, n1 = solve_crossings(s, a, b, tol, slope=0.9 * slope)
    assert ok0.all() and ok1.all()
    length = rb - ra
    assert (np.abs(t1 - t_ref) * length <= 0.5 * tol).all()
    assert n1 < n0


def test_projection_to_the_contour_lands_on_the_circle_from_the_newton_bracket():
    """Points near the circle of a vertical strut (the section is a disc): each
    projection lies on the gradient line (radial) within tol/2 of the circle, and
    where the Newton point's bracket holds, a point costs three evaluations; far
    points, whose Newton step overshoots, are still solved on the whole segment."""
    s = Skeleton([[0, 0, -5], [0, 0, 5]], [[0, 1]], [[1.0, 1.0]])
    _, t_ref, _, _ = solve_crossings(s, np.array([[0.5, 0, 0]]), np.array([[1.5, 0, 0]]), 1e-13)
    R = 0.5 + t_ref[0]                                     # the section's radius
    rng = np.random.default_rng(5)
    phi = rng.uniform(0, 2 * np.pi, 50)
    rad = R + rng.uniform(-0.01, 0.01, 50)
    xy = np.column_stack([rad * np.cos(phi), rad * np.sin(phi)])
    tol = 1e-3
    roots, ok, _, evals = project_to_contour(s, xy, 0.0, tol)
    assert ok.all()
    assert np.abs(np.hypot(roots[:, 0], roots[:, 1]) - R).max() <= 0.5 * tol
    assert np.abs(np.arctan2(roots[:, 1], roots[:, 0]) - np.arctan2(xy[:, 1], xy[:, 0])).max() < 1e-9
    assert evals == 3 * 50
    far = np.array([[0.7, 0.0], [1.2, 0.0], [0.0, -1.4]])   # a linear model is poor this far out
    roots, ok, _, evals = project_to_contour(s, far, 0.0, tol)
    assert ok.all() and np.abs(np.hypot(roots[:, 0], roots[:, 1]) - R).max() <= tol
    assert evals > 3 * 3                                   # the whole segment was searched


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10**6), px=st.sampled_from([0.09, 0.15, 0.23]))
@example(seed=262144, px=0.15)      # chord refinement once made a ring self-intersect
def test_random_skeletons_give_valid_wound_surface_contours(seed, px):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 6))
    nodes = rng.uniform(-2, 2, (n, 3))
    segs = [[i, i + 1] for i in range(n - 1)] + [[0, n - 1]]
    radii = rng.uniform(0.25, 0.8, (len(segs), 2))
    s = Skeleton(nodes, segs, radii)
    r = slice_skeleton(s, px)
    g = r.grid
    for k in np.linspace(0, g.layers - 1, 5).astype(int):
        z = g.origin[2] + k * g.layer_height
        mp = layer_contours(s, r, int(k))
        assert mp.is_valid
        rings = polygon_rings(mp)
        _assert_raster_within_tol(s, rasterize_rings(rings, g.origin[:2], g.pixel_size, g.height, g.width),
                                  layer_mask(r, int(k)), g, z)
        if rings:
            xy = np.concatenate(rings)
            f, gr = evaluate(s, np.column_stack([xy, np.full(len(xy), z)]), gradient=True)
            gxy = np.hypot(gr[:, 0], gr[:, 1])
            # in the layer plane, along a pixel edge or a projection: within tol
            assert (np.abs(f - 1) / gxy).max() <= TOL * 1.0001
        for poly in mp.geoms:
            assert poly.exterior.is_ccw and not any(h.is_ccw for h in poly.interiors)


def test_slice_writes_geojson_and_json_contours(tmp_path):
    from sample_lattices import sample_path

    scene = str(sample_path("cubic_2x2x2"))
    runner = CliRunner()
    out = tmp_path / "stack"
    gj = tmp_path / "c.geojson"
    res = runner.invoke(main, ["slice", scene, "-o", str(out), "--pixel-size", "0.2", "--contours", str(gj), "-q"])
    assert res.exit_code == 0, res.output
    d = json.loads(gj.read_text())
    assert d["type"] == "FeatureCollection"
    assert len(d["features"]) == json.loads((out / "slices.json").read_text())["layers"]
    feat = d["features"][len(d["features"]) // 2]
    geom = shapely.geometry.shape(feat["geometry"])
    assert geom.is_valid and geom.area > 0
    # RFC 7946 winding: exteriors counter-clockwise
    assert all(p.exterior.is_ccw for p in geom.geoms)
    # an existing contour file is refused before any work, replaced with --force
    res = runner.invoke(main, ["slice", scene, "-o", str(tmp_path / "s2"), "--pixel-size", "0.2",
                               "--contours", str(gj)])
    assert res.exit_code == 2 and "already exists" in res.output
    assert not (tmp_path / "s2").exists()
    js = tmp_path / "c.json"
    res = runner.invoke(main, ["slice", scene, "-o", str(tmp_path / "s3"), "--pixel-size", "0.2",
                               "--contours", str(js), "-q"])
    assert res.exit_code == 0, res.output
    d = json.loads(js.read_text())
    lay = d["layers"][len(d["layers"]) // 2]
    assert {"layer", "z", "polygons"} <= set(lay)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]     # no temporary leftovers


def test_signed_areas_of_known_rings():
    from slicer.contours import signed_areas

    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    tri = np.array([[0.0, 0.0], [0.0, 3.0], [4.0, 0.0]])          # clockwise
    assert signed_areas([square, tri, square + 10.0]).tolist() == [2.0, -6.0, 2.0]
    assert signed_areas([]).shape == (0,)


def test_rings_become_polygons_with_each_hole_in_the_smallest_shell_around_it():
    """Two nested shells and a separate one; a hole inside the inner shell goes
    to it, not to the outer; clockwise rings alone fill nothing; rings with
    fewer than three vertices are dropped."""
    def square(x, y, s, ccw=True):
        r = np.array([[x, y], [x + s, y], [x + s, y + s], [x, y + s]], float)
        return r if ccw else r[::-1].copy()

    outer, inner, apart = square(0, 0, 10), square(2, 2, 4), square(20, 0, 3)
    gap, hole = square(1, 1, 8, ccw=False), square(3, 3, 1, ccw=False)
    mp = rings_to_multipolygon([outer, gap, inner, hole, apart, np.zeros((2, 2))])
    assert mp.is_valid and len(mp.geoms) == 3
    areas = sorted((p.area, len(p.interiors)) for p in mp.geoms)
    assert areas == [(9.0, 0), (15.0, 1), (36.0, 1)]          # 4x4 - 1x1, 10x10 - 8x8, 3x3
    assert rings_to_multipolygon([gap, hole]).is_empty
    assert rings_to_multipolygon([]).is_empty


def test_simplify_keeps_the_holes_plain_douglas_peucker_would_drop():
    """The fast plain Douglas-Peucker result is kept only when it is valid
    with every ring: here it collapses the small hole in an outward bump
    (GEOS then drops it) and cuts the bump's tip, so the topology-preserving
    pass runs and keeps both."""
    from slicer.contours.simplify import simplify

    shell = [(0, 0), (4, 0), (5, -1), (6, 0), (10, 0), (10, 10), (0, 10)]
    hole = [(4.9, -0.6), (4.9, -0.4), (5.1, -0.4), (5.1, -0.6)]
    mp = shapely.MultiPolygon([shapely.Polygon(shell, [hole])])
    plain = shapely.simplify(mp, 1.5, preserve_topology=False)
    assert shapely.get_num_interior_rings(plain) == 0
    out = simplify(mp, 1.5)
    assert out.is_valid and len(out.geoms) == 1 and len(out.geoms[0].interiors) == 1
    assert (5.0, -1.0) in set(out.geoms[0].exterior.coords)
    assert out.geoms[0].exterior.is_ccw and not out.geoms[0].interiors[0].is_ccw


def test_simplify_drops_the_vertices_a_chord_can_skip_and_keeps_the_rest_on_the_ring():
    """On a finely sampled circle, simplify keeps a subset of the vertices
    (so still on the surface) and every dropped vertex is within ``dist`` of
    the result; the same vertices as the topology-preserving pass."""
    from slicer.contours.simplify import simplify

    a = np.linspace(0.0, 2 * np.pi, 2000, endpoint=False)
    ring = np.column_stack([np.cos(a), np.sin(a)])
    mp = shapely.MultiPolygon([shapely.Polygon(ring)])
    dist = 1e-4
    out = simplify(mp, dist)
    kept = np.asarray(out.geoms[0].exterior.coords)[:-1]
    assert 50 < len(kept) < 2000
    assert {tuple(p) for p in kept} <= {tuple(p) for p in ring}
    assert shapely.distance(out.geoms[0].exterior, shapely.points(ring)).max() <= dist * (1 + 1e-9)
    ref = shapely.simplify(mp, dist, preserve_topology=True)
    assert shapely.normalize(out).equals_exact(shapely.normalize(shapely.MultiPolygon([ref])), 0.0)
