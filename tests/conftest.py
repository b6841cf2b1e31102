"""Shared fixtures (shared plain functions and data are in ``tests/helpers.py``).

``ell``: a small chiral model (a post with a long +x arm and a short +y arm) saved
as JSON, once per test module; the format tests slice it.

``checker``: the Rust checker in ``tests/readers`` (our cargo project around
the ``colain``, ``goo`` and ``msla_format`` crates), built once per session with
``cargo build --release --locked``.

``uv3dp``: the Go readers in ``tests/readers_go`` (the ``uv3dp`` command line
and ``uv3dp-layers``, both on ``github.com/ezrec/uv3dp`` v1.2.12), built once
per session by ``tests/readers_go/build``.

Hypothesis profiles: ``ci`` (derandomised, no deadline, no example database: the same
examples on every run) is what the fuzz suite (tests/test_fuzz_cli.py) runs under by default;
``fuzz-long`` (``--hypothesis-profile=fuzz-long``) draws random examples,
``fuzz_helpers.LONG_FACTOR`` times as many. The session summary lists how many fuzz cases ran.

Tests that use them skip, naming the reason, where cargo or Go is missing;
with ``SKELSLICE_REQUIRE_READERS=1`` (set by ``.ci/run``) they fail instead:
in CI a skipped reader is not a pass.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

import fuzz_helpers
from helpers import missing_tool
from slicer import Skeleton

_FUZZ = dict(deadline=None, database=None, print_blob=True,
             suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])
settings.register_profile("ci", derandomize=True, **_FUZZ)
settings.register_profile("fuzz-long", derandomize=False, **_FUZZ)


def pytest_sessionfinish(session):
    """On a pytest-xdist worker: hand its fuzz case counts to the controller."""
    out = getattr(session.config, "workeroutput", None)
    if out is not None:
        out["fuzz_runs"] = [[name, code, n] for name, by in fuzz_helpers.RUNS.items() for code, n in by.items()]


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """On the pytest-xdist controller: add a finished worker's fuzz case counts."""
    for name, code, n in getattr(node, "workeroutput", {}).get("fuzz_runs", []):
        by = fuzz_helpers.RUNS.setdefault(name, {})
        by[code] = by.get(code, 0) + n


def pytest_terminal_summary(terminalreporter):
    """How many fuzz cases each command ran (tests/test_fuzz_cli.py), over every worker."""
    runs = fuzz_helpers.RUNS
    if runs:
        total = sum(sum(by.values()) for by in runs.values())
        each = "; ".join(f"{name} {sum(by.values())} (" + ", ".join(f"exit {k}: {v}" for k, v in sorted(by.items()))
                         + ")" for name, by in sorted(runs.items()))
        terminalreporter.write_line(f"fuzz cases run: {total}: {each}")


READERS = Path(__file__).resolve().parent / "readers"
READERS_GO = Path(__file__).resolve().parent / "readers_go"


@pytest.fixture(scope="module")
def ell(tmp_path_factory):
    """A small chiral model: a post with a long +x arm and a short +y arm."""
    p = tmp_path_factory.mktemp("ell") / "ell.json"
    Skeleton([[0, 0, 0], [0, 0, 1.6], [2.0, 0, 1.6], [0, 1.0, 1.6]], [[0, 1], [1, 2], [1, 3]],
             [[0.3, 0.3], [0.3, 0.3], [0.3, 0.3]]).save(p)
    return p


@pytest.fixture(scope="session")
def checker() -> Path:
    """Path of the built ``skelslice-readers`` executable."""
    cargo = shutil.which("cargo") or str(Path.home() / ".cargo" / "bin" / "cargo")
    if not Path(cargo).exists():
        missing_tool("cargo is not installed: cannot build the Rust checker in tests/readers")
    env = {**os.environ, "CARGO_TARGET_DIR": str(READERS / "target")}
    r = subprocess.run([cargo, "build", "--release", "--locked", "--quiet",
                        "--manifest-path", str(READERS / "Cargo.toml")],
                       capture_output=True, text=True, timeout=900, env=env)
    assert r.returncode == 0, f"cargo build failed:\n{r.stderr}"
    exe = READERS / "target" / "release" / "skelslice-readers"
    assert exe.is_file()
    return exe


@dataclass(frozen=True)
class Uv3dp:
    """The built Go readers: ``cli`` (the uv3dp command line) and ``layers`` (uv3dp-layers)."""

    cli: Path
    layers: Path


@pytest.fixture(scope="session")
def uv3dp() -> Uv3dp:
    """The uv3dp command line and ``uv3dp-layers``, built by ``tests/readers_go/build``."""
    go = shutil.which("go") or "/usr/local/go/bin/go"
    if not Path(go).exists():
        missing_tool("go is not installed: cannot build uv3dp in tests/readers_go")
    env = {**os.environ, "PATH": f"{Path(go).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    r = subprocess.run(["bash", str(READERS_GO / "build")], capture_output=True, text=True, timeout=1800, env=env)
    assert r.returncode == 0, f"tests/readers_go/build failed:\n{r.stdout}\n{r.stderr}"
    tools = Uv3dp(READERS_GO / "bin" / "uv3dp", READERS_GO / "bin" / "uv3dp-layers")
    assert tools.cli.is_file() and tools.layers.is_file()
    return tools
