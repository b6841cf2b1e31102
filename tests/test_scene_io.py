"""Scene files: JSON v1 and OBJ polylines, round trips, precedence rules and bad input.

``BAD_CASES`` (one entry per kind of bad input, in ``tests/helpers.py``) is shared
with ``test_cli_errors.py``, which runs every case through the real CLI.
"""
from __future__ import annotations

import json
import os
import string
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import BAD_CASES, BASE, OBJ_OK, make, scene
from slicer import Skeleton, load_scene, save_scene
from slicer.errors import OutputError, SceneError

# ----------------------------------------------------------------------------- helpers
def random_skeleton(rng, n=30, m=60, degree=6, sigma=2.0) -> Skeleton:
    nodes = rng.normal(size=(n, 3)) * 10 ** rng.uniform(-3, 3, size=(n, 1))
    a = rng.integers(0, n, m)
    b = (a + rng.integers(1, n, m)) % n
    radii = rng.uniform(0.01, 1.0, size=(m, 2)) / 3.0
    return Skeleton(nodes, np.stack([a, b], axis=1), radii, degree, sigma)


def assert_same(s: Skeleton, t: Skeleton) -> None:
    for name in ("nodes", "segments", "radii"):
        x, y = getattr(s, name), getattr(t, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name
    assert (s.degree, s.sigma) == (t.degree, t.sigma)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case", BAD_CASES, ids=[c.id for c in BAD_CASES])
def test_bad_input_raises_scene_error_naming_file_entry_and_value(case, tmp_path):
    path = make(case, tmp_path)
    with pytest.raises(SceneError) as info:
        load_scene(path, radius=case.radius)
    msg = str(info.value)
    assert info.value.source == str(path)
    assert msg.startswith(f"{path}: "), msg
    for fragment in case.must:
        assert fragment in msg, f"{fragment!r} not in {msg!r}"
    assert "\n" not in msg
    assert isinstance(info.value, ValueError)


def test_bad_cases_are_unique():
    ids = [c.id for c in BAD_CASES]
    names = [c.name for c in BAD_CASES]
    assert len(set(ids)) == len(ids) and len(set(names)) == len(names)


@pytest.mark.parametrize("radius", [0, -1.0, float("nan"), float("inf"), True, "1"])
def test_bad_radius_argument(radius, tmp_path):
    path = tmp_path / "s.obj"
    path.write_text(OBJ_OK)
    with pytest.raises(SceneError, match="radius"):
        load_scene(path, radius=radius)


# ----------------------------------------------------------------------------- JSON reading
def test_json_minimal_and_kernel_defaults(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene())
    s = load_scene(p)
    assert s.source == str(p)
    assert s.nodes.tolist() == [[0, 0, 0], [0, 0, 10], [10, 0, 10], [10, 10, 10]]
    assert s.segments.tolist() == [[0, 1], [1, 2], [2, 3]]
    assert s.radii.tolist() == [[1.0, 0.5], [0.5, 0.75], [0.75, 2.0]]
    assert (s.degree, s.sigma) == (6, 2.0)


@pytest.mark.parametrize("kernel, expected", [
    ({}, (6, 2.0)), ({"degree": 4}, (4, 2.0)), ({"sigma": 3}, (6, 3.0)), ({"degree": 8, "sigma": 1.5}, (8, 1.5)),
])
def test_json_kernel_partial(kernel, expected, tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(kernel=kernel))
    s = load_scene(p)
    assert (s.degree, s.sigma) == expected
    assert type(s.sigma) is float


def test_segment_radii_win_over_radii(tmp_path):
    p = tmp_path / "s.json"
    seg_r = [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]
    p.write_text(scene(segment_radii=seg_r))
    assert load_scene(p).radii.tolist() == seg_r
    p.write_text(scene(drop=("radii",), segment_radii=seg_r))
    assert load_scene(p).radii.tolist() == seg_r
    # the losing "radii" is still validated
    p.write_text(scene(radii=[1, 1, -1, 1], segment_radii=seg_r))
    with pytest.raises(SceneError, match=r"radii\[2\] = -1"):
        load_scene(p)


def test_json_radius_argument_is_a_default_only(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(drop=("radii",)))
    assert load_scene(p, radius=0.25).radii.tolist() == [[0.25, 0.25]] * 3
    p.write_text(scene())  # the file's radii win
    assert load_scene(p, radius=0.25).radii.tolist() == [[1.0, 0.5], [0.5, 0.75], [0.75, 2.0]]


@pytest.mark.parametrize("units, factor", [("mm", 1.0), ("um", 1e-3), ("cm", 10.0), ("m", 1000.0), ("in", 25.4)])
def test_units_are_converted_to_mm(units, factor, tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(units=units))
    s = load_scene(p)
    np.testing.assert_allclose(s.nodes, np.array(BASE["nodes"]) * factor, rtol=1e-15)
    np.testing.assert_allclose(s.radii[:, 0], np.array(BASE["radii"])[:3] * factor, rtol=1e-15)
    # the radius argument is in mm whatever the file's units
    p.write_text(scene(units=units, drop=("radii",)))
    assert load_scene(p, radius=0.3).radii.tolist() == [[0.3, 0.3]] * 3


def test_metadata_and_x_keys_are_ignored(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(metadata={"name": "cube", "author": [1, 2]}, **{"x-tool": {"v": 3}, "x-": None}))
    assert load_scene(p).n_segments == 3


def test_json_accepts_bom_pathlike_and_str(tmp_path):
    p = tmp_path / "s.JSON"
    p.write_bytes(b"\xef\xbb\xbf" + scene().encode())
    assert load_scene(p).n_segments == 3
    assert load_scene(str(p)).n_segments == 3


def test_json_unused_nodes_and_integer_coordinates(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(scene(nodes=BASE["nodes"] + [[5, 5, 5]], radii=[1, 1, 1, 1, 1]))
    s = load_scene(p)
    assert s.n_nodes == 5 and s.nodes.dtype == np.float64


# ----------------------------------------------------------------------------- OBJ reading
def test_obj_polylines_relative_indices_and_ignored_statements(tmp_path):
    text = (
        "# exported by hand\n"
        "mtllib x.mtl\no lattice\ng struts\ns off\nusemtl steel\n"
        "v 0 0 0 0.5\n"
        "v 0 0 10 0.5   # inline comment\n"
        "vn 0 0 1\nvt 0 0\nvp 0.5\n"
        "v 10 0 10 \\\n  0.25\n"          # continuation line
        "\n"
        "l 1 2 3\n"                        # polyline: two segments
        "v 10 10 10 0.75\n"
        "l -2 -1\n"                        # relative: vertices 3 and 4
        "l 4/1 1/2\n"                      # v/vt form
        "l 5 1\n"                          # forward absolute reference
        "v 20 20 20 1.0\n"
    )
    p = tmp_path / "s.obj"
    p.write_text(text)
    s = load_scene(p)
    assert s.segments.tolist() == [[0, 1], [1, 2], [2, 3], [3, 0], [4, 0]]
    assert s.nodes.tolist()[2] == [10, 0, 10]
    assert s.radii.tolist() == [[0.5, 0.5], [0.5, 0.25], [0.25, 0.75], [0.75, 0.5], [1.0, 0.5]]
    assert (s.degree, s.sigma) == (6, 2.0)


def test_obj_crlf_and_uppercase_suffix(tmp_path):
    p = tmp_path / "S.OBJ"
    p.write_bytes(OBJ_OK.replace("\n", "\r\n").encode())
    assert load_scene(p).segments.tolist() == [[0, 1], [1, 2]]


def test_obj_radius_argument_fills_missing_radii_and_file_radii_win(tmp_path):
    p = tmp_path / "s.obj"
    p.write_text("v 0 0 0\nv 0 0 10 2.0\nv 10 0 10\nl 1 2 3\n")
    s = load_scene(p, radius=0.5)
    assert s.radii.tolist() == [[0.5, 2.0], [2.0, 0.5]]
    p.write_text("v 0 0 0\nv 0 0 10\nl 1 2\n")
    assert load_scene(p, radius=0.5).radii.tolist() == [[0.5, 0.5]]


def test_obj_unused_vertex_without_radius_is_fine(tmp_path):
    p = tmp_path / "s.obj"
    p.write_text(OBJ_OK + "v 50 50 50\n")
    assert load_scene(p).n_nodes == 4


# ----------------------------------------------------------------------------- writing
@pytest.mark.parametrize("seed", range(5))
def test_json_round_trip_is_bit_exact(seed, tmp_path):
    rng = np.random.default_rng(seed)
    s = random_skeleton(rng, degree=int(rng.choice([2, 4, 6, 8, 16])), sigma=float(rng.uniform(1.01, 5)))
    p = tmp_path / "s.json"
    save_scene(s, p)
    assert_same(s, load_scene(p))
    json.loads(p.read_text())  # strict JSON (no NaN literals)


def test_json_round_trip_awkward_floats(tmp_path):
    # the awkward floats within the scene limits (docs/scene-format.md, "Limits"): subnormal and
    # signed-zero coordinates, 17-digit values, the largest coordinate and radius magnitude
    nodes = [[0.1 + 0.2, 1 / 3, -0.0], [5e-324, 1e8, -1.2345678901234567e8], [2.0 ** -1074 * 3, 1e-300, 7.0]]
    s = Skeleton(nodes, [[0, 1], [1, 2]], [[1.0000000000000002, 1e9], [1 / 7, 2.0 ** 0.5]], 4, 1.0000000000000002)
    p = tmp_path / "s.json"
    s.save(p)
    assert_same(s, load_scene(p))


@pytest.mark.parametrize("seed", range(3))
def test_obj_round_trip_is_exact_when_nodes_have_one_radius(seed, tmp_path):
    rng = np.random.default_rng(seed)
    n, m = 20, 40
    nodes = rng.normal(size=(n, 3)) * 7
    a = rng.integers(0, n, m)
    seg = np.stack([a, (a + rng.integers(1, n, m)) % n], axis=1)
    node_r = rng.uniform(0.01, 0.3, n) / 3
    s = Skeleton(nodes, seg, node_r[seg])
    p = tmp_path / "s.obj"
    save_scene(s, p)
    t = load_scene(p)
    assert_same(s, t)


def test_obj_round_trip_with_per_segment_radii_keeps_the_surface(tmp_path):
    s = random_skeleton(np.random.default_rng(7))
    p = tmp_path / "s.obj"
    save_scene(s, p)
    t = load_scene(p)
    assert t.n_segments == s.n_segments and t.n_nodes >= s.n_nodes
    sa, sb = s.endpoints()
    ta, tb = t.endpoints()
    assert sa.tobytes() == ta.tobytes() and sb.tobytes() == tb.tobytes()
    assert s.radii.tobytes() == t.radii.tobytes()
    assert t.nodes[: s.n_nodes].tobytes() == s.nodes.tobytes()


def test_obj_writer_refuses_a_non_default_kernel(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]], 4, 2.0)
    with pytest.raises(OutputError, match="kernel.*json"):
        save_scene(s, tmp_path / "s.obj")
    assert not list(tmp_path.iterdir())


