"""Peers: skelslice's trace against Fidget and the capsule mesh route, on one grid, in one run.

Usage::

    python benchmarks/peers.py [--repeat N] [--threads T] [--quick] [--json out.json]
                               [--methods skelslice fidget-jit fidget-vm capsules]
                               [--leaf 8] [--top 64]

The model and grid are ``benchmarks/speed.py``'s ``octet`` job: ``python -m slicer
lattice octet --cells 5 5 5 --cell-size 2 --radius 0.12:0.3`` (3,300 struts), every voxel
centre of the 513 x 513 px x 1008 layer grid over ``speed.octet_box`` (``--quick``: the
job's smoke size, 1 cell, 48 px, 40 layers). The methods:

``skelslice``
    ``slicer.tracer.slicing.trace`` of the grid: the ``trace_seconds`` the result
    reports, after a trace of a coarse grid in the same process that loads the kernels
    (as ``speed.py``'s ``micro`` job); the Numba kernels are compiled (or loaded into the
    cache) by one untimed run first.
``fidget-jit``, ``fidget-vm``
    ``benchmarks/peers/fidget``, a small Rust program on the Fidget crate (0.5.1), built
    here on first use (``cargo build --release --locked``, its target folder beside
    its sources): it reads the scene, writes the union of the struts as one Fidget
    expression (min over the segments of a round cone: the union of the balls swept
    along the segment, radius interpolated linearly between its ends) and classifies
    every voxel centre with an interval octree on Fidget's public evaluators: a cell's
    interval settles it inside or outside, else the expression is simplified by the
    interval evaluation's trace (the ``min`` branches that cannot win there are dropped)
    and the cell split, down to leaves of ``--leaf`` voxels (cells are about cubic in
    mm) whose centres the simplified expression's bulk float evaluator classifies;
    threads share a queue of the cells larger than ``--top``. Timed inside the program:
    classification only, after the expression and its first tape are built.
    ``jit`` compiles every simplified tape to machine code, ``vm`` interprets it.
``capsules``
    ``shared/tools/capsule_route.py SCENE WIDTH LAYERS`` beside this repository (a union
    of 16-sided tapered cylinders and node spheres by manifold3d, sliced and filled
    with Pillow into WIDTH x WIDTH images over the mesh's own box); its reported total
    (build, union, slice and fill). It is skipped, saying so, where the script is not
    there. manifold3d picks its own threads.

Every run is a fresh subprocess; the methods alternate run by run (A B C A B C ...),
so a load that comes and goes on the machine hits them all; every method gets the
same ``--threads`` (default: all cores) except the capsule route. The table gives the
median, the range and the ratio to skelslice's median, and each method's fraction of
inside voxels: they differ, since capsules are not skelslice's SIIS surface (a blended
convolution surface) and the capsule route reports no voxels at all. The JSON
(``--json``) holds every run, the command and the machine (:mod:`validation.machine`),
never a local path.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from speed import SIZES, byte_compile, octet_box  # noqa: E402  (benchmarks/speed.py: the octet job)

FIDGET = HERE / "peers" / "fidget"
FIDGET_EXE = FIDGET / "target" / "release" / "skelslice-peer-fidget"
CAPSULE_ROUTE = ROOT.parent / "shared" / "tools" / "capsule_route.py"
METHODS = ("skelslice", "fidget-jit", "fidget-vm", "capsules")
_CAPSULE_LINE = re.compile(r"total ([\d.]+) s")


# ---------------------------------------------------------------- worker side

def _worker_skelslice(scene: str, grid_json: str, threads: int) -> dict:
    import numpy as np

    from slicer.scene.read import load_scene
    from slicer.tracer.grid import SliceGrid, make_grid
    from slicer.tracer.slicing import trace

    skel = load_scene(scene)
    g = json.loads(grid_json)
    grid = SliceGrid(tuple(g["origin"]), tuple(g["pixel_size"]), g["layer_height"], g["width"], g["height"],
                     g["layers"])
    # the kernels' load in this process, paid by a coarse grid first (as speed.py's trace jobs)
    lo, hi = skel.support_bounds()
    t0 = time.perf_counter()
    trace(skel, make_grid(skel.support_bounds(), float(np.max(hi - lo)) / 16), threads=threads)
    setup = time.perf_counter() - t0
    res = trace(skel, grid, threads=threads)
    return {"seconds": res.stats["trace_seconds"], "inside": int(np.sum(res.k1 - res.k0)),
            "evaluations": res.stats["evaluations"], "setup_seconds": setup}


def worker(argv) -> int:
    """``peers.py --worker skelslice SCENE GRID_JSON THREADS``: one trace in this process, JSON out."""
    job, scene, grid_json, threads = argv
    if job != "skelslice":
        raise SystemExit(f"unknown worker job {job!r}")
    print(json.dumps(_worker_skelslice(scene, grid_json, int(threads))))
    return 0


# ---------------------------------------------------------------- driver side

def cargo() -> str | None:
    """The cargo executable: on ``PATH``, else ``~/.cargo/bin/cargo`` (as ``.ci/run``); None if neither."""
    found = shutil.which("cargo")
    if found:
        return found
    home = Path.home() / ".cargo" / "bin" / "cargo"
    return str(home) if home.exists() else None


def build_fidget(log=print) -> tuple[Path, float]:
    """Build the Fidget program (``cargo build --release --locked`` into its own
    ``target`` folder); returns the executable and the build's seconds (small
    when it was already built). RuntimeError if cargo is missing or the build fails."""
    exe = cargo()
    if exe is None:
        raise RuntimeError("cargo is not installed (neither on PATH nor in ~/.cargo/bin)")
    env = {**os.environ, "CARGO_TARGET_DIR": str(FIDGET / "target")}
    log("building benchmarks/peers/fidget (cargo build --release --locked; about a minute the first time)")
    t0 = time.perf_counter()
    p = subprocess.run([exe, "build", "--release", "--locked", "--quiet", "--manifest-path",
                        str(FIDGET / "Cargo.toml")], capture_output=True, text=True, env=env, timeout=3600)
    seconds = time.perf_counter() - t0
    if p.returncode != 0 or not FIDGET_EXE.is_file():
        raise RuntimeError(f"cargo build of benchmarks/peers/fidget failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return FIDGET_EXE, seconds


def fidget_args(grid) -> list[str]:
    """The Fidget program's grid arguments for a :class:`~slicer.tracer.grid.SliceGrid`:
    ``X0 Y0 Z0 PIXEL LAYER_HEIGHT W H K``, its rows counted from the lowest y (the same centres)."""
    px, py = grid.pixel_size
    if px != py:
        raise ValueError("the Fidget program takes square pixels")
    y0 = grid.origin[1] - (grid.height - 1) * py
    return [repr(float(grid.origin[0])), repr(float(y0)), repr(float(grid.origin[2])), repr(float(px)),
            repr(float(grid.layer_height)), str(grid.width), str(grid.height), str(grid.layers)]


def run_fidget(exe: Path, scene: Path, grid, threads: int, backend: str = "jit", leaf: int | None = None,
               top: int | None = None) -> dict:
    """One run of the Fidget program; its JSON line as a dict."""
    cmd = [str(exe), str(scene), *fidget_args(grid), "--threads", str(threads), "--backend", backend]
    if leaf is not None:
        cmd += ["--leaf", str(leaf)]
    if top is not None:
        cmd += ["--top", str(top)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"the Fidget program failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def _env(threads: int) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT)
    env["NUMBA_NUM_THREADS"] = str(max(threads, int(env.get("NUMBA_NUM_THREADS", "0") or 0), 1))
    env.pop("PYTHONSTARTUP", None)
    return env


def _python(args, threads: int, cwd: Path) -> str:
    cmd = [sys.executable, *map(str, args)]
    p = subprocess.run(cmd, cwd=cwd, env=_env(threads), capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[1:3])} ... failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return p.stdout


def run_skelslice(scene: Path, grid, threads: int, cwd: Path) -> dict:
    out = _python([HERE / "peers.py", "--worker", "skelslice", scene, json.dumps(grid.to_dict()), threads],
                  threads, cwd)
    return json.loads(out.strip().splitlines()[-1])


def run_capsules(scene: Path, pixels: int, layers: int, threads: int, cwd: Path) -> dict:
    out = _python([CAPSULE_ROUTE, scene, pixels, layers], threads, cwd)
    m = _CAPSULE_LINE.search(out)
    if m is None:
        raise RuntimeError(f"unexpected capsule route output: {out!r}")
    return {"seconds": float(m.group(1)), "report": out.strip()}


def make_scene(cells: int, work: Path, threads: int) -> Path:
    """The octet lattice of speed.py's octet job, generated by this tree's CLI."""
    scene = work / "octet.json"
    _python(["-m", "slicer", "lattice", "octet", "--cells", cells, cells, cells, "--cell-size", "2",
             "--radius", "0.12:0.3", "-o", scene.name], threads, work)
    return scene


def octet_grid(cells: int, pixels: int, layers: int):
    """The octet job's grid: ``slice --bounds lo lo lo hi hi hi`` over ``speed.octet_box``."""
    import numpy as np

    from slicer.tracer.grid import make_grid

    lo, hi, px, h = octet_box(cells, pixels, layers)
    return make_grid(np.array([[lo] * 3, [hi] * 3]), px, layer_height=h, bounds=(lo, lo, lo, hi, hi, hi))


