"""Where the tracer's primitive evaluations go, and what sharing work between columns could save.

Usage::

    python benchmarks/coherence_model.py [--scene octet|micro|SCENE.json] [--windows N] [--size S]
                                         [--quick] [--json out.json]

The interval tracer classifies each pixel column on its own. Neighbouring
columns cross the surface at nearly the same heights, so a column could start
from its neighbour's crossings. Before building such a walk, this script models
it, and the alternatives, on sampled windows of ``S x S`` columns (all layers),
counting primitive evaluations exactly as the tracer counts them (one per
point and per primitive whose support holds the point). Rows:

``today``
    The tracer as shipped (:func:`slicer.tracer.slicing.trace`, one thread),
    and its lazy walk (``lazy=True``): evaluations and seconds.
``floor``
    The two voxel centres on either side of each crossing, evaluated once: what
    any walk that decides every centre by the field's value must pay, however
    well it predicts the crossings.
``cuts``
    Today's cut points alone (every support entry and exit, every member's
    t* with a bound on the ray of at least 0.2), in the clusters whose bounds
    reach 1: what proving the stretches between crossings costs today.
``bounds``
    No cut points: each cluster is one piece, bounded from its ends
    (:func:`slicer._kernels.rays.walk.prim_bound`), split where the bound is
    ambiguous (at the Hermite estimate when the ends bracket a crossing,
    outside at the strongest member's t*, inside in the middle).
``coherent``
    ``bounds``, started from the left neighbour's crossings: the two centres
    around each of them are evaluated first, a pair of one class walks up to
    three centres toward the crossing, and the stretches between are proven by
    the same bounds. The first column of a row has no neighbour and walks as
    ``bounds``.
``boxes``
    Settling 3-D boxes before any column is walked, as an octree does: boxes
    of ``16 x 16`` columns by 32 layers, bounded over their circumscribed ball
    (:func:`slicer._kernels.meshing.ballbounds.ball_bounds`), split in eight
    while ambiguous down to ``2 x 2 x 4`` voxels, whose centres are then
    evaluated (values only). Its seconds (one thread) are compared with
    today's.

Each modelled walk must classify every centre as the tracer does (the
``mismatched columns`` count; the script fails otherwise). The modelled walks
run in Python over the compiled field and bound functions, so only their
evaluation counts are meaningful, not their time.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from speed import octet_box  # noqa: E402

from slicer.constants import PAD  # noqa: E402
from slicer.model.field import point_grid  # noqa: E402
from slicer.scene.lattice import generate_lattice  # noqa: E402
from slicer.scene.read import load_scene  # noqa: E402
from slicer.tracer.buckets import build_buckets  # noqa: E402
from slicer.tracer.grid import make_grid  # noqa: E402
from slicer.tracer.slicing import trace  # noqa: E402
from slicer._kernels.field.points import field_at_points  # noqa: E402
from slicer._kernels.field.segment import SCRATCH, segment_eval  # noqa: E402
from slicer._kernels.meshing.ballbounds import ball_bounds  # noqa: E402
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT, kprime_max, ray_support  # noqa: E402
from slicer._kernels.rays.walk import first_centre, hermite_point, prim_bound  # noqa: E402
from slicer._kernels.runtime.launch import numba_threads  # noqa: E402
from validation.machine import command_line, describe, publish  # noqa: E402

#: cut points of members whose bound on the ray is below this are skipped (the tracer's WEAK_CUT)
WEAK_CUT = 0.2
#: a boundary pair of one class walks at most this many centres toward the crossing
SEARCH = 3
#: the box model: first boxes (columns, layers) and leaves (columns, layers)
TOP, LEAF = (16, 32), (2, 4)


def scene_and_grid(scene: str, quick: bool):
    """The skeleton and the full grid of a job (the octet of benchmarks/speed.py, or a sample)."""
    if scene == "octet":
        cells, pixels, layers = (1, 48, 40) if quick else (5, 513, 1008)
        skel = generate_lattice("octet", (cells,) * 3, 2.0, 0.12, radius_top=0.3)
        lo, hi, px, h = octet_box(cells, pixels, layers)
        return skel, make_grid(skel.support_bounds(), px, layer_height=h, bounds=[lo, lo, lo, hi, hi, hi])
    path = ROOT / "sample_lattices" / "microstructure.json" if scene == "micro" else Path(scene)
    skel = load_scene(path)
    lo, hi = skel.support_bounds()
    pixels, layers = (48, 48) if quick else (512, 1024)
    px = float(max(hi[:2] - lo[:2])) / pixels
    h = float(hi[2] - lo[2]) / layers
    return skel, make_grid(skel.support_bounds(), px, layer_height=h)


class Column:
    """One pixel column: its hits, and an evaluation counter with memory (a point is evaluated once)."""

    def __init__(self, model, x, y):
        self.m = model
        self.x, self.y = x, y
        ids = model.bk.ids
        hrec = np.zeros((len(ids), NHIT))
        prim = []
        for g in ids:
            b = model.bk.boxes[g]
            if x < b[0] or x > b[3] or y < b[1] or y > b[4]:
                continue
            if ray_support(model.seg, g, x, y, 0.0, 0.0, 0.0, 1.0, model.n, model.sigma, model.norm, model.kmax,
                           hrec, len(prim)):
                if hrec[len(prim), H_TOUT] > model.zlo and hrec[len(prim), H_TIN] < model.zhi:
                    prim.append(g)
        self.hrec = hrec[:len(prim)].copy()
        self.prim = prim
        self.nev = 0
        self.known = {}

    def eval(self, z):
        """Per-member values and z-slopes at height z (mm)."""
        hit = self.known.get(z)
        if hit is not None:
            return hit
        m = self.m
        f = np.zeros(len(self.prim))
        d = np.zeros(len(self.prim))
        for r, g in enumerate(self.prim):
            if self.hrec[r, H_TIN] < z < self.hrec[r, H_TOUT]:
                v, _, _, gz = segment_eval(m.seg, g, self.x, self.y, z, m.half, m.inv_s2, m.norm, True, m.scratch)
                f[r], d[r] = v, gz
                self.nev += 1
        self.known[z] = (f, d)
        return f, d

    def bounds(self, a, b):
        """The tracer's per-primitive bound of F on [a, b] from the values at its ends."""
        fa, da = self.eval(a)
        fb, db = self.eval(b)
        lo = hi = 0.0
        live = inc = dec = 0
        for r in range(len(self.prim)):
            if self.hrec[r, H_TOUT] <= a or self.hrec[r, H_TIN] >= b:
                continue
            live += 1
            lo_r, hi_r, kind = prim_bound(self.hrec, r, fa[r], fb[r], fa[r], fb[r], da[r], db[r], a, b, False)
            lo += lo_r
            hi += hi_r
            inc += kind in (0, 1)
            dec += kind in (0, -1)
        mono = 1 if inc == live else (-1 if dec == live else 0)
        return lo, hi, mono, fa.sum(), fb.sum(), da.sum(), db.sum()

    def clusters(self):
        """``[cs, ce, members]`` of overlapping supports, by entry."""
        out = []
        for r in np.argsort(self.hrec[:, H_TIN], kind="stable"):
            a, b = self.hrec[r, H_TIN], self.hrec[r, H_TOUT]
            if out and a < out[-1][1]:
                out[-1][1] = max(out[-1][1], b)
                out[-1][2].append(r)
            else:
                out.append([a, b, [r]])
        return out