def test_save_rejects_unknown_suffix_and_empty_scene(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    with pytest.raises(OutputError, match=r"unknown scene file type '\.txt'"):
        save_scene(s, tmp_path / "s.txt")
    with pytest.raises(OutputError, match="no segments"):
        save_scene(Skeleton(np.zeros((0, 3)), np.zeros((0, 2), int), np.zeros((0, 2))), tmp_path / "e.json")
    assert not list(tmp_path.iterdir())


def test_save_replaces_atomically_and_cleans_up_on_failure(tmp_path, monkeypatch):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    p = tmp_path / "s.json"
    p.write_text("old")
    save_scene(s, p)
    assert load_scene(p).n_segments == 1
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.json"]
    before = p.read_bytes()

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match="No space left on device") as info:
        save_scene(Skeleton([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[1, 1]]), p)
    assert str(p) in str(info.value)
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.json"]


def test_save_into_missing_directory(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    with pytest.raises(OutputError, match="No such file or directory"):
        save_scene(s, tmp_path / "nope" / "s.json")


def test_saved_file_has_default_permissions(tmp_path):
    s = Skeleton([[0, 0, 0], [0, 0, 1]], [[0, 1]], [[1, 1]])
    p = tmp_path / "s.json"
    save_scene(s, p)
    umask = os.umask(0)
    os.umask(umask)
    assert p.stat().st_mode & 0o777 == 0o666 & ~umask


# ----------------------------------------------------------------------------- fuzz
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _load_or_scene_error(path: Path, text, radius=None):
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        s = load_scene(path, radius=radius)
    except SceneError as exc:
        assert str(exc).startswith(f"{path}: ")
        return None
    assert isinstance(s, Skeleton) and s.n_segments > 0
    return s


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 10) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=3),
    max_leaves=12,
)


