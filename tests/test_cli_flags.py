"""Flags of ``slice``, ``render`` and ``validate`` through the real entry point
(click's CliRunner on :func:`slicer.cli.app.main`), each test asserting the
flag's effect on what is written, not just that the command runs.

* slice: ``--strict`` (same bytes, more evaluations), ``--contour-tol``
  (contour vertices and edge midpoints within it of the surface),
  ``--gamma`` (the documented grey mapping of partial pixels, 50 % stays
  128), ``--pixel-size-y`` (rows at that pitch, recorded in slices.json),
  ``--radius`` (fills OBJ vertices without radii; file radii win).
* render (crossings read back with ``--roots-out``): ``--view top|side``
  (rays along the named axis, the image of a hand-built camera), ``--eye`` /
  ``--target``, ``--fov``, ``--opaque``, ``--transparent``, ``--bisection``,
  ``--tolerance``, ``--opacity`` / ``--max-opacity``, ``--strict``.
* validate: ``--mesh-edge`` (recorded, and it sets the reference mesh's
  error bound).
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from slicer import Skeleton, load_scene
from slicer._kernels.runtime.launch import serial
from slicer.cli.app import main
from slicer.scene.lattice import generate_lattice
from slicer.render.rendering import Camera, render

#: the chiral test model: a post, a long +x arm and a short +y arm (radius 0.3)
ELL = Skeleton([[0, 0, 0], [0, 0, 1.6], [2.0, 0, 1.6], [0, 1.0, 1.6]], [[0, 1], [1, 2], [1, 3]],
               [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3]])


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output + (r.stderr or "") + repr(r.exception)
    return r


@pytest.fixture(scope="module")
def ell(tmp_path_factory):
    p = tmp_path_factory.mktemp("flags") / "ell.json"
    ELL.save(p)
    return p


def stack(folder):
    meta = json.loads((folder / "slices.json").read_text())
    return meta, np.stack([np.asarray(Image.open(folder / f)) for f in meta["files"]])


def evaluations(stdout: str) -> int:
    return int(re.search(r"([\d,]+) evaluations", stdout).group(1).replace(",", ""))


# ============================================================================ slice
def test_slice_strict_writes_the_same_bytes_with_more_evaluations(ell, tmp_path):
    outs, ev = {}, {}
    for name, extra in (("plain", []), ("strict", ["--strict"])):
        out = tmp_path / name
        r = run("slice", ell, "-o", out, "--pixel-size", "0.05", "--layer-height", "0.1", *extra)
        outs[name], ev[name] = out, evaluations(r.stdout)
    meta = json.loads((outs["plain"] / "slices.json").read_text())
    for f in meta["files"] + ["slices.json"]:
        assert (outs["plain"] / f).read_bytes() == (outs["strict"] / f).read_bytes(), f
    assert ev["strict"] > 1.3 * ev["plain"], ev


def _in_plane_distance_ok(skel, pts, z, tol):
    """Whether each point (x, y) lies within ``tol`` of the section F(., ., z) = 1:
    F - 1 changes sign between p - tol n and p + tol n (n the in-plane gradient)."""
    P = np.column_stack([pts, np.full(len(pts), z)])
    g = skel.gradient(P)
    n = np.column_stack([g[:, :2], np.zeros(len(P))])
    n /= np.linalg.norm(n, axis=1)[:, None]
    lo = skel.field(P - tol * n) - 1.0
    hi = skel.field(P + tol * n) - 1.0
    return (lo <= 0) & (hi >= 0) | (lo >= 0) & (hi <= 0)


@pytest.mark.parametrize("tol", [1e-2, 1e-5])
def test_slice_contour_tol_bounds_the_contours_distance_to_the_surface(ell, tmp_path, tol):
    gj = tmp_path / "c.geojson"
    run("slice", ell, "-o", tmp_path / "s", "--pixel-size", "0.05", "--layer-height", "0.2", "--contours", gj,
        "--contour-tol", tol, "-q")
    doc = json.loads(gj.read_text())
    assert doc["skelslice"]["tolerance"] == tol
    nv = 0
    for ft in doc["features"]:
        z = ft["properties"]["z"]
        for poly in ft["geometry"]["coordinates"]:
            for ring in poly:
                r = np.asarray(ring)
                mids = 0.5 * (r[1:] + r[:-1])
                assert _in_plane_distance_ok(ELL, r[:-1], z, tol).all(), (tol, z)
                assert _in_plane_distance_ok(ELL, mids, z, tol).all(), (tol, z)
                nv += len(r) - 1
    assert nv > 100
    # a fine tolerance costs vertices: at 1e-2 the arcs are coarse chords
    assert (nv < 2000) if tol == 1e-2 else (nv > 5000), nv


def test_slice_gamma_maps_partial_coverage_as_documented(ell, tmp_path):
    """--aa 4: coverages are multiples of 1/16, so gamma 1 gives
    round(255 c) and each partial pixel's coverage is known exactly; gamma 2
    gives round(255 c^2 / (c^2 + (1 - c)^2)): darker below 50 %, brighter
    above, 128 at 50 %, solid and empty pixels unchanged."""
    greys = {}
    for g in ("1", "2"):
        out = tmp_path / f"g{g}"
        run("slice", ell, "-o", out, "--pixel-size", "0.05", "--layer-height", "0.2", "--aa", "4", "--gamma", g, "-q")
        greys[g] = stack(out)[1].astype(int)
    a, b = greys["1"], greys["2"]
    assert a.shape == b.shape
    k = np.arange(17)
    lin = np.floor(255 * k / 16 + 0.5).astype(int)
    assert np.isin(a, lin).all()                                   # only the 17 linear levels occur
    c = np.searchsorted(lin, a) / 16.0
    want = np.floor(255 * c**2 / (c**2 + (1 - c) ** 2) + 0.5).astype(int)
    assert np.array_equal(b, want)
    part = (c > 0) & (c < 1)
    assert part.sum() > 100
    assert np.all(b[part & (c < 0.5)] < a[part & (c < 0.5)]) and np.all(b[part & (c > 0.5)] > a[part & (c > 0.5)])
    assert (c == 0.5).any() and np.all(a[c == 0.5] == 128) and np.all(b[c == 0.5] == 128)
    assert np.array_equal(a[~part], b[~part])


def test_slice_pixel_size_y_sets_the_row_pitch(ell, tmp_path):
    bounds = ["--bounds", "-0.5", "-0.5", "-0.3", "2.5", "1.5", "1.9"]
    m1, v1 = stack_of(ell, tmp_path / "a", "--pixel-size", "0.05", *bounds)
    m2, v2 = stack_of(ell, tmp_path / "b", "--pixel-size", "0.05", "--pixel-size-y", "0.1", *bounds)
    assert m1["pixel_size"] == [0.05, 0.05] and m2["pixel_size"] == [0.05, 0.1]
    assert (m1["width"], m1["height"]) == (60, 40) and (m2["width"], m2["height"]) == (60, 20)
    # every pixel is F >= 1 at the voxel centre slices.json locates (rows at 0.1 mm)
    K, H, W = v2.shape
    (x0, y0, z0), (px, py), h = m2["origin"], m2["pixel_size"], m2["layer_height"]
    k, j, i = np.meshgrid(np.arange(K), np.arange(H), np.arange(W), indexing="ij")
    f = ELL.field(np.stack([x0 + i * px, y0 - j * py, z0 + k * h], -1).reshape(-1, 3)).reshape(K, H, W)
    bad = ((v2 == 255) != (f >= 1)) & (np.abs(f - 1) > 1e-9)
    assert not bad.any() and (v2 == 255).sum() > 100


def stack_of(scene, out, *args):
    run("slice", scene, "-o", out, "--layer-height", "0.1", "-q", *args)
    return stack(out)


def test_slice_radius_fills_obj_vertices_without_radii_and_file_radii_win(tmp_path):
    pts = "v 0 0 0{}\nv 0 0 1.6{}\nv 2 0 1.6{}\nl 1 2 3\n"
    bare, with_r = tmp_path / "bare.obj", tmp_path / "radii.obj"
    bare.write_text(pts.format("", "", ""))
    with_r.write_text(pts.format(" 0.25", " 0.3", " 0.35"))
    same_json = tmp_path / "same.json"
    Skeleton([[0, 0, 0], [0, 0, 1.6], [2, 0, 1.6]], [[0, 1], [1, 2]], [[0.4, 0.4], [0.4, 0.4]]).save(same_json)
    file_json = tmp_path / "file.json"
    Skeleton([[0, 0, 0], [0, 0, 1.6], [2, 0, 1.6]], [[0, 1], [1, 2]], [[0.25, 0.3], [0.3, 0.35]]).save(file_json)
    bounds = ["--pixel-size", "0.05", "--bounds", "-0.8", "-0.8", "-0.8", "2.8", "0.8", "2.4"]
    _, bare_v = stack_of(bare, tmp_path / "o1", "--radius", "0.4", *bounds)
    _, json_v = stack_of(same_json, tmp_path / "o2", *bounds)
    _, file_v = stack_of(with_r, tmp_path / "o3", "--radius", "0.4", *bounds)
    _, filej_v = stack_of(file_json, tmp_path / "o4", *bounds)
    assert np.array_equal(bare_v, json_v) and json_v.any()
    assert np.array_equal(file_v, filej_v) and not np.array_equal(file_v, bare_v)
    assert load_scene(with_r, radius=0.4).radii.tolist() == [[0.25, 0.3], [0.3, 0.35]]


# ============================================================================ render
SIZE = ["--size", "40", "30"]


def render_cli(scene, tmp_path, name, *args):
    """Render with --roots-out; returns (image array, roots npz, stdout)."""
    png, npz = tmp_path / f"{name}.png", tmp_path / f"{name}.npz"
    r = run("render", scene, "-o", png, "--roots-out", npz, *args)
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files}
    return np.asarray(Image.open(png)), arrays, r.stdout


def render_stats(stdout: str) -> dict:
    m = re.search(r"([\d,]+) crossings, ([\d,]+) evaluations: ([\d,]+) isolate \+ ([\d,]+) refine \((\w+)\) \+ "
                  r"([\d,]+) shade; ([\d,]+) rays stopped", stdout)
    n = [int(v.replace(",", "")) if v.replace(",", "").isdigit() else v for v in m.groups()]
    return dict(zip(("crossings", "evaluations", "isolate", "refine", "method", "shade", "cut"), n))


@pytest.mark.parametrize("view, forward, right, up", [
    ("top", (0, 0, -1), (1, 0, 0), (0, 1, 0)),          # seen from above: columns +x, rows -y
    ("side", (-1, 0, 0), (0, 1, 0), (0, 0, 1)),         # from +x: columns +y, rows -z
])
def test_render_view_looks_along_the_named_axis(ell, tmp_path, view, forward, right, up):
    img, z, _ = render_cli(ell, tmp_path, view, *SIZE, "--view", view)
    f, r, u = (np.array(v, float) for v in (forward, right, up))
    assert np.allclose(z["direction"], f, atol=1e-15)
    o = z["origin"]
    step = o[0, 1] - o[0, 0]
    pix = float(np.linalg.norm(step))
    assert np.allclose(o[:, 1:] - o[:, :-1], pix * r, atol=1e-12)
    assert np.allclose(o[1:, :] - o[:-1, :], -pix * u, atol=1e-12)
    assert np.allclose((o - o[0, 0]) @ f, 0.0, atol=1e-12)          # one plane in front of the model
    # the image of a camera built by hand from that frame (equal to rounding of the ray origins)
    cam = Camera.ortho(o[0, 0] - 0.5 * pix * r + 0.5 * pix * u, f, r, u, pix, 40, 30)
    mine = render(ELL, camera=cam, keep_roots=True)
    assert np.array_equal(mine.count, z["count"])
    assert np.abs(mine.image().astype(int) - img.astype(int)).max() <= 1
    # a pixel is lit where its ray meets the solid (dense samples of F; grazing rays aside)
    t = np.linspace(0.0, 8.0, 2001)
    with serial():                                    # one batch of 2.4 M points
        fmax = ELL.field((o.reshape(-1, 1, 3) + t[:, None] * f).reshape(-1, 3)).reshape(30, 40, -1).max(axis=2)
    lit = z["count"] > 0
    assert np.all(lit[fmax >= 1.0 + 1e-3]) and not np.any(lit[fmax < 1.0 - 1e-3]) and lit.sum() > 50


def test_render_top_and_side_differ(ell, tmp_path):
    top = render_cli(ell, tmp_path, "t", *SIZE, "--view", "top")[0]
    side = render_cli(ell, tmp_path, "s", *SIZE, "--view", "side")[0]
    assert not np.array_equal(top, side)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


EYE, TARGET = (6.0, -5.0, 4.0), (0.5, 0.3, 0.8)


def test_render_eye_and_target_orthographic(ell, tmp_path):
    _, z, _ = render_cli(ell, tmp_path, "o", *SIZE, "--eye", *EYE, "--target", *TARGET)
    f = _unit(np.subtract(TARGET, EYE))
    o = z["origin"]
    assert np.allclose(z["direction"], f, atol=1e-12)
    assert np.allclose((o - np.array(EYE)) @ f, 0.0, atol=1e-9)      # rays start on the plane through the eye
    centre = o[14:16, 19:21].reshape(-1, 3).mean(axis=0)           # the image centre's ray ...
    w = np.array(TARGET) - centre
    assert np.linalg.norm(w - (w @ f) * f) < 1e-9                  # ... passes through the target
    assert (z["count"] > 0).sum() > 50


def test_render_eye_target_and_fov_perspective(ell, tmp_path):
    lit = {}
    for fov in (30, 60):
        _, z, _ = render_cli(ell, tmp_path, f"p{fov}", *SIZE, "--camera", "perspective", "--fov", fov,
                             "--eye", *EYE, "--target", *TARGET)
        d = z["direction"]
        assert np.allclose(z["origin"], EYE, atol=1e-12)
        assert np.allclose(_unit(d[14:16, 19:21].reshape(-1, 3).sum(axis=0)), _unit(np.subtract(TARGET, EYE)),
                           atol=1e-12)
        # rows 0 and 29 of a middle column: 2 atan((H - 1) / H tan(fov / 2)) apart
        top, bottom = 0.5 * (d[0, 19] + d[0, 20]), 0.5 * (d[29, 19] + d[29, 20])
        angle = np.degrees(np.arccos(_unit(top) @ _unit(bottom)))
        want = 2 * np.degrees(np.arctan(29 / 30 * np.tan(np.radians(fov / 2))))
        assert angle == pytest.approx(want, abs=1e-6)
        lit[fov] = int((z["count"] > 0).sum())
    assert lit[30] > 1.8 * lit[60]                                  # a wider field of view: a smaller model


def test_render_opaque_keeps_the_first_crossing_fully_opaque(ell, tmp_path):
    png = tmp_path / "op.png"
    r = run("render", ell, "-o", png, *SIZE, "--opaque", "--transparent")
    st = render_stats(r.stdout)
    alpha = np.asarray(Image.open(png))[..., 3]
    lit = int((alpha > 0).sum())
    assert set(np.unique(alpha).tolist()) == {0, 255}
    assert st["crossings"] == st["cut"] == lit > 50                 # one crossing per lit pixel, then stop
    r2 = run("render", ell, "-o", tmp_path / "tr.png", *SIZE, "--transparent")
    st2 = render_stats(r2.stdout)
    alpha2 = np.asarray(Image.open(tmp_path / "tr.png"))[..., 3]
    assert np.array_equal(alpha2 > 0, alpha > 0)
    assert len(np.unique(alpha2)) > 2 and st2["crossings"] > 1.5 * lit and st2["evaluations"] > st["evaluations"]


def test_render_transparent_writes_rgba_with_a_clear_background(ell, tmp_path):
    rgba, z, _ = render_cli(ell, tmp_path, "t", *SIZE, "--transparent")
    rgb, _, _ = render_cli(ell, tmp_path, "w", *SIZE)
    assert Image.open(tmp_path / "t.png").mode == "RGBA" and Image.open(tmp_path / "w.png").mode == "RGB"
    hit = z["count"] > 0
    assert np.all(rgba[~hit, 3] == 0) and np.all(rgba[hit, 3] > 0)
    assert np.all(rgb[~hit] == 255)
    a = rgba[..., 3:4] / 255.0
    assert np.abs(rgba[..., :3] * a + 255 * (1 - a) - rgb).max() <= 2.0   # the same picture over white


def test_render_bisection_finds_the_same_roots_with_more_refinement(ell, tmp_path):
    _, h, out_h = render_cli(ell, tmp_path, "h", *SIZE)
    _, b, out_b = render_cli(ell, tmp_path, "b", *SIZE, "--bisection")
    sh, sb = render_stats(out_h), render_stats(out_b)
    assert (sh["method"], sb["method"]) == ("hermite", "bisection")
    assert np.array_equal(h["count"], b["count"]) and h["roots"].size > 100
    assert np.abs(h["roots"] - b["roots"]).max() <= h["tolerance"]
    assert sb["isolate"] == sh["isolate"] and sb["refine"] > 2 * sh["refine"]


def _bracketed(skel, z, tol):
    """Whether each isolated crossing r of each ray has F - 1 of opposite
    signs at r - tol and r + tol (the crossing is within tol of r)."""
    counts = z["count"].ravel()
    o = np.repeat(z["origin"].reshape(-1, 3), counts, axis=0)
    d = np.repeat(z["direction"].reshape(-1, 3), counts, axis=0)
    r = z["roots"]
    first = np.repeat(np.cumsum(counts) - counts, counts)
    idx = np.arange(len(r)) - first
    gap_l = np.where(idx > 0, r - np.roll(r, 1), np.inf)
    gap_r = np.where(idx < np.repeat(counts, counts) - 1, np.roll(r, -1) - r, np.inf)
    iso = (gap_l > 2 * tol) & (gap_r > 2 * tol)
    lo = skel.field(o + (r - tol)[:, None] * d) - 1.0
    hi = skel.field(o + (r + tol)[:, None] * d) - 1.0
    return (np.sign(lo) != np.sign(hi))[iso], int(iso.sum())


def test_render_tolerance_brackets_every_crossing(ell, tmp_path):
    _, dflt, out_d = render_cli(ell, tmp_path, "d", *SIZE)
    _, fine, out_f = render_cli(ell, tmp_path, "f", *SIZE, "--tolerance", "1e-5")
    lo, hi = ELL.support_bounds()
    assert dflt["tolerance"] == pytest.approx(1e-4 * np.linalg.norm(hi - lo), rel=1e-12)
    assert fine["tolerance"] == 1e-5
    for z in (dflt, fine):
        ok, n = _bracketed(ELL, z, float(z["tolerance"]))
        assert n > 100 and ok.all()
    assert np.array_equal(dflt["count"], fine["count"])
    assert render_stats(out_f)["evaluations"] > render_stats(out_d)["evaluations"]


def test_render_opacity_and_max_opacity_set_each_pixels_alpha(tmp_path):
    """alpha = 1 - (1 - opacity)^k over the k crossings composited; with
    --max-opacity 0.9 and opacity 0.5 a ray stops after 4 (0.875 < 0.9 <= 0.9375)."""
    lattice = tmp_path / "bcc.json"
    generate_lattice("bcc", cells=(2, 2, 2), cell_size=4.0, radius=0.35).save(lattice)
    for mx, cap, cut in (("1", None, False), ("0.9", 4, True)):
        img, z, out = render_cli(lattice, tmp_path, f"m{mx}", *SIZE, "--transparent", "--opacity", "0.5",
                                 "--max-opacity", mx)
        k = z["count"] if cap is None else np.minimum(z["count"], cap)
        want = np.rint(255 * (1 - 0.5 ** k)).astype(int)
        assert np.abs(img[..., 3].astype(int) - want).max() <= 1
        assert z["count"].max() > 4
        assert (render_stats(out)["cut"] > 0) == cut


def test_render_strict_finds_the_same_crossings_with_more_evaluations(ell, tmp_path):
    img, z, out = render_cli(ell, tmp_path, "n", *SIZE)
    img_s, zs, out_s = render_cli(ell, tmp_path, "s", *SIZE, "--strict")
    assert np.array_equal(z["count"], zs["count"])
    assert np.abs(z["roots"] - zs["roots"]).max() <= 1e-9 * float(z["tolerance"]) + 1e-12
    assert np.abs(img.astype(int) - img_s.astype(int)).max() <= 1
    assert render_stats(out_s)["evaluations"] > 2 * render_stats(out)["evaluations"]


# ============================================================================ validate
def test_validate_mesh_edge_is_recorded_and_sets_the_mesh_bound(ell):
    reps = {}
    for edge in ("0.02", "0.06"):
        r = CliRunner().invoke(main, ["validate", str(ell), "--pixels", "60", "--layers-checked", "2", "--json",
                                      "--mesh-edge", edge])
        assert r.exit_code in (0, 1), r.output
        reps[edge] = json.loads(r.stdout)
    fine, coarse = reps["0.02"], reps["0.06"]
    assert fine["settings"]["mesh_edge"] == 0.02 and coarse["settings"]["mesh_edge"] == 0.06
    assert [l["z"] for l in fine["layers"]] == [l["z"] for l in coarse["layers"]] and fine["layers"]
    for a, b in zip(fine["layers"], coarse["layers"]):
        assert b["mesh_bound"] > 2 * a["mesh_bound"] > 0
        assert b["mesh_triangles"] < a["mesh_triangles"]