class Model:
    """The window's bucket list and the kernel's constants."""

    def __init__(self, skel, win):
        self.win = win
        self.bk = build_buckets(skel, win, 0)
        self.seg = self.bk.table
        self.n, self.sigma, self.norm = skel.degree, skel.sigma, skel.normalisation
        self.kmax = kprime_max(self.n, self.sigma, self.norm)
        self.half, self.inv_s2 = self.n // 2, 1.0 / (self.sigma * self.sigma)
        self.scratch = np.empty(SCRATCH)
        self.z0, self.h, self.K = win.origin[2], win.layer_height, win.layers
        self.zlo, self.zhi = self.z0 - 0.5 * self.h, self.z0 + (self.K - 0.5) * self.h

    def centre(self, k):
        return self.z0 + k * self.h

    def k_of(self, t):
        return first_centre(t, self.z0, self.h, self.K)


def walk(model: Model, col: Column, hints=()):
    """Classify the column's centres by bounds and splits (``bounds``), after
    evaluating the centres around the neighbour's crossings ``hints``
    (``coherent``); returns the inside mask."""
    K, h = model.K, model.h
    inside = np.zeros(K, bool)
    for cs, ce, members in col.clusters():
        k0, k1 = model.k_of(cs), model.k_of(ce) - 1
        if k1 < k0:
            continue
        pts = {cs, ce}
        for kb in hints:       # kb: the first centre past a crossing; kb - 1 the last before it
            if not (k0 < kb <= k1):
                continue
            for k in (kb - 1, kb):
                pts.add(model.centre(k))
                inside[k] = col.eval(model.centre(k))[0].sum() >= 1.0
            if inside[kb - 1] == inside[kb]:   # not there: walk toward it
                f, d = col.eval(model.centre(kb))
                up = (d.sum() > 0.0) != bool(inside[kb])
                k = kb if up else kb - 1
                for _ in range(SEARCH):
                    k = k + 1 if up else k - 1
                    if not (k0 <= k <= k1):
                        break
                    pts.add(model.centre(k))
                    inside[k] = col.eval(model.centre(k))[0].sum() >= 1.0
                    if inside[k] != inside[kb]:
                        break
        pts = sorted(pts)
        stack = [(pts[i], pts[i + 1]) for i in range(len(pts) - 1)][::-1]
        while stack:
            a, b = stack.pop()
            qa, qb = model.k_of(a), model.k_of(b) - 1
            if model.centre(qa) == a:     # a centre at the left end is decided already
                qa += 1
            if qb < qa:
                continue
            lo, hi, mono, fa, fb, da, db = col.bounds(a, b)
            pad = PAD * (1.0 + abs(hi))
            if lo > 1.0 + pad:
                inside[qa:qb + 1] = True
                continue
            if hi < 1.0 - pad:
                continue
            km = (qa + qb) // 2
            if mono != 0 and (fa - 1.0) * (fb - 1.0) < 0.0:
                t = hermite_point(a, b, fa - 1.0, fb - 1.0, da, db, 0.125 * h / (b - a))
                km = min(max(int(math.floor((t - model.z0) / h + 0.5)), qa), qb)
            elif not (fa >= 1.0 and fb >= 1.0):
                best, tb = 0.0, None
                for r in members:
                    ts = col.hrec[r, H_TSTAR]
                    if a < ts < b and col.hrec[r, H_FMAX] > best:
                        best, tb = col.hrec[r, H_FMAX], ts
                if tb is not None:
                    km = min(max(int(math.floor((tb - model.z0) / h + 0.5)), qa), qb)
            zm = model.centre(km)
            inside[km] = col.eval(zm)[0].sum() >= 1.0
            stack.append((zm, b))
            stack.append((a, zm))
    return inside


