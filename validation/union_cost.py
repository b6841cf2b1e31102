"""What the union blend costs against the sum: tracer work on the sample lattices.

Each sample lattice is sliced with ``--blend sum`` and ``--blend union`` at
``pixels`` pixels across its support box (optionally with spans, as
``--aa-z`` traces), and the tracer's primitive evaluations (a count of work,
independent of the machine's load), inside voxels and runs are compared.
The wall-clock trace time is reported as a hint only.

Run: ``python -m validation.union_cost [--pixels 160] [--spans] [--json FILE]``.
"""
from __future__ import annotations

import argparse
import json
import sys

from sample_lattices import SAMPLES, load_sample
from slicer.atomic import write_bytes
from slicer.tracer.slicing import slice_skeleton


def cost(name: str, pixels: int = 160, spans: bool = False) -> dict:
    """Sum against union on sample ``name``.

    Returns
    -------
    dict
        ``scene``, ``segments``, ``pixel_mm``; per blend ``evaluations``,
        ``inside_voxels``, ``runs``, ``grid`` and ``seconds`` (a hint); the
        ratios ``union_over_sum_evaluations`` and ``union_over_sum_volume``.
    """
    sk = load_sample(name)
    lo, hi = sk.support_bounds()
    px = float(max(hi - lo)) / int(pixels)
    out = {"scene": name, "segments": sk.n_segments, "pixel_mm": px, "spans": bool(spans)}
    for blend in ("sum", "union"):
        r = slice_skeleton(sk, px, blend=blend, spans=spans)
        out[blend] = {"evaluations": int(r.stats["evaluations"]), "inside_voxels": int((r.k1 - r.k0).sum()),
                      "runs": r.n_runs, "grid": [r.grid.width, r.grid.height, r.grid.layers],
                      "seconds": r.stats["trace_seconds"]}
    out["union_over_sum_evaluations"] = out["union"]["evaluations"] / out["sum"]["evaluations"]
    out["union_over_sum_volume"] = out["union"]["inside_voxels"] / out["sum"]["inside_voxels"]
    return out


def format_table(rows: list[dict]) -> str:
    lines = [f"{'lattice':<20}{'segments':>9}{'sum evals':>13}{'union evals':>13}{'union/sum':>11}{'volume u/s':>12}",
             "-" * 78]
    for r in rows:
        lines.append(f"{r['scene']:<20}{r['segments']:>9}{r['sum']['evaluations']:>13,}"
                     f"{r['union']['evaluations']:>13,}{r['union_over_sum_evaluations']:>11.3f}"
                     f"{r['union_over_sum_volume']:>12.3f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pixels", type=int, default=160)
    ap.add_argument("--spans", action="store_true", help="Trace the spans too (as --aa-z does).")
    ap.add_argument("--samples", nargs="*", default=None, help="Sample names (default: all).")
    ap.add_argument("--json", default=None, help="Write the rows here.")
    a = ap.parse_args(argv)
    rows = [cost(n, a.pixels, a.spans) for n in (a.samples or sorted(SAMPLES))]
    print(format_table(rows))
    if a.json:
        write_bytes(a.json, (json.dumps(rows, indent=1) + "\n").encode(), force=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
