"""Tracing time against the bucket edge, all sizes in one process.

Usage::

    python benchmarks/bucket_size.py [--jobs jelly micro octet] [--buckets 64 32 16]
                                     [--repeat 5] [--threads 2] [--quick] [--json out.json]

Jobs (the grids of ``benchmarks/speed.py``):

``jelly``, ``micro``
    :func:`slicer.tracer.slicing.trace` of the jellyfish and the microstructure over a
    square box around their support, 512 x 512 px, 1024 layers.
``octet``
    The octet lattice of the speed benchmark (5 x 5 x 5 cells of 2 mm, radius
    0.12 -> 0.3 mm along z, :func:`slicer.scene.lattice.generate_lattice`) at
    513 x 513 px x 1008 layers.

Every repeat traces each job once per bucket edge, the edges in turn, so the
machine's load drifts over all of them alike; the table shows the median
seconds of the ``trace`` call. The layers must not depend on the edge: the
runs of every edge are compared with the first one's, and a difference is an
error. ``--quick`` shrinks the grids to a smoke test of a few seconds. The
JSON (``--json``) holds every run, the command and the machine.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from sample_lattices import load_sample  # noqa: E402
from slicer.tracer.grid import make_grid  # noqa: E402
from slicer.scene.lattice import generate_lattice  # noqa: E402
from slicer.tracer.slicing import trace  # noqa: E402
from speed import _square_bounds, octet_box  # noqa: E402
from validation import machine  # noqa: E402

#: job -> (full size, quick size): (pixels, layers)
SIZES = {"jelly": ((512, 1024), (48, 48)), "micro": ((512, 1024), (48, 48)), "octet": ((513, 1008), (48, 40))}


def _sample_grid(name: str, pixels: int, layers: int):
    """A sample over a square box around its support (``speed.py``'s trace jobs)."""
    skel = load_sample(name)
    bounds, px = _square_bounds(skel, pixels)
    grid = make_grid(skel.support_bounds(), px, layer_height=(bounds[5] - bounds[2]) / layers, bounds=bounds)
    return skel, grid


def _octet_grid(pixels: int, layers: int, quick: bool):
    """The speed benchmark's octet lattice (one cell when ``quick``) and grid."""
    cells = 1 if quick else 5
    skel = generate_lattice("octet", (cells, cells, cells), 2.0, 0.12, radius_top=0.3)
    lo, hi, px, h = octet_box(cells, pixels, layers)
    grid = make_grid(skel.support_bounds(), px, layer_height=h, bounds=(lo, lo, lo, hi, hi, hi))
    return skel, grid


def job_grid(job: str, quick: bool):
    pixels, layers = SIZES[job][1 if quick else 0]
    if job == "octet":
        return _octet_grid(pixels, layers, quick)
    return _sample_grid({"jelly": "jellyfish", "micro": "microstructure"}[job], pixels, layers)


def _layers_key(res) -> tuple:
    return res.pix.tobytes(), res.k0.tobytes(), res.k1.tobytes()


def measure(jobs, buckets, repeat: int, threads: int, quick: bool, log=print) -> list[dict]:
    rows = []
    for job in jobs:
        skel, grid = job_grid(job, quick)
        trace(skel, grid.sub(0, 0, 0, min(grid.width, 8), min(grid.height, 8), grid.layers), threads=threads)
        runs = {b: [] for b in buckets}
        evals = {}
        ref = None
        for _ in range(repeat):
            for b in buckets:
                t0 = time.perf_counter()
                res = trace(skel, grid, bucket=b, threads=threads)
                runs[b].append(time.perf_counter() - t0)
                evals[b] = int(res.stats["evaluations"])
                key = _layers_key(res)
                if ref is None:
                    ref = key
                elif key != ref:
                    raise RuntimeError(f"{job}: the layers of bucket {b} differ from those of bucket {buckets[0]}")
        for b in buckets:
            rows.append({"job": job, "bucket": b, "size": [grid.width, grid.height, grid.layers],
                         "threads": threads, "runs_seconds": [round(s, 4) for s in runs[b]],
                         "median_seconds": round(statistics.median(runs[b]), 4), "evaluations": evals[b]})
            log(f"{job} bucket {b}: {rows[-1]['median_seconds']} s")
    return rows


def table(rows) -> str:
    out = ["| job | size | bucket | median s | vs first | evaluations |", "|---|---|---|---|---|---|"]
    first = {}
    for r in rows:
        base = first.setdefault(r["job"], r["median_seconds"])
        size = " x ".join(map(str, r["size"]))
        out.append(f"| {r['job']} | {size} | {r['bucket']} | {r['median_seconds']:.3f} | "
                   f"{r['median_seconds'] / base:.2f} | {r['evaluations']:,} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", nargs="+", choices=sorted(SIZES), default=["jelly", "micro", "octet"])
    ap.add_argument("--buckets", nargs="+", type=int, default=[64, 32, 16])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="tiny grids: a smoke test")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    if a.repeat < 1 or a.threads < 1 or any(b < 1 for b in a.buckets):
        ap.error("--repeat, --threads and every bucket must be >= 1")
    rows = measure(a.jobs, a.buckets, a.repeat, a.threads, a.quick)
    res = {"benchmark": "bucket_size", "command": machine.command_line("python benchmarks/bucket_size.py", argv),
           "machine": machine.describe(), "quick": a.quick, "repeat": a.repeat, "rows": rows}
    machine.publish(res, table(rows), a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
