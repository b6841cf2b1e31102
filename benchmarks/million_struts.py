"""Scale benchmark: a lattice of a million struts sliced to a printer archive.

Usage::

    python benchmarks/million_struts.py [--struts 1000000] [--width 4000 --height 2500]
        [--layers 1000] [--max-memory 4GB] [--format zip] [--executor serial] [--workers N]
        [--slab N] [--prefetch | --no-prefetch] [--out DIR] [--json result.json] [--keep]

A body-centred-cubic lattice (8 struts per cell, radius 6 % of the cell) is
generated with :func:`slicer.scene.lattice.generate_lattice`, with cells laid out
in proportion to the plate (width x height px) and the layer count, so that
the plate is filled; the plate is sliced with explicit bounds (no trim) at
``width x height`` pixels and ``layers`` layers, within ``--max-memory``,
and written with the chosen writer (``zip``: PNG layers + metadata in one
zip, the layout of an SL1/SL1S archive without its printer-specific fields,
which need the printer's own display size). Printed as JSON: the sizes, the
plan, time per stage and the peak resident memory of this process and of
its worker processes (``resource.getrusage``), and whether the peak stayed
within the budget.

Scaled-down check (about a minute here)::

    python benchmarks/million_struts.py --struts 20000 --width 800 --height 500 --layers 200 --max-memory 1GB
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import shutil
import tempfile
import time
from pathlib import Path

from validation import machine

STRUTS_PER_CELL = 8   # bcc: the body centre joined to the 8 corners


def cells_for(struts: int, width: int, height: int, layers: int) -> tuple[int, int, int]:
    """Cell counts in proportion to the plate and the layers, with >= ``struts`` struts."""
    n = math.ceil(struts / STRUTS_PER_CELL)
    k = (n / (width * height * layers)) ** (1 / 3)
    nx, ny, nz = (max(1, round(v * k)) for v in (width, height, layers))
    while nx * ny * nz < n:   # round up the axis with the most room
        ax = max(range(3), key=lambda a: (width, height, layers)[a] / (nx, ny, nz)[a])
        if ax == 0:
            nx += 1
        elif ax == 1:
            ny += 1
        else:
            nz += 1
    return nx, ny, nz


def peak_rss() -> dict:
    """Peak resident memory so far, bytes: this process and its (waited-for) children."""
    self_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return {"self": self_kb * 1024, "children": child_kb * 1024}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--struts", type=int, default=1_000_000)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--height", type=int, default=2500)
    ap.add_argument("--layers", type=int, default=1000)
    ap.add_argument("--cell", type=float, default=None, help="cell size, mm (default: 2.5 mm at 4000 px width)")
    ap.add_argument("--max-memory", default="4GB")
    ap.add_argument("--format", default="zip")
    ap.add_argument("--executor", default="serial", choices=["serial", "threads", "processes", "dask"])
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--slab", type=int, default=None, help="layers per slab (default: planned)")
    ap.add_argument("--prefetch", dest="prefetch", action="store_true", default=None,
                    help="trace the next slab while one is written, slabs sized for two "
                         "(default: only when two planned slabs fit)")
    ap.add_argument("--no-prefetch", dest="prefetch", action="store_false", help="never prefetch")
    ap.add_argument("--out", default=None, help="output folder (default: a temporary one, removed)")
    ap.add_argument("--keep", action="store_true", help="keep the archive")
    ap.add_argument("--json", default=None, help="also write the result here")
    args = ap.parse_args(argv)

    from slicer.scale.executors import open_executor
    from slicer.job.run import run_slice
    from slicer.scene.lattice import generate_lattice
    from slicer.scale.tiles import parse_size

    nx, ny, nz = cells_for(args.struts, args.width, args.height, args.layers)
    # voxels: pixel = plate / width; the cell spans the plate's width in nx cells
    cell = args.cell or 2.5
    radius = 0.06 * cell
    margin = 2.0 * radius                       # support of the outer struts (sigma = 2)
    t0 = time.perf_counter()
    skel = generate_lattice("bcc", cells=(nx, ny, nz), cell_size=cell, radius=radius)
    t_gen = time.perf_counter() - t0
    lo = [-margin, -margin, -margin]
    hi = [nx * cell + margin, ny * cell + margin, nz * cell + margin]
    px = (hi[0] - lo[0]) / args.width
    py = (hi[1] - lo[1]) / args.height
    h = (hi[2] - lo[2]) / args.layers
    # shave a hair off the far faces so the grid has exactly width x height x layers voxels
    bounds = lo + [lo[0] + (args.width - 1e-6) * px, lo[1] + (args.height - 1e-6) * py,
                   lo[2] + (args.layers - 1e-6) * h]
    tmp = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="million_struts_"))
    tmp.mkdir(parents=True, exist_ok=True)
    out = tmp / f"lattice.{args.format}"
    budget = parse_size(args.max_memory)
    plan_text = []
    t1 = time.perf_counter()
    with open_executor(args.executor, args.workers) as (ex, info):
        summary = run_slice(skel, out, pixel_size=px, pixel_size_y=py, layer_height=h, bounds=bounds,
                            threads=args.threads, fmt=args.format, force=True, progress=False,
                            max_memory=budget, executor=ex, executor_info=info, report=plan_text.append,
                            slab=args.slab, prefetch=args.prefetch)
    t_job = time.perf_counter() - t1
    peak = peak_rss()
    size = out.stat().st_size if out.is_file() else sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    result = {
        "benchmark": "million_struts",
        "command": machine.command_line("python benchmarks/million_struts.py", argv),
        "struts": skel.n_segments, "cells": [nx, ny, nz], "cell_mm": cell, "radius_mm": radius,
        "width": summary["width"], "height": summary["height"], "layers": summary["layers"],
        "pixel_size_mm": [px, py], "layer_height_mm": h,
        "format": summary["format"], "archive_bytes": size,
        "executor": info.describe(), "max_memory": budget,
        "plan": summary.get("plan"),
        "seconds": {"generate": round(t_gen, 3), "job": round(t_job, 3),
                    "trace_sum": round(summary.get("trace_seconds", 0.0), 3),
                    "write": round(summary.get("write_seconds", 0.0), 3)},
        "evaluations": summary.get("evaluations"),
        "peak_rss_bytes": peak,
        "peak_within_budget": budget is None or peak["self"] + peak["children"] <= budget,
        "machine": machine.describe(),
    }
    if not (args.keep or args.out):
        shutil.rmtree(tmp, ignore_errors=True)
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return result


if __name__ == "__main__":
    main()
