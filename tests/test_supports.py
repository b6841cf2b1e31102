"""Supports and a pad (``skelslice supports``, ``--supports auto``), on scenes with known answers.

* Hypothesis on random-strut scenes: once supported, the check's own island
  finder finds no island; every local minimum of the skeleton has a support
  under it; no support strut's axis runs inside the model except where its
  ends enter it; every voxel of the (lifted) model is still inside; the
  model's struts come first, in order, moved only along z.
* The scene format's ``"groups"``: read back bit-exactly, and every malformed
  entry refused by name.
* The real entry point: a scene the check calls unprintable is clean with
  ``--supports auto``, and so is the output sliced from the scene
  ``skelslice supports`` wrote; bad options exit 2 and write nothing.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from slicer import Skeleton
from slicer.cli.app import main
from slicer.printability import IslandFinder
from slicer.scene.read import load_scene
from slicer.tracer.slicing import slice_skeleton
from slicer.supports.build import SupportSettings, supported_scene, write_supported
from slicer.supports.groups import GroupedSkeleton

PX = 0.1


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def islands_of(result) -> list:
    """Islands as ``skelslice check`` finds them, on a traced result's layers."""
    f = IslandFinder(result.grid)
    for k, img in enumerate(result.iter_layers()):
        f.add(k, img > 0)
    return f.islands


def minimum_nodes(skel) -> list[int]:
    """Brute force: nodes used by a segment none of whose neighbours is lower."""
    out = []
    for v in range(skel.n_nodes):
        nb = [int(b) if int(a) == v else int(a) for a, b in skel.segments if v in (int(a), int(b))]
        if nb and all(skel.nodes[u, 2] >= skel.nodes[v, 2] for u in nb):
            out.append(v)
    return out


# A branch hanging down to a free end, a V meeting at a node in mid-air and a floating strut above
# the V (its supports land on the model).
HANG = Skeleton([[0, 0, 0], [0, 0, 4], [3, 0, 4], [3, 0, 2.5], [6, 0, 3], [5, 0, 5.5], [7, 0, 5.5]],
                [[0, 1], [1, 2], [2, 3], [3, 4], [5, 6]], [[0.5, 0.5], [0.5, 0.4], [0.4, 0.3], [0.4, 0.4],
                                                           [0.35, 0.35]])


@st.composite
def strut_scenes(draw):
    """2 to 4 struts with random ends in a 5 mm box, radii 0.3 to 0.5 mm."""
    n = draw(st.integers(2, 4))
    coord = st.floats(0.0, 5.0, allow_nan=False).map(lambda v: round(v, 2))
    nodes, segs, radii = [], [], []
    for s in range(n):
        a = [draw(coord), draw(coord), draw(coord) + 1.0]
        b = [draw(coord), draw(coord), draw(coord) + 1.0]
        if np.linalg.norm(np.subtract(a, b)) < 1.5:
            b[2] = a[2] + 1.5
        nodes += [a, b]
        segs.append([2 * s, 2 * s + 1])
        r = draw(st.floats(0.3, 0.5)).__round__(2)
        radii.append([r, r])
    return Skeleton(nodes, segs, radii)


@st.composite
def lattice_scenes(draw):
    """A small unit-cell lattice (1 or 2 cells a side, 3 mm cells), radius 0.3 to 0.5 mm, graded or not."""
    from slicer.scene.lattice import generate_lattice
    kind = draw(st.sampled_from(["cubic", "bcc", "octet", "kelvin", "bcc+cubic"]))
    cells = tuple(draw(st.integers(1, 2)) for _ in range(3))
    r0, r1 = (round(draw(st.floats(0.3, 0.5)), 2) for _ in range(2))
    return generate_lattice(kind, cells, 3.0, r0, radius_top=r1)


def _support_axis_inside(scene: GroupedSkeleton, model: Skeleton, lift: float, st_: SupportSettings) -> list:
    """Points of support axes inside the (lifted) model farther than the penetration from the
    strut's ends (there the tips and the ends on the model enter it on purpose)."""
    lifted = model.translated((0, 0, lift))
    bad = []
    mask = scene.role_mask(("support",))
    for s in np.nonzero(mask)[0]:
        a, b = scene.nodes[scene.segments[s, 0]], scene.nodes[scene.segments[s, 1]]
        length = float(np.linalg.norm(b - a))
        t = np.linspace(0, 1, max(3, int(length / 0.02)))
        pts = a + t[:, None] * (b - a)
        inside = lifted.field(pts) >= 1.0
        from_end = np.minimum(t, 1 - t) * length
        far = inside & (from_end > st_.penetration + 1e-9)
        if far.any():
            bad.append((int(s), pts[far][0].tolist()))
    return bad


