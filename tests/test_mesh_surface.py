"""The surface as a certified mesh (slicer.meshing.surface, docs/mesh.md).

* The ball bounds (slicer._kernels.meshing.ballbounds) hold at sampled points of random
  balls near random segments: L <= F <= U, the Hessian's norm (central differences of the
  closed-form gradient) <= H, and its restriction to the ball's plane <= H_P.
* The acceptance check, independent of the mesher (tests/mesh_checks.py), on a few tapered
  struts, a needle and a small lattice: the mesh is watertight and consistently wound with
  outward normals; points sampled on it have the surface within the tolerance along the
  gradient; surface points found by bisection on random lines are within the tolerance of it.
* The compact mesh's distance bounds (slicer._kernels.meshing.nearest) hold against exact
  distances: a fine mesh to its simplification, and wedges and fans of near-flat triangles
  (random fans, and a plate whose top face the simplification triangulates anew).
* The bound printed is the bound certified, the output files read back (trimesh, lib3mf),
  the thread count changes nothing, and bad input is refused by the command line with
  exit status 2 and nothing written.
"""
from __future__ import annotations

import math

import manifold3d
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from mesh_checks import (assert_certified_mesh, point_to_triangles, point_triangle_distance,
                         surface_points_on_lines)
from slicer import Skeleton, generate_lattice
from slicer._kernels.runtime.launch import numba_threads
from slicer._kernels.meshing.ballbounds import ball_bounds
from slicer.cli.app import main
from slicer.errors import OptionError, SceneError
from slicer.model.field import evaluate, point_grid
from slicer.meshing import mesh_scene, write_mesh
from slicer.meshing import cubes as mesh_cubes
from slicer.meshing import surface as mesh_surface
from slicer.meshing.certificate import MeshField, distances_to_surface, enclosing_balls, straight_chains
from slicer.meshing import compact
from slicer.meshing.compact import mesh_to_mesh, simplify
from slicer._kernels.meshing.nearest import point_triangle_sq
from slicer.scene.threemf import load_3mf, read_3mf

FD_STEP = 1e-6
FD_MARGIN = 1e-5


def hessians(skel, pts):
    """Symmetrised Hessians (k, 3, 3) by central differences of the closed-form gradient."""
    hess = np.zeros((len(pts), 3, 3))
    for j in range(3):
        step = np.zeros(3)
        step[j] = FD_STEP
        hess[:, :, j] = (evaluate(skel, pts + step, gradient=True)[1]
                         - evaluate(skel, pts - step, gradient=True)[1]) / (2 * FD_STEP)
    return 0.5 * (hess + hess.transpose(0, 2, 1))


unit = st.floats(-1.0, 1.0)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.tuples(unit, unit, unit).filter(lambda v: sum(x * x for x in v) > 0.01),
       st.sampled_from([0.05, 1.0, 4.0]), st.floats(0.1, 1.0), st.floats(0.1, 1.0),
       st.booleans(),                                        # untapered struts (their own sharper bounds)
       st.integers(1, 3),                                    # struts meeting at the node
       st.floats(0.0, 1.0), st.floats(0.0, 2.2), st.sampled_from([0.001, 0.05, 0.4]),
       st.tuples(unit, unit, unit), st.sampled_from([4, 6, 8]), st.integers(0, 2**31))
def test_ball_bounds_hold(direction, length, r0, r1, untapered, k, t, off, r, normal, degree, seed):
    rng = np.random.default_rng(seed)
    u = np.array(direction) / np.linalg.norm(direction)
    ends = [u * length] + [rng.normal(size=3) for _ in range(k - 1)]
    nodes = np.array([np.zeros(3)] + ends)
    segs = [[0, i + 1] for i in range(k)]
    if untapered:
        r1 = r0
    radii = [[r0, r1]] + [[q, q] if untapered else [q, rng.uniform(0.1, 1.0)] for q in rng.uniform(0.1, 1.0, k - 1)]
    skel = Skeleton(nodes, segs, radii, degree=degree)
    side = np.cross(u, rng.normal(size=3))
    side /= np.linalg.norm(side)
    c = t * length * u + off * max(r0, r1) * side
    nu = np.array(normal)
    nu = nu / np.linalg.norm(nu) if np.linalg.norm(nu) > 0.1 else np.zeros(3)
    table, grid = point_grid(skel)
    U, L, H, HP = (a[0] for a in ball_bounds(table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims,
                                             c[None], np.array([r]), nu[None], degree, skel.sigma,
                                             skel.normalisation))
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pts = np.vstack([c, c + d * r * np.cbrt(rng.uniform(0, 1, 40))[:, None], c + d[:10] * r * (1 - 1e-9)])
    f = evaluate(skel, pts)[0]
    assert f.max() <= U * (1 + 1e-9) and f.min() >= L * (1 - 1e-9) - 1e-12, (f.min(), f.max(), L, U)
    hess = hessians(skel, pts)
    norm = np.abs(np.linalg.eigvalsh(hess)).max(axis=1)
    assert norm.max() <= H + FD_MARGIN * (1 + H), (norm.max(), H)
    if nu.any():
        v = np.cross(nu, rng.normal(size=(20, 3)))
        v /= np.linalg.norm(v, axis=1)[:, None]
        second = np.abs(np.einsum("vi,kij,vj->kv", v, hess, v)).max()
        assert second <= HP + FD_MARGIN * (1 + HP), (second, HP)
    assert HP <= H


@pytest.mark.parametrize("radii, radius, ratio", [((0.5, 0.5), 1e-4, 1.01), ((0.5, 0.5), 0.1, 1.01),
                                                 ((0.45, 0.3), 1e-4, 1.1), ((0.45, 0.3), 0.05, 1.2)])
