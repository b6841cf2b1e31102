"""Error against run time, for every method and a sweep of its knobs.

``python -m validation.error_time`` (or ``skelslice bench --error``) slices a
sample model into layer contours with

* ``interval``, ``sampling``, ``segment``: the tracer's exact raster, then
  :mod:`slicer.contours` (root-refined vertices, chords refined to ``tol``);
* ``guaranteed``: no raster at all: :func:`slicer.contours.plane_contours`
  per layer, the layers on the threads as the contour outputs run them
  (:func:`slicer.contours.each_plane`; the adaptive quadtree settled by the field's bounds, every
  feature wider than ``tol``, vertices and chords to ``tol``);
* ``dense``: the baseline of PySLM's implicit example: the field on the pixel
  grid of every layer (:func:`slicer.model.field.evaluate`), marching squares with
  linear interpolation, no root refinement;

sweeping pixel size, layer height, contour tolerance and bucket size one at a
time around a base setting. Each run's wall time covers the whole stack
(every layer traced and contoured). Every route does the same work after its
rings: each layer becomes the MultiPolygon the contour outputs write
(:func:`slicer.contours.finish_rings`), and the layers are contoured on the
threads, one per thread, as the guaranteed contours' planes are. Its error is measured at a few fixed
heights against a fine reference: our own contours of a single layer at
``REF_PIXELS`` pixels and a 0.01 um tolerance (checked against the meshed
manifold3d reference by ``skelslice validate``):

``error_layer``
    Hausdorff distance, in the layer's plane, between the run's contour of
    the layer that covers the height and the exact contour at that layer's
    centre: the accuracy of the contours themselves.
``error_solid``
    The same against the exact contour at the height itself: what the
    printed staircase gets wrong, so layer height counts.

The result is JSON plus a log-log plot (error against time, Pareto front
marked). Timings depend on the machine and its load.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from sample_lattices import load_sample
from slicer._kernels.runtime.launch import numba_threads, serial
from slicer.contours import each_plane, finish_rings, grid_box, layer_mask, mask_rings
from slicer.model.field import evaluate
from slicer.tracer.grid import make_grid
from slicer.scale.ordered_map import map_in_order
from slicer.tracer.slicing import slice_skeleton, trace

from validation import machine
from validation.bench import _warmup
from validation.metrics import hausdorff, polygon_rings
from slicer.constants import REFERENCE_CONTOUR_TOL as REF_TOL

#: reference: pixels across the support box, contour tolerance (mm)
REF_PIXELS = 1024
#: fractions of the model's height where the error is measured
TARGETS = (0.17, 0.33, 0.5, 0.67, 0.83)

BASE = {"pixels": 128, "layers": 128, "tol": 1e-3, "bucket": 64}


def default_sweep(quick: bool = False) -> list[dict]:
    """The configurations run by default: one knob at a time around :data:`BASE`."""
    px = (64, 128) if quick else (64, 128, 256)
    cfgs = []
    for m in ("interval", "sampling", "segment"):
        cfgs += [{"method": m, **BASE, "pixels": p} for p in px]
    cfgs += [{"method": "interval", **BASE, "tol": t} for t in ((1e-2,) if quick else (1e-2, 1e-4))]
    cfgs += [{"method": "guaranteed", **BASE, "tol": t} for t in ((1e-2, 1e-3) if quick else (1e-2, 1e-3, 1e-4))]
    cfgs += [{"method": "interval", **BASE, "bucket": b} for b in ((16,) if quick else (16, 0))]
    cfgs += [{"method": "interval", **BASE, "layers": n} for n in ((64,) if quick else (64, 256))]
    dpx = (64, 128, 256) if quick else (64, 128, 256, 512)
    cfgs += [{"method": "dense", **BASE, "pixels": p, "tol": None, "bucket": None} for p in dpx]
    cfgs += [{"method": "dense", **BASE, "layers": n, "tol": None, "bucket": None}
             for n in ((64,) if quick else (64, 256))]
    return cfgs


def contour_sweep(pixels: int = 113, layers: int = 113) -> list[dict]:
    """The two contour routes on one grid (``--contours``), each at 1, 10 and
    0.1 um: the tracer's raster with root-refined contours, and the guaranteed
    contours."""
    base = {**BASE, "pixels": int(pixels), "layers": int(layers)}
    return [{**base, "method": m, "tol": t} for t in (1e-3, 1e-2, 1e-4) for m in ("interval", "guaranteed")]


def square_box(skel):
    """The square XY box over the support, and the support's z range, mm."""
    lo, hi = skel.support_bounds()
    c = 0.5 * (lo[:2] + hi[:2])
    half = 0.5 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    return (c[0] - half, c[1] - half, c[0] + half, c[1] + half), (float(lo[2]), float(hi[2]))


