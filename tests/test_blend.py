"""Blend operators: the union field at points, the tracer's union, the refusals, the node bulge.

The tracer's union blend is tested in depth in ``tests/test_union_trace.py``;
here: one strut traced with either blend is the same solid, a 12-valent node
traced with the union is the union of the struts' own solids, and the
commands that only implement the sum (rendering, contour outputs) refuse the
union by name.
"""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from slicer.cli.app import main
from slicer.errors import OptionError
from slicer.model.field import evaluate
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import slice_skeleton
import validation.union_validate as uv
from validation.bulge import bulge, node
from validation.union_validate import validate_union

RNG = np.random.default_rng(7)
NODE = node(12, 0.5, 3.0)


def _points(n, box=3.5):
    return RNG.uniform(-box, box, size=(n, 3))


def test_union_of_one_strut_is_its_field():
    s = Skeleton([[0, 0, 0], [1, 2, 3]], [[0, 1]], [[0.4, 0.7]])
    p = _points(5000, 3.0)
    fs, gs = evaluate(s, p, gradient=True)
    fu, gu = evaluate(s, p, gradient=True, blend="union")
    assert np.array_equal(fs, fu) and np.allclose(gs, gu, rtol=0, atol=0)


def test_union_is_the_largest_strut_field():
    p = _points(4000)
    per = np.stack([evaluate(Skeleton(NODE.nodes, NODE.segments[i:i + 1], NODE.radii[i:i + 1]), p)[0]
                    for i in range(NODE.n_segments)])
    fu = evaluate(NODE, p, blend="union")[0]
    fs = evaluate(NODE, p)[0]
    assert np.array_equal(fu, per.max(axis=0))
    assert np.allclose(fs, per.sum(axis=0), rtol=1e-12, atol=1e-15)
    assert np.all(fu <= fs) and np.any(fs >= 1) and np.any((fs >= 1) & (fu < 1))   # the sum bulges
    g = evaluate(NODE, p, gradient=True, blend="union")[1]
    best = per.argmax(axis=0)
    k = np.flatnonzero(per.max(axis=0) > 0)[:50]
    for q in k:
        one = Skeleton(NODE.nodes, NODE.segments[best[q]:best[q] + 1], NODE.radii[best[q]:best[q] + 1])
        assert np.allclose(g[q], evaluate(one, p[q:q + 1], gradient=True)[1][0])


def test_unknown_blend_refused():
    with pytest.raises(OptionError, match="unknown --blend 'smooth'; choose one of sum, union"):
        evaluate(NODE, [[0, 0, 0]], blend="smooth")


def test_tracer_refuses_union_with_segment_tracing():
    with pytest.raises(OptionError) as e:
        slice_skeleton(NODE, 0.1, blend="union", method="segment")
    msg = str(e.value)
    assert "--blend union" in msg and "--method segment" in msg and "--method interval" in msg


@pytest.mark.parametrize("cmd, what", [
    (["render", "-o", "OUT.png"], "rendering"),
    (["slice", "-o", "OUT.svg", "--pixel-size", "0.1"], "svg format"),
    (["slice", "-o", "OUT.png", "--pixel-size", "0.1", "--contours", "OUT.geojson"], "--contours"),
    (["slice", "-o", "OUT.png", "--pixel-size", "0.1", "--method", "segment"], "--method segment"),
])
def test_commands_refuse_union_where_only_the_sum_is_implemented(tmp_path, cmd, what):
    scene = tmp_path / "s.obj"
    scene.write_text("v 0 0 0 0.5\nv 0 0 3 0.5\nl 1 2\n")
    args = [a.replace("OUT", str(tmp_path / "out")) for a in cmd]
    r = CliRunner().invoke(main, [args[0], str(scene), *args[1:], "--blend", "union"])
    assert r.exit_code == 2 and "--blend union" in r.output and what in r.output and "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.obj"]


