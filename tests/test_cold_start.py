"""A first run says that it compiles, and `skelslice warmup` compiles ahead of time (slicer/compiling.py,
slicer/job/warmup.py). The fresh-cache tests compile the renderer (the smallest walk) in a cache of their own."""
from __future__ import annotations

import io
import logging
import os
import select
import subprocess
import sys
from pathlib import Path

import pytest

from slicer import Skeleton, save_scene
from slicer.cli.compile_notice import compile_notices
from slicer.compiling import LOG, compiling, is_compiled


class _Cold:
    """A stand-in for a Numba dispatcher never compiled: no overload, no cache index."""

    overloads: dict = {}

    class _cache:
        class _cache_file:
            _index_path = "/nonexistent/skelslice-test.nbi"


class _Warm:
    overloads = {"sig": object()}


def test_compiling_logs_once_around_a_cold_kernel_and_never_around_warm_ones(caplog):
    caplog.set_level(logging.INFO, logger=LOG.name)
    assert not is_compiled(_Cold) and is_compiled(_Warm)
    with compiling("the tracer", [_Warm], 60):
        pass
    assert caplog.records == []
    with compiling("the tracer", [_Warm, _Cold], 60) as said:
        with compiling("the tracer", [_Cold], 60) as nested:
            pass
    assert said and not nested
    texts = [r.getMessage() for r in caplog.records]
    assert len(texts) == 2
    assert texts[0].startswith("compiling the tracer for this machine (") and texts[0].endswith("about 60 s)")
    assert texts[1].startswith("compiled the tracer in ")


def test_the_cli_handler_prints_both_lines_and_nothing_when_quiet():
    out = io.StringIO()
    with compile_notices(stream=out):
        with compiling("the renderer", [_Cold], 45):
            pass
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("compiling the renderer") and lines[1].startswith("compiled")
    quiet = io.StringIO()
    with compile_notices(enabled=False, stream=quiet):
        with compiling("the renderer", [_Cold], 45):
            pass
    assert quiet.getvalue() == ""
    assert not any(isinstance(h, logging.Handler) and h.__class__.__name__ == "_Notice" for h in LOG.handlers)


@pytest.fixture
def tiny(tmp_path) -> Path:
    path = tmp_path / "tiny.json"
    save_scene(Skeleton([[0, 0, 0.8], [0, 0, 3]], [[0, 1]], [[0.8, 0.6]]), path)
    return path


def _cli(cache: Path, *args) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "SKELSLICE_NUMBA_CACHE"}
    env["NUMBA_CACHE_DIR"] = str(cache)
    return subprocess.run([sys.executable, "-m", "slicer", *map(str, args)], env=env, capture_output=True,
                          text=True, timeout=900, stdin=subprocess.DEVNULL)


def test_a_cold_render_says_it_compiles_before_it_does(tmp_path, tiny):
    """The first line a render writes in an empty cache announces the compilation (the process is
    stopped there: the closing line is the handler's, tested above, and compiling the renderer is the
    next test's)."""
    env = {k: v for k, v in os.environ.items() if k != "SKELSLICE_NUMBA_CACHE"}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    with subprocess.Popen([sys.executable, "-m", "slicer", "render", str(tiny), "-o", str(tmp_path / "a.png"),
                           "--size", "32", "32"], env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                          stdin=subprocess.DEVNULL, text=True) as p:
        try:        # a job that never writes fails the test instead of holding it
            first = p.stderr.readline() if select.select([p.stderr], [], [], 600)[0] else ""
        finally:
            p.kill()
    assert first.startswith("compiling the renderer for this machine (first run only, about "), first
    assert not (tmp_path / "a.png").exists()


@pytest.mark.slow
def test_warmup_fills_the_cache_that_later_jobs_load(tmp_path, tiny):
    """``warmup render`` compiles the renderer in an empty cache; later renders load it, say nothing of
    compiling, and agree to the byte."""
    cache = tmp_path / "cache"
    w = _cli(cache, "warmup", "render")
    assert w.returncode == 0, w.stderr
    assert w.stdout.split()[:1] == ["render"] and w.stdout.rstrip().endswith("ok"), w.stdout
    assert any(d.name.startswith("render-") for d in cache.iterdir())
    for name in ("a.png", "b.png"):
        later = _cli(cache, "render", tiny, "-o", tmp_path / name, "--size", "32", "32")
        assert later.returncode == 0 and "compil" not in later.stderr, later.stderr
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_warmup_refuses_unknown_features_before_compiling(tmp_path):
    r = _cli(tmp_path / "cache", "warmup", "trace", "nosuch")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        "error: unknown feature 'nosuch'; choose one of check, contours, parts, printer, render, sampling, segment, "
        "trace, union"]
    assert not list((tmp_path / "cache").rglob("*.nbi"))       # nothing compiled
