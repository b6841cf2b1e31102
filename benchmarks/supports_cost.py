"""What supports cost against slicing, and whether they hold every island, per sample.

Usage::

    python benchmarks/supports_cost.py [--samples jellyfish cubic_2x2x2 ...] [--pixel-size 0.05]
                                       [--no-pad] [--elevation 3] [--cli] [--json out.json]

For each sample, in one process and one after the other:

``model slice``
    :func:`slicer.tracer.slicing.slice_skeleton` of the model alone at the pitch (the
    Prusa SL1S's 0.05 mm pixels and layers by default), and its islands as
    ``skelslice check`` counts them;
``supports``
    :func:`slicer.supports.supported_scene` (which slices the model and then
    the supported scene again, to re-check it);
``supported slice``
    the supported scene sliced at the same pitch, and its islands.

``bottom`` counts the model's islands that start within the printer's 10
bottom layers above its lowest layer (the first-layer artefacts of a rounded
bottom), whose largest area the JSON holds.

With ``--cli`` each sample also goes through the real entry point, as the
acceptance asks: ``skelslice check SCENE --printer prusa-sl1s --supports
auto``, and ``skelslice supports`` -> ``skelslice slice --printer
prusa-sl1s -o out.sl1s`` -> ``skelslice check out.sl1s``; the exit statuses
are listed (0: no island). Times are wall-clock seconds on whatever machine
runs it; the evaluation counts do not depend on the load.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from sample_lattices import load_sample  # noqa: E402
from slicer.tracer.slicing import slice_skeleton  # noqa: E402
from slicer.supports.build import SupportSettings, supported_scene  # noqa: E402
from slicer.supports.points import unheld_regions  # noqa: E402
from validation import machine  # noqa: E402

SAMPLES = ("jellyfish", "cubic_2x2x2", "octet_2x2x2", "bcc_3x3x3_graded", "kelvin_2x2x2", "microstructure")


#: the Prusa SL1S's bottom (faded) layers
BOTTOM_LAYERS = 10


def _timed_slice(skel, px: float, h: float):
    t0 = time.perf_counter()
    res = slice_skeleton(skel, px, None, h)
    sec = time.perf_counter() - t0
    return res, sec, unheld_regions(res, plate_held=True)


def _bottom(res, regions) -> tuple[int, float]:
    """Islands starting within the bottom layers above the lowest solid layer: count, largest area mm²."""
    first = int(res.k0.min())
    g = res.grid
    near = [len(ii) * g.pixel_size[0] * g.pixel_size[1] for k, ii, _jj in regions if k - first < BOTTOM_LAYERS]
    return len(near), max(near, default=0.0)


def measure(name: str, px: float, h: float, pad: bool, elevation: float) -> dict:
    """One sample's row (see the module docstring)."""
    model = load_sample(name)
    res, t_model, regions = _timed_slice(model, px, h)
    bottom, bottom_area = _bottom(res, regions)
    t0 = time.perf_counter()
    sup, rep = supported_scene(model, SupportSettings(pixel_size=px, layer_height=h, pad=pad, elevation=elevation))
    t_sup = time.perf_counter() - t0
    res2, t_sliced, left = _timed_slice(sup, px, h)
    return {"sample": name, "segments": model.n_segments, "islands": len(regions), "bottom_islands": bottom,
            "bottom_island_area_max": bottom_area, "supports": rep.supports,
            "kinds": {k: rep.kinds.count(k) for k in sorted(set(rep.kinds))},
            "to_model": rep.to_model, "pad_rows": rep.pad_rows, "support_struts": sup.support_segments,
            "rounds": rep.rounds, "model_slice_s": t_model, "supports_s": t_sup, "supported_slice_s": t_sliced,
            "model_evaluations": int(res.stats["evaluations"]), "supported_evaluations": int(res2.stats["evaluations"]),
            "layers": [res.grid.layers, res2.grid.layers], "islands_after": len(left)}


def _run(args, cwd) -> int:
    return subprocess.run([sys.executable, "-m", "slicer", *args], cwd=cwd, capture_output=True).returncode


def cli_row(name: str) -> dict:
    """Exit statuses of the acceptance's command chains for one sample."""
    scene = str(ROOT / "sample_lattices" / f"{name}.json")
    with tempfile.TemporaryDirectory() as tmp:
        auto = _run(["check", scene, "--printer", "prusa-sl1s", "--supports", "auto", "-q"], tmp)
        made = _run(["supports", scene, "-o", "sup.json", "--printer", "prusa-sl1s", "-q"], tmp)
        sliced = _run(["slice", "sup.json", "--printer", "prusa-sl1s", "-o", "out.sl1s", "-q"], tmp)
        checked = _run(["check", "out.sl1s", "-q"], tmp) if sliced == 0 else None
        plain = _run(["check", scene, "--printer", "prusa-sl1s", "-q"], tmp)
    return {"check": plain, "check --supports auto": auto, "supports": made, "slice": sliced,
            "check out.sl1s": checked}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", nargs="+", default=list(SAMPLES), choices=SAMPLES)
    ap.add_argument("--pixel-size", type=float, default=0.05)
    ap.add_argument("--layer-height", type=float, default=None)
    ap.add_argument("--no-pad", action="store_true")
    ap.add_argument("--elevation", type=float, default=3.0)
    ap.add_argument("--cli", action="store_true", help="Also run the acceptance's command chains (prusa-sl1s).")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    h = a.layer_height or a.pixel_size
    rows = []
    for name in a.samples:
        row = measure(name, a.pixel_size, h, not a.no_pad, a.elevation)
        if a.cli:
            row["exit"] = cli_row(name)
        rows.append(row)
        print(f"... {name} done", file=sys.stderr, flush=True)
    head = (f"{'sample':18} {'segs':>5} {'islands':>7} {'bottom':>6} {'supports':>8} {'struts':>6} {'slice s':>8} "
            f"{'supports s':>10} {'ratio':>6} {'supported slice s':>17} {'islands after':>13}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['sample']:18} {r['segments']:>5} {r['islands']:>7} {r['bottom_islands']:>6} "
                     f"{r['supports']:>8} "
                     f"{r['support_struts']:>6} {r['model_slice_s']:>8.2f} {r['supports_s']:>10.2f} "
                     f"{r['supports_s'] / r['model_slice_s']:>6.2f} {r['supported_slice_s']:>17.2f} "
                     f"{r['islands_after']:>13}")
    if a.cli:
        lines.append("")
        lines.append("exit statuses (prusa-sl1s): " + ", ".join(rows[0]["exit"]))
        for r in rows:
            lines.append(f"{r['sample']:18} " + "  ".join(f"{v!s:>3}" for v in r["exit"].values()))
    res = {"command": machine.command_line("python benchmarks/supports_cost.py", argv), "machine": machine.describe(),
           "pixel_size": a.pixel_size, "layer_height": h, "pad": not a.no_pad, "elevation": a.elevation, "rows": rows}
    machine.publish(res, "\n".join(lines), a.json)
    return res


if __name__ == "__main__":
    main()
