"""``skelslice slice`` through the real entry point: outputs and failure modes."""
from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from helpers import assert_refused, run
from interrupting import interrupt_and_check, start_slice, wait_mid_write
from slicer import Skeleton


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "y.json"
    Skeleton([[0, 0, 0], [0, 0, 2], [1, 0, 3], [-1, 0, 3]], [[0, 1], [1, 2], [1, 3]],
             [[0.4, 0.3], [0.3, 0.2], [0.3, 0.2]]).save(p)
    return p


def test_slice_writes_stack_and_layout(scene, tmp_path):
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.1", "--layer-height", "0.15")
    assert r.exit_code == 0, r.output
    meta = json.loads((out / "slices.json").read_text())
    assert meta["pixel_size"] == [0.1, 0.1] and meta["layer_height"] == 0.15
    assert len(meta["files"]) == meta["layers"] > 0
    assert all((out / f).is_file() for f in meta["files"])
    assert meta["method"] == "interval"


@pytest.mark.parametrize("method", ["sampling", "segment"])
def test_baselines_write_identical_layers(scene, tmp_path, method):
    outs = []
    for m in ("interval", method):
        out = tmp_path / m
        assert run("slice", scene, "-o", out, "--pixel-size", "0.09", "--method", m, "-q").exit_code == 0
        outs.append(out)
    files = json.loads((outs[0] / "slices.json").read_text())["files"]
    for f in files:
        assert (outs[0] / f).read_bytes() == (outs[1] / f).read_bytes()


def test_absurd_grid_refused_before_any_work(scene, tmp_path):
    out = tmp_path / "huge"
    r = run("slice", scene, "-o", out, "--pixel-size", "1e-6")
    assert_refused(r, "voxels", "limit")
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag,value,needle", [
    ("--pixel-size", "-0.1", "pixel size must be a finite number > 0, got -0.1"),
    ("--pixel-size", "nan", "pixel size must be a finite number > 0"),
    ("--layer-height", "0", "layer height must be a finite number > 0, got 0"),
    ("--pixel-size-y", "-1", "pixel size y must be a finite number > 0, got -1"),
])
def test_bad_sizes(scene, tmp_path, flag, value, needle):
    args = ["slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.1", flag, value]
    assert_refused(run(*args), needle)


def test_bad_bounds(scene, tmp_path):
    r = run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.1", "--bounds", "1", "0", "0", "0", "1", "1")
    assert_refused(r, "X1 > X0")


@pytest.mark.parametrize("args", [["--method", "magic"], ["--threads", "0"], ["--bucket", "-3"]])
def test_bad_options_are_usage_errors(scene, tmp_path, args):
    assert_refused(run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.1", *args))


def test_existing_output_is_never_replaced_without_force(scene, tmp_path):
    out = tmp_path / "stack"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    assert_refused(run("slice", scene, "-o", out, "--pixel-size", "0.1"), "already exists", "--force")
    assert (out / "precious.txt").read_text() == "keep me"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.1", "--force", "-q")
    assert r.exit_code == 0, r.output
    assert not (out / "precious.txt").exists() and (out / "slices.json").exists()


def test_missing_output_folder(scene, tmp_path):
    assert_refused(run("slice", scene, "-o", tmp_path / "no" / "such" / "dir", "--pixel-size", "0.1"),
                   "does not exist")


def test_scene_without_surface_is_refused(tmp_path):
    p = tmp_path / "short.json"
    Skeleton([[0, 0, 0], [0.3, 0, 0]], [[0, 1]], [[0.6, 0.6]]).save(p)
    out = tmp_path / "o"
    assert_refused(run("slice", p, "-o", out, "--pixel-size", "0.05"), "surface is empty")
    assert not out.exists()


def test_bad_scene_through_slice(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{"skelslice": 1, "units": "mm", "nodes": [[0,0,0],[0,0,1]], "segments": [[0, 5]], '
                 '"radii": [1, 1]}')
    assert_refused(run("slice", p, "-o", tmp_path / "o", "--pixel-size", "0.1"), "bad.json", "segments[0][1]", "5")


def test_failure_mid_write_leaves_nothing(scene, tmp_path, monkeypatch):
    """A crash while layers are being written leaves no output and no temporary folder."""
    from formats.png_stack import PngStackWriter
    from slicer.job.run import run_slice
    from slicer import load_scene

    real = PngStackWriter.store_layer      # the in-order step of writing a layer (encoding runs on a pool)

    def flaky(self, k, image, payload):
        if k == 3:
            raise KeyboardInterrupt  # as if the user pressed Ctrl-C
        return real(self, k, image, payload)

    monkeypatch.setattr(PngStackWriter, "store_layer", flaky)
    out = tmp_path / "stack"
    with pytest.raises(KeyboardInterrupt):
        run_slice(load_scene(scene), out, pixel_size=0.1, progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["term", "kill"])
def test_signal_while_writing_a_traced_result_leaves_no_output(tmp_path, sig):
    """The whole model traced first, then 6000 layers written (each file
    fsynced): SIGTERM or SIGKILL during the write leaves nothing at the
    target (streamed slabs: test_cli_scale)."""
    scene = tmp_path / "tall.json"
    n = 30                                                  # a 60 mm post: 6000 layers of 0.01 mm
    Skeleton([[0, 0, 2.0 * i] for i in range(n + 1)], [[i, i + 1] for i in range(n)], [[0.5, 0.5]] * n).save(scene)
    out = tmp_path / "stack"
    proc = start_slice(scene, out, "--pixel-size", "0.015", "--layer-height", "0.01", "-q")
    wait_mid_write(proc, out, layers=5)
    interrupt_and_check(proc, out, sig)
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == ["tall.json"]


def test_sigterm_is_handled_only_while_a_command_runs(scene, tmp_path, monkeypatch):
    """The SIGTERM handler (a clean exit, like Ctrl-C) is in force inside the
    command and restored afterwards, so an embedding process keeps its own."""
    import slicer.cli.commands.slice

    real = slicer.cli.commands.slice.run_slice
    seen = []

    def spy(*a, **k):
        seen.append(signal.getsignal(signal.SIGTERM))
        return real(*a, **k)

    monkeypatch.setattr(slicer.cli.commands.slice, "run_slice", spy)
    before = signal.getsignal(signal.SIGTERM)
    assert run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.1", "-q").exit_code == 0
    assert len(seen) == 1 and seen[0] not in (signal.SIG_DFL, signal.SIG_IGN, None)
    assert signal.getsignal(signal.SIGTERM) == before
    with pytest.raises(SystemExit) as exc:
        seen[0](signal.SIGTERM, None)
    assert exc.value.code == 128 + signal.SIGTERM
