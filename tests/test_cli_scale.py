"""``skelslice slice`` at scale, through the real entry points: --max-memory,
--slab/--tile streaming, --dry-run, --config, --force never the input, and
the failure modes (absurd requests, disk full, unwritable output, Ctrl-C,
SIGTERM and SIGKILL mid-write) leaving no partial output."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from formats.base import encode_workers
from interrupting import interrupt_and_check, start_slice, wait_mid_write
from slicer.cli.app import main
from slicer.scene.lattice import generate_lattice


def run(*args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def assert_refused(r, *needles):
    everything = r.output + (r.stderr or "")
    assert r.exit_code == 2, (r.exit_code, everything)
    assert "Traceback" not in everything
    for n in needles:
        assert n in everything, (n, everything)


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def leftovers(folder: Path, name: str) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(name) or p.name.startswith(f".{name}"))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "lattice.json"
    generate_lattice("bcc", cells=(3, 2, 2), cell_size=2.0, radius=0.15, radius_top=0.3).save(p)
    return p


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "-q", "--max-memory", "none")
    assert r.exit_code == 0, r.output
    return files(out)


# ----------------------------------------------------------------------------- streaming
@pytest.mark.parametrize("extra", [
    ["--slab", "9", "--tile", "32"],                 # 2 passes (trimmed), 12 slabs
    ["--slab", "40", "--threads", "1"],
    ["--tile", "64", "--threads", "2"],
    ["--executor", "threads", "--workers", "2", "--slab", "25"],
])
def test_streamed_and_tiled_runs_write_the_same_bytes(scene, reference, tmp_path, extra):
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "-q", *extra)
    assert r.exit_code == 0, r.output
    assert files(out) == reference


def test_repeated_runs_are_byte_identical(scene, reference, tmp_path):
    for n in range(2):
        out = tmp_path / f"run{n}"
        assert run("slice", scene, "-o", out, "--pixel-size", "0.05", "-q").exit_code == 0
        assert files(out) == reference


@pytest.mark.parametrize("flag, prefetch", [([], True), (["--prefetch"], True), (["--no-prefetch"], False)])
def test_prefetch_flag_sets_the_plan_and_not_the_layers(scene, reference, tmp_path, flag, prefetch):
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "-v", "--slab", "20", "--max-memory", "none", *flag)
    assert r.exit_code == 0, r.output
    assert ("the next is traced while one is written" in r.stderr) == prefetch, r.stderr
    assert files(out) == reference


def test_verbose_prints_the_plan_on_stderr(scene, tmp_path):
    r = run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.05", "-v", "--slab", "20")
    assert r.exit_code == 0, r.output
    assert "slabs:     6 of up to 17 layers (2 passes" in r.stderr
    assert "tiles:" in r.stderr and "memory:" in r.stderr and "budget" in r.stderr
    assert "layers ->" in r.stdout


def test_max_memory_budget_streams_and_says_so(scene, tmp_path, monkeypatch):
    """A budget just above what the process already holds forces Z slabs; the
    output is the unbudgeted one. The process's size is held at one reading:
    in a long test session it moves by more than the job between the budget
    and the run, which made the plan's choice depend on the garbage collector.
    The budget is matched as the plan prints it (in GiB once it passes 1 GiB,
    as it does late in a long session)."""
    import slicer.scale.tileplan
    from slicer import load_scene
    from slicer.scale.tiles import current_rss, format_size, plan_slice

    ref = tmp_path / "ref"
    assert run("slice", scene, "-o", ref, "--pixel-size", "0.035", "-q", "--max-memory", "none").exit_code == 0
    plan_slice(load_scene(scene), 0.035, sample=True)      # kernels loaded: RSS is realistic
    held = current_rss()
    monkeypatch.setattr(slicer.scale.tileplan, "current_rss", lambda: held)
    plan = plan_slice(load_scene(scene), 0.035, sample=True)
    assert plan.estimate["process"] == held
    job = plan.estimate["total"] - plan.estimate["process"]
    budget = int(held + 4 * 2**20 + 0.4 * job)
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.035", "-v", "--max-memory", str(budget))
    assert r.exit_code == 0, r.output
    # the plan prints the budget in binary units: MiB, or GiB once the process holds over 1 GiB
    assert "2 passes" in r.stderr and f"budget {format_size(budget)}" in r.stderr
    assert files(out) == files(ref)


def test_too_small_budget_is_refused_before_any_work(scene, tmp_path):
    out = tmp_path / "o"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "--max-memory", "1MB")
    assert_refused(r, "--max-memory", "too small", "needs")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, needle", [
    (["--max-memory", "2XB"], "cannot read '2XB'"),
    (["--tile", "0"], "--tile"),
    (["--slab", "0"], "--slab"),
    (["--workers", "0"], "--workers"),
    (["--executor", "mpi"], "--executor"),
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler needs --executor dask"),
])
def test_bad_scale_options(scene, tmp_path, args, needle):
    assert_refused(run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "0.05", *args), needle)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- dry run
def test_dry_run_prints_plan_and_estimates_and_writes_nothing(scene, tmp_path):
    before = sorted(p.name for p in scene.parent.iterdir())
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "--dry-run", "--max-memory", "4GB")
    assert r.exit_code == 0, r.output
    text = r.stdout
    for needle in ("dry run: nothing is written", f"output:    {out} [png]", "executor:  serial",
                   "grid:      147 x 107 px x 101 layers", "tiles:     1 of", "slabs:     1 of",
                   "(estimated from a sample)", "budget 3.7 GiB", "time:      ~"):
        assert needle in text, (needle, text)
    assert list(tmp_path.iterdir()) == []
    assert sorted(p.name for p in scene.parent.iterdir()) == before


def test_dry_run_warns_about_thin_struts(tmp_path):
    p = tmp_path / "thin.json"
    generate_lattice("cubic", cells=(2, 1, 1), cell_size=2.0, radius=0.02).save(p)
    r = run("slice", p, "-o", tmp_path / "o", "--pixel-size", "0.1", "--dry-run")
    assert r.exit_code == 0, r.output
    assert "warning:   " in r.stdout and "thinner than a pixel" in r.stdout


def test_dry_run_refuses_absurd_grids_at_once(scene, tmp_path):
    t0 = time.perf_counter()
    r = run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "1e-5", "--dry-run")   # ~1e15 voxels
    assert_refused(r, "voxels", "limit")
    assert time.perf_counter() - t0 < 10


def test_absurd_grid_refused_before_a_cluster_starts(scene, tmp_path, monkeypatch):
    import slicer.scale.executors

    def boom(*a, **k):
        raise AssertionError("an executor was opened")

    monkeypatch.setattr(slicer.scale.executors, "open_executor", boom)
    r = run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "2e-5", "--executor", "dask")
    assert_refused(r, "voxels", "limit")
    r = run("slice", scene, "-o", tmp_path / "o", "--pixel-size", "-0.05", "--executor", "processes")
    assert_refused(r, "pixel size must be a finite number > 0")


def test_python_m_slicer_dry_run_subprocess(scene, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "slicer", "slice", str(scene), "-o", str(tmp_path / "o"),
                           "--pixel-size", "0.05", "--dry-run"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "tiles:" in proc.stdout and "memory:" in proc.stdout
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- config
def test_config_file_flags_win_over_file_over_defaults(scene, tmp_path):
    cfg = tmp_path / "job.toml"
    cfg.write_text(f'scene = "{scene}"\noutput = "from_file"\npixel-size = 0.1\nlayer_height = 0.2\n'
                   'max-memory = "2GB"\nquiet = true\n')
    r = run("slice", "--config", cfg)
    assert r.exit_code == 0, r.output
    meta = json.loads((tmp_path / "from_file" / "slices.json").read_text())   # relative to the file
    assert meta["pixel_size"] == [0.1, 0.1] and meta["layer_height"] == 0.2
    assert r.stdout == ""
    out = tmp_path / "from_flags"
    r = run("slice", "--config", cfg, "-o", out, "--pixel-size", "0.08")
    assert r.exit_code == 0, r.output
    meta = json.loads((out / "slices.json").read_text())
    assert meta["pixel_size"] == [0.08, 0.08] and meta["layer_height"] == 0.2   # flag, then file
    assert meta["method"] == "interval"                                          # default


@pytest.mark.parametrize("text, needles", [
    ("pixl-size = 0.1\n", ["job.toml: unknown key 'pixl-size'", "pixel-size"]),
    ('pixel-size = "abc"\n', ["job.toml: key 'pixel-size'", "abc"]),
    ("pixel-size = 0.1\npixel_size = 0.2\n", ["job.toml: key 'pixel_size' sets 'pixel_size' a second time"]),
    ("[slice]\npixel-size = 0.1\n", ["job.toml: unknown key 'slice'"]),
    ("pixel-size = [\n", ["job.toml: not valid TOML"]),
    ('executor = "mpi"\n', ["job.toml: key 'executor'", "mpi"]),
])
def test_bad_config_files(scene, tmp_path, text, needles):
    cfg = tmp_path / "job.toml"
    cfg.write_text(text)
    r = run("slice", scene, "-o", tmp_path / "o", "--config", cfg)
    assert_refused(r, *needles)
    assert not (tmp_path / "o").exists()


def test_missing_config_file(scene, tmp_path):
    assert_refused(run("slice", scene, "-o", tmp_path / "o", "--config", tmp_path / "nope.toml"),
                   "nope.toml: no such config file")


# ----------------------------------------------------------------------------- never the input
def test_force_never_overwrites_the_input(scene, tmp_path):
    import shutil

    src = tmp_path / "in" / "scene.json"
    src.parent.mkdir()
    shutil.copy(scene, src)
    before = src.read_bytes()
    assert_refused(run("slice", src, "-o", src, "--pixel-size", "0.1", "--force"), "the output is the input")
    assert_refused(run("slice", src, "-o", src.parent, "--pixel-size", "0.1", "--force"),
                   "the output holds the input")
    assert_refused(run("slice", src, "-o", tmp_path, "--pixel-size", "0.1", "--force"), "holds the input")
    assert src.read_bytes() == before and sorted(p.name for p in src.parent.iterdir()) == ["scene.json"]


# ----------------------------------------------------------------------------- disk full, unwritable
def test_disk_full_mid_stack_is_a_clear_error_and_leaves_nothing(scene, tmp_path, monkeypatch):
    """ENOSPC raised by the image encoder at layer 5 (in-process, streamed plan)."""
    import formats.png_stack

    real = formats.png_stack.png_bytes
    calls = {"n": 0}

    def full(image, *a, **k):
        calls["n"] += 1
        if calls["n"] == 5:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(image, *a, **k)

    monkeypatch.setattr(formats.png_stack, "png_bytes", full)
    out = tmp_path / "stack"
    r = run("slice", scene, "-o", out, "--pixel-size", "0.05", "--slab", "10")
    assert_refused(r, "No space left on device", str(out))
    # layers are encoded on a pool that runs at most 2 * workers layers ahead of the one that failed
    assert 5 <= calls["n"] <= 5 + 2 * encode_workers()
    assert leftovers(tmp_path, "stack") == []


@pytest.fixture
def tiny_disk(tmp_path):
    """A 48 KiB tmpfs (needs root and mount; skipped otherwise)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(mnt)], capture_output=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("name", ["stack", "stack.zip"])