@settings(max_examples=6, deadline=None)
@given(st.one_of(strut_scenes(), lattice_scenes()))
def test_random_scenes_are_held_and_kept(model):
    st_ = SupportSettings(pixel_size=PX, layer_height=PX, rounds=3)
    scene, rep = supported_scene(model, st_)
    m, n = model.n_segments, model.n_nodes
    # the model first, in order, moved only along z by the lift (whole layers)
    assert scene.groups[0] == ("model", 0, m)
    assert np.array_equal(scene.segments[:m], model.segments) and np.array_equal(scene.radii[:m], model.radii)
    assert np.array_equal(scene.nodes[:n, :2], model.nodes[:, :2])
    assert np.array_equal(scene.nodes[:n, 2], model.nodes[:, 2] + rep.lift)
    assert abs(rep.lift / PX - round(rep.lift / PX)) < 1e-9
    # no island left, as the check finds them
    res = slice_skeleton(scene, PX)
    assert islands_of(res) == []
    assert rep.islands_left == 0
    # every model voxel is still inside
    lifted = model.translated((0, 0, rep.lift))
    b = res.grid
    box = (b.origin[0] - PX / 2, b.origin[1] - (b.height - 0.5) * PX, b.origin[2] - PX / 2,
           b.origin[0] + (b.width - 0.5) * PX, b.origin[1] + PX / 2, b.origin[2] + (b.layers - 0.5) * PX)
    alone = slice_skeleton(lifted, PX, bounds=box)
    together = slice_skeleton(scene, PX, bounds=box)
    for ma, mb in zip(alone.iter_layers(), together.iter_layers()):
        assert not np.any((ma > 0) & (mb == 0))
    # every local minimum of the skeleton inside the solid has a support point under it
    for v in minimum_nodes(lifted):
        p = lifted.nodes[v]
        if lifted.field(p[None])[0] < 1.0:
            continue
        d = np.hypot(rep.points[:, 0] - p[0], rep.points[:, 1] - p[1])
        near = (d <= 2 * st_.pillar_radius + PX) & (rep.points[:, 2] <= p[2] + 1e-9)
        assert near.any(), f"no support under node {v} at {p.tolist()}"
    # no support passes through the model
    assert _support_axis_inside(scene, model, rep.lift, st_) == []


def test_hanging_scene_needs_and_gets_supports(tmp_path):
    scene = tmp_path / "hang.json"
    HANG.save(scene)
    plain = run("check", scene, "--pixel-size", PX, "-q")
    assert plain.exit_code == 1, plain.output                    # islands as it is
    auto = run("check", scene, "--pixel-size", PX, "--supports", "auto", "--json", tmp_path / "r.json")
    assert auto.exit_code == 0, auto.output
    assert json.loads((tmp_path / "r.json").read_text())["islands"] == []
    made = run("supports", scene, "-o", tmp_path / "sup.json", "--pixel-size", PX, "--tip-radius", 0.25)
    assert made.exit_code == 0, made.output
    doc = json.loads((tmp_path / "sup.json").read_text())           # read independently
    m = HANG.n_segments
    assert doc["skelslice"] == 2 and doc["groups"][0] == {"role": "model", "segments": [0, m]}
    assert doc["segments"][:m] == HANG.segments.tolist() and doc["segment_radii"][:m] == HANG.radii.tolist()
    lift = doc["nodes"][0][2] - HANG.nodes[0, 2]
    assert lift == pytest.approx(3.0)
    for got, want in zip(doc["nodes"], HANG.nodes.tolist()):
        assert got[:2] == want[:2] and got[2] == want[2] + lift
    sup_segments = range(doc["groups"][1]["segments"][0], doc["groups"][1]["segments"][1])
    assert min(min(doc["segment_radii"][s]) for s in sup_segments) == 0.25      # the tips
    out = tmp_path / "out.zip"
    sliced = run("slice", tmp_path / "sup.json", "--pixel-size", PX, "-o", out, "-q")
    assert sliced.exit_code == 0, sliced.output
    checked = run("check", out, "-q")
    assert checked.exit_code == 0, checked.output


