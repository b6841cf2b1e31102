"""Bundled sample scenes ("examples are tests").

Each sample is a ``build() -> Skeleton`` function, registered in
:data:`SAMPLES`; its output is committed next to this file as
``<name>.json`` (scene format v1). ``python -m sample_lattices`` regenerates
the JSON files; ``tests/test_samples.py`` checks that they match ``build()``.

Examples
--------
>>> from sample_lattices import SAMPLES, load_sample
>>> sorted(SAMPLES)[:3]
['bcc_3x3x3_graded', 'cubic_2x2x2', 'jellyfish']
>>> load_sample("cubic_2x2x2").n_segments
54
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from slicer.errors import SceneError
from slicer.scene.read import load_scene, save_scene
from slicer.model.skeleton import Skeleton

from . import jellyfish, microstructure, small

#: sample name -> function building it
SAMPLES: dict[str, Callable[[], Skeleton]] = {
    "jellyfish": jellyfish.build,
    "microstructure": microstructure.build,
    "cubic_2x2x2": small.cubic_2x2x2,
    "bcc_3x3x3_graded": small.bcc_3x3x3_graded,
    "octet_2x2x2": small.octet_2x2x2,
    "kelvin_2x2x2": small.kelvin_2x2x2,
}


def _check(name: str) -> None:
    if name not in SAMPLES:
        raise SceneError(f"unknown sample {name!r}; samples: {', '.join(sorted(SAMPLES))}")


def sample_path(name: str) -> Path:
    """Path of the committed scene file of sample ``name``."""
    _check(name)
    return Path(__file__).with_name(f"{name}.json")


def load_sample(name: str) -> Skeleton:
    """Load the committed scene of sample ``name``."""
    return load_scene(sample_path(name))


def write_samples(names=None) -> list[Path]:
    """Rebuild samples (all by default) and write their JSON files; returns the paths."""
    paths = [sample_path(name) for name in (names or SAMPLES)]  # check every name first
    for path in paths:
        save_scene(SAMPLES[path.stem](), path)
    return paths


__all__ = ["SAMPLES", "sample_path", "load_sample", "write_samples"]