def test_ball_bounds_are_close_on_a_strut_surface(radii, radius, ratio):
    """On the surface of a long strut (away from its ends), the Hessian bound over a ball is
    within ``ratio`` of the largest Hessian norm sampled in it: untapered, the exact
    curvatures of the line; tapered, the frame about the apex (the split Hessian alone gives
    1.85 to 2.4 times the sampled value there)."""
    skel = Skeleton([[0, 0, -4], [0, 0, 4]], [[0, 1]], [list(radii)])
    xs = np.linspace(0.05, 1.2, 20001)
    x = xs[np.argmin(np.abs(evaluate(skel, np.stack([xs, 0 * xs, 0 * xs + 0.3], 1))[0] - 1.0))]
    c = np.array([x, 0.0, 0.3])
    table, grid = point_grid(skel)
    _, _, H, _ = ball_bounds(table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims, c[None],
                             np.array([radius]), np.zeros((1, 3)), skel.degree, skel.sigma, skel.normalisation)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    pts = np.vstack([c + d * radius * np.cbrt(rng.uniform(0, 1, 3000))[:, None], c + d[:500] * radius])
    true = np.abs(np.linalg.eigvalsh(hessians(skel, pts))).max()
    assert true <= H[0] + FD_MARGIN * (1 + H[0]) and H[0] <= ratio * true, (H[0], true)


@pytest.mark.parametrize("cell", ["cubic", "octet", "bcc"])
def test_straight_chains_join_runs_and_keep_the_field(cell):
    """Struts continuing straight through nodes are joined (graded radii too, which stay
    linear along z), and the joined skeleton's field is the skeleton's."""
    skel = generate_lattice(cell, (3, 2, 2), 2.0, 0.2, radius_top=0.35)
    lines = straight_chains(skel)
    assert lines.n_segments < skel.n_segments
    rng = np.random.default_rng(1)
    lo, hi = skel.support_bounds()
    pts = rng.uniform(lo, hi, (4000, 3))
    a, ga = evaluate(skel, pts, gradient=True)
    b, gb = evaluate(lines, pts, gradient=True)
    assert np.abs(a - b).max() <= 1e-12 * (1 + np.abs(a).max())
    assert np.abs(ga - gb).max() <= 1e-11 * (1 + np.abs(ga).max())
    # every joined segment runs along the original ones: its length is a sum of theirs
    total = lambda s: np.linalg.norm(s.nodes[s.segments[:, 1]] - s.nodes[s.segments[:, 0]], axis=1).sum()
    assert total(lines) == pytest.approx(total(skel), rel=1e-12)


def test_straight_chains_keep_bends_kinks_and_branches():
    nodes = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [3, 0.001, 0], [1, 0, 1]]
    # 0-1-2 straight with one radius: joined; 1-5 branches off; 2-3 bends; 2-4 almost straight on
    # from 1-2 but not quite; the radius of 1-2 changes rate at 1 (a kink): not joined there
    skel = Skeleton(nodes, [[0, 1], [1, 2], [2, 3], [2, 4], [1, 5]],
                    [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3], [0.3, 0.3], [0.2, 0.2]])
    lines = straight_chains(skel)
    assert sorted(map(tuple, lines.segments.tolist())) == [(0, 2), (1, 5), (2, 3), (2, 4)]
    kink = Skeleton(nodes[:3], [[0, 1], [1, 2]], [[0.3, 0.4], [0.4, 0.6]])
    assert straight_chains(kink) is kink
    linear = Skeleton(nodes[:3], [[0, 1], [2, 1]], [[0.3, 0.4], [0.5, 0.4]])
    assert straight_chains(linear).segments.tolist() == [[0, 2]]
    assert straight_chains(linear).radii.tolist() == [[0.3, 0.5]]


def test_ball_bounds_of_joined_runs_hold_in_a_lattice():
    """The mesher's bounds (over the joined runs) hold at sampled points of random balls
    around the nodes and struts of a graded octet lattice."""
    skel = generate_lattice("octet", (2, 1, 1), 2.0, 0.25, radius_top=0.35)
    fld = MeshField(skel)
    assert fld.lines.n_segments < skel.n_segments
    rng = np.random.default_rng(2)
    lo, hi = skel.support_bounds()
    centres = np.vstack([skel.nodes + rng.normal(scale=0.3, size=skel.nodes.shape), rng.uniform(lo, hi, (60, 3))])
    radii = rng.choice([0.01, 0.05, 0.2], len(centres))
    U, L, H, _ = fld.balls_bounds(centres, radii)
    for c, r, u, l, h in zip(centres, radii, U, L, H):
        d = rng.normal(size=(30, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        pts = np.vstack([c, c + d * r * np.cbrt(rng.uniform(0, 1, 30))[:, None]])
        f = evaluate(skel, pts)[0]
        assert f.max() <= u * (1 + 1e-9) and f.min() >= l * (1 - 1e-9) - 1e-12
        norm = np.abs(np.linalg.eigvalsh(hessians(skel, pts))).max()
        assert norm <= h + FD_MARGIN * (1 + h), (c, r, norm, h)


def test_enclosing_balls_are_the_smallest():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(500, 3, 3))
    c, r = enclosing_balls(tri)
    assert (np.linalg.norm(tri - c[:, None], axis=2).max(axis=1) <= r).all()
    # no smaller ball: each is the circumscribed ball of its triangle's acute part or half its longest edge
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    assert (r >= 0.5 * longest * (1 - 1e-12)).all()
    for t, cc, rr in zip(tri[:50], c[:50], r[:50]):
        far = [np.linalg.norm(t - (cc + 1e-3 * rr * s), axis=1).max() for s in rng.normal(size=(30, 3))]
        assert min(far) >= rr * (1 - 1e-9)


def needle():
    return Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[0.4, 0.08]])


def struts():
    rng = np.random.default_rng(11)
    nodes = rng.uniform(0, 3, (5, 3))
    return Skeleton(nodes, [[0, 1], [1, 2], [2, 3], [1, 4]], rng.uniform(0.25, 0.6, (4, 2)))


def two_struts():
    """Two tapered struts at a bend: about 10,000 band cubes at ``--tol 0.1``, meshed in about a second."""
    return Skeleton([[0, 0, 0], [0, 0, 1.5], [1.2, 0, 1.5]], [[0, 1], [1, 2]], [[0.5, 0.35], [0.35, 0.3]])


def small_lattice():
    return generate_lattice("cubic", (1, 1, 1), 2.0, 0.3)


