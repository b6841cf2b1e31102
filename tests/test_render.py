"""Transparent rendering: every crossing of every ray, against a dense march.

The reference for a ray is the field sampled every ``tol / 2`` along it with
:meth:`Skeleton.field` (the bucket-free point evaluator), each sign change
refined by plain bisection: it finds every crossing pair wider than ``tol``.
The renderer must find the same crossings, each within ``tol``; only pairs
narrower than ``tol`` (grazing rays, double roots) may be missed by either.

The reference image ``tests/data/render_node.png`` is regenerated only on
purpose, with ``python tests/test_render.py --regenerate``.
"""
from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import zlib

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from slicer import Skeleton
from slicer.cli.app import main
from slicer.scene.lattice import generate_lattice
from slicer.render.rendering import (AMBIENT, BACK_COLOUR, DIFFUSE, FRONT_COLOUR, LIGHT, SHININESS, SPECULAR, Camera,
                           make_camera, render, screen_boxes)

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import reference as ref  # noqa: E402  (independent quadrature, imports nothing from slicer)

DATA = pathlib.Path(__file__).resolve().parent / "data"
REF_IMAGE = DATA / "render_node.png"


def _scene(nodes, segs, radii):
    return Skeleton(np.asarray(nodes, float), np.asarray(segs), np.asarray(radii, float))


SCENES = {
    "strut": _scene([[0, 0, 0], [0, 0, 10]], [[0, 1]], [[1.0, 1.0]]),
    "cone": _scene([[0, 0, 0], [1, 0.5, 8]], [[0, 1]], [[1.2, 0.3]]),
    "node": _scene([[0, 0, 0], [6, 0, 0], [-3, 5, 1], [-2, -4, 4]], [[0, 1], [0, 2], [0, 3]],
                   [[0.8, 0.5], [0.8, 0.4], [0.7, 0.6]]),
    "bcc": generate_lattice("bcc", cells=(2, 2, 2), cell_size=4.0, radius=0.35),
}


# ----------------------------------------------------------------------------- reference
def march_roots(skel, o, d, tol, t_end):
    """Crossings of ``o + t d``, t in [0, t_end]: samples every tol/2, then
    60 bisection steps per sign change (``F >= 1`` is inside)."""
    t = np.arange(0.0, t_end + tol, 0.5 * tol)
    inside = skel.field(o + t[:, None] * d) >= 1.0
    k = np.nonzero(inside[1:] != inside[:-1])[0]
    a, b = t[k], t[k + 1]
    ia = inside[k]
    for _ in range(60):
        m = 0.5 * (a + b)
        im = skel.field(o + m[:, None] * d) >= 1.0
        same = im == ia
        a = np.where(same, m, a)
        b = np.where(same, b, m)
    return 0.5 * (a + b)


def _isolated(r, w):
    """Mask of roots whose neighbours are both farther than w."""
    if r.size == 0:
        return np.zeros(0, bool)
    gap = np.diff(r)
    left = np.concatenate([[np.inf], gap])
    right = np.concatenate([gap, [np.inf]])
    return (left > w) & (right > w)


def assert_same_crossings(found, expect, tol, where):
    """Every crossing not part of a pair narrower than 2 tol is on both lists,
    at most tol apart (the renderer brackets each root to tol)."""
    slack = tol * (1.0 + 1e-6)
    for mine, other, what in ((expect, found, "missed"), (found, expect, "spurious")):
        for r in mine[_isolated(mine, 2.0 * tol)]:
            dist = np.abs(other - r).min() if other.size else np.inf
            assert dist <= slack, f"{where}: {what} crossing at t = {r:.9g} (nearest {dist:.3g} away, " \
                                  f"tol {tol:.3g}); found {found}, reference {expect}"
    if _isolated(found, 2.0 * tol).all() and _isolated(expect, 2.0 * tol).all():
        assert found.size == expect.size, f"{where}: {found} vs reference {expect}"


def pixel_roots(res, j, i):
    """The crossings of pixel (j, i) from a result rendered with keep_roots."""
    start = res.count.ravel()[: j * res.camera.width + i].sum()
    return res.roots[start:start + res.count[j, i]]


