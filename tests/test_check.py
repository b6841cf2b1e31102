"""``skelslice check``: islands, thin struts, resin traps, areas, on scenes with known answers.

* The labelling kernels against breadth-first flood fills (hypothesis).
* The island and trap finders against slow 3-D references on random voxel stacks.
* Constructed scenes through the real entry point: a branch hanging down to
  a free end and a strut floating in mid-air (reported at the layer and
  place a brute-force field evaluation gives), an A-frame on the plate
  (nothing, and nothing printed), a strut thinner than a pixel (named), a
  closed hollow sphere of struts (its volume against a spherical quadrature
  of the exact cavity, within a voxel layer), the same sphere cut open at
  the top (no trap) and cut by the plate (a suction cup).
"""
from __future__ import annotations

import json
from collections import deque

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from slicer import Skeleton
from slicer._kernels.raster.labels import label_layer, link_layers, region_stats
from slicer.cli.app import main
from slicer.tracer.grid import SliceGrid
from slicer.printability import IslandFinder, TrapFinder, printed_widths
from slicer.tracer.slicing import slice_skeleton


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


# ---------------------------------------------------------------- references
def flood_labels(mask: np.ndarray, eight: bool) -> np.ndarray:
    """Labels of the connected regions of ``mask`` by breadth-first search,
    numbered in the row-major order of their first pixel (-1 outside)."""
    h, w = mask.shape
    lab = np.full(mask.shape, -1, np.int64)
    steps = [(-1, 0), (1, 0), (0, -1), (0, 1)] + ([(-1, -1), (-1, 1), (1, -1), (1, 1)] if eight else [])
    n = 0
    for r in range(h):
        for c in range(w):
            if not mask[r, c] or lab[r, c] >= 0:
                continue
            lab[r, c] = n
            todo = deque([(r, c)])
            while todo:
                y, x = todo.popleft()
                for dy, dx in steps:
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w and mask[yy, xx] and lab[yy, xx] < 0:
                        lab[yy, xx] = n
                        todo.append((yy, xx))
            n += 1
    return lab


def islands_reference(vol: np.ndarray) -> list[tuple[int, int]]:
    """(layer, pixels) of every 8-connected region of a layer with no pixel
    solid in the layer below, above the lowest solid layer."""
    out = []
    ks = [k for k in range(vol.shape[0]) if vol[k].any()]
    for k in range(ks[0] + 1, vol.shape[0]) if ks else []:
        lab = flood_labels(vol[k], True)
        for q in range(lab.max() + 1):
            sel = lab == q
            if not (sel & vol[k - 1]).any():
                out.append((k, int(sel.sum())))
    return out


def traps_reference(vol: np.ndarray) -> list[tuple[str, int]]:
    """(kind, voxels) of the 6-connected empty components from the lowest
    solid layer up that reach neither the side nor the top; "plate" if they
    reach the lowest solid layer."""
    ks = [k for k in range(vol.shape[0]) if vol[k].any()]
    if not ks:
        return []
    sub = ~vol[ks[0]:]
    K, H, W = sub.shape
    seen = np.zeros(sub.shape, bool)
    out = []
    for start in zip(*np.nonzero(sub)):
        if seen[start]:
            continue
        seen[start] = True
        todo, n, open_, plate = deque([start]), 0, False, False
        while todo:
            k, j, i = todo.popleft()
            n += 1
            open_ |= k == K - 1 or j in (0, H - 1) or i in (0, W - 1)
            plate |= k == 0
            for dk, dj, di in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
                q = (k + dk, j + dj, i + di)
                if 0 <= q[0] < K and 0 <= q[1] < H and 0 <= q[2] < W and sub[q] and not seen[q]:
                    seen[q] = True
                    todo.append(q)
        if not open_:
            out.append(("plate" if plate else "closed", n))
    return sorted(out)


def grid_of(vol: np.ndarray, px: float = 0.1, h: float = 0.1) -> SliceGrid:
    return SliceGrid((0.0, 0.0, 0.0), (px, px), h, vol.shape[2], vol.shape[1], vol.shape[0])


def masks(draw_shape=st.tuples(st.integers(1, 12), st.integers(1, 12))):
    return draw_shape.flatmap(lambda s: st.integers(0, 2**32 - 1).map(lambda seed: (s, seed)))