@FUZZ
@given(st.text(alphabet=string.printable + "\x00\u00e9\u2028", max_size=200), st.sampled_from([".json", ".obj"]))
def test_fuzz_random_text(tmp_path, text, suffix):
    _load_or_scene_error(tmp_path / ("fuzz" + suffix), text)


@FUZZ
@given(st.data())
def test_fuzz_garbled_valid_files(tmp_path, data):
    suffix = data.draw(st.sampled_from([".json", ".obj"]))
    text = scene(kernel={"degree": 6, "sigma": 2.0}) if suffix == ".json" else OBJ_OK + "v 1 1 1 0.5\nl 4 -2\n"
    chars = list(text)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(chars)))
        op = data.draw(st.sampled_from(["delete", "insert", "replace"]))
        c = data.draw(st.sampled_from(list('0123456789.-+eE[]{},:" \n/#ablvfnNI')))
        if op == "insert":
            chars.insert(i, c)
        elif chars and i < len(chars):
            if op == "delete":
                del chars[i]
            else:
                chars[i] = c
    radius = data.draw(st.sampled_from([None, 0.5]))
    _load_or_scene_error(tmp_path / ("garbled" + suffix), "".join(chars), radius)


@FUZZ
@given(st.data())
def test_fuzz_structured_json(tmp_path, data):
    d = json.loads(scene(segment_radii=[[1, 1], [1, 1], [1, 1]], kernel={"degree": 6, "sigma": 2.0}))
    for _ in range(data.draw(st.integers(1, 3))):
        key = data.draw(st.sampled_from(sorted(d) + ["extra", "x-extra"]))
        target = d
        value = d.get(key)
        # descend into nested lists/dicts of the chosen key now and then
        while isinstance(value, (list, dict)) and value and data.draw(st.booleans()):
            target, key = value, data.draw(st.sampled_from(list(range(len(value))) if isinstance(value, list)
                                                           else sorted(value)))
            value = target[key]
        target[key] = data.draw(json_values)
    _load_or_scene_error(tmp_path / "structured.json", json.dumps(d))


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(["v", "l", "f", "vn", "o", "#", "", "p", "v/", "\\"]),
                          st.lists(st.sampled_from(["0", "1", "-1", "2", "3", "-2", "1.5", "-0.5", "1e3", "nan",
                                                    "x", "1/2", "//", "0.0", "4"]), max_size=5)),
                max_size=12),
       st.sampled_from([None, 1.0]))