def test_real_full_disk(scene, tiny_disk, name):
    out = tiny_disk / name
    r = run("slice", scene, "-o", out, "--pixel-size", "0.03", "--slab", "10", "--bounds", "-0.5", "-0.5", "0", "6.5", "4.5", "4")
    assert_refused(r, str(out), "No space left on device")
    assert sorted(p.name for p in tiny_disk.iterdir()) == []


def test_unwritable_output_folder(scene, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() == 0:
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True)
        if proc.returncode != 0:
            pytest.skip("root, and cannot mount a read-only tmpfs")
    else:
        ro.chmod(0o555)
    try:
        r = run("slice", scene, "-o", ro / "stack", "--pixel-size", "0.1")
        assert_refused(r, str(ro / "stack"), "Read-only file system" if os.geteuid() == 0 else "Permission denied")
        assert list(ro.iterdir()) == []
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", "-l", str(ro)], capture_output=True)
        else:
            ro.chmod(0o755)


# ----------------------------------------------------------------------------- interruption
@pytest.fixture(scope="module")
def big_scene(tmp_path_factory):
    p = tmp_path_factory.mktemp("big") / "big.json"
    generate_lattice("bcc", cells=(3, 3, 3), cell_size=4.0, radius=0.5).save(p)
    return p


#: explicit bounds (one pass) and thin slabs, streamed: the first layers are
#: written within seconds, the whole job (467 layers of 467 x 467 px, 59 slabs)
#: lasts 25-60 s; it is interrupted after 6 layers or 20 kB
JOB = ["--pixel-size", "0.03", "--bounds", "-1", "-1", "-1", "13", "13", "13", "--slab", "8", "-q"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["int", "term", "kill"])
@pytest.mark.parametrize("name", ["stack", "stack.zip"])
def test_signal_mid_write_leaves_no_output(big_scene, tmp_path, name, sig):
    """Ctrl-C, SIGTERM (``timeout``, job schedulers) and SIGKILL while the
    streamed layers are being written: nothing ever appears at the target;
    Ctrl-C and SIGTERM also remove the hidden temporary and exit non-zero
    without a traceback (interrupting.interrupt_and_check)."""
    out = tmp_path / name
    proc = start_slice(big_scene, out, *JOB)
    wait_mid_write(proc, out, layers=5, size=20_000)
    interrupt_and_check(proc, out, sig)
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == []


