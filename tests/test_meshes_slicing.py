"""Meshes at the voxel centres: every centre against a winding-number reference, the
closed boundary convention, vertical spans, interval booleans, sections."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from parts_helpers import centres, inside_mesh, rotated, tmesh
from slicer.tracer.grid import SliceGrid
from slicer.parts.meshes import make_mesh
from slicer.parts.mesh_slicing import (Sections, Soup, column_spans, combine_intervals, layer_masks, part_op,
                                 runs_from_masks)


def grid_around(mesh, px=0.13, py=0.11, h=0.17, pad=0.3) -> SliceGrid:
    lo, hi = mesh.bounds()
    n = np.ceil((hi - lo + 2 * pad) / [px, py, h]).astype(int) + 1
    return SliceGrid((lo[0] - pad, hi[1] + pad, lo[2] - pad), (px, py), h, int(n[0]), int(n[1]), int(n[2]))


def volume_of(masks) -> np.ndarray:
    return np.stack([m for _, m in masks])


SHAPES = {
    "sphere": trimesh.creation.icosphere(2, radius=2.0),
    "torus": trimesh.creation.torus(2.0, 0.7, major_sections=24, minor_sections=12),
    "box": trimesh.creation.box(extents=(3.0, 2.0, 1.5)),
    "annulus": trimesh.creation.annulus(r_min=0.8, r_max=1.8, height=1.2, sections=24),
}


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_every_centre_matches_the_winding_number(shape, seed):
    """Positions are generic (random rotation): every centre not within 1e-3 of the
    surface (by winding number) is classified as the winding number says."""
    m = tmesh(rotated(SHAPES[shape], seed), shape)
    g = grid_around(m)
    vol = volume_of(layer_masks(Soup.of([m]), g)).reshape(-1)
    ref, sure = inside_mesh([m], centres(g))
    assert sure.mean() > 0.98 and ref.sum() > 100
    assert np.array_equal(vol[sure], ref[sure])


def test_closed_convention_on_faces_edges_and_corners():
    """A box whose faces pass through centres: every centre on its surface is inside
    (as the lattice counts F = 1 inside), none beyond it."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    box.apply_translation((1.0, 1.0, 1.0))
    m = tmesh(box)
    g = SliceGrid((-0.5, 2.5, -0.5), (0.25, 0.25), 0.25, 13, 13, 13)
    vol = volume_of(layer_masks(Soup.of([m]), g))
    z, y, x = np.meshgrid(g.centres_z(), g.centres_y(), g.centres_x(), indexing="ij")
    want = (x >= 0) & (x <= 2) & (y >= 0) & (y <= 2) & (z >= 0) & (z <= 2)
    assert np.array_equal(vol, want) and vol.sum() == 9 ** 3