def measure(methods, repeat: int, threads: int, quick: bool, leaf=None, top=None, log=print) -> dict:
    """Run every method ``repeat`` times, alternating; returns the rows and what was skipped."""
    cells, pixels, layers = SIZES["octet"][1 if quick else 0]
    grid = octet_grid(cells, pixels, layers)
    methods = list(methods)
    skipped, build = {}, None
    if not byte_compile(ROOT):
        raise RuntimeError("a source file of the tree does not compile")
    exe = None
    if any(m.startswith("fidget") for m in methods):
        try:
            exe, build = build_fidget(log)
            log(f"fidget program ready ({build:.1f} s)")
        except RuntimeError as e:
            for m in methods:
                if m.startswith("fidget"):
                    skipped[m] = f"not run: {e}"
    if "capsules" in methods and not CAPSULE_ROUTE.is_file():
        skipped["capsules"] = ("not run: shared/tools/capsule_route.py is not beside this repository "
                               "(the capsule route is not part of skelslice)")
    for m, why in skipped.items():
        log(f"{m}: {why}")
    methods = [m for m in methods if m not in skipped]
    runs = {m: [] for m in methods}
    with tempfile.TemporaryDirectory(prefix="skelslice-peers-") as tmp:
        work = Path(tmp)
        scene = make_scene(cells, work, threads)
        n_segments = len(json.loads(scene.read_text())["segments"])
        if "skelslice" in methods:               # compile (or load into the cache) the kernels, untimed
            t0 = time.perf_counter()
            run_skelslice(scene, octet_grid(*SIZES["octet"][1]), threads, work)
            log(f"skelslice: kernels ready in {time.perf_counter() - t0:.1f} s")
        for _ in range(repeat):
            for m in methods:
                if m == "skelslice":
                    r = run_skelslice(scene, grid, threads, work)
                elif m == "capsules":
                    r = run_capsules(scene, pixels, layers, threads, work)
                else:
                    r = run_fidget(exe, scene, grid, threads, m.split("-")[1], leaf, top)
                runs[m].append(r)
                log(f"{m}: {r['seconds']:.2f} s")
    rows = [_row(m, runs[m], grid) for m in methods]
    base = next((r for r in rows if r["method"] == "skelslice"), None)
    for r in rows:
        if base is not None and base["median_seconds"] > 0:
            r["ratio_to_skelslice"] = r["median_seconds"] / base["median_seconds"]
    return {"rows": rows, "skipped": skipped, "fidget_build_seconds": build,
            "grid": grid.to_dict(), "voxels": grid.n_voxels,
            "scene": {"lattice": "octet", "cells": cells, "cell_size": 2, "radius": "0.12:0.3",
                      "segments": n_segments}}