class Reference:
    """Exact contours at any height, cached: one fine layer per height."""

    def __init__(self, skel, pixels: int = REF_PIXELS, tol: float = REF_TOL):
        self.skel, self.tol = skel, tol
        self.box, _ = square_box(skel)
        self.px = (self.box[2] - self.box[0]) / pixels
        self.cache: dict[float, list[np.ndarray]] = {}
        self.seconds = 0.0

    def rings(self, z: float) -> list[np.ndarray]:
        z = float(z)
        if z not in self.cache:
            t0 = time.perf_counter()
            x0, y0, x1, y1 = self.box
            h = self.px
            res = slice_skeleton(self.skel, self.px, layer_height=h,
                                 bounds=(x0, y0, z - 0.5 * h, x1, y1, z + 0.5 * h))
            g = res.grid
            self.cache[z] = mask_rings(self.skel, layer_mask(res, 0), g.origin[:2], g.pixel_size, z, self.tol)
            self.seconds += time.perf_counter() - t0
        return self.cache[z]


def run_config(skel, cfg: dict, keep: set[int]) -> tuple[float, dict, dict]:
    """Slice the whole stack into contours with one configuration.

    Every route ends as the contour outputs do: each layer's MultiPolygon
    (:func:`slicer.contours.finish_rings`; vertices a chord skips within
    ``tol / 4`` dropped where there is a tolerance), and the layers' contours
    are computed on the Numba threads at once, one layer per thread
    (:func:`slicer.scale.ordered_map.map_in_order`, each layer's kernels serial), as
    :func:`slicer.contours.each_plane` computes the guaranteed contours'
    planes. The tracing itself runs on all the threads.

    Returns
    -------
    seconds : float
        Wall time of tracing (or sampling) plus contouring every layer.
    rings : dict
        Layer index -> rings, for the layers in ``keep``.
    info : dict
        Grid and counters.
    """
    (x0, y0, x1, y1), (z0, z1) = square_box(skel)
    px = (x1 - x0) / cfg["pixels"]
    h = (z1 - z0) / cfg["layers"]
    grid = make_grid(skel.support_bounds(), px, layer_height=h, bounds=(x0, y0, z0, x1, y1, z1))
    box = grid_box(grid)
    tol = cfg["tol"]
    out = {}
    st = {}
    with numba_threads(None) as workers:
        pass
    t0 = time.perf_counter()
    if cfg["method"] == "guaranteed":
        layers = each_plane(skel, grid.centres_z(), tol, box, st)
    elif cfg["method"] == "dense":
        X, Y = np.meshgrid(grid.centres_x(), grid.centres_y())
        xy = np.column_stack([X.ravel(), Y.ravel()])

        def dense_layer(z):
            with serial():
                V = evaluate(skel, np.column_stack([xy, np.full(xy.shape[0], z)]))[0].reshape(grid.height, grid.width)
                rings = mask_rings(skel, V >= 1.0, grid.origin[:2], grid.pixel_size, z, refine=False, values=V)
                return finish_rings(rings, None, box), {}

        layers = _merged(map_in_order(dense_layer, grid.centres_z(), workers, name="error-time"), st)
        st["evaluations"] = grid.n_voxels
    else:
        res = trace(skel, grid, method=cfg["method"], bucket=cfg["bucket"])
        st["evaluations"] = res.stats["evaluations"]

        def raster_layer(item):
            z, img = item
            ls: dict = {}
            with serial():
                rings = mask_rings(skel, img.astype(bool), grid.origin[:2], grid.pixel_size, z, tol, stats=ls)
                return finish_rings(rings, tol, box), ls

        items = zip(grid.centres_z(), res.iter_layers(1))
        layers = _merged(map_in_order(raster_layer, items, workers, name="error-time"), st)
    for k, (_, mp) in enumerate(layers):
        if k in keep:
            out[k] = polygon_rings(mp)
    seconds = time.perf_counter() - t0
    return seconds, out, {"grid": grid.to_dict(), **st}