def bent_struts():
    """Three tapered struts at 0.02 mm: the first simplification leaves a few uniform triangles
    too far from it, and holding those certifies (:func:`slicer.meshing.compact.simplified`)."""
    return Skeleton([[0, 0, 0], [3, 0, 0], [3, 3, 1], [0, 3, 2]], [[0, 1], [1, 2], [2, 3]],
                    [[0.5, 0.3], [0.3, 0.45], [0.45, 0.6]])


SCENES = {"struts": (struts, 0.06), "needle": (needle, 0.05), "lattice": (small_lattice, 0.06),
          "held": (bent_struts, 0.02)}


@pytest.fixture(scope="module")
def meshed():
    """Each scene of SCENES meshed once: name -> (skeleton, tol, SurfaceMesh)."""
    cache = {}

    def get(name):
        if name not in cache:
            make, tol = SCENES[name]
            skel = make()
            cache[name] = (skel, tol, mesh_scene(skel, tol=tol))
        return cache[name]
    return get


# the lattice case ("lattice", a cubic cell at 0.06 mm) takes minutes: benchmarks/mesh_bench.py runs it
@pytest.mark.parametrize("name", ["needle", "struts", "held"])
def test_the_mesh_is_watertight_and_within_tol_both_ways(meshed, name):
    skel, tol, m = meshed(name)
    assert_certified_mesh(skel, m, tol)


def test_tip_of_a_needle_is_kept(meshed):
    """The thin end (radius 0.08 mm) of a needle, wider than the tolerance, is in the mesh:
    its highest vertex is within the tolerance of the surface's top on the axis."""
    skel, tol, m = meshed("needle")
    top = skel.nodes[1][2]
    ztop = m.vertices[:, 2].max()
    # the surface's highest point on the axis, by bisection
    lo, hi = top, top + 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if skel.field([[0, 0, mid]])[0] >= 1 else (lo, mid)
    assert abs(ztop - lo) <= tol


def test_threads_change_nothing():
    skel = two_struts()
    with numba_threads(1):
        a = mesh_scene(skel, tol=0.1)
    with numba_threads(2):
        b = mesh_scene(skel, tol=0.1)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces) and a.bound == b.bound


def canonical_faces(faces):
    """Faces as a sorted array, each rotated to start at its smallest vertex (orientation kept)."""
    k = faces.argmin(axis=1)
    rot = np.stack([faces[np.arange(len(faces)), (k + i) % 3] for i in range(3)], 1)
    return rot[np.lexsort(rot.T[::-1])]


def test_chunks_change_nothing(monkeypatch):
    """The band is settled, meshed and certified in chunks; chunks of 101 cubes (so that
    chunk borders cut the surface everywhere) give the same vertices, the same faces and
    the same bound as the default chunks."""
    skel = two_struts()
    a = mesh_scene(skel, tol=0.1, compact=False)
    monkeypatch.setattr(mesh_cubes, "CHUNK", 101)
    b = mesh_scene(skel, tol=0.1, compact=False)
    assert a.stats["band_cubes"] > 50 * 101
    assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(canonical_faces(a.faces), canonical_faces(b.faces))
    assert a.bound == b.bound and a.stats["triangles"] == b.stats["triangles"]
    assert b.trimesh().is_watertight


def test_a_retry_beyond_the_memory_limit_says_why(monkeypatch):
    """When an attempt's cubes cannot be certified and the smaller cubes asked for would
    exceed the band's limit, the refusal names the cubes not certified and says that a
    larger tolerance does not help; on the first attempt it asks for a larger --tol."""
    skel = small_lattice()
    grid = mesh_cubes._grid(skel, 0.25)
    first = len(mesh_cubes._band(MeshField(skel), grid)[0])
    monkeypatch.setattr(mesh_cubes, "MAX_BAND", int(first * 1.05))
    with pytest.raises(OptionError, match=r"of the [\d,]+ band cubes could not be certified .* a larger --tol does "
                                          r"not make them larger"):
        mesh_scene(skel, tol=0.05, cell=0.25)
    monkeypatch.setattr(mesh_cubes, "MAX_BAND", first // 2)
    with pytest.raises(OptionError, match=r"keeps in memory; ask for a larger --tol"):
        mesh_scene(skel, tol=0.05, cell=0.25)


def test_refusals():
    with pytest.raises(SceneError, match="degree 2"):
        mesh_scene(Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[0.5, 0.5]], degree=2))


def test_cli_writes_and_reports_the_bound(tmp_path):
    scene = tmp_path / "s.json"
    needle().save(scene)
    out = tmp_path / "m.3mf"
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--tol", "0.1"])
    assert res.exit_code == 0, res.output
    bound = float(res.output.split("certified Hausdorff bound ")[1].split()[0])
    assert 0 < bound <= 0.1
    lib3mf = pytest.importorskip("lib3mf")
    model = lib3mf.get_wrapper().CreateModel()
    model.QueryReader("3mf").ReadFromFile(str(out))
    objs = model.GetMeshObjects()
    assert objs.MoveNext()
    mesh = objs.GetCurrentMeshObject()
    assert mesh.GetTriangleCount() > 100 and mesh.IsManifoldAndOriented()


def test_cli_says_where_its_cubes_are_finer(tmp_path):
    """The random struts at 0.06 mm: the first cube side fails where struts meet, and finer cubes
    certify those places; the command says how many, level by level, and the mesh is certified."""
    scene = tmp_path / "s.json"
    struts().save(scene)
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(tmp_path / "m.stl"), "--tol", "0.06"])
    assert res.exit_code == 0, res.output
    assert "1 attempt(s) (finer where struts meet: " in res.output
    levels = res.output.split("finer where struts meet: ")[1].split(")")[0].split(", ")
    cubes = [int(level.split(" of ")[0].replace(",", "")) for level in levels]
    assert cubes and min(cubes) > 0
    assert float(res.output.split("certified Hausdorff bound ")[1].split()[0]) <= 0.06


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".3mf"])
def test_every_format_reads_back(meshed, tmp_path, suffix):
    _, _, m = meshed("struts")
    out = tmp_path / f"m{suffix}"
    write_mesh(m.vertices, m.faces, out)
    if suffix == ".3mf":
        (back,) = read_3mf(out).solids                # our reader: closed, outward, manifold
        assert np.allclose(back.vertices, m.vertices, atol=1e-5) and np.array_equal(back.faces, m.faces)
    else:
        t = trimesh.load(out, force="mesh", process=suffix == ".stl")     # STL: merge the corners
        assert t.is_watertight and t.is_winding_consistent and len(t.faces) == len(m.faces)
        assert abs(t.volume - m.trimesh().volume) < 1e-5 * t.volume
        if suffix != ".stl":
            assert np.allclose(t.vertices, m.vertices, atol=1e-6)