def _row(method: str, runs: list[dict], grid) -> dict:
    secs = [r["seconds"] for r in runs]
    row = {"method": method, "runs_seconds": secs, "median_seconds": statistics.median(secs),
           "min_seconds": min(secs), "max_seconds": max(secs)}
    if "inside" in runs[0]:
        row["inside"] = runs[0]["inside"]
        row["inside_fraction"] = runs[0]["inside"] / grid.n_voxels
        if any(r["inside"] != row["inside"] for r in runs):
            row["inside_varies"] = True
    if method == "skelslice":
        row["evaluations"] = runs[0]["evaluations"]
        row["median_setup_seconds"] = statistics.median(r["setup_seconds"] for r in runs)
    elif method.startswith("fidget"):
        first = runs[0]
        row["fidget"] = {k: first[k] for k in ("backend", "threads", "leaf", "top", "tape_len", "cells",
                                                "settled_inside", "settled_outside", "simplified", "leaves",
                                                "points")}
        row["median_build_seconds"] = statistics.median(r["build_seconds"] for r in runs)
    else:
        row["reports"] = [r["report"] for r in runs]
    return row


def table(result: dict) -> str:
    """method | median s | min-max s | ratio to skelslice | inside voxels."""
    lines = ["| method | median s | min–max s | × skelslice | inside voxels |", "|---|---|---|---|---|"]
    for r in result["rows"]:
        ratio = f"{r['ratio_to_skelslice']:.2f}×" if "ratio_to_skelslice" in r else "-"
        inside = (f"{r['inside']:,} ({100 * r['inside_fraction']:.2f} %)" if "inside" in r
                  else "not reported")
        lines.append(f"| {r['method']} | {r['median_seconds']:.2f} | {r['min_seconds']:.2f}–{r['max_seconds']:.2f} "
                     f"| {ratio} | {inside} |")
    for m, why in result["skipped"].items():
        lines.append(f"| {m} | - | - | - | {why.splitlines()[0]} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        return worker(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="Runs per method; the table shows the median.")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="Threads for every method (default: all cores).")
    ap.add_argument("--quick", action="store_true", help="The octet job's smoke size (1 cell, 48 px, 40 layers).")
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    ap.add_argument("--leaf", type=int, default=None, help="Fidget octree: leaf edge in voxels (the program's default: 8).")
    ap.add_argument("--top", type=int, default=None, help="Fidget octree: cells larger than this go through the threads' queue (default 64).")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.threads < 1:
        ap.error("--repeat and --threads must be >= 1")
    from validation import machine

    result = measure(args.methods, args.repeat, args.threads, args.quick, args.leaf, args.top,
                     log=lambda s: print(s, file=sys.stderr))
    print(table(result))
    print("Inside voxels differ by method: the Fidget program's shape is a union of round cones and the capsule "
          "route's a union of faceted cylinders and spheres, not skelslice's SIIS surface.")
    if args.json is not None:
        doc = {"benchmark": "peers", "command": machine.command_line("python benchmarks/peers.py", argv),
               "machine": machine.describe(), "quick": args.quick, "repeat": args.repeat, "threads": args.threads,
               "fidget": {"crate": "fidget 0.5.1", "leaf": args.leaf or 8, "top": args.top or 64}, **result}
        machine.write_json(args.json, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