def _merged(results, stats: dict):
    """``(item, mp)`` of each ``(item, (mp, counts))`` of ``results``, in order,
    the counts added to ``stats``."""
    for item, (mp, counts) in results:
        for key, v in counts.items():
            stats[key] = stats.get(key, 0) + v
        yield item, mp


def measure(skel, cfg: dict, ref: Reference, repeat: int = 1) -> dict:
    """Time and error of one configuration (best time of ``repeat`` runs)."""
    (_, _, _, _), (z0, z1) = square_box(skel)
    h = (z1 - z0) / cfg["layers"]
    targets = [z0 + f * (z1 - z0) for f in TARGETS]
    ks = [min(cfg["layers"] - 1, max(0, int(round((z - z0) / h - 0.5)))) for z in targets]
    best = None
    for _ in range(repeat):
        sec, rings, info = run_config(skel, cfg, set(ks))
        best = sec if best is None else min(best, sec)
    e_layer, e_solid = [], []
    for z, k in zip(targets, ks):
        zk = z0 + (k + 0.5) * h
        e_layer.append(hausdorff(rings[k], ref.rings(zk)))
        e_solid.append(hausdorff(rings[k], ref.rings(z)))
    return {**cfg, "seconds": best, "error_layer": max(e_layer), "error_layer_mean": float(np.mean(e_layer)),
            "error_solid": max(e_solid), "evaluations": info.get("evaluations"),
            "contour_vertices": info.get("vertices"), "pixel_size": info["grid"]["pixel_size"][0],
            "layer_height": info["grid"]["layer_height"]}


def pareto(rows: list[dict], key: str) -> list[int]:
    """Indices of the rows no other row beats on both time and ``key``."""
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["seconds"], rows[i][key]))
    front, best = [], float("inf")
    for i in order:
        if rows[i][key] < best:
            front.append(i)
            best = rows[i][key]
    return front


def sweep(model: str = "jellyfish", configs=None, quick: bool = False, repeat: int = 1, threads=None,
          progress=None, ref_pixels: int = REF_PIXELS, ref_tol: float = REF_TOL) -> dict:
    """Run the sweep; returns a JSON-ready dict (``ref_pixels``, ``ref_tol``: the reference's
    resolution and contour tolerance, mm)."""
    skel = load_sample(model)
    compile_s = _warmup()
    configs = configs or default_sweep(quick)
    ref = Reference(skel, ref_pixels, ref_tol)
    rows = []
    with numba_threads(threads) as nthreads:
        for cfg in configs:
            row = measure(skel, cfg, ref, repeat)
            rows.append(row)
            if progress:
                progress(row)
    return {"benchmark": "error_time", "model": model, "segments": skel.n_segments,
            "reference": {"pixels": ref_pixels, "tol": ref_tol, "seconds": ref.seconds,
                          "heights": sorted(ref.cache)},
            "targets": list(TARGETS), "threads": nthreads, "compile_seconds": compile_s,
            "machine": machine.describe(),
            "rows": rows, "pareto_layer": pareto(rows, "error_layer"), "pareto_solid": pareto(rows, "error_solid")}


