"""Field-evaluation throughput on a lattice-like scene.

Usage::

    python benchmarks/field_bench.py [--points N] [--repeat R] [--threads 1,2]
                                     [--cache] [--json out.json]

The scene is a graded body-centred-cubic lattice built here with plain numpy
(8 x 8 x 6 cells of 5 mm, each body centre joined to its 8 corners: 3,072
tapered struts, radius 0.35 -> 0.70 mm from bottom to top, 1.2x at the body
centres).  Two point sets: uniform in the support box, and near the surface
(r = 0.9 ... 1.1 tau(s) from random strut axes).

Reported per (threads, gradient, point set): points/s and candidate
segment-evaluations/s (the (point, segment) pairs the support grid hands to
the kernel), plus the share of those pairs whose support actually holds the
point.  JIT cost is reported apart: the first call (compile, or on-disk cache
load with --cache) against the steady state.  By default the Numba on-disk
cache is disabled so that the compile time is measured honestly.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from validation import machine


def bcc_lattice(nx=8, ny=8, nz=6, cell=5.0, r_bottom=0.35, r_top=0.70, centre_factor=1.2):
    """Graded BCC strut lattice: (nodes (n,3), segments (m,2), radii (m,2))."""
    ii, jj, kk = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
    corners = np.stack([ii, jj, kk], -1).reshape(-1, 3) * cell
    ci, cj, ck = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    cidx = np.stack([ci, cj, ck], -1).reshape(-1, 3)
    centres = (cidx + 0.5) * cell
    nodes = np.concatenate([corners.astype(float), centres])
    height = nz * cell
    node_r = r_bottom + (r_top - r_bottom) * nodes[:, 2] / height
    n_corner = corners.shape[0]
    node_r[n_corner:] *= centre_factor

    def corner_id(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    segs = []
    for c, (i, j, k) in enumerate(cidx):
        for di in (0, 1):
            for dj in (0, 1):
                for dk in (0, 1):
                    segs.append((n_corner + c, corner_id(i + di, j + dj, k + dk)))
    segs = np.array(segs, dtype=np.int64)
    return nodes, segs, node_r[segs]


def near_surface_points(rng, nodes, segs, radii, n):
    a = nodes[segs[:, 0]]
    b = nodes[segs[:, 1]]
    j = rng.integers(0, len(segs), n)
    s = rng.uniform(0, 1, n)
    D = b[j] - a[j]
    u = D / np.linalg.norm(D, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    v -= np.sum(v * u, axis=1, keepdims=True) * u
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    tau = radii[j, 0] + s * (radii[j, 1] - radii[j, 0])
    return a[j] + s[:, None] * D + v * (tau * rng.uniform(0.9, 1.1, n))[:, None]


def candidate_pairs(points, grid):
    """Sum over points of the length of their grid cell's segment list."""
    idx = np.floor((points - grid.origin) / grid.cell).astype(np.int64)
    ok = np.all((idx >= 0) & (idx < grid.dims), axis=1)
    c = (idx[:, 2] * grid.dims[1] + idx[:, 1]) * grid.dims[0] + idx[:, 0]
    counts = np.diff(grid.offsets)
    return int(counts[c[ok]].sum())