@pytest.mark.parametrize("args, needle_text", [
    (["-o", "{d}/m.xyz"], "unknown mesh file type"),
    (["-o", "{d}/m.stl", "--tol", "0"], "--tol"),
    (["-o", "{d}/m.stl", "--blend", "max"], "--blend"),
    (["-o", "{d}/m.stl", "--beams"], "name the output .3mf"),
])
def test_cli_refusals_write_nothing(tmp_path, args, needle_text):
    scene = tmp_path / "s.json"
    needle().save(scene)
    before = set(tmp_path.iterdir())
    res = CliRunner().invoke(main, ["mesh", str(scene)] + [a.format(d=tmp_path) for a in args])
    assert res.exit_code == 2, res.output
    assert needle_text in res.output
    assert set(tmp_path.iterdir()) == before


def test_cli_beams_read_back(tmp_path):
    scene = tmp_path / "s.json"
    skel = small_lattice()
    skel.save(scene)
    out = tmp_path / "l.3mf"
    res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--beams"])
    assert res.exit_code == 0, res.output
    back = load_3mf(out)
    assert back.n_segments == skel.n_segments
    assert np.allclose(back.nodes, skel.nodes[np.unique(skel.segments)], atol=1e-5)


# --- compact meshes (slicer.meshing.compact) ---

def test_point_triangle_distance_matches_the_projection_reference():
    """The kernel's closest-point distance against tests/mesh_checks.py's (projection onto the
    plane, else the nearest edge), on random, thin and degenerate triangles."""

    rng = np.random.default_rng(4)
    tri = rng.normal(size=(300, 3, 3))
    tri[:40, 2] = tri[:40, 0] + 1e-7 * rng.normal(size=(40, 3))          # slivers
    tri[40:60, 1] = tri[40:60, 0]                                          # two corners equal
    tri[60:80, 2] = 0.5 * (tri[60:80, 0] + tri[60:80, 1])                  # collinear
    for t in tri:
        for p in rng.normal(scale=2.0, size=(20, 3)):
            got = math.sqrt(point_triangle_sq(tuple(p), tuple(t[0]), tuple(t[1]), tuple(t[2])))
            want = point_to_triangles(p, t[None])[0]
            assert abs(got - want) <= 1e-9 * (1.0 + want), (t, p, got, want)


@pytest.mark.parametrize("seed", range(3))
def test_mesh_to_mesh_bounds_hold_and_are_tight(seed):
    """Per triangle of a fine closed mesh, the bound of its distance to a simplified one is at
    least the distance of any point sampled on it (exact, by the projection reference), and
    below the target where the samples are well below it (its pieces are split until then)."""
    rng = np.random.default_rng(seed)
    fine = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    v0 = fine.vertices * rng.uniform(0.6, 1.4, 3) + rng.normal(scale=1e-3, size=fine.vertices.shape)
    f0 = np.asarray(fine.faces, np.int64)
    v1, f1 = simplify(v0, f0, 0.03)
    assert 0 < len(f1) < len(f0) / 4
    target = 0.02
    bound = mesh_to_mesh(v0, f0, v1, f1, target, 0.1)
    # the triangles farthest from the simplified mesh, and others
    pick = np.concatenate([np.argsort(-bound)[:40], rng.choice(len(f0), 60, replace=False)])
    w = rng.dirichlet([1.0, 1.0, 1.0], size=(len(pick), 40))
    pts = np.concatenate([np.einsum("tkj,tjd->tkd", w, v0[f0[pick]]), v0[f0[pick]]], axis=1)
    d = point_triangle_distance(pts.reshape(-1, 3), v1[f1]).reshape(len(pick), -1).max(axis=1)
    assert (bound[pick] >= d).all(), (bound[pick] - d).min()
    # well below the target, a triangle's pieces are split until their bound is below it
    near = d < 0.8 * target
    assert near.sum() >= 20 and (bound[pick][near] <= target * (1 + 1e-6)).all()
    # the fixture is not trivial (some triangles are farther than the target), and no bound is wild
    assert target < d.max() <= bound.max() <= 3.0 * d.max()


def test_compact_mesh_is_far_smaller_and_certified(meshed):
    """The struts' mesh is the simplified one: far fewer triangles than the certified uniform
    mesh (``--uniform``), within the tolerance both ways (the acceptance checks above ran on
    it). Its uniform mesh is graded: the cubes its first cube side could not certify are
    certified by finer meshes."""
    skel, tol, m = meshed("struts")
    assert m.stats["attempts"] == 1 and m.stats["finer"] and m.stats["refined_cubes"] > 0
    u = mesh_scene(skel, tol=tol, compact=False)
    assert u.stats["attempts"] > 1 and len(u.faces) >= 20 * len(m.faces)
    assert m.certified and m.bound <= tol
    # surface to mesh: the uniform mesh's side plus its distance to the simplified one
    assert m.surface_to_mesh >= m.stats["uniform_surface_to_mesh"] > 0
    kept = [r for r in m.stats["simplify"] if r.get("kept")]
    assert len(kept) == 1 and kept[0]["triangles"] == len(m.faces)
    # surface to mesh adds the uniform mesh's side and its distance to the simplified one
    assert m.surface_to_mesh >= kept[0]["uniform_to_compact"]
    # it is not the uniform mesh's vertex set: the simplified mesh keeps a subset of it
    u, _ = mesh_surface.uniform_mesh(MeshField(skel), tol, None, mesh_surface.ATTEMPTS, triangles=False, graded=True)
    assert len(u.faces) == m.stats["uniform_triangles"]
    common = {tuple(v) for v in u.vertices}
    assert all(tuple(v) in common for v in m.vertices)


