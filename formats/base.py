"""Writer protocol and atomic publication helpers."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from slicer.errors import OutputError


class StackWriter:
    """Streams a layer stack to one output, published atomically.

    Parameters
    ----------
    path : path-like
        Final output location.
    grid : slicer.grid.SliceGrid
        Grid of the layers.
    meta : dict
        Extra metadata (method, scene, ...), written where the format allows.
    force : bool
        Replace an existing output.
    """

    def __init__(self, path, grid, meta: dict | None = None, force: bool = False):
        self.path = Path(path)
        self.grid = grid
        self.meta = dict(meta or {})
        self.force = force
        check_destination(self.path, force)

    def write_layer(self, k: int, image: np.ndarray) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def abort(self) -> None:  # pragma: no cover - protocol
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def check_destination(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing output unless ``force``; check the parent exists."""
    if path.exists() and not force:
        raise OutputError(f"{path}: already exists (use --force to replace it)")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{path}: the folder {parent} does not exist")


class atomic_dir:
    """A temporary folder beside ``path`` that becomes ``path`` on :meth:`publish`.

    Until then nothing exists at ``path``; :meth:`discard` removes the
    temporary folder. A crash leaves at most a hidden ``.<name>.tmp-*`` folder,
    never a half-written output at ``path``.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        parent = self.path.parent if str(self.path.parent) else Path(".")
        try:
            self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.tmp-", dir=parent))
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot create a temporary folder ({exc.strerror})") from None

    def publish(self, force: bool) -> None:
        if self.path.exists():
            if not force:
                self.discard()
                raise OutputError(f"{self.path}: already exists (use --force to replace it)")
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            os.replace(self.path, old)
            os.replace(self.tmp, self.path)
            if old.is_dir():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink(missing_ok=True)
        else:
            os.replace(self.tmp, self.path)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