# ---------------------------------------------------------------- kernels
@settings(max_examples=150, deadline=None)
@given(masks(), st.floats(0.1, 0.9), st.booleans())
def test_label_layer_matches_flood_fill(shape_seed, p, eight):
    (h, w), seed = shape_seed
    mask = np.random.default_rng(seed).random((h, w)) < p
    lab = np.empty((h, w), np.int32)
    n = label_layer(mask.view(np.uint8), eight, lab)
    ref = flood_labels(mask, eight)
    assert n == ref.max() + 1
    assert np.array_equal(lab, ref)


@settings(max_examples=100, deadline=None)
@given(masks(), st.floats(0.2, 0.8))
def test_link_layers_and_region_stats(shape_seed, p):
    (h, w), seed = shape_seed
    rng = np.random.default_rng(seed)
    a, b = rng.random((h, w)) < p, rng.random((h, w)) < p
    la, lb = np.empty((h, w), np.int32), np.empty((h, w), np.int32)
    m, n = label_layer(a.view(np.uint8), False, la), label_layer(b.view(np.uint8), False, lb)
    group = link_layers(la, lb, m, n)
    # reference: two regions share a group iff connected through shared pixels (3-D, two layers)
    ref = flood_labels_3d(np.stack([a, b]))
    node_ref = [ref[0][la == q][0] for q in range(m)] + [ref[1][lb == q][0] for q in range(n)]
    for x in range(m + n):
        for y in range(m + n):
            assert (group[x] == group[y]) == (node_ref[x] == node_ref[y])
    stats = region_stats(lb, n)
    for q in range(n):
        rows, cols = np.nonzero(lb == q)
        assert stats[q].tolist() == [rows.size, cols.sum(), rows.sum(), cols.min(), rows.min(), cols.max(), rows.max()]


def flood_labels_3d(vol: np.ndarray) -> np.ndarray:
    lab = np.full(vol.shape, -1, np.int64)
    n = 0
    for s in zip(*np.nonzero(vol)):
        if lab[s] >= 0:
            continue
        lab[s] = n
        todo = deque([s])
        while todo:
            p = todo.popleft()
            for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
                q = tuple(np.add(p, d))
                if all(0 <= q[i] < vol.shape[i] for i in range(3)) and vol[q] and lab[q] < 0:
                    lab[q] = n
                    todo.append(q)
        n += 1
    return lab


# ---------------------------------------------------------------- finders on random stacks
@settings(max_examples=80, deadline=None)
@given(st.integers(1, 8), st.integers(1, 9), st.integers(1, 9), st.integers(0, 2**32 - 1), st.floats(0.3, 0.8))
def test_islands_match_reference(K, H, W, seed, p):
    vol = np.random.default_rng(seed).random((K, H, W)) < p
    f = IslandFinder(grid_of(vol))
    for k in range(K):
        f.add(k, np.ascontiguousarray(vol[k]))
    got = sorted((i.layer, i.pixels) for i in f.islands)
    assert got == sorted(islands_reference(vol))


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 8), st.integers(1, 9), st.integers(1, 9), st.integers(0, 2**32 - 1), st.floats(0.4, 0.9))
def test_traps_match_reference(K, H, W, seed, p):
    vol = np.random.default_rng(seed).random((K, H, W)) < p
    f = TrapFinder(grid_of(vol))
    for k in range(K):
        f.add(k, np.ascontiguousarray(vol[k]))
    got = sorted((t.kind, t.voxels) for t in f.finish())
    assert got == traps_reference(vol)


def test_trap_geometry_of_a_box():
    """A 5 x 5 x 5 solid box with a 3 x 2 x 1 hole: one closed trap, its
    centroid, layers, bounding box and volume."""
    vol = np.zeros((7, 7, 7), bool)
    vol[1:6, 1:6, 1:6] = True
    vol[3, 2:4, 2:5] = False                    # layer 3, rows 2-3, columns 2-4
    f = TrapFinder(grid_of(vol, px=0.2, h=0.1))
    for k in range(7):
        f.add(k, np.ascontiguousarray(vol[k]))
    (t,) = f.finish()
    assert (t.kind, t.voxels, t.layers, t.bbox) == ("closed", 6, (3, 3), (2, 2, 3, 4, 3, 3))
    assert t.volume == pytest.approx(6 * 0.2 * 0.2 * 0.1)
    assert (t.x, t.y, t.z) == pytest.approx((0.6, -0.5, 0.3))


