"""Transparent rendering benchmark (EG22 §5, "Ray-tracing"): the two sample
models at 700 x 700, iso view, with and without the opacity cut-off, on 1 and
2 threads; plus one bisection run per model to measure what cubic Hermite
refinement saves.

    python benchmarks/render_bench.py [--json FILE] [--size 700] [--models jellyfish microstructure]
                                      [--threads 1 2]

The first call of a process compiles (or loads) the Numba kernels; that time
is measured on a tiny image and reported apart (``jit_seconds``). Every other
time is the render alone (buckets + kernels), without writing the PNG.
The paper's GPU times (GTX 1650, 700 x 700): jellyfish 431.4 ms, microstructure
1037.1 ms.
"""
from __future__ import annotations

import argparse
import json
import time

from validation import machine

PAPER_MS = {"jellyfish": 431.4, "microstructure": 1037.1}


def run(models, size, threads, opacity, max_opacity):
    from sample_lattices import load_sample
    from slicer.render.rendering import render

    t0 = time.perf_counter()
    render(load_sample("cubic_2x2x2"), size=(8, 8))
    jit = time.perf_counter() - t0
    rows = []
    for name in models:
        skel = load_sample(name)
        for nt in threads:
            for cut in (True, False):
                t0 = time.perf_counter()
                res = render(skel, size=(size, size), view="iso", opacity=opacity,
                             max_opacity=max_opacity if cut else 1.0, threads=nt)
                wall = time.perf_counter() - t0
                rows.append({"model": name, "segments": skel.n_segments, "threads": nt, "cutoff": cut,
                             "wall_seconds": wall, **{k: res.stats[k] for k in (
                                 "seconds", "evaluations", "isolate_evaluations", "refine_evaluations",
                                 "shade_evaluations", "split_evaluations", "roots", "rays_cut", "refine", "tolerance")}})
                print(_line(rows[-1]), flush=True)
        # refinement strategy: all roots, max threads, Hermite vs bisection
        nt = max(threads)
        res = render(skel, size=(size, size), view="iso", opacity=opacity, max_opacity=1.0, threads=nt,
                     bisection=True)
        herm = next(r for r in rows if r["model"] == name and r["threads"] == nt and not r["cutoff"])
        rows.append({"model": name, "segments": skel.n_segments, "threads": nt, "cutoff": False,
                     "wall_seconds": res.stats["seconds"], **{k: res.stats[k] for k in (
                         "seconds", "evaluations", "isolate_evaluations", "refine_evaluations",
                         "shade_evaluations", "split_evaluations", "roots", "rays_cut", "refine", "tolerance")},
                     "hermite_refine_evaluations": herm["refine_evaluations"]})
        print(_line(rows[-1]), flush=True)
    return {"size": [size, size], "view": "iso", "opacity": opacity, "max_opacity": max_opacity,
            "jit_seconds": jit, "machine": machine.describe(), "paper_gpu_ms": PAPER_MS, "rows": rows}


def _line(r):
    return (f"{r['model']:<15} {r['threads']:>2} thr  cut-off {'on ' if r['cutoff'] else 'off'}  "
            f"{r['refine']:<9} {r['seconds']:8.2f} s  {r['evaluations']:>12,} evals "
            f"({r['isolate_evaluations']:,} isolate, {r['refine_evaluations']:,} refine, "
            f"{r['shade_evaluations']:,} shade)  {r['roots']:>10,} roots  {r['rays_cut']:>8,} rays cut")


def summary(out) -> str:
    rows = out["rows"]
    lines = [f"JIT compile/load (first call, tiny image): {out['jit_seconds']:.2f} s", "",
             "| model | threads | cut-off | time | evaluations | roots | rays cut | paper GPU |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["refine"] != "hermite":
            continue
        lines.append(f"| {r['model']} ({r['segments']:,}) | {r['threads']} | {'on' if r['cutoff'] else 'off'} | "
                     f"{r['seconds']:.2f} s | {r['evaluations'] / 1e6:.2f} M | {r['roots'] / 1e6:.2f} M | "
                     f"{r['rays_cut']:,} | {PAPER_MS[r['model']]:.0f} ms |")
    lines.append("")
    for r in rows:
        if r["refine"] == "bisection":
            h, b = r["hermite_refine_evaluations"], r["refine_evaluations"]
            lines.append(f"{r['model']}: refinement evaluations, Hermite {h / 1e6:.2f} M vs bisection "
                         f"{b / 1e6:.2f} M ({100 * (1 - h / b):.0f}% saved)")
    for name in PAPER_MS:
        on = [r for r in rows if r["model"] == name and r["cutoff"] and r["refine"] == "hermite"]
        off = [r for r in rows if r["model"] == name and not r["cutoff"] and r["refine"] == "hermite"]
        if on and off:
            a, b = on[-1]["evaluations"], off[-1]["evaluations"]
            lines.append(f"{name}: opacity cut-off saves {100 * (1 - a / b):.0f}% of the evaluations "
                         f"({a / 1e6:.2f} M vs {b / 1e6:.2f} M)")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None, help="Write the results to this JSON file.")
    ap.add_argument("--size", type=int, default=700)
    ap.add_argument("--models", nargs="+", default=["jellyfish", "microstructure"], choices=sorted(PAPER_MS))
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--opacity", type=float, default=0.3)
    ap.add_argument("--max-opacity", type=float, default=0.99)
    a = ap.parse_args(argv)
    out = run(a.models, a.size, a.threads, a.opacity, a.max_opacity)
    out = {"command": machine.command_line("python benchmarks/render_bench.py", argv), **out}
    print()
    print(summary(out))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)
        print(f"\nwrote {a.json}")


if __name__ == "__main__":
    main()
