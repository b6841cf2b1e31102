"""Benchmarks that compare methods in one run and print a table (+ JSON).

``python -m validation.bench table1``: the paper's Table 1 protocol. Each sample
model is sliced at 512 x 512 pixels over its support box (explicit bounds, so
every method sees the same grid) at several layer counts, with

* ``sampling-global``: field at every voxel centre, one global z-sorted list
  (no buckets);
* ``sampling``: the same with 64 x 64 buckets (Liu et al. 2021);
* ``interval``: per-primitive interval arithmetic (EG22, this project);
* ``segment``: segment tracing on the directional Lipschitz bound (GGPP20).

Reported: trace wall time (JIT compilation measured apart, on a warm-up
scene), primitive evaluations, image writing time (apart, PNG stack), speed-up
over bucketed sampling, and voxels that differ from the interval result.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sample_lattices import load_sample
from slicer._kernels.runtime.launch import numba_threads
from slicer.tracer.grid import make_grid
from slicer.raster.placed_layers import write_stack
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import trace

from validation import machine

METHOD_ARGS = {
    "sampling-global": ("sampling", 0),
    "sampling": ("sampling", 64),
    "interval": ("interval", 64),
    "segment": ("segment", 64),
}


def _warmup() -> float:
    """Compile every kernel on a tiny scene; returns the seconds it took."""
    s = Skeleton([[0, 0, 0], [0, 0, 1], [1, 0, 1]], [[0, 1], [1, 2]], [[0.3, 0.2], [0.2, 0.3]])
    g = make_grid(s.support_bounds(), 0.2)
    t0 = time.perf_counter()
    for m in ("interval", "sampling", "segment"):
        trace(s, g, method=m)
    return time.perf_counter() - t0


def square_bounds(skel, pixels: int):
    """Bounds of a pixels x pixels image over the model's support box, and its pixel size."""
    lo, hi = skel.support_bounds()
    c = 0.5 * (lo[:2] + hi[:2])
    half = 0.5 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    px = 2 * half / pixels
    return (c[0] - half, c[1] - half, lo[2], c[0] + half, c[1] + half, hi[2]), px


def table1(models=("jellyfish", "microstructure"), layers=(512, 1024), pixels=512,
           methods=tuple(METHOD_ARGS), threads=None, write_images=True, repeat=1) -> dict:
    """Run the Table 1 protocol; returns the results as a JSON-ready dict."""
    compile_s = _warmup()
    rows = []
    with numba_threads(threads) as nthreads:
        for name in models:
            skel = load_sample(name)
            bounds, px = square_bounds(skel, pixels)
            for K in layers:
                h = (bounds[5] - bounds[2]) / K
                grid = make_grid(skel.support_bounds(), px, layer_height=h, bounds=bounds)
                ref = None
                base = None
                for meth in methods:
                    code, bucket = METHOD_ARGS[meth]
                    best = None
                    for _ in range(repeat):
                        res = trace(skel, grid, method=code, bucket=bucket)
                        t = res.stats["trace_seconds"]
                        best = t if best is None else min(best, t)
                    vol_key = (res.pix, res.k0, res.k1)
                    if ref is None:
                        ref = vol_key
                        diff = 0
                    else:
                        diff = _run_diff(ref, vol_key, grid)
                    row = {"model": name, "segments": skel.n_segments, "pixels": pixels, "layers": K,
                           "method": meth, "bucket": bucket, "seconds": best,
                           "evaluations": res.stats["evaluations"], "runs": res.n_runs,
                           "voxels_differing_from_first": diff}
                    if meth == "sampling":
                        base = best
                    rows.append(row)
                    if write_images and meth == "interval":
                        with tempfile.TemporaryDirectory() as tmp:
                            row["write_seconds"] = write_stack(res, Path(tmp) / "stack", "png", progress=False)
                for row in rows:
                    if row["model"] == name and row["layers"] == K and base:
                        row["speedup_vs_sampling"] = base / row["seconds"]
    return {"benchmark": "table1", "compile_seconds": compile_s, "threads": nthreads,
            "machine": machine.describe(), "rows": rows}


def _run_diff(a, b, grid) -> int:
    """Number of voxels whose class differs between two run sets."""
    def vol(r):
        pix, k0, k1 = r
        v = np.zeros(grid.width * grid.height * grid.layers, np.int8)
        idx_start = pix * grid.layers + k0
        idx_end = pix * grid.layers + k1
        np.add.at(v, idx_start, 1)
        ends = idx_end[idx_end < v.shape[0]]
        np.add.at(v, ends, -1)
        return np.cumsum(v, dtype=np.int32) > 0
    return int(np.count_nonzero(vol(a) != vol(b)))


def format_table(result: dict) -> str:
    head = (f"{'model':<15}{'layers':>7}  {'method':<16}{'trace s':>9}{'evals':>15}"
            f"{'speed-up':>10}{'write s':>9}{'diff':>6}")
    lines = [f"JIT compile (all kernels, warm-up): {result['compile_seconds']:.2f} s; "
             f"threads: {result['threads']}", head, "-" * len(head)]
    for r in result["rows"]:
        sp = r.get("speedup_vs_sampling")
        ws = r.get("write_seconds")
        lines.append(
            f"{r['model']:<15}{r['layers']:>7}  {r['method']:<16}{r['seconds']:>9.3f}{r['evaluations']:>15,}"
            f"{(f'{sp:.2f}x' if sp else '-'):>10}{(f'{ws:.2f}' if ws is not None else '-'):>9}"
            f"{r['voxels_differing_from_first']:>6}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m validation.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    t1 = sub.add_parser("table1", help="the paper's Table 1 protocol")
    t1.add_argument("--models", nargs="+", default=["jellyfish", "microstructure"])
    t1.add_argument("--layers", nargs="+", type=int, default=[512, 1024])
    t1.add_argument("--pixels", type=int, default=512)
    t1.add_argument("--methods", nargs="+", default=list(METHOD_ARGS), choices=list(METHOD_ARGS))
    t1.add_argument("--threads", type=int, default=None)
    t1.add_argument("--repeat", type=int, default=1, help="best of N runs per method")
    t1.add_argument("--no-write", action="store_true", help="skip the PNG writing measurement")
    t1.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args(argv)
    res = table1(args.models, args.layers, args.pixels, args.methods, args.threads,
                 not args.no_write, args.repeat)
    res = {"command": machine.command_line("python -m validation.bench", argv), **res}
    machine.publish(res, format_table(res), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