def test_finer_cubes_cover_every_cube_the_band_could_not_certify(monkeypatch):
    """A graded uniform mesh (made for simplifying): every band cube is certified at its own
    side or cut into eight, each of which is settled by the field's bounds, certified within
    FINER_SHARE of the tolerance, or cut again; a finer cube certified has its 26 neighbours
    meshed (or settled), as the certificate's argument needs; and every surface point found on
    random lines is within its bound of some face of the mesh or of a patch."""
    skel, tol = struts(), 0.06
    fld = MeshField(skel)
    seen = {}
    real_band, real_finer, real_s2m = mesh_surface._mesh_band, mesh_surface._finer, mesh_cubes._surface_to_mesh

    def band_spy(*args):
        out = real_band(*args)
        seen["coarse"] = (args[1], args[2], out[4])         # grid, band, the cubes' distances
        return out

    def finer_spy(fld, grid, band, bad, tol, stats):
        seen["bad"] = bad.copy()
        seen["levels"] = []
        return real_finer(fld, grid, band, bad, tol, stats)

    def s2m_spy(fld, grid, band, g, Hr, worst, tol, which=None):
        d = real_s2m(fld, grid, band, g, Hr, worst, tol, which)
        if which is not None:
            seen["levels"].append((grid, band.copy(), which.copy(), d.copy()))
        return d

    monkeypatch.setattr(mesh_surface, "_mesh_band", band_spy)
    monkeypatch.setattr(mesh_surface, "_finer", finer_spy)
    monkeypatch.setattr(mesh_cubes, "_surface_to_mesh", s2m_spy)
    u, _ = mesh_surface.uniform_mesh(fld, tol, None, mesh_surface.ATTEMPTS, triangles=False, graded=True)
    aim = mesh_surface.FINER_SHARE * tol
    grid, band, d_cell = seen["coarse"]
    bad = seen["bad"]
    assert u.patches and len(u.patches) == len(seen["levels"]) and bad.any()
    assert np.array_equal(bad, ~(d_cell <= aim))
    corners = mesh_cubes._CORNERS
    todo = {tuple(c) for c in band[bad]}
    for fine, fband, inner, d in seen["levels"]:
        where = {tuple(c): k for k, c in enumerate(fband)}
        kids = np.array([2 * np.array(c) + k for c in sorted(todo) for k in corners])
        ins, out = mesh_cubes.settle(fld, fine.centres(kids, 0), 0.5 * math.sqrt(3.0) * fine.h)
        nxt = set()
        for kid, settled in zip(map(tuple, kids), ins | out):
            k = where.get(kid)
            assert settled or (k is not None and inner[k]), kid           # every unsettled half is certified here
            if k is not None and not d[k] <= aim:
                nxt.add(kid)
        # the neighbours of the halves certified are meshed or settled
        ok = np.flatnonzero(inner & (d <= aim))
        steps = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])
        around = np.unique((fband[ok][:, None, :] + steps[None]).reshape(-1, 3), axis=0)
        missing = np.array([c for c in around if tuple(c) not in where]).reshape(-1, 3)
        ins, out = mesh_cubes.settle(fld, fine.centres(missing, 0), 0.5 * math.sqrt(3.0) * fine.h)
        assert (ins | out).all()
        todo = nxt
    assert not todo
    # each face's bound holds every certified cube whose 3 x 3 x 3 block holds the face (its
    # centroid strictly inside the block): a surface point there may have only that face near it
    levels = [(grid, band, ~bad, d_cell)] + [(fine, fband, inner & (d <= aim), d)
                                             for fine, fband, inner, d in seen["levels"]]
    for (g_, cubes, ok, dist), (tri, bounds) in zip(levels, [(u.vertices[u.faces], u.face_bounds)]
                                                    + [(v[f], b) for v, f, b in u.patches]):
        assert ok.any() and len(bounds) == len(tri)
        span = cubes.max(axis=0) + 4
        key = lambda c: ((c[:, 2] + 1) * span[1] + c[:, 1] + 1) * span[0] + c[:, 0] + 1      # noqa: E731
        known = key(cubes[ok])
        order = np.argsort(known)
        known, certified_d = known[order], dist[ok][order]
        pos = (tri.mean(axis=1) - g_.origin) / g_.h
        q = np.floor(pos).astype(np.int64)
        on_low = pos - q < 1e-9
        need = np.zeros(len(tri))
        for step in np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]):
            c = q + step
            j = np.minimum(np.searchsorted(known, key(c)), len(known) - 1)
            hit = (known[j] == key(c)) & ~(on_low & (step == 1)).any(axis=1)
            need[hit] = np.maximum(need[hit], certified_d[j[hit]])
        assert (bounds >= need).all(), float((need - bounds).max())
    # every surface point is within its bound of a face: of a patch in the cubes refined, of the
    # mesh itself in the others (each side alone, so that a bound given to the wrong faces shows)
    mesh_faces = [(u.vertices[u.faces], u.face_bounds)]
    patch_faces = [(v[f], b) for v, f, b in u.patches]
    refined = {tuple(c) for c in band[bad]}
    surf = surface_points_on_lines(skel, n_lines=60)
    cube = np.floor((surf - grid.origin) / grid.h).astype(np.int64)
    in_refined = np.array([tuple(c) in refined for c in cube])
    assert in_refined.sum() >= 10 and (~in_refined).sum() >= 10
    for p, fine in zip(surf, in_refined):
        slack = min(float((point_to_triangles(p, tri) - b).min()) for tri, b in (patch_faces if fine else mesh_faces))
        assert slack <= 0.0, (p, fine, slack)
    assert max(float(b.max()) for _, b in mesh_faces + patch_faces) <= u.surface_to_mesh <= aim


def test_uniform_triangles_held_where_the_first_simplification_fails(meshed):
    """Where the first simplification leaves uniform triangles too far from it, those places
    are held uniform and the same tolerance tried again: the mesh kept has the larger
    triangles elsewhere, fewer than the next tolerance's; held triangles stay in the output."""
    skel, tol, m = meshed("held")
    rows = m.stats["simplify"]
    assert not rows[0]["kept"] and rows[0]["held"] == 0
    assert rows[0]["uniform_to_compact"] + m.stats["uniform_surface_to_mesh"] > tol     # too far
    kept = rows[-1]
    assert kept["kept"] and kept["held"] > 0 and kept["eps"] == rows[0]["eps"]
    assert kept["held"] <= compact.HOLD_SHARE * len(m.faces)
    u = mesh_scene(skel, tol=tol, compact=False)
    half = simplify(u.vertices, u.faces, 0.5 * kept["eps"])[1]
    assert len(m.faces) < 0.8 * len(half)


