"""Atomic folders (:class:`slicer.atomic.AtomicDir`): every file durable before the rename,
a write error at any file leaves nothing at the target."""
from __future__ import annotations

import os

import pytest

from slicer import atomic
from slicer.atomic import AtomicDir
from slicer.errors import OutputError


def _record(monkeypatch):
    """Log ``("fsync", name)`` and ``("replace", name)`` in the order they happen."""
    log = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        log.append(("fsync", os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))))
        return real_fsync(fd)

    def replace(src, dst):
        log.append(("replace", os.path.basename(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return log


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="names fds through /proc")
def test_every_file_is_fsynced_before_the_folder_is_renamed(tmp_path, monkeypatch):
    log = _record(monkeypatch)
    d = AtomicDir(tmp_path / "stack")
    names = [f"layer_{k:05d}.png" for k in range(5)] + ["slices.json"]
    for k, name in enumerate(names):
        d.write_file(name, bytes([k]) * (100 + k))
    assert log == []                                     # nothing synced while the files stream in
    d.publish(force=False)
    at = log.index(("replace", "stack"))
    synced = {name for kind, name in log[:at] if kind == "fsync"}
    assert set(names) <= synced                          # each file, before the rename
    assert sorted(p.name for p in (tmp_path / "stack").iterdir()) == sorted(names)
    assert (tmp_path / "stack" / "layer_00003.png").read_bytes() == bytes([3]) * 103
    assert [p.name for p in tmp_path.iterdir()] == ["stack"]


def test_a_file_that_cannot_be_made_durable_leaves_nothing(tmp_path, monkeypatch):
    d = AtomicDir(tmp_path / "stack")
    for k in range(4):
        d.write_file(f"layer_{k:05d}.png", b"x" * 10)
    real_fsync = os.fsync
    calls = []

    def fsync(fd):                                       # the third file's writeback failed
        calls.append(fd)
        if len(calls) == 3:
            raise OSError(5, "Input/output error")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OutputError, match="Input/output error") as info:
        d.publish(force=False)
    assert str(tmp_path / "stack") in str(info.value)
    assert list(tmp_path.iterdir()) == []                # no target, no temporary folder left


def test_files_written_twice_are_synced_once_and_hold_the_last_data(tmp_path, monkeypatch):
    synced = []
    monkeypatch.setattr(atomic, "_SYNCFS", None)         # the portable path: fsync alone
    real = atomic.sync_files

    def spy(folder, names):
        synced.extend(names)
        return real(folder, names)

    monkeypatch.setattr(atomic, "sync_files", spy)
    d = AtomicDir(tmp_path / "out")
    d.write_file("a", b"first")
    d.write_file("b", b"b")
    d.write_file("a", b"second")
    d.publish(force=False)
    assert synced == ["a", "b"]
    assert (tmp_path / "out" / "a").read_bytes() == b"second"