# ---------------------------------------------------------------- scenes
def slice_masks(skel, px):
    """Brute force: the field at every voxel centre of the grid ``slice`` uses."""
    g = slice_skeleton(skel, px).grid
    X, Y, Z = np.meshgrid(g.centres_x(), g.centres_y(), g.centres_z(), indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    inside = skel.field(pts).reshape(X.shape) >= 1.0          # (rows, columns, layers)
    return g, np.transpose(inside, (2, 0, 1))


@pytest.fixture(scope="module")
def hanging(tmp_path_factory):
    """A post with an arm and a branch hanging down from it to a free end, and
    a horizontal strut floating beside it."""
    r = 0.3
    s = Skeleton([[0, 0, 0], [0, 0, 3], [2, 0, 3], [2, 0, 1.5], [4, 0, 2], [5, 0, 2]],
                 [[0, 1], [1, 2], [2, 3], [4, 5]], [[r, r]] * 4)
    p = tmp_path_factory.mktemp("hang") / "hang.json"
    s.save(p)
    return s, p


def test_hanging_branch_and_floating_strut_are_islands(hanging, tmp_path):
    skel, scene = hanging
    out = tmp_path / "rep.json"
    r = run("check", scene, "--pixel-size", "0.05", "--json", out)
    assert r.exit_code == 1, r.output
    doc = json.loads(out.read_text())
    isl = doc["islands"]
    assert len(isl) == 2, isl
    g, vol = slice_masks(skel, 0.05)
    for item, x_lo, x_hi, x_mid in ((isl[0], 1.4, 2.6, 2.0), (isl[1], 3.5, 5.5, 4.5)):
        cols = (g.centres_x() > x_lo) & (g.centres_x() < x_hi)
        part = vol[:, :, cols]
        k_first = int(np.nonzero(part.any(axis=(1, 2)))[0][0])   # lowest inside centre of that part
        assert item["layer"] == k_first
        assert item["z"] == pytest.approx(g.origin[2] + k_first * g.layer_height)
        sel = part[k_first]
        rows, cc = np.nonzero(sel)
        assert item["area"] == pytest.approx(rows.size * 0.05 * 0.05)
        assert item["x"] == pytest.approx(x_mid, abs=0.05 / 2)
        assert item["y"] == pytest.approx(0.0, abs=0.05 / 2)
    assert "island" in r.output and "layer" in r.output
    assert set(doc) >= {"islands", "thin_segments", "traps", "areas", "estimate", "ok", "blocking"}
    assert doc["thin_segments"] == [] and doc["traps"] == [] and doc["ok"] is False


def test_a_frame_on_the_plate_is_clean_and_quiet(tmp_path):
    r = 0.3
    scene = tmp_path / "a.json"
    Skeleton([[-2, 0, 0], [2, 0, 0], [0, 0, 3], [-1.2, 0, 1.2], [1.2, 0, 1.2]],
             [[0, 3], [3, 2], [1, 4], [4, 2], [3, 4]], [[r, r]] * 5).save(scene)
    res = run("check", scene, "--pixel-size", "0.05", "--json", tmp_path / "a_rep.json")
    assert res.exit_code == 0 and res.output == "", res.output
    doc = json.loads((tmp_path / "a_rep.json").read_text())
    assert doc["islands"] == [] and doc["thin_segments"] == [] and doc["traps"] == [] and doc["ok"]
    assert doc["areas"]["largest"]["area"] > 0 and doc["estimate"]["layers"] > 0
    v = run("check", scene, "--pixel-size", "0.05", "-v")
    assert v.exit_code == 0 and "nothing found" in v.output and "summary:" in v.output


@pytest.fixture(scope="module")
def thin_scene(tmp_path_factory):
    """Two posts joined at the top by a strut of radius 0.02 mm (0.04 mm wide, under a 0.05 mm pixel)."""
    p = tmp_path_factory.mktemp("thin") / "thin.json"
    s = Skeleton([[0, 0, 0], [0, 0, 2], [1, 0, 2], [1, 0, 0]], [[0, 1], [1, 2], [2, 3]],
                 [[0.3, 0.3], [0.02, 0.02], [0.3, 0.3]])
    s.save(p)
    return s, p


def test_strut_thinner_than_a_pixel_is_named(thin_scene, tmp_path):
    skel, scene = thin_scene
    out = tmp_path / "t.json"
    r = run("check", scene, "--pixel-size", "0.05", "--json", out)
    assert r.exit_code == 1, r.output
    (t,) = json.loads(out.read_text())["thin_segments"]
    assert t["segment"] == 1 and t["threshold"] == 0.05
    assert 0.04 <= t["width"] < 0.05                      # 2 x radius, widened a little by the posts' fields
    assert (t["x"], t["y"], t["z"]) == pytest.approx((0.5, 0.0, 2.0))
    assert "segment 1" in r.output
    # the posts are named only once the minimum feature exceeds their width (0.6 mm)
    out2 = tmp_path / "t2.json"
    assert run("check", scene, "--pixel-size", "0.05", "--min-feature", "0.59", "--json", out2).exit_code == 1
    assert [t["segment"] for t in json.loads(out2.read_text())["thin_segments"]] == [1]
    r = run("check", scene, "--pixel-size", "0.05", "--min-feature", "0.61", "--json", out2, "--force")
    assert r.exit_code == 1
    assert [t["segment"] for t in json.loads(out2.read_text())["thin_segments"]] == [0, 1, 2]
    # not blocking when thin struts are not in --fail-on
    assert run("check", scene, "--pixel-size", "0.05", "--fail-on", "islands,traps").exit_code == 0


def test_printed_width_of_a_long_strut_is_its_diameter():
    """Far from its ends a lone strut's surface is the cylinder of radius tau
    (the kernel's normalisation); a strut shorter than 0.688 tau has no
    surface, so its width is 0."""
    s = Skeleton([[0, 0, 0], [3, 4, 12], [10, 0, 0], [10.2, 0, 0]], [[0, 1], [2, 3]], [[0.5, 0.5], [0.4, 0.4]])
    w = printed_widths(s)
    assert w[0] == pytest.approx(1.0, rel=1e-6)
    assert w[1] == 0.0


def test_outputs_are_checked_as_written(hanging, tmp_path):
    """The same job written as a PNG stack, zip, SL1S, GOO and NanoDLP, read
    back: the same islands (layer and area; plate positions for printer
    formats equal those of checking the scene on that printer)."""
    skel, scene = hanging
    ref = tmp_path / "ref.json"
    prn = ["--printer", "elegoo-mars-4-ultra", "--layer-height", "0.1"]
    assert run("check", scene, *prn, "--json", ref).exit_code == 1
    want = [(i["layer"], round(i["area"], 9), round(i["x"], 6), round(i["y"], 6))
            for i in json.loads(ref.read_text())["islands"]]
    assert len(want) == 2
    for name in ("p.goo", "p.nanodlp", "p.zip"):
        out = tmp_path / name
        assert run("slice", scene, "-o", out, *prn, "-q").exit_code == 0
        rep = tmp_path / f"{name}.json"
        r = run("check", out, "--json", rep)
        assert r.exit_code == 1, (name, r.output)
        doc = json.loads(rep.read_text())
        got = [(i["layer"], round(i["area"], 9), round(i["x"], 6), round(i["y"], 6)) for i in doc["islands"]]
        assert got == want, name
        assert doc["thin_segments"] is None
    sl1s = tmp_path / "p.sl1s"
    assert run("slice", scene, "-o", sl1s, "-q").exit_code == 0
    rep = tmp_path / "sl1s.json"
    assert run("check", sl1s, "--json", rep).exit_code == 1
    assert len(json.loads(rep.read_text())["islands"]) == 2
    stack = tmp_path / "stack"
    assert run("slice", scene, "-o", stack, "--pixel-size", "0.05", "-q").exit_code == 0
    assert run("check", stack, "--json", tmp_path / "s.json").exit_code == 1
    mine = json.loads((tmp_path / "s.json").read_text())["islands"]
    scene_rep = tmp_path / "scene.json"
    run("check", scene, "--pixel-size", "0.05", "--json", scene_rep)
    assert mine == json.loads(scene_rep.read_text())["islands"]


def test_bad_input_exits_2(hanging, tmp_path):
    _skel, scene = hanging
    for args, needle in [((tmp_path / "none.json", "--pixel-size", "0.1"), "none.json"),
                         ((scene, "--pixel-size", "0.1", "--fail-on", "islands,bogus"), "bogus"),
                         ((scene, "--pixel-size", "0.1", "--min-feature", "-1"), "--min-feature"),
                         ((scene,), "pixel"),
                         ((tmp_path / "c.cli",), "contours")]:
        if str(args[0]).endswith(".cli"):
            (tmp_path / "c.cli").write_bytes(b"$$HEADERSTART")
        r = run("check", *args)
        assert r.exit_code == 2, (args, r.output)
        assert needle in r.output and "Traceback" not in r.output, r.output
    stack = tmp_path / "st"
    assert run("slice", scene, "-o", stack, "--pixel-size", "0.1", "-q").exit_code == 0
    r = run("check", stack, "--pixel-size", "0.1")
    assert r.exit_code == 2 and "already sliced" in r.output


# ---------------------------------------------------------------- resin traps
def icosphere(level: int):
    """Unit-sphere vertices and edges of a subdivided icosahedron."""
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(level):
        cache, nf = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[key] = len(v) - 1
            return cache[key]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = nf
    edges = sorted({(min(x, y), max(x, y)) for a, b, c in f for x, y in ((a, b), (b, c), (c, a))})
    return np.array(v), np.array(edges)


R_SHELL, R_STRUT, PX = 3.0, 0.45, 0.1
CENTRE = np.array([0.0, 0.0, R_SHELL + R_STRUT + 0.5])


def shell(open_top: bool = False) -> Skeleton:
    """A closed shell: the 480 edges of a twice-subdivided icosahedron of radius 3 mm,
    struts of radius 0.45 mm (edges about 0.9 mm long), sealed by the blend."""
    v, e = icosphere(2)
    if open_top:                                  # drop every edge near the top: a hole ~2.4 mm across
        e = e[~((v[e[:, 0], 2] > 0.8) | (v[e[:, 1], 2] > 0.8))]
    return Skeleton(v * R_SHELL + CENTRE, e, np.full((len(e), 2), R_STRUT))


def cavity_volume(skel: Skeleton, n_theta: int = 64, n_phi: int = 128) -> float:
    """Exact volume of the star-shaped cavity around CENTRE: ∫ rho³/3 dΩ with
    rho the first crossing of F = 1 along each direction (march + 45
    bisections), Gauss-Legendre in cos(theta) x trapezoid in phi (spectral
    for a smooth periodic integrand)."""
    mu, w = np.polynomial.legendre.leggauss(n_theta)
    ph = np.arange(n_phi) * 2 * np.pi / n_phi
    MU, PH = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1 - MU ** 2)
    d = np.stack([s * np.cos(PH), s * np.sin(PH), MU], -1).reshape(-1, 3)
    steps = np.linspace(0, R_SHELL + 2 * R_STRUT, 48)[1:]
    f = skel.field((CENTRE + steps[None, :, None] * d[:, None, :]).reshape(-1, 3)).reshape(len(d), -1)
    assert (f >= 1).any(axis=1).all(), "a direction leaves the shell: not closed"
    first = np.argmax(f >= 1, axis=1)
    lo, hi = np.where(first > 0, steps[first - 1], 0.0), steps[first]
    for _ in range(45):
        m = 0.5 * (lo + hi)
        out = skel.field(CENTRE + m[:, None] * d) < 1
        lo, hi = np.where(out, m, lo), np.where(out, hi, m)
    rho = (0.5 * (lo + hi)).reshape(n_theta, n_phi)
    return float((w[:, None] * rho ** 3 / 3).sum() * 2 * np.pi / n_phi), float(rho.min()), float(rho.max())