def _patched_simplify(monkeypatch, scale, grow=None):
    """``compact.simplify`` with the tolerance of each call scaled by ``scale[k]``, k the
    fraction of the budget it is called at (``compact.FRACTIONS`` = 1/8, 1/16 here), and the
    result grown ``grow[k]`` times about the origin; the calls are recorded as (k, held
    triangles)."""
    real, calls = compact.simplify, []
    monkeypatch.setattr(compact, "FRACTIONS", (0.125, 0.0625))
    eps_of = {}

    def patched(vertices, faces, eps, hold=None, planes=None):
        k = eps_of.setdefault(eps, len(eps_of))
        calls.append((k, 0 if hold is None else int(hold.sum())))
        v, f = real(vertices, faces, eps * scale[k], hold, planes)
        return v * (grow or {}).get(k, 1.0), f

    monkeypatch.setattr(compact, "simplify", patched)
    return calls


def test_a_simplification_with_no_fewer_triangles_than_the_next_is_passed_over(monkeypatch):
    """Where manifold3d leaves at least as many triangles at a tolerance as at the next, smaller
    one (dense lattices), the next is checked first, with the simplification made to compare:
    here the first tolerance is made to return a finer simplification (an eighth of it), which
    would certify; it is passed over unchecked and the next one's, with fewer triangles, kept.
    With no next tolerance, the same finer simplification is checked and kept."""
    skel = two_struts()
    calls = _patched_simplify(monkeypatch, {0: 1 / 8, 1: 1.0})
    m = mesh_scene(skel, tol=0.1)
    rows = m.stats["simplify"]
    assert calls == [(0, 0), (1, 0)]                              # each simplified once, nothing held
    assert rows[0].get("dominated") and "uniform_to_compact" not in rows[0] and "mesh_to_surface" not in rows[0]
    assert rows[1]["triangles"] < rows[0]["triangles"] and rows[1]["kept"] and m.certified
    assert len(rows) == 2 and len(m.faces) == rows[1]["triangles"]
    monkeypatch.setattr(compact, "FRACTIONS", compact.FRACTIONS[:1])
    alone = mesh_scene(skel, tol=0.1)
    assert alone.certified and len(alone.faces) == rows[0]["triangles"] > len(m.faces)


def test_a_tolerance_passed_over_is_checked_when_the_next_is_not_kept(monkeypatch):
    """The first tolerance passed over (as above) while the next one's simplification is not
    certified (grown by a fifth: farther from the uniform mesh than the whole tolerance,
    nothing held): the first is then simplified again, checked and kept."""
    skel = two_struts()
    calls = _patched_simplify(monkeypatch, {0: 1 / 8, 1: 1.0}, grow={1: 1.2})
    m = mesh_scene(skel, tol=0.1)
    rows = m.stats["simplify"]
    assert calls == [(0, 0), (1, 0), (0, 0)]
    assert len(rows) == 3 and rows[0].get("dominated") and not rows[1]["kept"] and rows[1]["held"] == 0
    assert rows[1]["uniform_to_compact"] > 0.1
    assert rows[2]["eps"] == rows[0]["eps"] and rows[2]["kept"] and m.certified
    assert len(m.faces) == rows[2]["triangles"] == rows[0]["triangles"]


def test_a_certification_can_stop_at_its_first_failure(meshed, monkeypatch):
    """``triangle_bounds(..., first_failure=True)`` (a last held round's): the same bounds when
    every triangle certifies; when some do not, it stops after the first batch holding one,
    with fewer pieces (the batches after it are not certified), and the triangles it did
    certify have the same bounds."""
    skel, tol, m = meshed("needle")
    fld = MeshField(skel)
    tri = m.vertices[m.faces[:320]]
    c = tri.mean(axis=1)[:, None, :]
    tri[100] = c[100] + 40.0 * (tri[100] - c[100])                # one triangle far too large
    verts, faces = tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)
    full, n_full = compact.triangle_bounds(fld, verts, faces, tol)
    monkeypatch.setattr(compact, "BATCH", 64 * 64)                # batches of 64 triangles
    ok = np.ones(len(faces), bool)
    ok[100] = False
    same, n_same = compact.triangle_bounds(fld, verts, faces[ok], tol, first_failure=True)
    assert np.array_equal(full[ok], same) and np.isfinite(same).all()
    part, n_part = compact.triangle_bounds(fld, verts, faces, tol, first_failure=True)
    assert np.isinf(full[100]) and np.isinf(part[100]) and np.isinf(part[128:]).all() and n_part < n_full
    done = np.isfinite(part)
    assert done.any() and np.array_equal(part[done], full[done])