def test_vertex_on_a_layer_and_a_row():
    """An octahedron with its vertices on centres: the apexes and equator corners are inside."""
    oct_ = trimesh.Trimesh([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                           [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    m = tmesh(oct_)
    g = SliceGrid((-1.5, 1.5, -1.5), (0.25, 0.25), 0.25, 13, 13, 13)
    vol = volume_of(layer_masks(Soup.of([m]), g))
    z, y, x = np.meshgrid(g.centres_z(), g.centres_y(), g.centres_x(), indexing="ij")
    want = np.abs(x) + np.abs(y) + np.abs(z) <= 1.0            # exact in binary for these centres
    assert np.array_equal(vol, want)


def test_positive_fill_joins_overlapping_shells():
    """Two overlapping boxes in one mesh (a 3MF may hold that): their union."""
    a = trimesh.creation.box(extents=(2, 2, 2))
    b = a.copy()
    b.apply_translation((1.0, 0.5, 0.25))
    u = trimesh.util.concatenate([a, b])
    m = make_mesh(u.vertices, u.faces, "two", check_self_intersections=False)
    g = grid_around(m, 0.1, 0.1, 0.1)
    vol = volume_of(layer_masks(Soup.of([m]), g)).reshape(-1)
    p = centres(g)
    inside = lambda c, q: np.all(np.abs(q - c) <= 1.0, axis=1)     # noqa: E731
    want = inside(np.zeros(3), p) | inside(np.array([1.0, 0.5, 0.25]), p)
    assert np.array_equal(vol, want)


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_vertical_spans_agree_with_the_layers(shape):
    m = tmesh(rotated(SHAPES[shape], 3), shape)
    g = grid_around(m, 0.05, 0.04, 0.07)
    soup = Soup.of([m])
    pix, k0, k1 = runs_from_masks(layer_masks(soup, g), g.width * g.height)
    sp, t0, t1 = column_spans(soup, g)
    zc = g.centres_z()
    from_runs = np.zeros((g.layers, g.width * g.height), bool)
    for p, a, b in zip(pix, k0, k1):
        from_runs[a:b, p] = True
    from_spans = np.zeros_like(from_runs)
    for p, a, b in zip(sp, t0, t1):
        from_spans[(zc >= a) & (zc <= b), p] = True
    assert from_runs.sum() > 1000 and np.array_equal(from_runs, from_spans)
    # the spans' lengths add up to the volume (midpoint rule over the pixel columns)
    assert (t1 - t0).sum() * g.pixel_size[0] * g.pixel_size[1] == pytest.approx(m.volume(), rel=2e-3)


def test_runs_from_masks_layout():
    masks = [(k, np.array([[k in (1, 2, 4)], [k == 0]])) for k in range(5)]
    pix, k0, k1 = runs_from_masks(iter(masks), 2)
    assert pix.tolist() == [0, 0, 1] and k0.tolist() == [1, 4, 0] and k1.tolist() == [3, 5, 1]


def _runs(rng, npix, layers):
    pix, a, b = [], [], []
    for p in range(npix):
        cuts = np.sort(rng.choice(layers + 1, size=2 * rng.integers(0, 3), replace=False))
        for x, y in cuts.reshape(-1, 2):
            pix.append(p)
            a.append(x)
            b.append(y)
    return np.array(pix, np.int64), np.array(a, np.int64), np.array(b, np.int64)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_combine_intervals_is_the_voxel_boolean(seed, has_ci):
    """((L and CI) and not CO) or S, per voxel, against a dense reference."""
    rng = np.random.default_rng(seed)
    npix, K = 6, 12
    groups = [_runs(rng, npix, K) for _ in range(4)]
    if not has_ci:
        groups[1] = (np.zeros(0, np.int64),) * 3
    pix, a, b = combine_intervals(groups, part_op(has_ci))
    dense = []
    for p, x, y in groups:
        v = np.zeros((npix, K), bool)
        for q, s, e in zip(p, x, y):
            v[q, s:e] = True
        dense.append(v)
    lat = dense[0] & ~dense[2]
    if has_ci:
        lat &= dense[1]
    want = lat | dense[3]
    got = np.zeros((npix, K), bool)
    for q, s, e in zip(pix, a, b):
        assert not got[q, s:e].any()                       # disjoint
        got[q, s:e] = True
    assert np.array_equal(got, want)
    assert np.all(np.diff(pix) >= 0) and np.all(b > a)    # sorted by pixel, non-empty


def test_sections_follow_the_closed_convention():
    """manifold3d cuts half-open at horizontal faces; the sections join the cut just below."""
    box = trimesh.creation.box(extents=(2, 2, 2))
    box.apply_translation((0, 0, 1))
    s = Sections([tmesh(box)])
    for z in (0.0, 1.0, 2.0):
        rings = s.rings(z)
        assert len(rings) == 1
        area = 0.5 * abs(np.dot(rings[0][:, 0], np.roll(rings[0][:, 1], -1))
                         - np.dot(np.roll(rings[0][:, 0], -1), rings[0][:, 1]))
        assert area == pytest.approx(4.0)
    assert s.rings(2.0 + 1e-9) == [] and s.rings(-1e-9) == []


@pytest.mark.parametrize("seed", range(6))
def test_grid_aligned_convex_hulls(seed):
    """Hulls of random points *on* the voxel centres: faces, edges and vertices through
    centres everywhere. Reference: the exact orientation of every centre against every
    face (a convex solid's inside or surface is on no face's outer side). Centres off
    the surface must match exactly; centres on it are inside wherever the cut is exact in
    floating point (faces parallel to an axis; the mesh's vertices and edges), and may
    go either way on slanted faces (rounding of the cut points, as F = 1 for the lattice)."""
    import manifold3d

    from slicer.parts.mesh_intersect import orient3d

    rng = np.random.default_rng(seed)
    pitch = np.array([0.25, 0.25, 0.5])
    pts = rng.integers(0, 9, size=(12, 3)) * pitch
    hull = manifold3d.Manifold.hull_points(pts).to_mesh64()
    m = make_mesh(np.asarray(hull.vert_properties)[:, :3], np.asarray(hull.tri_verts).astype(np.int64), "hull")
    g = SliceGrid((-0.5, 2.5, -1.0), (0.25, 0.25), 0.5, 13, 13, 11)
    vol = volume_of(layer_masks(Soup.of([m]), g)).reshape(-1)
    p = centres(g)
    t = m.triangles()
    outside = np.zeros(p.shape[0], bool)
    on_axis = np.zeros(p.shape[0], bool)
    on_slanted = np.zeros(p.shape[0], bool)
    for a, b, c in t:
        s = orient3d(np.broadcast_to(a, p.shape), np.broadcast_to(b, p.shape), np.broadcast_to(c, p.shape), p)
        outside |= s > 0                                   # outward normals: > 0 is the outer side
        n = np.cross(b - a, c - a)
        (on_axis if np.count_nonzero(n) == 1 else on_slanted)[...] |= s == 0
    surface = ~outside & (on_axis | on_slanted)
    strict = ~surface
    assert vol.sum() > 0 and np.array_equal(vol[strict], ~outside[strict])
    assert vol[~outside & on_axis].all()
    corners = np.isin(p.view([("", p.dtype)] * 3).ravel(), m.vertices.view([("", p.dtype)] * 3).ravel())
    assert vol[corners].all()