# ----------------------------------------------------------------------------- fuzzed scenes, real CLI
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_fuzzed_scenes_through_slice_never_traceback(tmp_path, data):
    """Garbled JSON/OBJ scenes through ``slice --dry-run``: exit 0 or a named
    error with exit 2, never a traceback."""
    suffix = data.draw(st.sampled_from([".json", ".obj"]))
    if suffix == ".json":
        text = json.dumps({"skelslice": 1, "units": "mm", "nodes": [[0, 0, 0], [0, 0, 4], [3, 0, 4]],
                           "segments": [[0, 1], [1, 2]], "radii": [1, 0.8, 0.6]})
    else:
        text = "v 0 0 0 1\nv 0 0 4 0.8\nv 3 0 4 0.6\nl 1 2 3\n"
    chars = list(text)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(chars)))
        c = data.draw(st.sampled_from(list('0123456789.-eE[]{},:" \nvlnNaI')))
        if data.draw(st.booleans()) or i >= len(chars):
            chars.insert(i, c)
        else:
            chars[i] = c
    path = tmp_path / ("fuzz" + suffix)
    path.write_text("".join(chars))
    r = run("slice", path, "-o", tmp_path / "o", "--pixel-size", "0.25", "--dry-run")
    everything = r.output + (r.stderr or "")
    assert "Traceback" not in everything
    assert r.exit_code in (0, 2), (r.exit_code, everything, repr(r.exception))
    if r.exit_code == 2:
        assert r.stderr.startswith("error: ") or "Usage:" in r.stderr
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- progress bars
def test_progress_bars_are_quiet_off_a_terminal_and_shown_when_asked(scene, tmp_path, capsys):
    r = run("slice", scene, "-o", tmp_path / "quiet", "--pixel-size", "0.05", "-q", "--slab", "30", "--tile", "64")
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == ""     # CliRunner is not a terminal
    from slicer import load_scene
    from slicer.job.run import run_slice

    run_slice(load_scene(scene), tmp_path / "bars", pixel_size=0.05, slab=30, tile=64, progress=True)
    err = capsys.readouterr().err
    assert "tracing" in err and "tile" in err and "writing" in err and "layer" in err