def test_held_triangles_are_kept_as_they_are():
    """``simplify(..., hold)``: the triangles held come out unchanged (a sphere's cap), while
    the rest is simplified."""
    s = trimesh.creation.icosphere(subdivisions=5, radius=5.0)
    v, f = np.asarray(s.vertices), np.asarray(s.faces, np.int64)
    hold = v[f].mean(axis=1)[:, 0] > 3.5
    v1, f1 = simplify(v, f, 0.05, hold)
    out = {tuple(sorted(map(tuple, t))) for t in v1[f1]}
    assert all(tuple(sorted(map(tuple, t))) in out for t in v[f[hold]])
    assert len(f1) < 0.5 * len(f)
    assert len(simplify(v, f, 0.05)[1]) < len(f1) - hold.sum() // 2


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 30), st.floats(0.01, 2.0))
def test_within_holds_every_ball_and_nothing_far(seed, k, scale):
    """``within``: every point in a ball is marked; no point farther than a few cells from all
    balls is (naive reference)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-5, 5, (2000, 3))
    c = rng.uniform(-5, 5, (k, 3))
    r = scale * rng.uniform(0.05, 1.0, k)
    got = compact.within(pts, c, r)
    d = np.linalg.norm(pts[:, None, :] - c[None], axis=2)
    assert got[(d <= r).any(axis=1)].all()
    side = max(2.0 * float(np.median(r)), float(r.max()) / 8.0, 1e-9)
    # a marked point is in a cell meeting a ball's box: within √3 (r + side) of its centre
    assert not got[(d > math.sqrt(3.0) * (r + side)).all(axis=1)].any()


def test_cli_uniform_keeps_the_uniform_mesh(tmp_path):
    scene = tmp_path / "s.json"
    two_struts().save(scene)
    outs = {}
    for flag in ([], ["--uniform"]):
        out = tmp_path / f"m{len(flag)}.ply"
        res = CliRunner().invoke(main, ["mesh", str(scene), "-o", str(out), "--tol", "0.1"] + flag)
        assert res.exit_code == 0, res.output
        assert ("simplified from" in res.output) == (not flag)
        outs[len(flag)] = trimesh.load(out, process=False)
    assert len(outs[1].faces) == len(mesh_scene(two_struts(), tol=0.1, compact=False).faces)
    assert len(outs[0].faces) * 10 < len(outs[1].faces)


def test_reaches_that_cannot_certify_are_skipped_without_changing_the_result(meshed):
    """The certificate skips a reach where even the smallest curvature bound leaves the slope
    too low (``floor``): the distances are those of trying every reach, on pieces of the
    needle's mesh from whole triangles (most certified) to groups of many (mostly not)."""
    skel, tol, m = meshed("needle")
    fld = MeshField(skel)
    rng = np.random.default_rng(5)
    tri = m.vertices[m.faces[rng.choice(len(m.faces), 3000)]]
    grown = tri.mean(axis=1)[:, None, :] + (tri - tri.mean(axis=1)[:, None, :]) * rng.uniform(0.02, 3, (3000, 1, 1))
    c, r = enclosing_balls(grown)
    n = np.cross(grown[:, 1] - grown[:, 0], grown[:, 2] - grown[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    _, _, H, HP = fld.balls_bounds(c, r, n)
    e = np.abs(fld.values(grown.reshape(-1, 3))[0] - 1.0).reshape(-1, 3).max(axis=1) + 0.5 * HP * r * r
    g = np.linalg.norm(fld.values(c, gradient=True)[1], axis=1)
    start = fld.balls
    every = distances_to_surface(fld, c, r, e, g, tol)
    middle = fld.balls
    skipping = distances_to_surface(fld, c, r, e, g, tol, floor=H)
    assert np.array_equal(every, skipping)
    assert 0.2 < np.isfinite(every).mean() < 0.8, np.isfinite(every).mean()
    assert fld.balls - middle < 0.8 * (middle - start)      # fewer balls bounded


def _same_mesh(a, b):
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert (a.bound, a.mesh_to_surface, a.surface_to_mesh, a.cell) == (b.bound, b.mesh_to_surface, b.surface_to_mesh,
                                                                       b.cell)
    assert a.stats["attempts"] == b.stats["attempts"]


def test_uniform_mesh_kept_when_no_simplification_certifies(monkeypatch):
    """A compact job leaves the uniform mesh's triangles uncertified until it knows it keeps
    that mesh; when no simplification certifies, the mesh written is the one ``--uniform``
    writes, bound and attempts included, also when the triangles' certificate fails at the
    first cube side (the attempts go on with smaller cubes, as they would have, and their mesh
    is simplified in its turn)."""
    skel = two_struts()
    real_simplified = mesh_surface.simplified
    monkeypatch.setattr(mesh_surface, "simplified", lambda fld, uniform, tol: None)
    plain = mesh_scene(skel, tol=0.1, compact=False)
    graded = mesh_scene(skel, tol=0.1)
    # its first uniform mesh was graded, and is not written (nor are its finer cubes reported as the mesh's)
    assert graded.stats["graded_attempt"] and "finer" not in graded.stats
    _same_mesh(graded, plain)
    real = mesh_surface._triangles_bound

    def first_fails(fld, verts, faces, tol, resid, stats):
        calls.append(len(faces))
        return math.inf if len(calls) == 1 else real(fld, verts, faces, tol, resid, stats)

    monkeypatch.setattr(mesh_surface, "_triangles_bound", first_fails)
    calls = []
    a = mesh_scene(skel, tol=0.1)
    first_compact = list(calls)
    calls = []
    b = mesh_scene(skel, tol=0.1, compact=False)
    assert len(first_compact) == 2 and first_compact[1] > first_compact[0] and calls == first_compact
    _same_mesh(a, b)
    assert a.certified and a.stats["attempts"] > plain.stats["attempts"]
    # the smaller cubes' mesh is simplified in its turn
    tries = []

    def second_only(fld, uniform, tol):
        tries.append(uniform.cell)
        return real_simplified(fld, uniform, tol) if len(tries) == 2 else None

    monkeypatch.setattr(mesh_surface, "simplified", second_only)
    calls = []
    c = mesh_scene(skel, tol=0.1)
    assert len(tries) == 2 and tries[1] < tries[0] and c.certified and "uniform_triangles" in c.stats
    assert len(c.faces) * 10 < len(a.faces)


def _fan(rng, k, span, lift, walls):
    """Triangles round the origin (a simplified mesh's flat face at one vertex): k triangles,
    one orientation (counter-clockwise seen from +z), of angles summing to ``span``, corners
    lifted by up to ``lift``; with ``walls``, a steep triangle across each end edge."""
    cuts = np.sort(rng.uniform(0.0, span, k - 1))
    ang = np.concatenate([[0.0], cuts, [span]])
    r = rng.uniform(0.3, 2.0, k + 1)
    ring = np.stack([r * np.cos(ang), r * np.sin(ang), lift * rng.uniform(-1.0, 1.0, k + 1)], 1)
    v = np.concatenate([np.zeros((1, 3)), ring])
    f = [[0, i + 1, i + 2] for i in range(k) if ang[i + 1] > ang[i]]
    if walls and span < 2 * math.pi - 1e-6:
        mid = 0.5 * (span + 2 * math.pi)                      # into the cone the fan leaves out
        w = np.array([[0.5 * math.cos(mid), 0.5 * math.sin(mid), -rng.uniform(0.05, 1.0)]] * 2)
        w[1, 2] = -rng.uniform(0.05, 1.0)
        v = np.concatenate([v, w])
        f += [[1, 0, k + 2], [0, k + 1, k + 3]]
    return v, np.array(f, np.int64)


def _to_triangles(pts, tri):
    """Exact distance from each point (q, 3) to the nearest triangle (t, 3, 3): the foot of the
    perpendicular when it falls inside a triangle, else the nearest point of its edges (over
    every triangle, points at once: for small meshes, where
    :func:`mesh_checks.point_triangle_distance` would loop over the points)."""
    best = np.full(len(pts), np.inf)
    for a, b, c in tri:
        n = np.cross(b - a, c - a)
        nn = float(n @ n)
        if nn > 0.0:
            foot = pts - np.outer((pts - a) @ n / nn, n)
            inside = np.ones(len(pts), bool)
            for u, w in ((a, b), (b, c), (c, a)):
                inside &= np.cross(w - u, foot - u) @ n >= 0.0
            best = np.minimum(best, np.where(inside, np.linalg.norm(pts - foot, axis=1), np.inf))
        for u, w in ((a, b), (b, c), (c, a)):
            e = w - u
            t = np.clip((pts - u) @ e / max(float(e @ e), 1e-300), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(pts - (u + t[:, None] * e), axis=1))
    return best


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 14), span=st.floats(0.2, 2 * math.pi),
       lift=st.sampled_from([0.0, 1e-6, 1e-3, 4e-3, 0.05]), walls=st.booleans(),
       target=st.sampled_from([1e-4, 2e-3, 0.01, 0.05]))