@pytest.mark.slow
def test_supports_through_the_entry_point_with_a_printer(tmp_path):
    """``python -m slicer`` in a subprocess: the printer's pitch, an SL1S archive, checked clean."""
    import subprocess
    import sys
    scene = tmp_path / "hang.json"
    HANG.save(scene)

    def sk(*args):
        return subprocess.run([sys.executable, "-m", "slicer", *map(str, args)], cwd=tmp_path,
                              capture_output=True, text=True)

    r = sk("supports", scene, "-o", "sup.json", "--printer", "prusa-sl1s", "--no-pad")
    assert r.returncode == 0, r.stderr
    r = sk("slice", "sup.json", "--printer", "prusa-sl1s", "-o", "out.sl1s", "-q")
    assert r.returncode == 0, r.stderr
    r = sk("check", "out.sl1s")
    assert r.returncode == 0, r.stdout + r.stderr


def test_groups_round_trip_and_errors(tmp_path):
    scene, _ = supported_scene(HANG, SupportSettings(pixel_size=0.2, layer_height=0.2, rounds=0))
    path = tmp_path / "s.json"
    write_supported(scene, path)
    back = load_scene(path)
    assert isinstance(back, GroupedSkeleton) and back.groups == scene.groups
    for a in ("nodes", "segments", "radii"):
        assert np.array_equal(getattr(back, a), getattr(scene, a))
    doc = json.loads(path.read_text())
    m = len(doc["segments"])
    cases = [
        ({"skelslice": 1}, '"groups" needs scene format version 2'),
        ({"groups": []}, '"groups" is empty'),
        ({"groups": [{"role": "model", "segments": [0, m - 1]}]}, "the groups end at segment"),
        ({"groups": [{"role": "model", "segments": [1, m]}]}, "must follow one another"),
        ({"groups": [{"role": "model", "segments": [0, m + 1]}]}, "reaches past the last segment"),
        ({"groups": [{"role": "brace", "segments": [0, m]}]}, "is not a group role"),
        ({"groups": [{"role": "model", "segments": [0, 0]}, {"role": "pad", "segments": [0, m]}]}, "is empty"),
        ({"groups": [{"role": "model", "segments": [0, 2.0]}]}, "two JSON integers"),
        ({"groups": [{"role": "model", "segments": [0, m], "colour": 1}]}, 'unknown key "colour"'),
        ({"groups": {"role": "model"}}, "must be a list"),
    ]
    for change, message in cases:
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({**doc, **change}))
        r = run("info", bad)
        assert r.exit_code == 2 and message in r.output, (change, r.output)
        assert "Traceback" not in r.output


def test_bad_options_exit_2_and_write_nothing(tmp_path):
    scene = tmp_path / "hang.json"
    HANG.save(scene)
    sup = tmp_path / "sup.json"
    cases = [
        (["check", scene, "--pixel-size", PX, "--tip-radius", 0.3], "--tip-radius needs --supports auto"),
        (["supports", scene, "-o", sup, "--elevation", 0, "--no-pad"], "needs --pad"),
        (["supports", scene, "-o", sup, "--tip-radius", -1], "--tip-radius"),
        (["supports", scene, "-o", sup, "--tip-radius", 0.8], "larger than the pillar radius"),
        (["supports", scene, "-o", tmp_path / "sup.obj"], "written as .json"),
        (["supports", scene, "-o", scene, "--force"], "input"),
    ]
    for args, message in cases:
        r = run(*args)
        assert r.exit_code == 2 and message in r.output, (args, r.output)
    assert not sup.exists() and not (tmp_path / "sup.obj").exists()
    write_supported(supported_scene(HANG, SupportSettings(pixel_size=0.2, layer_height=0.2, rounds=0))[0], sup)
    r = run("supports", sup, "-o", tmp_path / "again.json")
    assert r.exit_code == 2 and "already has support groups" in r.output
    r = run("slice", sup, "-o", tmp_path / "tiles", "--pixel-size", PX, "--tile", 8)
    assert r.exit_code == 2 and "sliced in one piece" in r.output
    assert not (tmp_path / "again.json").exists() and not (tmp_path / "tiles").exists()