@pytest.fixture(scope="module")
def exact_cavity():
    """(volume, rho_min, rho_max) of the closed shell's cavity, and the volume
    from half the quadrature points in each direction."""
    return cavity_volume(shell()), cavity_volume(shell(), 32, 64)[0]


def test_closed_cavity_volume_within_a_voxel_layer(tmp_path, exact_cavity):
    skel = shell()
    scene = tmp_path / "shell.json"
    skel.save(scene)
    out = tmp_path / "shell_rep.json"
    r = run("check", scene, "--pixel-size", PX, "--json", out)
    assert r.exit_code == 1 and "closed cavity" in r.output, r.output
    (t,) = json.loads(out.read_text())["traps"]
    (exact, rho_min, rho_max), coarse = exact_cavity
    assert abs(coarse - exact) < 1e-3 * exact               # the quadrature has converged
    voxel_layer = 4 * np.pi * rho_max ** 2 * PX              # the cavity's surface x one voxel
    assert t["kind"] == "closed"
    assert abs(t["volume"] - exact) <= voxel_layer
    assert abs(t["volume"] - exact) <= 0.01 * exact          # in fact much closer (0.06 % measured)
    assert (t["x"], t["y"], t["z"]) == pytest.approx(tuple(CENTRE), abs=PX)


