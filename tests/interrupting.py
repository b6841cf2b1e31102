"""Interrupting a real ``python -m slicer slice`` while it writes its output.

Shared by the CLI and format tests. A job is started in a fresh process; the
test waits until the hidden temporary output ``.NAME.tmp-*`` beside the
target holds some layers, signals the process and checks what is left.
Every step *fails* (never skips) when the job does not behave: a temporary
that never appears (a writer writing straight to the target), a job that
ends before it could be interrupted, a process that ignores the signal.

The jobs are chosen to last far longer than the wait (tens of seconds to
minutes of layers, interrupted after the first few), so the signal always
arrives mid-write.
"""
from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

#: seconds to wait for the temporary output to fill (start-up, Numba cache, tracing)
APPEAR_TIMEOUT = 300
#: seconds a process may take to clean up and exit after the signal
EXIT_TIMEOUT = 120


@contextlib.contextmanager
def _signals_not_ignored():
    """Children inherit ignored signals across exec (a shell without job
    control ignores SIGINT in background jobs, and Python then installs no
    KeyboardInterrupt handler): make SIGINT and SIGTERM deliverable in the
    child by not ignoring them in this process while it starts."""
    saved = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is signal.SIG_IGN:
            saved[sig] = signal.signal(sig, signal.SIG_DFL if sig == signal.SIGTERM
                                       else signal.default_int_handler)
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)


def start_slice(scene, out, *args) -> subprocess.Popen:
    """``python -m slicer slice SCENE -o OUT ARGS...`` in a new process."""
    cmd = [sys.executable, "-m", "slicer", "slice", str(scene), "-o", str(out), *map(str, args)]
    with _signals_not_ignored():
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def temporaries(out: Path) -> list[Path]:
    """The hidden temporaries ``.NAME.tmp-*`` beside ``out``."""
    return sorted(out.parent.glob(f".{out.name}.tmp-*"))


def _stop(proc):
    if proc.poll() is None:
        proc.kill()
    return proc.communicate(timeout=EXIT_TIMEOUT)


def wait_mid_write(proc: subprocess.Popen, out: Path, *, layers: int = 0, size: int = 0) -> Path:
    """Wait until the job is writing: its temporary folder holds more than
    ``layers`` PNG files, or its temporary file is larger than ``size`` bytes.

    Returns the temporary. Fails the test (killing the job) if the job exits
    first, if the target appears before it was interrupted, or if no such
    temporary appears within :data:`APPEAR_TIMEOUT` seconds.
    """
    deadline = time.monotonic() + APPEAR_TIMEOUT
    seen = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            _, err = _stop(proc)
            pytest.fail(f"the job ended (status {proc.returncode}) before it could be interrupted; "
                        f"temporary seen: {seen}; target exists: {out.exists()}\n{err[-3000:]}")
        if out.exists():
            _stop(proc)
            pytest.fail(f"{out} exists while the job is still writing: the output is not written "
                        f"to a hidden temporary first")
        for tmp in temporaries(out):
            seen = tmp.name
            try:
                if tmp.is_dir() and len(list(tmp.glob("*.png"))) > layers:
                    return tmp
                if tmp.is_file() and tmp.stat().st_size > size:
                    return tmp
            except FileNotFoundError:       # renamed or removed under us: look again
                continue
        time.sleep(0.02)
    _stop(proc)
    pytest.fail(f"no temporary .{out.name}.tmp-* with more than {layers} layers / {size} bytes appeared "
                f"within {APPEAR_TIMEOUT} s (seen: {seen})")


def interrupt(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    """Send ``sig`` to the running job and wait for it; returns (status, stderr)."""
    assert proc.poll() is None, "the job ended before the signal"
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=EXIT_TIMEOUT)
    except subprocess.TimeoutExpired:
        _, err = _stop(proc)
        pytest.fail(f"the job did not exit within {EXIT_TIMEOUT} s of signal {sig}\n{err[-3000:]}")
    return proc.returncode, err


def interrupt_and_check(proc: subprocess.Popen, out: Path, sig: int) -> None:
    """Signal the job mid-write and check what it leaves.

    * Nothing at the target, whatever the signal.
    * SIGINT (Ctrl-C) and SIGTERM: a non-zero status, no traceback, and the
      hidden temporary removed too (SIGTERM exits with 143 = 128 + 15).
    * SIGKILL: status -9 and the temporary still there (nothing can clean up
      after SIGKILL; that it is left proves the kill came mid-write).
    """
    rc, err = interrupt(proc, sig)
    assert not out.exists(), f"{out} was published although the job was interrupted"
    left = [p.name for p in temporaries(out)]
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL, (rc, err[-3000:])
        assert left, "no temporary after SIGKILL: the job was not interrupted mid-write"
        return
    assert rc != 0, err[-3000:]
    if sig == signal.SIGTERM:
        assert rc == 128 + signal.SIGTERM, (rc, err[-3000:])
        assert "terminated (SIGTERM)" in err
    assert "Traceback" not in err, err[-3000:]
    assert left == [], f"{sig!r} left the temporary output behind: {left}"
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(out.name)] == []