def check_pixels(skel, res, pixels):
    o, d = res.camera.rays()
    tol = res.stats["tolerance"]
    lo, hi = skel.support_bounds()
    for j, i in pixels:
        t_end = np.linalg.norm(o[j, i] - 0.5 * (lo + hi)) + np.linalg.norm(hi - lo)
        expect = march_roots(skel, o[j, i], d[j, i], tol, t_end)
        assert_same_crossings(pixel_roots(res, j, i), expect, tol, f"pixel (j={j}, i={i})")


def _some_pixels(res, rng, k_hit=10, k_any=4):
    hit = np.argwhere(res.count > 0)
    pick = hit[rng.choice(len(hit), size=min(k_hit, len(hit)), replace=False)]
    anyp = np.stack([rng.integers(0, res.camera.height, k_any), rng.integers(0, res.camera.width, k_any)], 1)
    return [tuple(p) for p in np.concatenate([pick, anyp])]


# ----------------------------------------------------------------------------- crossings
@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("camera,view", [("ortho", "iso"), ("perspective", "front")])
def test_crossings_match_dense_march(name, camera, view):
    skel = SCENES[name]
    res = render(skel, size=(21, 17), view=view, camera=camera, keep_roots=True)
    assert res.count.sum() == res.roots.size > 0
    rng = np.random.default_rng(zlib.crc32(f"{name}-{camera}".encode()))
    check_pixels(skel, res, _some_pixels(res, rng))


def test_grazing_rays_tangent_to_a_cylinder():
    """Rays at x = x_iso + k delta past a long strut along z (delta = 0.3 tol): the
    tangent one may report a double root or nothing; every other ray whose pair
    is wider than tol must report both crossings."""
    skel = _scene([[0, 0, -10], [0, 0, 10]], [[0, 1]], [[1.0, 1.0]])
    a, b = 0.5, 1.5
    for _ in range(80):   # x_iso: F(x, 0, 0) = 1
        m = 0.5 * (a + b)
        a, b = (m, b) if skel.field([[m, 0.0, 0.0]])[0] >= 1.0 else (a, m)
    x_iso = 0.5 * (a + b)
    tol = 1e-3
    delta = 0.3 * tol
    W = 11
    cam = Camera.ortho([x_iso - (W / 2) * delta, -5.0, 0.5 * delta], [0, 1, 0], [1, 0, 0], [0, 0, 1],
                       delta, W, 1)
    res = render(skel, camera=cam, tolerance=tol, keep_roots=True)
    o, d = cam.rays()
    np.testing.assert_allclose(o[0, :, 0], x_iso + (np.arange(W) - 5) * delta, atol=1e-12)
    for i in range(W):
        found = pixel_roots(res, 0, i)
        expect = march_roots(skel, o[0, i], d[0, i], tol, 10.0)
        assert_same_crossings(found, expect, tol, f"grazing ray {i - 5:+d} delta")
        if i < 5:   # inside: a pair 2 sqrt(x_iso^2 - x^2) >= 0.05 mm wide
            assert found.size == 2 and found[1] - found[0] > 0.02, (i, found)
        if i > 5:
            assert found.size == 0, (i, found)


@pytest.mark.parametrize("radii", [(1.0, 1.0), (0.4, 1.3)])
def test_rays_exactly_along_a_strut_axis(radii):
    """Orthographic and perspective rays running exactly along a strut's axis
    (and their neighbours): entry near one end cap, exit near the other."""
    skel = _scene([[0, -5, 0], [0, 5, 0]], [[0, 1]], [radii])
    tol = 1e-3
    cams = [Camera.ortho([-0.625, -12.0, 0.625], [0, 1, 0], [1, 0, 0], [0, 0, 1], 0.25, 5, 5),
            Camera.perspective([0.0, -12.0, 0.0], [0, 1, 0], [1, 0, 0], [0, 0, 1], 0.0625, 5, 5)]
    for cam in cams:
        o, d = cam.rays()
        assert np.array_equal(d[2, 2], [0.0, 1.0, 0.0]) and o[2, 2, 0] == 0.0 and o[2, 2, 2] == 0.0
        res = render(skel, camera=cam, tolerance=tol, keep_roots=True)
        assert res.count[2, 2] == 2
        check_pixels(skel, res, [(j, i) for j in range(1, 4) for i in range(1, 4)])


