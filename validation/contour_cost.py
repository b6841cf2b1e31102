"""Where the guaranteed contours spend their field evaluations, next to the tracer.

Usage::

    python -m validation.contour_cost [--model octet_2x2x2] [--pixels 113] [--layers 113]
                                      [--pixel-size P] [--tol 0.001] [--repeat 3] [--threads 1]
                                      [--json out.json]

The grid is that of the error-against-time sweep (:mod:`validation.error_time`):
a square image of ``--pixels`` over the model's support box and ``--layers``
layers over its height (octet_2x2x2: 113 x 113 px x 113 layers of about
0.1 mm). With ``--pixel-size P`` it is instead the grid of ``skelslice slice
MODEL --pixel-size P`` (pixels and layers of P mm on the lattice of multiples
of P, trimmed to the model; octet_2x2x2 at 0.1 mm: 113 x 113 px x 113 layers,
10 of whose planes touch the tops and bottoms of the struts lying in them). Two jobs on that grid:

``trace``
    :func:`slicer.tracer.slicing.trace` (interval method, buckets of 64 px): the
    layer rasters. Its count is of primitive evaluations (point and segment
    pairs), as the ``slice`` command reports it.
``guaranteed``
    :func:`slicer.contours.plane_contours` on every layer plane, tolerance
    ``--tol`` mm, one plane per thread (:func:`slicer.contours.each_plane`,
    as ``slice`` writes contours); with ``--threads`` above 1 also
    ``guaranteed_one_plane_at_a_time`` (planes in turn, each plane's kernels
    on the threads). Its counts are of field evaluations at points (every
    segment that reaches the point), split by stage:

    * ``cells``: cell centres of the quadtree (value and gradient);
    * ``corners``: leaf corners on the boundary walks (value);
    * ``roots``: root solves of the crossings on elementary edges;
    * ``checks``: chord quarter points and midpoints (value and gradient);
    * ``projections``: new chord vertices put on the contour.

Counts are deterministic; seconds are the median of ``--repeat`` runs in
this process (a first call of each job, which loads or compiles the
kernels, is not timed; for the contours, one layer plane). The JSON
(``--json``) holds the command, the machine (:mod:`validation.machine`),
every run's seconds and the counts.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from sample_lattices import load_sample
from slicer._kernels.runtime.launch import numba_threads
from slicer.contours import each_plane, grid_box, plane_contours
from slicer.tracer.grid import make_grid
from slicer.tracer.slicing import slice_skeleton, trace

from validation import machine
from validation.error_time import square_box

#: stage name in the table -> key of the contour statistics
STAGES = {"cells": "cell_evaluations", "corners": "corner_evaluations", "roots": "root_evaluations",
          "checks": "check_evaluations", "projections": "projection_evaluations"}


def sweep_grid(skel, pixels: int, layers: int):
    """The grid of :func:`validation.error_time.run_config` for ``pixels`` and ``layers``."""
    (x0, y0, x1, y1), (z0, z1) = square_box(skel)
    return make_grid(skel.support_bounds(), (x1 - x0) / pixels, layer_height=(z1 - z0) / layers,
                     bounds=(x0, y0, z0, x1, y1, z1))


def run_trace(skel, grid) -> tuple[float, dict]:
    """Seconds and counts of tracing the grid."""
    t0 = time.perf_counter()
    res = trace(skel, grid, method="interval", bucket=64)
    return time.perf_counter() - t0, {"evaluations": int(res.stats["evaluations"])}


def run_contours(skel, grid, tol: float, workers: int | None = None) -> tuple[float, dict]:
    """Seconds and counts of the guaranteed contours of every layer plane of the grid,
    ``workers`` planes at once (default: one per thread, as ``slice`` does)."""
    st: dict = {}
    box = grid_box(grid)
    t0 = time.perf_counter()
    for _ in each_plane(skel, grid.centres_z(), tol, box, st, workers):
        pass
    return time.perf_counter() - t0, st


def measure(model: str = "octet_2x2x2", pixels: int = 113, layers: int = 113, tol: float = 1e-3,
            repeat: int = 3, threads: int | None = 1, pixel_size: float | None = None) -> dict:
    """Counts and seconds of both jobs; returns a JSON-ready dict. ``pixel_size``:
    the ``slice`` command's grid at that pixel size instead of the sweep's."""
    skel = load_sample(model)
    if pixel_size is None:
        grid = sweep_grid(skel, pixels, layers)
    else:
        grid = slice_skeleton(skel, pixel_size).grid        # trimmed to the model, as the command's
    out = {"benchmark": "contour_cost", "model": model, "segments": skel.n_segments,
           "grid": {"width": grid.width, "height": grid.height, "layers": grid.layers,
                    "pixel_size": float(grid.pixel_size[0]), "layer_height": float(grid.layer_height)},
           "tol": tol, "repeat": repeat}
    with numba_threads(threads) as nthreads:
        out["threads"] = nthreads
        zmid = float(grid.centres_z()[grid.layers // 2])
        warm = {"trace": lambda: run_trace(skel, grid),
                "guaranteed": lambda: plane_contours(skel, zmid, tol, grid_box(grid))}
        jobs = [("trace", lambda: run_trace(skel, grid)),
                ("guaranteed", lambda: run_contours(skel, grid, tol))]
        if nthreads > 1:        # the same contours one plane after the other, kernels on the threads
            warm["guaranteed_one_plane_at_a_time"] = warm["guaranteed"]
            jobs.append(("guaranteed_one_plane_at_a_time", lambda: run_contours(skel, grid, tol, 1)))
        for name, job in jobs:
            warm[name]()                            # loads or compiles the kernels
            runs = [job() for _ in range(repeat)]
            counts = runs[0][1]
            if any(r[1] != counts for r in runs):   # pragma: no cover - the counts are deterministic
                raise RuntimeError(f"{name}: counts differ between runs")
            secs = [r[0] for r in runs]
            out[name] = {"seconds": statistics.median(secs), "runs": secs,
                         "counts": {k: (int(v) if isinstance(v, (int, float)) and float(v).is_integer() else v)
                                    for k, v in counts.items()}}
    return out


def format_table(res: dict) -> str:
    g = res["grid"]
    tr, gu = res["trace"], res["guaranteed"]
    c = gu["counts"]
    lines = [f"model {res['model']} ({res['segments']} segments), {g['width']} x {g['height']} px x "
             f"{g['layers']} layers ({g['pixel_size']:.4f} mm), tol {res['tol'] * 1e3:g} um, "
             f"threads {res['threads']}, median of {res['repeat']}",
             f"{'job / stage':<26}{'evaluations':>14}{'share':>8}{'seconds':>10}",
             "-" * 58,
             f"{'trace (primitive evals)':<26}{tr['counts']['evaluations']:>14,}{'':>8}{tr['seconds']:>10.3f}",
             f"{'guaranteed (points)':<26}{c['evaluations']:>14,}{'':>8}{gu['seconds']:>10.3f}"]
    if "guaranteed_one_plane_at_a_time" in res:
        one = res["guaranteed_one_plane_at_a_time"]
        lines.append(f"{'  one plane at a time':<26}{one['counts']['evaluations']:>14,}{'':>8}{one['seconds']:>10.3f}")
    for stage, key in STAGES.items():
        v = c.get(key, 0)
        lines.append(f"{'  ' + stage:<26}{v:>14,}{v / max(c['evaluations'], 1):>8.1%}")
    lines.append(f"cells {c.get('cells', 0):,}, leaves {c.get('leaves', 0):,} "
                 f"(small {c.get('small_leaves', 0):,}, thin {c.get('thin_leaves', 0):,}), "
                 f"vertices {c.get('vertices', 0):,}, "
                 f"refined {c.get('refined', 0):,}, unbracketed {c.get('unbracketed', 0)}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m validation.contour_cost", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="octet_2x2x2")
    ap.add_argument("--pixels", type=int, default=113)
    ap.add_argument("--layers", type=int, default=113)
    ap.add_argument("--pixel-size", type=float, default=None,
                    help="the slice command's grid at this pixel size, mm (instead of --pixels, --layers)")
    ap.add_argument("--tol", type=float, default=1e-3, help="contour tolerance, mm")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    args = ap.parse_args(argv)
    res = measure(args.model, args.pixels, args.layers, args.tol, args.repeat, args.threads, args.pixel_size)
    res = {"command": machine.command_line("python -m validation.contour_cost", argv), **res,
           "machine": machine.describe()}
    machine.publish(res, format_table(res), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
