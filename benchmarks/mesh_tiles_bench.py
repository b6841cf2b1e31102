"""A lattice meshed in tiles: one Numba thread against all of them, and the mesh in one piece.

Usage::

    python benchmarks/mesh_tiles_bench.py [--repeat N] [--scene NAME] [--tol MM] [--tile MM] [--json out.json]

The sample cubic_2x2x2 (10 mm) at ``--tol 0.05`` in tiles of 5 mm (27 tiles; the same job
``skelslice mesh SCENE --tile 5`` runs), with ``--threads 1`` (the tiles one after the other)
and with every thread (as many tiles at once as threads, :func:`slicer.meshing.tiles.tile_threads`),
and the same lattice in one piece. Each row: triangles, the certified bound, the median
seconds of ``--repeat`` runs, and whether the mesh is byte for byte the same as the one-thread
mesh (the one-piece row: "-", another mesh). The ratio is to the one-thread row. The kernels
are warmed first.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from sample_lattices import load_sample
from slicer._kernels.runtime.launch import cores, numba_threads
from slicer.meshing import mesh_scene
from validation import machine


def run(scene: str, tol: float, tile: float, repeat: int) -> list:
    skel = load_sample(scene)
    mesh_scene(skel, tol=tol, tile=tile)        # warm the kernels
    methods = [("tiles, 1 thread", 1, tile), (f"tiles, {cores()} threads", cores(), tile),
               (f"one piece, {cores()} threads", cores(), None)]
    rows, first = [], None
    for name, threads, size in methods:
        times, m = [], None
        for _ in range(repeat):
            with numba_threads(threads):
                start = time.perf_counter()
                m = mesh_scene(skel, tol=tol, tile=size)
                times.append(time.perf_counter() - start)
        if first is None:
            first = m
        # (the one-piece mesh is another mesh: compared with nothing)
        same = (bool(np.array_equal(m.vertices, first.vertices) and np.array_equal(m.faces, first.faces))
                if size is not None else None)
        rows.append({"method": name, "threads": threads, "tiles": len(m.stats.get("tiles", ())) or 1,
                     "triangles": int(len(m.faces)), "bound": m.bound, "seconds": statistics.median(times),
                     "runs": times, "same_as_one_thread": same})
        print(rows[-1], file=sys.stderr, flush=True)
    return rows


def table(rows: list, scene: str, tol: float) -> str:
    base = rows[0]["seconds"]
    lines = [f"{scene} at --tol {tol:g}", "",
             "| method | tiles | triangles | certified bound (mm) | median s | ratio to 1 thread | same mesh as 1 thread |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['tiles']} | {r['triangles']:,} | {r['bound']:.4g} | {r['seconds']:.1f} | "
                     f"{r['seconds'] / base:.2f} | {_same(r['same_as_one_thread'])} |")
    return "\n".join(lines)


def _same(same) -> str:
    return "-" if same is None else "yes" if same else "no"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubic_2x2x2", help="A bundled sample (default: cubic_2x2x2).")
    ap.add_argument("--tol", type=float, default=0.05, help="Tolerance, mm (default 0.05).")
    ap.add_argument("--tile", type=float, default=5.0, help="Tile width, mm (default 5).")
    ap.add_argument("--repeat", type=int, default=3, help="Runs per method (default 3).")
    ap.add_argument("--json", default=None, help="Also write the rows, command and machine here.")
    a = ap.parse_args(argv)
    rows = run(a.scene, a.tol, a.tile, a.repeat)
    res = {"benchmark": "mesh_tiles_bench", "command": machine.command_line("python benchmarks/mesh_tiles_bench.py", argv),
           "machine": machine.describe(), "scene": a.scene, "tol": a.tol, "tile": a.tile, "rows": rows}
    machine.publish(res, table(rows, a.scene, a.tol), a.json)


if __name__ == "__main__":
    sys.exit(main())