def test_roots_lie_on_the_surface_of_the_independent_reference():
    """Each isolated crossing separates inside from outside for the
    independent Gauss-Legendre field: F(t - tol) and F(t + tol) straddle 1."""
    skel = SCENES["node"]
    res = render(skel, size=(9, 7), camera="perspective", keep_roots=True)
    o, d = res.camera.rays()
    tol = res.stats["tolerance"]
    pts, signs = [], []
    for j, i in np.argwhere(res.count > 0)[:12]:
        r = pixel_roots(res, j, i)
        for t in r[_isolated(r, 4 * tol)]:
            pts += [o[j, i] + (t - 1.5 * tol) * d[j, i], o[j, i] + (t + 1.5 * tol) * d[j, i]]
    assert pts
    a, b = skel.endpoints()
    f = ref.skeleton_field(skel.nodes, skel.segments, skel.radii, np.array(pts))
    inside = f.reshape(-1, 2) >= 1.0
    assert np.all(inside[:, 0] != inside[:, 1]), f.reshape(-1, 2)


def test_ray_support_on_random_rays_matches_brute_force():
    """ray_support for arbitrary directions: [t_in, t_out] holds every sampled
    point of the support, and is tight up to the sampling step."""
    from slicer._kernels.rays.support import H_TIN, H_TOUT, NHIT, kprime_max, ray_support
    from slicer.model.field import segment_table

    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(40):
        a = rng.uniform(-2, 2, 3)
        b = a + rng.normal(size=3) * rng.uniform(0.3, 3)
        r = rng.uniform(0.1, 1.0, 2)
        skel = _scene([a, b], [[0, 1]], [r])
        seg = segment_table(skel)
        target = a + rng.uniform(0, 1) * (b - a) + rng.normal(size=3) * 2 * r.max()
        o = target - rng.normal(size=3) * 10
        d = target - o
        d /= np.linalg.norm(d)
        recs = np.zeros((1, NHIT))
        rec = recs[0]
        hit = ray_support(seg, 0, *o, *d, skel.degree, skel.sigma, skel.normalisation,
                          kprime_max(skel.degree, skel.sigma, skel.normalisation), recs, 0)
        t_end = np.linalg.norm(target - o) + np.linalg.norm(b - a) + 2 * skel.sigma * r.max() + 1.0
        t = np.linspace(0, t_end, 4001)
        step = t[1]
        P = o + t[:, None] * d
        margin = ref.homothetic_margin(np.tile(a, (len(t), 1)), np.tile(b, (len(t), 1)), r[0], r[1], P)
        ins = margin < 0
        if not hit:
            assert not ins.any()
            continue
        checked += 1
        if ins.any():
            assert rec[H_TIN] <= t[ins].min() and rec[H_TOUT] >= t[ins].max()
            assert t[ins].min() - rec[H_TIN] < 2 * step and rec[H_TOUT] - t[ins].max() < 2 * step
    assert checked > 15


# ----------------------------------------------------------------------------- refinement and cut-off
def test_hermite_and_bisection_agree_and_hermite_saves_evaluations():
    skel = SCENES["bcc"]
    h = render(skel, size=(24, 24), keep_roots=True)
    b = render(skel, size=(24, 24), keep_roots=True, bisection=True)
    tol = h.stats["tolerance"]
    assert np.array_equal(h.count, b.count)
    assert np.abs(h.roots - b.roots).max() <= tol
    assert h.stats["isolate_evaluations"] == b.stats["isolate_evaluations"]
    assert h.stats["refine_evaluations"] < 0.7 * b.stats["refine_evaluations"]