def test_pad_under_a_model_at_elevation_zero(tmp_path):
    """``--elevation 0``: the model rests on the pad, the model's nodes unmoved."""
    scene, rep = supported_scene(HANG, SupportSettings(pixel_size=PX, layer_height=PX, elevation=0))
    assert rep.lift == 0 and np.array_equal(scene.nodes[:HANG.n_nodes], HANG.nodes)
    roles = [g[0] for g in scene.groups]
    assert roles[0] == "model" and "pad" in roles
    res = slice_skeleton(scene, PX)
    assert islands_of(res) == []
    assert _support_axis_inside(scene, HANG, 0.0, SupportSettings()) == []
    assert rep.to_model >= 1                                 # the floating strut's pillars land on the V
    pad = scene.group_skeleton(roles.index("pad"))
    lowest_model = slice_skeleton(HANG, PX)
    z_model = lowest_model.grid.origin[2] + lowest_model.k0.min() * PX
    assert pad.support_bounds()[0, 2] < z_model                # under the model


def test_a_long_flat_beam_gets_supports_no_farther_apart_than_the_bridge():
    """A 16 mm beam on two posts: its flat underside gets overhang supports along it, every
    part of it within the bridge length of one (so consecutive ones at most two bridge
    lengths apart); with critical angle 0 none."""
    beam = Skeleton([[0, 0, 0], [0, 0, 3], [16, 0, 3], [16, 0, 0]], [[0, 1], [1, 2], [2, 3]],
                    [[0.5, 0.5], [0.4, 0.4], [0.5, 0.5]])
    bridge = 2.0
    scene, rep = supported_scene(beam, SupportSettings(pixel_size=PX, layer_height=PX, bridge_length=bridge))
    under = rep.points[np.array([k == "overhang" for k in rep.kinds])]
    assert len(under) >= 3
    assert np.all(np.abs(under[:, 1]) < 0.5) and np.all(under[:, 2] < 3 + rep.lift)
    xs = np.sort(under[:, 0])
    assert np.diff(xs).max() <= 2 * bridge + 2 * PX
    assert xs[0] > 1.0 and xs[-1] < 15.0                       # the posts hold the ends
    assert islands_of(slice_skeleton(scene, PX)) == []
    _, flat = supported_scene(beam, SupportSettings(pixel_size=PX, layer_height=PX, critical_angle=0))
    assert "overhang" not in flat.kinds


def test_neighbouring_heads_share_a_pillar():
    """Two short struts floating 2 mm apart, high up: their heads join one pillar by branches
    steeper than 45 degrees; with --tree-distance 0 each has its own."""
    pair = Skeleton([[0, 0, 8], [1, 0, 8], [0, 2, 8], [1, 2, 8]], [[0, 1], [2, 3]], [[0.4, 0.4], [0.4, 0.4]])
    st_ = SupportSettings(pixel_size=PX, layer_height=PX)
    scene, rep = supported_scene(pair, st_)
    assert rep.trees >= 1 and rep.pillars < rep.supports
    assert islands_of(slice_skeleton(scene, PX)) == []
    assert _support_axis_inside(scene, pair, rep.lift, st_) == []
    sup = scene.role_mask(("support",))
    a, b = scene.nodes[scene.segments[sup, 0]], scene.nodes[scene.segments[sup, 1]]
    run_ = np.hypot(*(b - a)[:, :2].T)
    assert np.all(np.abs((b - a)[:, 2]) >= run_ - 1e-9)           # no strut flatter than 45 degrees
    _, alone = supported_scene(pair, SupportSettings(pixel_size=PX, layer_height=PX, tree_distance=0))
    assert alone.trees == 0 and alone.pillars == alone.supports


def test_tall_pillars_are_braced():
    """Two struts 4 mm apart, 15 mm above a low block elsewhere, each on its own pillar: X braces of
    45-degree struts join the two tall pillars, out of the model, and nothing is left unheld."""
    pair = Skeleton([[0, 0, 15], [1, 0, 15], [0, 4, 15], [1, 4, 15], [12, 2, 0], [13, 2, 0]],
                    [[0, 1], [2, 3], [4, 5]], [[0.4, 0.4], [0.4, 0.4], [0.4, 0.4]])
    st_ = SupportSettings(pixel_size=PX, layer_height=PX, tree_distance=0)
    scene, rep = supported_scene(pair, st_)
    assert rep.pillars >= 3 and rep.braces >= 4
    sup = scene.role_mask(("support",))
    thin = sup & (scene.radii[:, 0] == st_.pillar_radius / 2)
    a, b = scene.nodes[scene.segments[thin, 0]], scene.nodes[scene.segments[thin, 1]]
    assert thin.sum() == rep.braces
    assert np.allclose(np.abs((b - a)[:, 2]), np.hypot(*(b - a)[:, :2].T))      # 45 degrees
    assert islands_of(slice_skeleton(scene, PX)) == []
    assert _support_axis_inside(scene, pair, rep.lift, st_) == []