def runs_of(inside):
    """``[(k0, k1), ...]``: the inside runs of a mask."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])]


def floor_evals(model, x, y, runs):
    col = Column(model, x, y)
    for a, b in runs:
        for k in (a - 1, a, b - 1, b):
            if 0 <= k < model.K:
                col.eval(model.centre(k))
    return col.nev


def cut_evals(model, x, y):
    col = Column(model, x, y)
    for cs, ce, members in col.clusters():
        if sum(col.hrec[r, H_FMAX] for r in members) < 1.0:
            continue
        for r in members:
            for t in (col.hrec[r, H_TIN], col.hrec[r, H_TOUT], col.hrec[r, H_TSTAR]):
                keep = t != col.hrec[r, H_TSTAR] or (col.hrec[r, H_FMAX] >= WEAK_CUT
                                                     and col.hrec[r, H_TIN] < t < col.hrec[r, H_TOUT])
                if keep and model.zlo - model.h < t < model.zhi + model.h:
                    col.eval(t)
    return col.nev


def box_seconds(skel, win, repeat):
    """Seconds (one thread, best of ``repeat``) of settling boxes by ball bounds and evaluating the
    leaves' centres; returns (seconds, balls, leaf centres, inside centres)."""
    seg, pg = point_grid(skel)
    n_, s_, nm = skel.degree, skel.sigma, skel.normalisation
    ox, oy, oz = win.origin
    px, py = win.pixel_size
    h, W, H, K = win.layer_height, win.width, win.height, win.layers
    zero = np.zeros((1, 3))
    ball_bounds(seg, pg.offsets, pg.ids, pg.origin, pg.cell, pg.dims, zero, np.ones(1), zero, n_, s_, nm)
    field_at_points(zero, seg, pg.offsets, pg.ids, pg.origin, pg.cell, pg.dims, n_ // 2, 1 / s_ ** 2, nm, False)
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        boxes = np.array([(i, min(i + TOP[0], W) - 1, j, min(j + TOP[0], H) - 1, k, min(k + TOP[1], K) - 1)
                          for i in range(0, W, TOP[0]) for j in range(0, H, TOP[0]) for k in range(0, K, TOP[1])],
                         np.int64)
        nball = 0
        n_in = 0
        leaves = []
        while len(boxes):
            x0, x1 = ox + boxes[:, 0] * px, ox + boxes[:, 1] * px
            y0, y1 = oy - boxes[:, 2] * py, oy - boxes[:, 3] * py
            z0, z1 = oz + boxes[:, 4] * h, oz + boxes[:, 5] * h
            c = np.stack([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2], 1)
            r = 0.5 * np.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2) * (1 + 1e-12) + 1e-12
            U, L, _, _ = ball_bounds(seg, pg.offsets, pg.ids, pg.origin, pg.cell, pg.dims, c, r, np.zeros_like(c),
                                     n_, s_, nm)
            nball += len(boxes)
            vol = (boxes[:, 1] - boxes[:, 0] + 1) * (boxes[:, 3] - boxes[:, 2] + 1) * (boxes[:, 5] - boxes[:, 4] + 1)
            n_in += int(vol[L >= 1.0].sum())
            amb = boxes[(U >= 1.0) & (L < 1.0)]
            leaf = ((amb[:, 1] - amb[:, 0] + 1) <= LEAF[0]) & ((amb[:, 5] - amb[:, 4] + 1) <= LEAF[1])
            leaves.append(amb[leaf])
            boxes = _children(amb[~leaf])
        pts = [np.stack(np.meshgrid(ox + np.arange(a, b + 1) * px, oy - np.arange(c_, d + 1) * py,
                                    oz + np.arange(e, f + 1) * h, indexing="ij"), -1).reshape(-1, 3)
               for a, b, c_, d, e, f in np.concatenate(leaves)]
        pts = np.concatenate(pts) if pts else np.zeros((0, 3))
        F = field_at_points(pts, seg, pg.offsets, pg.ids, pg.origin, pg.cell, pg.dims, n_ // 2, 1 / s_ ** 2, nm,
                            False)
        F = F[0] if isinstance(F, tuple) else F
        n_in += int((F >= 1.0).sum())
        dt = time.perf_counter() - t0
        best = dt if best is None else min(best, dt)
    return best, nball, len(pts), n_in


