"""Compiling ahead of time: each feature's kernels compiled by a small job of its own, in several processes.

A fresh install, container image or cluster machine compiles the kernels a job uses the first time it runs
them (:mod:`slicer.compiling`). :func:`warm_up` pays that up front: each feature of :data:`FEATURES` runs
the command-line job that uses its kernels on a tiny scene, in its own process (Numba's compiler holds one
lock per process, so threads would compile one after another), ``jobs`` processes at a time. The compiled
code lands in the cache (:func:`slicer._jit.cache_root`) that later jobs load it from.
"""
from __future__ import annotations

import concurrent.futures as cf
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import trimesh

from slicer.arguments import choice
from slicer.errors import OptionError
from slicer.model.skeleton import Skeleton
from slicer.scene.read import save_scene

#: what each feature runs (``skelslice`` arguments; ``{dir}`` is a scratch folder holding ``scene.json``
#: and ``box.stl``), and the kernels it compiles
FEATURES: dict[str, tuple[tuple[str, ...], str]] = {
    "trace": (("slice", "{dir}/scene.json", "-o", "{dir}/stack", "--pixel-size", "0.2"),
              "the tracer (interval method) and the PNG stack's layer writer"),
    "printer": (("slice", "{dir}/scene.json", "-o", "{dir}/out.sl1s", "--printer", "prusa-sl1s", "--aa", "2"),
                "placement on a printer's plate, anti-aliasing, printer files"),
    "contours": (("slice", "{dir}/scene.json", "-o", "{dir}/out.svg", "--pixel-size", "0.2"),
                 "the guaranteed contours (contour formats, --contours, --aa exact)"),
    "union": (("slice", "{dir}/scene.json", "-o", "{dir}/union", "--pixel-size", "0.2", "--blend", "union"),
              "the union blend's tracer"),
    "sampling": (("slice", "{dir}/scene.json", "-o", "{dir}/sampling", "--pixel-size", "0.2", "--method",
                  "sampling"), "the sampling baseline"),
    "segment": (("slice", "{dir}/scene.json", "-o", "{dir}/segment", "--pixel-size", "0.2", "--method",
                 "segment"), "the segment-tracing baseline"),
    "parts": (("slice", "{dir}/scene.json", "-o", "{dir}/part", "--pixel-size", "0.2", "--solid",
               "{dir}/box.stl"), "parts: meshes cut at the voxel centres"),
    "check": (("check", "{dir}/scene.json", "--pixel-size", "0.2"), "the printability check"),
    "render": (("render", "{dir}/scene.json", "-o", "{dir}/render.png", "--size", "64", "64"),
               "the transparent renderer"),
}
#: what ``skelslice warmup`` compiles without arguments: the README's quick start
DEFAULT = ("trace",)


@dataclass(frozen=True)
class Warmed:
    """One feature compiled: its name, seconds, exit status and the end of its error output."""

    feature: str
    seconds: float
    status: int
    error: str = ""


def _scratch(folder: Path) -> None:
    """The tiny scene (a bent strut pair on the plate) and a small box mesh the features slice."""
    save_scene(Skeleton([[0, 0, 0.8], [0, 0, 3], [1.5, 0, 4]], [[0, 1], [1, 2]], [[0.8, 0.6], [0.6, 0.4]]),
               folder / "scene.json")
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).apply_translation((0, 0, 2.0)).export(folder / "box.stl")


def _run(feature: str, folder: str) -> Warmed:
    args = [a.format(dir=folder) for a in FEATURES[feature][0]]
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "slicer", *args, "-q"], capture_output=True, text=True,
                         stdin=subprocess.DEVNULL)
    # ``check`` exits 1 when it finds something blocking: the kernels ran all the same
    ok = out.returncode == 0 or (feature == "check" and out.returncode == 1)
    return Warmed(feature, time.perf_counter() - t0, 0 if ok else out.returncode,
                  "" if ok else out.stderr.strip()[-400:])


def feature_names(features) -> list[str]:
    """``features`` checked against :data:`FEATURES` (case-insensitive), without repeats, in order."""
    names = list(dict.fromkeys(choice(f, sorted(FEATURES), "feature") for f in features))
    if not names:
        raise OptionError("warmup: no feature given")
    return names


def warm_up(features=DEFAULT, jobs: int | None = None, on_done=None) -> list[Warmed]:
    """Compile the kernels of ``features`` (names of :data:`FEATURES`) into the cache.

    Parameters
    ----------
    features : iterable of str
        Feature names; unknown ones are refused before anything runs.
    jobs : int, optional
        Processes at a time (default: the machine's cores, at most the features' count).
    on_done : callable, optional
        Called with each :class:`Warmed` as it finishes.

    Returns
    -------
    list of Warmed
        In the order of ``features``.
    """
    names = feature_names(features)
    jobs = min(len(names), jobs or os.cpu_count() or 1)
    done = {}
    with tempfile.TemporaryDirectory(prefix="skelslice-warmup-") as tmp:
        _scratch(Path(tmp))
        # threads start the processes; each process compiles on its own
        with cf.ThreadPoolExecutor(jobs) as pool:
            futures = {pool.submit(_run, f, tmp): f for f in names}
            for fut in cf.as_completed(futures):
                w = fut.result()
                done[w.feature] = w
                if on_done is not None:
                    on_done(w)
    return [done[f] for f in names]


__all__ = ["FEATURES", "DEFAULT", "Warmed", "feature_names", "warm_up"]