def _page(html_path) -> dict:
    import re
    m = re.search(r'<script type="application/json" id="skelslice-data">(.*?)</script>',
                  html_path.read_text("utf-8"), re.S)
    return json.loads(m.group(1))


def test_preview_shows_the_supports_in_their_own_colour(tmp_path):
    """``preview --supports auto``: no island found, and the render has the model's blue and the
    supports' orange (orange pixels only below the model, where the supports are)."""
    import base64
    import io

    from PIL import Image
    scene = tmp_path / "hang.json"
    HANG.save(scene)
    html = tmp_path / "v.html"
    r = run("preview", scene, "-o", html, "--pixel-size", 0.2, "--supports", "auto", "--render-size", 96)
    assert r.exit_code == 0, r.output
    doc = _page(html)
    assert [f for f in doc["findings"] if f["kind"] == "island"] == []
    render = doc["renders"][0]
    assert "supports in orange" in render["caption"]
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(render["src"].split(",", 1)[1]))).convert("RGBA"))
    rgb = img[..., :3].astype(int)
    seen = img[..., 3] > 64
    orange = seen & (rgb[..., 0] > rgb[..., 2] + 40)
    blue = seen & (rgb[..., 2] > rgb[..., 0] + 40)
    assert orange.sum() > 20 and blue.sum() > 20
    assert np.nonzero(orange)[0].max() > np.nonzero(blue)[0].max()     # the pad below the model


def test_the_same_scene_whatever_the_thread_count(tmp_path):
    scene = tmp_path / "hang.json"
    HANG.save(scene)
    outs = []
    for threads in (1, 2):
        out = tmp_path / f"s{threads}.json"
        r = run("supports", scene, "-o", out, "--pixel-size", 0.2, "--threads", threads, "-q")
        assert r.exit_code == 0, r.output
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_a_pillar_beside_the_model_is_made_thinner_to_keep_clear():
    """A strut floating above a post's side: the pillar under it passes 0.6 mm from the post's
    axis (0.4 mm from its surface), so the 0.5 mm pillar would cut into the post; it is made 0.25 mm
    and every vertical pillar's surface stays out of the model."""
    scene_ = Skeleton([[0, 0, 6], [1, 0, 6], [0.5, 0.6, 0], [0.5, 0.6, 5]], [[0, 1], [2, 3]],
                      [[0.4, 0.4], [0.2, 0.2]])
    st_ = SupportSettings(pixel_size=PX, layer_height=PX, tree_distance=0)
    scene, rep = supported_scene(scene_, st_)
    lifted = scene_.translated((0, 0, rep.lift))
    sup = np.nonzero(scene.role_mask(("support",)))[0]
    a, b = scene.nodes[scene.segments[sup, 0]], scene.nodes[scene.segments[sup, 1]]
    vertical = (np.hypot(*(b - a)[:, :2].T) == 0) & (scene.radii[sup, 0] == scene.radii[sup, 1])
    under = vertical & (np.abs(a[:, 1]) < 1e-9) & (np.abs(a[:, 0] - 0.5) < 1e-9)
    assert under.any() and np.all(scene.radii[sup[under], 0] == st_.pillar_radius / 2)
    ang = np.arange(16) * np.pi / 8
    for q in np.nonzero(vertical)[0]:
        r = scene.radii[sup[q], 0]
        lo, hi = sorted([a[q, 2], b[q, 2]])
        z = np.linspace(lo, hi, 60)
        pts = np.array([[a[q, 0] + 0.95 * r * np.cos(t), a[q, 1] + 0.95 * r * np.sin(t), zz] for t in ang for zz in z])
        assert np.all(lifted.field(pts) < 1.0), q
    assert islands_of(slice_skeleton(scene, PX)) == []
