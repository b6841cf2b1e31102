"""Hashes of the binary layers of every sample and every stiff-suite case, to pin the tracer's output.

Usage (the committed file was produced by release 0.1.0)::

    PYTHONPATH=<0.1.0 checkout> python benchmarks/golden_layers.py --out tests/data/golden_layers.json
    python benchmarks/golden_layers.py --check tests/data/golden_layers.json

Each entry traces one scene with the interval method (``slicer.tracer.slicing.trace``,
64-pixel buckets) on a fixed grid and hashes the inside runs (pixel, k0, k1,
as little-endian int64): equal hashes mean byte-identical binary layers. The
samples are traced over a square box around their support at ``PIXELS`` x
``PIXELS`` x ``LAYERS`` voxels, plain and with ``strict``; the stiff cases on
their own grid (``fast`` size). ``tests/test_golden.py`` recomputes the
hashes with the tree under test and compares them with the committed ones.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys

import numpy as np

import slicer
from sample_lattices import SAMPLES, load_sample
from slicer.tracer.grid import make_grid
from slicer.tracer.slicing import trace
from validation.stiff import CASES

PIXELS = 160
LAYERS = 160


def runs_hash(res) -> str:
    """SHA-256 of a result's runs: equal hashes <=> identical binary layers."""
    h = hashlib.sha256()
    for a in (res.pix, res.k0, res.k1):
        h.update(np.ascontiguousarray(a, dtype="<i8").tobytes())
    return h.hexdigest()


def sample_cases():
    """``(name, skeleton, grid, strict)`` of every sample, plain and strict."""
    for name in sorted(SAMPLES):
        skel = load_sample(name)
        lo, hi = skel.support_bounds()
        cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
        half = 0.5 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
        bounds = (cx - half, cy - half, float(lo[2]), cx + half, cy + half, float(hi[2]))
        grid = make_grid(skel.support_bounds(), 2 * half / PIXELS, layer_height=(bounds[5] - bounds[2]) / LAYERS,
                         bounds=bounds)
        yield f"sample:{name}", skel, grid, False
        yield f"sample:{name}:strict", skel, grid, True


def stiff_cases():
    """``(name, skeleton, grid, False)`` of every stiff-suite case at its fast size."""
    for case in CASES:
        st = case.build(True)
        grid = make_grid(st.skel.support_bounds(), st.pixel_size, layer_height=st.layer_height, bounds=st.bounds)
        yield f"stiff:{case.name}", st.skel, grid, False


def compute(names=None, **kwargs) -> dict:
    """Name -> {"grid": [w, h, layers], "runs": n, "sha256": hex} for the tree on ``sys.path``
    (``kwargs``: more options of ``trace``, e.g. ``lazy=True``)."""
    out = {}
    for gen in (sample_cases, stiff_cases):
        for name, skel, grid, strict in gen():
            if names is not None and name not in names:
                continue
            res = trace(skel, grid, method="interval", bucket=64, strict=strict, **kwargs)
            out[name] = {"grid": [grid.width, grid.height, grid.layers], "runs": res.n_runs,
                         "sha256": runs_hash(res)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--out", help="Write the hashes of the tree on PYTHONPATH here (JSON).")
    g.add_argument("--check", help="Compare with this file; exit 1 on a difference.")
    args = ap.parse_args(argv)
    if args.out:
        doc = {"what": "sha256 of the interval tracer's runs (pix, k0, k1 as <i8)",
               "pixels": PIXELS, "layers": LAYERS, "skelslice": slicer.__version__, "cases": compute()}
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(doc, indent=1, sort_keys=True) + "\n")
        return 0
    with open(args.check, encoding="utf-8") as fh:
        ref = json.load(fh)["cases"]
    now = compute()
    bad = sorted(k for k in ref if now.get(k) != ref[k])
    for k in bad:
        print(f"{k}: {now.get(k)} != {ref[k]}")
    missing = sorted(set(now) ^ set(ref))
    for k in missing:
        print(f"{k}: only in one of the two")
    return 1 if bad or missing else 0


if __name__ == "__main__":
    sys.exit(main())