def test_slice_command_traces_the_union(tmp_path):
    scene = tmp_path / "s.obj"
    scene.write_text("v 0 0 0 0.5\nv 0 0 3 0.5\nv 2 0 3 0.5\nl 1 2\nl 2 3\n")
    outs = {}
    for blend in ("sum", "union"):
        out = tmp_path / f"{blend}.png"
        r = CliRunner().invoke(main, ["slice", str(scene), "-o", str(out), "--pixel-size", "0.1", "--blend", blend])
        assert r.exit_code == 0, r.output
        outs[blend] = b"".join(f.read_bytes() for f in sorted(out.iterdir()) if f.suffix == ".png")
    assert outs["sum"] != outs["union"]     # the elbow bulges with the sum


def test_info_with_union_drops_the_duplicate_warning(tmp_path):
    scene = tmp_path / "d.obj"
    scene.write_text("v 0 0 0 0.5\nv 0 0 3 0.5\nl 1 2\nl 2 1\n")
    r = CliRunner().invoke(main, ["info", str(scene)])
    assert "duplicate segment" in r.output
    r = CliRunner().invoke(main, ["info", str(scene), "--blend", "union"])
    assert r.exit_code == 0 and "duplicate" not in r.output and "blend union" in r.output


def test_node_bulge():
    rows = {r["blend"]: r for r in bulge(12, 0.5, 5.0, rays=600)}
    assert rows["sum"]["bulge_mm"] > 0.1 * 0.5 and rows["sum"]["radius_near_node_mm"] > 0.55
    assert rows["union"]["bulge_mm"] < 1e-6
    assert rows["union"]["radius_near_node_mm"] == pytest.approx(0.5, rel=1e-3)


# ----------------------------------------------------------------------------- the tracer's union
def test_tracer_union_of_one_strut_equals_sum():
    s = Skeleton([[0, 0, 0], [0.3, 0.2, 4.0]], [[0, 1]], [[0.6, 0.4]])
    a = slice_skeleton(s, 0.07, blend="union")
    b = slice_skeleton(s, 0.07)
    assert a.grid == b.grid and np.array_equal(a.volume(), b.volume())


def test_tracer_union_at_a_node_is_the_union_of_the_struts():
    """Every voxel of the union blend is inside exactly when some strut's own field is >= 1
    (no tolerance: both evaluate each strut's field at the same points)."""
    bounds = (-3.5, -3.5, -3.5, 3.5, 3.5, 3.5)
    res = slice_skeleton(NODE, 0.1, bounds=bounds, blend="union")
    g = res.grid
    z, y, x = np.meshgrid(g.centres_z(), g.centres_y(), g.centres_x(), indexing="ij")
    p = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    per = np.stack([evaluate(Skeleton(NODE.nodes, NODE.segments[i:i + 1], NODE.radii[i:i + 1]), p)[0]
                    for i in range(NODE.n_segments)])
    want = (per >= 1.0).any(axis=0)
    got = res.volume().reshape(-1)
    assert np.array_equal(got, want) and want.sum() > 1000


def test_validate_union_against_the_manifold_union_of_the_struts(tmp_path, monkeypatch):
    """validate --blend union passes on a node; traced with the sum instead, the
    same report fails (the bulge is outside the union of the struts)."""
    sk = node(12, 0.5, 2.0)
    rep = validate_union(sk, pixel_size=0.08, layers_checked=3)
    assert rep["passed"] and rep["layers"] and all(r["pixel_mismatch_unexplained"] == 0 for r in rep["layers"])
    real = uv.slice_skeleton
    monkeypatch.setattr(uv, "slice_skeleton", lambda *a, **k: real(*a, **{**k, "blend": "sum"}))
    bad = validate_union(sk, pixel_size=0.08, layers_checked=3)
    assert not bad["passed"] and not bad["checks"]["contours_match_raster"]
    monkeypatch.undo()
    scene = tmp_path / "n.json"
    sk.save(scene)
    r = CliRunner().invoke(main, ["validate", str(scene), "--pixel-size", "0.1", "--layers-checked", "2",
                                  "--blend", "union"])
    assert r.exit_code == 0, r.output
    assert "[pass] contours_match_raster" in r.output
