"""Where a trace or a render spends its time, kernel function by kernel function (Linux ``perf``).

Usage::

    python benchmarks/kernel_profile.py [--job trace] [--model microstructure] [--pixels 256] [--layers 512]
                                        [--threads 1] [--frequency 999] [--json out.json]
    python benchmarks/kernel_profile.py --job render --pixels 700      # the renderer, iso view
    python benchmarks/kernel_profile.py --job contours --model octet_2x2x2 --pixels 113 --layers 113
    python benchmarks/kernel_profile.py --model octet.json --pixels 256 --layers 504   # any scene file

``perf`` samples Numba's machine code as anonymous memory: it cannot name the
functions. This script runs the job in a child process under ``perf record``;
the child compiles the kernels afresh (Numba's cache off: functions loaded from
the cache carry no symbol table), runs the job once, writes
``/tmp/perf-<pid>.map`` (the address range of every compiled function of
:mod:`slicer._kernels`, the file ``perf report`` reads for JIT code) and runs
it again. The table gives each kernel function's share of the samples that
fell in compiled kernels (functions inlined into their callers count as their
callers), the JIT code's share of all samples (the rest is mostly compiling)
and the seconds of the second run. Shares of sampled time, so a function's
share includes the memory stalls of its loads; both runs are sampled, so a
job of a few seconds gives a few thousand samples in the kernels.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import pkgutil
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from validation import machine

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: a perf report line: "  12.34%  symbol" (``--sort sym``, the ``[.]`` marker optional)
_LINE = re.compile(r"^\s*([0-9.]+)%\s+(?:\[\.\]\s+)?(\S+)")


def kernel_name(symbol: str) -> str | None:
    """``module.function`` of a Numba symbol of :mod:`slicer._kernels`
    (``_ZN6slicer8_kernels5trace18trace_ray_intervalB3v20B...`` ->
    ``trace.trace_ray_interval``), ``NRT_incref``-style runtime names as they
    are, None for anything else."""
    if symbol.startswith("NRT_"):
        return symbol
    if not symbol.startswith("_ZN"):
        return None
    parts, i = [], 3
    while i < len(symbol) and symbol[i].isdigit():
        j = i
        while symbol[j].isdigit():
            j += 1
        n = int(symbol[i:j])
        parts.append(symbol[j:j + n])
        i = j + n
    if parts[:2] != ["slicer", "_kernels"] or len(parts) < 4:
        return None
    return ".".join(parts[2:4])


def kernel_shares(report: str) -> tuple[dict[str, float], float]:
    """Per kernel function, its share of the kernels' samples (summed over
    specialisations), and the kernels' share of all samples, from the text of
    ``perf report --sort sym --stdio``."""
    per: dict[str, float] = {}
    for line in report.splitlines():
        m = _LINE.match(line)
        if not m:
            continue
        name = kernel_name(m.group(2))
        if name is not None:
            per[name] = per.get(name, 0.0) + float(m.group(1))
    total = sum(per.values())
    if total <= 0.0:
        return {}, 0.0
    return {k: v / total for k, v in sorted(per.items(), key=lambda kv: -kv[1])}, total / 100.0


def _write_map(path: Path) -> int:
    """The perf map of every compiled function of :mod:`slicer._kernels`; returns their count."""
    from numba.core.registry import CPUDispatcher

    import slicer._kernels as kernels

    syms = set()
    for info in pkgutil.iter_modules(kernels.__path__):
        mod = importlib.import_module(f"slicer._kernels.{info.name}")
        for obj in vars(mod).values():
            if not isinstance(obj, CPUDispatcher):
                continue
            for cres in obj.overloads.values():
                lib = cres.library
                for f in lib._final_module.functions:
                    if not f.is_declaration:
                        addr = lib.get_pointer_to_function(f.name)
                        if addr:
                            syms.add((addr, f.name))
    rows = sorted(syms)
    with open(path, "w") as fh:
        for k, (addr, name) in enumerate(rows):
            size = rows[k + 1][0] - addr if k + 1 < len(rows) else 1 << 16
            fh.write(f"{addr:x} {min(size, 1 << 20):x} {name}\n")
    return len(rows)


def _child(args) -> None:
    from sample_lattices import load_sample
    from slicer.scene.read import load_scene

    skel = load_scene(args.model) if args.model.endswith(".json") else load_sample(args.model)
    if args.job == "render":
        from slicer.render.rendering import render

        def job():
            return render(skel, size=(args.pixels, args.pixels), view="iso")

        size = [args.pixels, args.pixels]
    elif args.job == "contours":
        from slicer.contours import each_plane, grid_box
        from slicer.tracer.grid import make_grid

        lo, hi = skel.support_bounds()
        grid = make_grid(skel.support_bounds(), max(hi[0] - lo[0], hi[1] - lo[1]) / args.pixels,
                         layer_height=(hi[2] - lo[2]) / args.layers)

        class _Res:
            stats: dict

        def job():
            res = _Res()
            res.stats = {}
            for _ in each_plane(skel, grid.centres_z(), 1e-3, grid_box(grid), res.stats):
                pass
            return res

        size = [grid.width, grid.height, grid.layers]
    else:
        from slicer.tracer.grid import make_grid
        from slicer.tracer.slicing import trace

        lo, hi = skel.support_bounds()
        grid = make_grid(skel.support_bounds(), max(hi[0] - lo[0], hi[1] - lo[1]) / args.pixels,
                         layer_height=(hi[2] - lo[2]) / args.layers)

        def job():
            return trace(skel, grid, method="interval")

        size = [grid.width, grid.height, grid.layers]
    job()
    n = _write_map(Path(f"/tmp/perf-{os.getpid()}.map"))
    t0 = time.perf_counter()
    res = job()
    print(json.dumps({"seconds": time.perf_counter() - t0, "evaluations": int(res.stats["evaluations"]),
                      "functions": n, "grid": size, "pid": os.getpid()}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/kernel_profile.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--job", choices=("trace", "render", "contours"), default="trace",
                    help="trace (slicing, --pixels x --pixels x --layers), render (--pixels square, iso view) "
                         "or contours (the guaranteed contours, tol 1 um, of the --layers planes of that grid)")
    ap.add_argument("--model", default="microstructure",
                    help="a sample's name, or a scene file (.json), e.g. the octet lattice of benchmarks/speed.py")
    ap.add_argument("--pixels", type=int, default=256)
    ap.add_argument("--layers", type=int, default=512)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--frequency", type=int, default=999, help="perf samples per second")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(args)
        return 0
    if shutil.which("perf") is None:
        print("kernel_profile: needs Linux perf on PATH", file=sys.stderr)
        return 2
    env = dict(os.environ, SKELSLICE_NUMBA_CACHE="0", NUMBA_NUM_THREADS=str(args.threads),
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        child = subprocess.run(["perf", "record", "-q", "-F", str(args.frequency), "-o", str(data), "--",
                                sys.executable, str(Path(__file__).resolve()), "--child", "--job", args.job, "--model", args.model,
                                "--pixels", str(args.pixels), "--layers", str(args.layers)],
                               env=env, capture_output=True, text=True)
        if child.returncode != 0:
            print(child.stderr, file=sys.stderr)
            return 1
        job = json.loads(child.stdout.strip().splitlines()[-1])
        report = subprocess.run(["perf", "report", "-i", str(data), "--sort", "sym", "--stdio"],
                                capture_output=True, text=True).stdout
    Path(f"/tmp/perf-{job['pid']}.map").unlink(missing_ok=True)
    shares, jit = kernel_shares(report)
    model = Path(args.model).name      # a scene file by its name: no local path in the results
    out = {"command": machine.command_line("python benchmarks/kernel_profile.py", argv),
           "benchmark": "kernel_profile", "job": args.job, "model": model, "grid": job["grid"], "threads": args.threads,
           "seconds": job["seconds"], "evaluations": job["evaluations"], "jit_share_of_samples": jit,
           "shares": shares, "machine": machine.describe()}
    lines = [f"{args.job} {model}, {'x'.join(map(str, job['grid']))}, {args.threads} thread(s): "
             f"{job['seconds']:.2f} s, {job['evaluations']:,} evaluations; kernels hold {jit:.1%} of all "
             f"samples (the rest: compiling)", f"{'kernel function':<40}{'share':>8}"]
    lines += [f"{name:<40}{v:>8.1%}" for name, v in shares.items() if v >= 0.002]
    machine.publish(out, "\n".join(lines), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