def label(row: dict) -> str:
    if row["method"] == "dense":
        return f"dense {row['pixels']}px {row['layers']}L"
    if row["method"] == "guaranteed":
        return f"guaranteed {row['layers']}L tol {row['tol']:g}"
    return f"{row['method']} {row['pixels']}px {row['layers']}L tol {row['tol']:g} B{row['bucket']}"


def format_table(result: dict) -> str:
    head = f"{'configuration':<46}{'time s':>9}{'err layer um':>14}{'err solid um':>14}"
    lines = [f"model {result['model']} ({result['segments']} segments), threads {result['threads']}; "
             f"reference {result['reference']['pixels']} px, tol {result['reference']['tol'] * 1e3:g} um", head,
             "-" * len(head)]
    front = set(result["pareto_layer"])
    for i, r in enumerate(result["rows"]):
        lines.append(f"{label(r):<46}{r['seconds']:>9.3f}{r['error_layer'] * 1e3:>14.3f}"
                     f"{r['error_solid'] * 1e3:>14.1f}{'  *' if i in front else ''}")
    lines.append("* on the Pareto front of layer error against time")
    return "\n".join(lines)


def plot(result: dict, path) -> Path:
    """Log-log plot of error against time, one marker per method, Pareto front
    drawn; two panels (layer error, solid error)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    style = {"interval": ("o", "C0"), "sampling": ("s", "C1"), "segment": ("^", "C2"), "dense": ("D", "C3"),
             "guaranteed": ("*", "C4")}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, key, title in ((axes[0], "error_layer", "contour error in the layer plane"),
                           (axes[1], "error_solid", "error of the layer stack (staircase included)")):
        for m, (mk, col) in style.items():
            pts = [(r["seconds"], r[key] * 1e3) for r in rows if r["method"] == m]
            if pts:
                x, y = zip(*pts)
                ax.scatter(x, y, marker=mk, color=col, label=m, zorder=3)
        front = pareto(rows, key)
        fx = [rows[i]["seconds"] for i in front]
        fy = [rows[i][key] * 1e3 for i in front]
        ax.step(fx, fy, where="post", color="k", lw=1, alpha=0.6, label="Pareto front", zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time, whole stack (s)")
        ax.set_ylabel("Hausdorff error (um)")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{result['model']}: error against run time ({result['threads']} threads; "
                 f"reference {result['reference']['pixels']} px, tol {result['reference']['tol'] * 1e3:g} um)",
                 fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m validation.error_time", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="jellyfish")
    ap.add_argument("--quick", action="store_true", help="a smaller sweep")
    ap.add_argument("--repeat", type=int, default=1, help="best of N runs per configuration")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--plot", type=Path, default=None, help="write the plot here (needs matplotlib)")
    ap.add_argument("--contours", nargs=2, type=int, default=None, metavar=("PIXELS", "LAYERS"),
                    help="only the two contour routes (raster and guaranteed) on this grid")
    ap.add_argument("--ref-pixels", type=int, default=REF_PIXELS, help="pixels of the reference's sections")
    args = ap.parse_args(argv)
    configs = contour_sweep(*args.contours) if args.contours else None
    res = sweep(args.model, configs=configs, quick=args.quick, repeat=args.repeat, threads=args.threads,
                ref_pixels=args.ref_pixels,
                progress=lambda r: print(f"  {label(r)}: {r['seconds']:.3f} s, {r['error_layer'] * 1e3:.3f} um",
                                         file=sys.stderr, flush=True))
    res = {"command": machine.command_line("python -m validation.error_time", argv), **res}
    machine.publish(res, format_table(res), args.json)
    if args.plot:
        plot(res, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