def test_fuzz_obj_statements(tmp_path, lines, radius):
    text = "\n".join(" ".join([k, *args]) for k, args in lines)
    _load_or_scene_error(tmp_path / "tokens.obj", text, radius)


# ----------------------------------------------------------------------------- float64 limits
_LIMIT_CASES = [
    ('{"skelslice": 1, "units": "m", "nodes": [[0, 0, 0], [0, 0, 1e7]], "segments": [[0, 1]], "radii": [1, 1]}',
     ".json", "nodes[1][2] = 1e+10 mm is beyond the supported magnitude 1e+09 mm"),
    ('{"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1]], "segments": [[0, 1]], '
     '"segment_radii": [[1, 5e-324]]}', ".json", "segment_radii[0][1] = 5e-324 mm is below the smallest supported "
                                                  "radius 1e-09 mm"),
    ('{"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 1], [0, 0, 2]], "segments": [[0, 1], [1, 2]], '
     '"radii": [1, 1, 1e12]}', ".json", "radii[2] = 1e+12 mm is beyond"),
    ("v 0 0 0 1e-6\nv 1e5 0 0 1\nl 1 2\n", ".obj",
     "line 2: vertex 2 x = 100000.0 mm is more than 1e+09 times the smallest radius (line 1: vertex 1 radius = "
     "1e-06 mm)"),
    ("v 0 0 0 1\nv 1e308 0 0 1\nl 1 2\n", ".obj", "line 2: vertex 2 x = 1e+308 mm is beyond"),
]


@pytest.mark.parametrize("text,suffix,needle", _LIMIT_CASES)
def test_numbers_float64_cannot_resolve_are_refused_by_name(text, suffix, needle, tmp_path):
    """docs/scene-format.md "Limits": the entry, its value (as people write it) and the limit."""
    p = tmp_path / f"s{suffix}"
    p.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(p)
    assert needle in str(exc.value) and str(p) in str(exc.value), str(exc.value)
    assert len(str(exc.value)) < 400


def test_numbers_at_the_limits_are_read(tmp_path):
    """Coordinates of 1e9 mm with a 1 mm strut, radii of 1e-9 mm near the origin, subnormal and
    signed-zero coordinates: inside the limits, read exactly."""
    p = tmp_path / "s.json"
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[1e9, 0, 0], [1e9, 0, 5], [-0.0, 5e-324, 0], '
                 '[0, 0, 1e-6]], "segments": [[0, 1], [2, 3]], "segment_radii": [[1, 1], [1e-9, 1e-9]]}')
    with pytest.raises(SceneError, match="more than 1e\\+09 times the smallest radius"):
        load_scene(p)                    # 1e9 mm is 1e18 times the 1e-9 mm strut
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[1e9, 0, 0], [1e9, 0, 5]], "segments": [[0, 1]], '
                 '"radii": [1, 1]}')
    assert load_scene(p).nodes[0, 0] == 1e9
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[-0.0, 5e-324, 0], [0, 0, 1e-6]], "segments": [[0, 1]], '
                 '"radii": [1e-9, 1e-9]}')
    s = load_scene(p)
    assert s.nodes[0, 1] == 5e-324 and s.radii.min() == 1e-9