def _children(amb):
    """The eight (or fewer) halves of each box (z split only above the leaf height)."""
    out = []
    for i0, i1, j0, j1, k0, k1 in amb:
        im, jm, km = (i0 + i1) // 2, (j0 + j1) // 2, (k0 + k1) // 2
        zs = ((k0, km), (km + 1, k1)) if k1 - k0 + 1 > LEAF[1] else ((k0, k1),)
        for a, b in ((i0, im), (im + 1, i1)):
            for c, d in ((j0, jm), (jm + 1, j1)):
                if b >= a and d >= c:
                    out.extend((a, b, c, d, e, f) for e, f in zs)
    return np.array(out, np.int64).reshape(-1, 6)


def window(skel, grid, i0, j0, size, repeat):
    """Every count of one window of ``size x size`` columns at column ``i0``, row ``j0``."""
    win = grid.sub(i0, j0, 0, size, size, grid.layers)
    row = {"window": [int(i0), int(j0), int(size)], "columns": size * size}
    for label, lazy in (("today", False), ("today_lazy", True)):
        secs = []
        for _ in range(repeat):
            res = trace(skel, win, threads=1, lazy=lazy)
            secs.append(res.stats["trace_seconds"])
        row[label] = int(res.stats["evaluations"])
        row[label + "_seconds"] = statistics.median(secs)
    runs = {}
    for p, a, b in zip(res.pix, res.k0, res.k1):
        runs.setdefault(int(p), []).append((int(a), int(b)))
    model = Model(skel, win)
    tot = {"floor": 0, "cuts": 0, "bounds": 0, "coherent": 0}
    bad = 0
    crossings = 0
    for j in range(size):
        prev = None
        for i in range(size):
            x, y = win.origin[0] + i * win.pixel_size[0], win.origin[1] - j * win.pixel_size[1]
            truth = runs.get(j * size + i, [])
            crossings += sum((a > 0) + (b < win.layers) for a, b in truth)
            col = Column(model, x, y)
            bad += runs_of(walk(model, col)) != truth
            tot["bounds"] += col.nev
            if prev is not None:
                col = Column(model, x, y)
                bad += runs_of(walk(model, col, sorted({k for a, b in prev for k in (a, b)}))) != truth
            tot["coherent"] += col.nev
            tot["floor"] += floor_evals(model, x, y, truth)
            tot["cuts"] += cut_evals(model, x, y)
            prev = truth
    row.update(tot)
    row["crossings"] = int(crossings)
    row["mismatched_columns"] = int(bad)
    secs, nball, npts, n_in = box_seconds(skel, win, repeat)
    row.update(boxes_seconds=secs, boxes_balls=nball, boxes_leaf_centres=npts,
               boxes_inside=n_in, today_inside=int((res.k1 - res.k0).sum()))
    return row