def test_wedges_bound_the_distance_to_flat_fans(seed, k, span, lift, walls, target):
    """The bound of a triangle's distance to a mesh, where wedges and fans of near-flat triangles
    serve (docs/mesh.md, "The compact mesh"), is at least the exact distance of every point
    sampled on it: fans narrower and wider than π, lifted or not, with steep triangles across
    their ends, and triangles reaching into the cone the fan leaves out."""
    rng = np.random.default_rng(seed)
    v1, f1 = _fan(rng, k, span, lift, walls)
    piece = np.concatenate([rng.uniform(-2.2, 2.2, (3, 2)), lift * rng.uniform(-1.5, 1.5, (3, 1))], 1)
    if rng.random() < 0.5:                        # a small triangle near the vertex
        piece = 0.05 * piece + rng.normal(scale=0.02, size=3) * [1, 1, lift]
    bound = mesh_to_mesh(piece, np.array([[0, 1, 2]]), v1, f1, target, 10.0)[0]
    s = np.linspace(0.0, 1.0, 101)[:, None]
    edges = [s * np.eye(3)[i] + (1 - s) * np.eye(3)[(i + 1) % 3] for i in range(3)]
    pts = np.concatenate([rng.dirichlet([0.3, 0.3, 0.3], 3000)] + edges) @ piece
    exact = _to_triangles(pts, v1[f1])
    assert bound >= exact.max() - 1e-12, (bound, exact.max())


def test_wedges_bound_the_distance_to_lifted_fans():
    """As above, on 200 fixed fans whose corners are lifted by up to a fifth of the target
    (the fans take them: their lift counts in the bound) and pieces flat at z = 0, where a
    bound without the lift would be short for about one fan in twenty-five."""
    s = np.linspace(0.0, 1.0, 101)[:, None]
    edges = [s * np.eye(3)[i] + (1 - s) * np.eye(3)[(i + 1) % 3] for i in range(3)]
    for seed in range(200):
        rng = np.random.default_rng(seed)
        k, span = int(rng.integers(1, 15)), rng.uniform(0.2, 2 * math.pi)
        lift, target = (1e-3, 4e-3)[seed % 2], (0.01, 0.05)[(seed // 2) % 2]
        v1, f1 = _fan(rng, k, span, lift, bool(seed % 3))
        piece = np.concatenate([rng.uniform(-2.2, 2.2, (3, 2)), np.zeros((3, 1))], 1)
        if rng.random() < 0.5:
            piece = 0.05 * piece + rng.normal(scale=0.02, size=3) * [1, 1, 0]
        bound = mesh_to_mesh(piece, np.array([[0, 1, 2]]), v1, f1, target, 10.0)[0]
        exact = _to_triangles(np.concatenate([rng.dirichlet([0.3] * 3, 1500)] + edges) @ piece, v1[f1])
        assert bound >= exact.max() - 1e-12, (seed, bound, exact.max())


def test_wedges_bound_a_flat_face_triangulated_anew():
    """A plate with two posts, simplified: the plate's top face is triangulated anew round the
    posts' simplified feet. Its triangles are within 1e-8 mm of the simplified mesh by wedges and
    fans, where one triangle of it per piece leaves some above the target after six cuts."""
    plate = manifold3d.Manifold.cube((4, 4, 0.5), True)
    posts = (manifold3d.Manifold.cylinder(2.0, 0.6, 0.6, 96).translate((0.3, -0.2, 0.0))
             + manifold3d.Manifold.cylinder(2.0, 0.4, 0.4, 96).translate((-1.2, 1.1, 0.0)))
    u = (plate + posts).to_mesh()
    v0 = np.array(u.vert_properties, np.float64)[:, :3]
    f0 = np.array(u.tri_verts, np.int64)
    v1, f1 = simplify(v0, f0, 0.01)
    top = f0[np.abs(v0[f0][:, :, 2] - 0.25).max(axis=1) == 0.0]
    assert len(top) > 100 and len(f1) < len(f0) / 2
    target = 0.005
    bound = mesh_to_mesh(v0, top, v1, f1, target, 0.1)
    assert (bound <= 1e-8).all()
    rng = np.random.default_rng(0)
    pts = np.einsum("tkj,tjd->tkd", rng.dirichlet([1.0, 1.0, 1.0], size=(len(top), 20)), v0[top])
    exact = _to_triangles(pts.reshape(-1, 3), v1[f1]).reshape(len(top), -1).max(axis=1)
    assert (bound >= exact - 1e-12).all()
    assert (mesh_to_mesh(v0, top, v1, f1, target, 0.1, wedges=False) > target).sum() >= 5