def test_shell_open_at_the_top_holds_no_resin(tmp_path):
    scene = tmp_path / "open.json"
    shell(open_top=True).save(scene)
    out = tmp_path / "open_rep.json"
    r = run("check", scene, "--pixel-size", PX, "--json", out, "--fail-on", "traps")
    assert r.exit_code == 0, r.output
    assert json.loads(out.read_text())["traps"] == []


def test_shell_cut_by_the_plate_is_a_suction_cup(tmp_path, exact_cavity):
    """Slicing only the upper half (bounds from the centre up) puts the plate
    across the cavity: it is open to the plate only."""
    scene = tmp_path / "cup.json"
    shell().save(scene)
    c = CENTRE
    b = [c[0] - 4, c[1] - 4, c[2], c[0] + 4, c[1] + 4, c[2] + 4]
    out = tmp_path / "cup_rep.json"
    r = run("check", scene, "--pixel-size", PX, "--bounds", *b, "--json", out)
    assert r.exit_code == 1 and "suction cup" in r.output, r.output
    (t,) = json.loads(out.read_text())["traps"]
    assert t["kind"] == "plate" and t["layers"][0] == 0
    exact = exact_cavity[0][0]
    assert t["volume"] == pytest.approx(exact / 2, rel=0.05)


@pytest.mark.parametrize("keep", [0, 150, 10**9])
def test_cropped_stack_equals_the_cut_of_the_whole_stack(tmp_path, keep):
    """Read once (every box kept), past the budget at the second box (read
    again) or twice: the same window and layers as cutting the full images."""
    from PIL import Image

    from formats.readback import open_stack

    rng = np.random.default_rng(7)
    H, W, K = 40, 56, 6
    vol = np.zeros((K, H, W), np.uint8)
    for k in (1, 2, 4):                                  # layers 0, 3 and 5 stay empty
        r, c = rng.integers(3, H - 12), rng.integers(5, W - 15)
        vol[k, r:r + 8, c:c + 10] = rng.integers(1, 256, (8, 10), dtype=np.uint8)      # 80 bytes each
    files = [f"{k:03d}.png" for k in range(K)]
    for k, f in enumerate(files):
        Image.fromarray(vol[k]).save(tmp_path / f)
    (tmp_path / "slices.json").write_text(json.dumps({
        "origin": [0.05, 0.05, 0.05], "pixel_size": [0.1, 0.1], "layer_height": 0.1,
        "width": W, "height": H, "layers": K, "files": files}))
    rows = np.flatnonzero(vol.any(axis=(0, 2)))
    cols = np.flatnonzero(vol.any(axis=(0, 1)))
    want = (rows[0] - 1, cols[0] - 1, rows[-1] + 2, cols[-1] + 2)
    window, layers = open_stack(tmp_path).cropped(keep=keep)
    assert window == want
    got = np.stack(list(layers))
    assert np.array_equal(got, vol[:, want[0]:want[2], want[1]:want[3]])
    assert open_stack(tmp_path).solid_window() == want