def table(rows) -> str:
    tot = {k: sum(r[k] for r in rows) for k in ("columns", "crossings", "today", "today_lazy", "floor", "cuts",
                                                 "bounds", "coherent", "today_seconds", "today_lazy_seconds",
                                                 "boxes_seconds")}
    base = tot["today"]
    lines = ["| walk | evaluations per column | per crossing | of today's | seconds (1 thread) |",
             "|---|---|---|---|---|"]
    for key, label, secs in (("today", "today", "today_seconds"), ("today_lazy", "today, lazy walk",
                                                                   "today_lazy_seconds"),
                             ("floor", "floor: two centres per crossing", None),
                             ("cuts", "today's cut points alone", None), ("bounds", "bounds, no cut points", None),
                             ("coherent", "coherent: neighbour's crossings first", None)):
        lines.append(f"| {label} | {tot[key] / tot['columns']:.0f} | {tot[key] / max(tot['crossings'], 1):.1f} "
                     f"| {tot[key] / base:.2f} | {'%.3f' % tot[secs] if secs else '-'} |")
    lines.append(f"| boxes: ball bounds, then leaf centres | - | - | - | {tot['boxes_seconds']:.3f} "
                 f"({tot['boxes_seconds'] / tot['today_seconds']:.1f}x today's) |")
    lines.append("")
    lines.append("| window (i, j, size) | today | floor | cuts | bounds | coherent | crossings per column |")
    lines.append("|---|---|---|---|---|---|---|")
    for r in rows:
        lines.append(f"| {tuple(r['window'])} | {r['today'] / r['columns']:.0f} | {r['floor'] / r['today']:.2f} | "
                     f"{r['cuts'] / r['today']:.2f} | {r['bounds'] / r['today']:.2f} | "
                     f"{r['coherent'] / r['today']:.2f} | {r['crossings'] / r['columns']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="octet", help="octet (benchmarks/speed.py's job), micro, or a scene file")
    ap.add_argument("--windows", type=int, default=6, help="sampled windows (default 6)")
    ap.add_argument("--size", type=int, default=16, help="window edge in columns (default 16)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of the traces and the box model (median)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="a small grid, one window: a smoke test")
    ap.add_argument("--json", help="write every window's counts and the machine here")
    args = ap.parse_args(argv)
    skel, grid = scene_and_grid(args.scene, args.quick)
    size = min(args.size, grid.width, grid.height, 8 if args.quick else args.size)
    nwin = 1 if args.quick else args.windows
    rng = np.random.default_rng(args.seed)
    spots = [(int(rng.integers(0, grid.width - size + 1)), int(rng.integers(0, grid.height - size + 1)))
             for _ in range(nwin)]
    with numba_threads(1):
        for lazy in (False, True):      # load the tracer's walks once
            trace(skel, grid.sub(0, 0, 0, 4, 4, 8), threads=1, lazy=lazy)
        rows = [window(skel, grid, i, j, size, args.repeat) for i, j in spots]
    bad = sum(r["mismatched_columns"] for r in rows)
    res = {"benchmark": "coherence_model", "command": command_line("python benchmarks/coherence_model.py", argv),
           "scene": args.scene, "grid": [grid.width, grid.height, grid.layers], "quick": args.quick,
           "windows": rows, "machine": describe()}
    publish(res, table(rows), args.json)
    if bad:
        print(f"error: the modelled walks classified {bad} columns differently from the tracer", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
