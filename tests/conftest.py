"""Shared fixtures.

``checker``: the Rust checker in ``tests/readers`` (our cargo project around
the ``colain``, ``goo`` and ``msla_format`` crates), built once per session with
``cargo build --release --locked``; tests that use it skip, naming the
reason, where cargo is missing.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

READERS = Path(__file__).resolve().parent / "readers"


@pytest.fixture(scope="session")
def checker() -> Path:
    """Path of the built ``skelslice-readers`` executable."""
    cargo = shutil.which("cargo") or str(Path.home() / ".cargo" / "bin" / "cargo")
    if not Path(cargo).exists():
        pytest.skip("cargo is not installed: cannot build the Rust checker in tests/readers")
    env = {**os.environ, "CARGO_TARGET_DIR": str(READERS / "target")}
    r = subprocess.run([cargo, "build", "--release", "--locked", "--quiet",
                        "--manifest-path", str(READERS / "Cargo.toml")],
                       capture_output=True, text=True, timeout=900, env=env)
    assert r.returncode == 0, f"cargo build failed:\n{r.stderr}"
    exe = READERS / "target" / "release" / "skelslice-readers"
    assert exe.is_file()
    return exe