def test_opacity_cut_off_saves_work_and_keep_roots_keeps_them():
    skel = SCENES["bcc"]
    full = render(skel, size=(24, 24), opacity=0.5, max_opacity=1.0, keep_roots=True)
    cut = render(skel, size=(24, 24), opacity=0.5, max_opacity=0.9)
    kept = render(skel, size=(24, 24), opacity=0.5, max_opacity=0.9, keep_roots=True)
    assert cut.stats["rays_cut"] > 0 and cut.stats["evaluations"] < full.stats["evaluations"]
    assert np.array_equal(kept.count, full.count) and np.array_equal(kept.roots, full.roots)
    assert np.array_equal(kept.rgba, cut.rgba)
    assert np.array_equal(cut.count, np.minimum(full.count, 4))   # 1 - 0.5^3 < 0.9 <= 1 - 0.5^4
    assert cut.rgba[..., 3].max() <= 1.0 and np.all(cut.rgba[cut.count >= 4, 3] >= 0.9)


def test_refine_root_solves_the_cubic_only_where_the_crossing_is_kept():
    """refine_root with ``exact`` returns the cubic Hermite root of its final
    bracket; without it (a crossing that is only shaded) the bracket's
    midpoint, from the same evaluations and the same gradient. Both lie
    within the tolerance of the crossing; the cubic's root is on it to far
    better than that. Bisection returns the midpoint either way."""
    from slicer._kernels.field.segment import SCRATCH
    from slicer._kernels.render.walk import field_grad_along, refine_root
    from slicer.model.field import segment_table

    skel = SCENES["cone"]
    seg = segment_table(skel)
    hprim = np.zeros(1, np.int64)
    sarr = np.zeros(1, np.int64)
    kp = (skel.degree // 2, 1.0 / skel.sigma ** 2, skel.normalisation)
    ray = (-3.0, 0.1, 4.0, 1.0, 0.0, 0.0)          # across the cone: outside at x = -2.5, inside at x = 0.4
    scratch = np.empty(SCRATCH)
    a, b = 0.5, 3.4
    fa, _, _, _, da = field_grad_along(seg, hprim, sarr, 1, ray, a, kp, scratch)
    fb, _, _, _, db = field_grad_along(seg, hprim, sarr, 1, ray, b, kp, scratch)
    assert fa < 1.0 <= fb
    bracket = (a, b, fa - 1.0, fb - 1.0, da, db)
    tol = 1e-3
    exact = refine_root(seg, hprim, sarr, 1, ray, bracket, (tol, False, True), kp, scratch)
    mid = refine_root(seg, hprim, sarr, 1, ray, bracket, (tol, False, False), kp, scratch)
    assert exact[1:] == mid[1:] and mid[5] and mid[4] > 0       # same gradient, evaluations, have_grad
    assert exact[0] != mid[0] and abs(exact[0] - mid[0]) <= 0.5 * tol
    f_exact, _, _, _, slope = field_grad_along(seg, hprim, sarr, 1, ray, exact[0], kp, scratch)
    f_mid = field_grad_along(seg, hprim, sarr, 1, ray, mid[0], kp, scratch)[0]
    assert abs(f_mid - 1.0) <= abs(slope) * tol            # within the tolerance
    assert abs(f_exact - 1.0) <= 1e-3 * abs(slope) * tol   # on the crossing
    for keep in (True, False):
        bis = refine_root(seg, hprim, sarr, 1, ray, bracket, (tol, True, keep), kp, scratch)
        assert bis[0] == refine_root(seg, hprim, sarr, 1, ray, bracket, (tol, True, not keep), kp, scratch)[0]


# ----------------------------------------------------------------------------- shading and compositing
def _shade_reference(n_out, view, light, opacities):
    """Front-to-back composite of crossings with outward normals n_out."""
    C = np.zeros(3)
    A = 0.0
    for n, a in zip(n_out, opacities):
        front = n @ view < 0
        nf = n if front else -n
        base = np.array(FRONT_COLOUR if front else BACK_COLOUR)
        lam = max(nf @ light, 0.0)
        h = light - view
        h /= np.linalg.norm(h)
        spec = SPECULAR * max(nf @ h, 0.0) ** SHININESS if lam > 0 else 0.0
        col = np.clip(base * (AMBIENT + DIFFUSE * lam) + spec, 0, 1)
        C += (1 - A) * a * col
        A += (1 - A) * a
    return C, A


def test_pixel_colour_is_front_then_back_surface_composited():
    """Central ray through a long strut seen from the front: the entry surface
    (outward normal toward the viewer) in the front colour, then the exit
    surface in the back colour behind it."""
    skel = _scene([[0, 0, -10], [0, 0, 10]], [[0, 1]], [[1.0, 1.0]])
    cam = Camera.ortho([-0.5, -6.0, 0.5], [0, 1, 0], [1, 0, 0], [0, 0, 1], 1.0, 1, 1)
    light = -cam.forward + LIGHT[0] * cam.right + LIGHT[1] * cam.up
    light /= np.linalg.norm(light)
    view = cam.forward
    normals = [np.array([0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0])]
    for alpha in (0.3, 0.8):
        res = render(skel, camera=cam, opacity=alpha, max_opacity=1.0)
        C, A = _shade_reference(normals, view, light, [alpha, alpha])
        np.testing.assert_allclose(res.rgba[0, 0], [*C, A], atol=1e-6)
    op = render(skel, camera=cam, opaque=True)
    C, A = _shade_reference(normals[:1], view, light, [1.0])
    np.testing.assert_allclose(op.rgba[0, 0], [*C, A], atol=1e-6)
    assert op.count[0, 0] == 1 and op.stats["rays_cut"] == 1


def _reference_render():
    return render(SCENES["node"], size=(48, 40), opacity=0.35)


def test_image_matches_committed_reference():
    img = _reference_render().image()
    want = np.asarray(Image.open(REF_IMAGE).convert("RGB"))
    assert img.shape == want.shape
    diff = np.abs(img.astype(int) - want.astype(int))
    assert diff.mean() < 0.5 and np.percentile(diff, 99.5) <= 3, (diff.mean(), diff.max())


def test_transparent_png_unpremultiplies():
    res = _reference_render()
    rgba = res.image(transparent=True)
    rgb = res.image()
    assert rgba.shape[2] == 4 and rgba[0, 0, 3] == 0
    a = rgba[..., 3:4] / 255.0
    over_white = rgba[..., :3] / 255.0 * a + (1 - a)
    assert np.abs(over_white * 255 - rgb).max() <= 2.0


def test_default_framing_holds_every_support_and_perspective_boxes_are_conservative():
    skel = SCENES["node"]
    for camera in ("ortho", "perspective"):
        cam = make_camera(skel, (40, 30), "iso", camera)
        box = screen_boxes(skel, cam)
        assert box[:, :2].min() > 0 and box[:, 2].max() < 40 and box[:, 3].max() < 30
    # perspective: sampled support points project inside their segment's box
    cam = make_camera(skel, (40, 30), "front", "perspective")
    box = screen_boxes(skel, cam)
    rng = np.random.default_rng(3)
    a, b = skel.endpoints()
    for s in range(skel.n_segments):
        u = rng.uniform(0, 1, 400)
        q = a[s] + u[:, None] * (b[s] - a[s])
        tau = skel.radii[s, 0] + u * (skel.radii[s, 1] - skel.radii[s, 0])
        v = rng.normal(size=(400, 3))
        p = q + v / np.linalg.norm(v, axis=1)[:, None] * (skel.sigma * tau * rng.uniform(0, 1, 400) ** 0.3)[:, None]
        w = p - cam.origin
        x, y, z = w @ cam.right, -(w @ cam.up), w @ cam.forward
        pu, pv = x / z / cam.pixel + 20, y / z / cam.pixel + 15
        assert np.all((pu >= box[s, 0]) & (pu <= box[s, 2]) & (pv >= box[s, 1]) & (pv <= box[s, 3]))


# ----------------------------------------------------------------------------- CLI
@pytest.fixture
def scene_file(tmp_path):
    p = tmp_path / "node.json"
    SCENES["node"].save(p)
    return p


@pytest.mark.parametrize("args,needle", [
    (["--size", "0", "5"], "width must be an integer in [1, 16384]"),
    (["--size", "20", "-3"], "height must be an integer"),
    (["--view", "diagonal"], "diagonal"),
    (["--eye", "1", "2", "3"], "give both --eye and --target"),
    (["--opacity", "1.5"], "opacity must be in (0, 1]"),
    (["--camera", "perspective", "--fov", "180"], "fov must be in (0, 180)"),
])
def test_cli_rejects_bad_options(scene_file, tmp_path, args, needle):
    out = tmp_path / "x.png"
    r = CliRunner().invoke(main, ["render", str(scene_file), "-o", str(out), *args])
    assert r.exit_code == 2, r.output
    assert needle in r.output
    assert "Traceback" not in r.output and not out.exists()


def test_cli_refuses_existing_output_without_force(scene_file, tmp_path):
    out = tmp_path / "x.png"
    out.write_bytes(b"keep")
    r = CliRunner().invoke(main, ["render", str(scene_file), "-o", str(out), "--size", "8", "8"])
    assert r.exit_code == 2 and "already exists (use --force" in r.output
    assert out.read_bytes() == b"keep"
    r = CliRunner().invoke(main, ["render", str(scene_file), "-o", str(out), "--size", "8", "8", "--force", "-q"])
    assert r.exit_code == 0, r.output
    assert Image.open(out).size == (8, 8)
    umask = os.umask(0o022)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask   # the usual mode, not mkstemp's 0600
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_cli_roots_out_layout(scene_file, tmp_path):
    out, npz = tmp_path / "img.png", tmp_path / "roots.npz"
    r = CliRunner().invoke(main, ["render", str(scene_file), "-o", str(out), "--size", "12", "10",
                                  "--camera", "perspective", "--roots-out", str(npz)])
    assert r.exit_code == 0, r.output
    assert "crossings" in r.output and "evaluations" in r.output
    img = Image.open(out)
    assert img.size == (12, 10) and img.mode == "RGB"
    z = np.load(npz)
    assert set(z.files) >= {"origin", "direction", "count", "roots"}
    assert z["origin"].shape == z["direction"].shape == (10, 12, 3)
    assert z["count"].shape == (10, 12) and z["count"].dtype.kind == "i"
    assert z["roots"].ndim == 1 and z["roots"].dtype == np.float64 and z["roots"].size == z["count"].sum() > 0
    np.testing.assert_allclose(np.linalg.norm(z["direction"], axis=2), 1.0, atol=1e-12)
    start = np.concatenate([[0], np.cumsum(z["count"].ravel())])
    for p in range(120):
        rr = z["roots"][start[p]:start[p + 1]]
        assert np.all(np.diff(rr) > 0) and np.all(rr >= 0)
    # the file's rays and roots are the API's
    api = render(SCENES["node"], size=(12, 10), camera="perspective", keep_roots=True)
    assert np.array_equal(api.roots, z["roots"]) and np.array_equal(api.count, z["count"])
    o, d = api.camera.rays()
    assert np.array_equal(o, z["origin"]) and np.array_equal(d, z["direction"])


def test_one_and_two_threads_give_identical_bytes(scene_file, tmp_path):
    outs = []
    for t in (1, 2):
        png, npz = tmp_path / f"t{t}.png", tmp_path / f"t{t}.npz"
        r = subprocess.run([sys.executable, "-m", "slicer", "render", str(scene_file), "-o", str(png),
                            "--size", "40", "33", "--bucket", "8", "--threads", str(t), "--roots-out", str(npz),
                            "-q"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        outs.append((png.read_bytes(), npz.read_bytes()))
    assert outs[0] == outs[1]


if __name__ == "__main__":   # python tests/test_render.py --regenerate
    if sys.argv[1:] == ["--regenerate"]:
        DATA.mkdir(exist_ok=True)
        Image.fromarray(_reference_render().image(), "RGB").save(REF_IMAGE, optimize=True)
        print(f"wrote {REF_IMAGE}")
    else:
        print(__doc__)