def supported_pairs(points, table, grid, inv_s2):
    from numba import njit

    from slicer._kernels.field.segment import support_interval

    @njit
    def count(points, seg, offsets, ids, origin, cell, dims, inv_s2):
        n = 0
        for p in range(points.shape[0]):
            ix = int(np.floor((points[p, 0] - origin[0]) / cell[0]))
            iy = int(np.floor((points[p, 1] - origin[1]) / cell[1]))
            iz = int(np.floor((points[p, 2] - origin[2]) / cell[2]))
            if ix < 0 or iy < 0 or iz < 0 or ix >= dims[0] or iy >= dims[1] or iz >= dims[2]:
                continue
            c = (iz * dims[1] + iy) * dims[0] + ix
            for r in range(offsets[c], offsets[c + 1]):
                ta, tb, _, _ = support_interval(seg, ids[r], points[p, 0], points[p, 1], points[p, 2], inv_s2)
                if tb > ta:
                    n += 1
        return n

    return int(count(points, table, grid.offsets, grid.ids, grid.origin, grid.cell, grid.dims, inv_s2))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=50_000, help="points per set (default 50,000)")
    ap.add_argument("--repeat", type=int, default=3, help="timed repeats, best kept (default 3)")
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts (default 1,2)")
    ap.add_argument("--cache", action="store_true", help="use the Numba on-disk cache (default: off)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)

    if not args.cache:
        os.environ["SKELSLICE_NUMBA_CACHE"] = "0"   # read by slicer._jit at import
    t_import = time.perf_counter()
    import numba

    from slicer import Skeleton
    from slicer.model.field import evaluate, point_grid
    t_import = time.perf_counter() - t_import

    rng = np.random.default_rng(args.seed)
    nodes, segs, radii = bcc_lattice()
    skel = Skeleton(nodes, segs, radii)
    lo, hi = skel.support_bounds()
    sets = {
        "uniform": rng.uniform(lo, hi, (args.points, 3)),
        "near-surface": near_surface_points(rng, nodes, segs, radii, args.points),
    }

    # ---- JIT / setup cost, measured apart
    t = time.perf_counter()
    table, grid = point_grid(skel)
    t_grid_first = time.perf_counter() - t
    small = sets["uniform"][:1000]
    t = time.perf_counter()
    evaluate(skel, small, gradient=True)
    t_first = time.perf_counter() - t
    t = time.perf_counter()
    evaluate(skel, small, gradient=True)
    t_steady = time.perf_counter() - t

    pairs = {k: candidate_pairs(p, grid) for k, p in sets.items()}
    useful = {k: supported_pairs(p, table, grid, 1.0 / skel.sigma**2) for k, p in sets.items()}

    rows = []
    max_threads = numba.config.NUMBA_NUM_THREADS
    for nt in [int(x) for x in args.threads.split(",")]:
        if nt > max_threads:
            print(f"skipping {nt} threads (NUMBA_NUM_THREADS = {max_threads})", file=sys.stderr)
            continue
        numba.set_num_threads(nt)
        for grad in (False, True):
            for name, pts in sets.items():
                best = np.inf
                for _ in range(args.repeat):
                    t = time.perf_counter()
                    evaluate(skel, pts, gradient=grad)
                    best = min(best, time.perf_counter() - t)
                rows.append({
                    "threads": nt, "gradient": grad, "points": name, "n_points": len(pts),
                    "seconds": best, "points_per_s": len(pts) / best,
                    "candidate_pairs": pairs[name], "pair_evals_per_s": pairs[name] / best,
                    "supported_share": useful[name] / max(pairs[name], 1),
                })

    print(f"scene: {skel.n_segments} struts, {skel.n_nodes} nodes; grid {grid.dims.tolist()} cells of "
          f"{np.round(grid.cell, 3).tolist()} mm, {grid.ids.size} binned entries")
    print(f"on-disk cache {'on' if args.cache else 'off'}; {machine.summary()}")
    print(f"import slicer+numba {t_import:.2f} s | grid build (first call, incl. JIT of binning) "
          f"{t_grid_first:.2f} s | field first call (1,000 pts, incl. JIT) {t_first:.2f} s | "
          f"steady {t_steady * 1e3:.1f} ms -> JIT ~{t_first - t_steady:.2f} s")
    hdr = f"{'threads':>7} {'grad':>5} {'points':>13} {'n':>8} {'time s':>8} {'points/s':>11} " \
          f"{'pairs/pt':>8} {'pair-evals/s':>13} {'in support':>10}"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(f"{r['threads']:>7} {str(r['gradient']):>5} {r['points']:>13} {r['n_points']:>8} "
              f"{r['seconds']:>8.3f} {r['points_per_s']:>11.3e} {r['candidate_pairs'] / r['n_points']:>8.1f} "
              f"{r['pair_evals_per_s']:>13.3e} {r['supported_share']:>9.1%}")
    if args.json:
        out = {
            "command": machine.command_line("python benchmarks/field_bench.py", argv),
            "machine": machine.describe(),
            "scene": {"struts": skel.n_segments, "nodes": skel.n_nodes, "grid_dims": grid.dims.tolist(),
                      "cell_mm": grid.cell.tolist()},
            "cache": bool(args.cache),
            "jit": {"import_s": t_import, "grid_first_s": t_grid_first, "field_first_call_s": t_first,
                    "field_steady_s": t_steady, "jit_estimate_s": t_first - t_steady},
            "rows": rows,
        }
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
