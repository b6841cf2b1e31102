"""Reading skelslice's printer files with uv3dp (the tools of the ``uv3dp`` fixture).

* :func:`uv3dp_layers`: ``uv3dp-layers FILE`` (uv3dp's own decoders, one
  SHA-256 per decoded layer) as a dict.
* :func:`uv3dp_convert`: ``uv3dp FILE OUT.uvj``, the uv3dp command line's
  conversion to its zip of PNG layers plus ``config.json``; returns the
  config and the decoded layers.
"""
from __future__ import annotations

import hashlib
import json
import subprocess
import zipfile

import numpy as np
from PIL import Image


def sha256(image: np.ndarray) -> str:
    """SHA-256 of an image's row-major 8-bit pixels (what uv3dp-layers prints)."""
    return hashlib.sha256(np.ascontiguousarray(image, dtype=np.uint8).tobytes()).hexdigest()


def uv3dp_layers(tools, path, ok: bool = True) -> dict:
    """Run ``uv3dp-layers`` on ``path``; ``ok`` is whether uv3dp must accept the file."""
    r = subprocess.run([str(tools.layers), str(path)], capture_output=True, text=True, timeout=600)
    doc = json.loads(r.stdout)
    assert (r.returncode == 0) == ok, (r.returncode, r.stdout[:500], r.stderr[:500])
    return doc


def uv3dp_convert(tools, path, out) -> tuple[dict, list[np.ndarray]]:
    """Convert ``path`` with the uv3dp command line to ``out`` (a ``.uvj``); returns
    (config.json, the layer images in order)."""
    r = subprocess.run([str(tools.cli), str(path), str(out)], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    with zipfile.ZipFile(out) as z:
        config = json.loads(z.read("config.json"))
        n = config["Properties"]["Size"]["Layers"]
        layers = [np.asarray(Image.open(z.open(f"slice/{k:08d}.png")).convert("L")) for k in range(n)]
    return config, layers
